"""The true set-up a seed stands for, one for every sensor kind: the robot's deviations, its tool
point and the frames two kinds share, so that the files ``jaxcal simulate`` writes with one
``--seed`` (a position file, a point-contact file, a camera file, ...) can be combined in one fit.
"""

from __future__ import annotations

import jax

from .._core._params import Deviations, layout_for

__all__ = ["simulated_truth"]


def simulated_truth(key, robot, measurement=None, *, anchor_std_mm: float = 0.0,
                    cable_offset_std_mm: float = 0.0) -> Deviations:
    """The true deviations of the robot simulated from ``key`` (``jax.random.key(seed)``), the
    same whatever the sensor kind.

    * The robot's deviations: :func:`~jaxcal.draw_deviations` with the experiment's defaults
      (0.2°, 0.6 mm; a chain entry by entry) from the key :func:`jaxcal.simulate_experiment`
      draws its own from (``jax.random.split(key, 4)[0]``): a draw-wire, position, pose or
      marker file of the seed is that simulation's data, bit for bit.
    * The tool point and the sensor frame (``base_rotation``, ``base_translation``): nominal.
      Every kind sees them, so they are part of the one set-up (the contact kinds were once
      simulated with a tool ~2 mm off that the other kinds lacked, and their files of one seed
      could not be combined).
    * A sensor's own extras are the sensor's: the draw-wire's anchor and zero offset are drawn
      here with ``anchor_std_mm`` / ``cable_offset_std_mm`` (mm; ``jaxcal simulate
      --unknown-anchor``), from sub-keys of their own (the robot's deviations do not depend on
      them); planes, points, marker offsets and the camera's frames are zero here and set by
      their simulators.

    Args:
        key: ``jax.random`` key. robot: the nominal robot.
        measurement: the deviations come in ``layout_for(robot, measurement)`` (the model's own
            groups zero); ``None``: the robot's layout with the standard extras.
        anchor_std_mm, cable_offset_std_mm: σ of the draw-wire's anchor (per axis) and zero
            offset (mm).

    Returns:
        :class:`~jaxcal.Deviations`.
    """
    from ._simulate import draw_deviations

    k_dev = jax.random.split(key, 4)[0]  # simulate_experiment's deviation key
    dev = draw_deviations(k_dev, robot, anchor_std_mm=anchor_std_mm, cable_offset_std_mm=cable_offset_std_mm)
    if measurement is None:
        return dev
    layout = layout_for(robot, measurement)
    return Deviations({g: v for g, v in dev.values.items() if g in layout.group_names}, layout)
