"""From a data file to what a calibration of measured data needs: the measurement model and the
sensor extras to estimate.

:func:`jaxcal.calibrate` estimates the extras it is given (``extras=``); a data file of a given
kind cannot do without some: a distance bar or contact data never fix the tool point, a
draw-wire file without a known anchor needs the anchor and the wire's zero offset, marker data
need the motion-capture frame. Each kind's own code (its ``SensorKind`` in the sensor's module:
``setup``, ``required_extras``) adds those to the ones asked for and says why in one note each.
:func:`measurement_for` builds the whole set-up of a loaded data file
(its kind, its ``#`` metadata lines as defaults: ``anchor_mm``, ``radius_mm``, ``target``,
``camera_intrinsics``, ``mount``, ``image_size_px``), exactly as ``jaxcal calibrate`` does, and
:func:`block_from_file` makes a data file a :class:`jaxcal.Block` the same way (``jaxcal plan
--with``). Their error messages name the command line's options, which the keywords stand for
(``estimate`` for ``--estimate``, ``target`` for ``--target``...).
"""

from __future__ import annotations

import dataclasses
import math
import pathlib

__all__ = ["MeasurementSetup", "block_from_file", "measurement_for"]


@dataclasses.dataclass(frozen=True)
class MeasurementSetup:
    """What :func:`measurement_for` builds from a data file: the model to calibrate with and the
    extras to estimate.

    Attributes:
        measurement: the measurement model (:class:`~jaxcal.CableLength`, :class:`~jaxcal.Position`,
            :class:`~jaxcal.Pose`, :class:`~jaxcal.Markers`, :class:`~jaxcal.SessionMarkers`,
            :class:`~jaxcal.Camera`, :class:`~jaxcal.PlaneContact`, :class:`~jaxcal.FixedPoint`
            or :class:`~jaxcal.DistanceBar`).
        estimate: the extras to estimate as ``jaxcal calibrate --estimate`` names them
            (``anchor``, ``offset``, ``tool``, ``base``): those asked for and those the data need.
        notes: one sentence per default chosen and per fact worth knowing about the data (masked
            readings, sessions), as ``jaxcal calibrate`` prints them.
    """

    measurement: object
    estimate: frozenset = frozenset()
    notes: tuple = ()

    @property
    def extras(self) -> list[str]:
        """:attr:`estimate` as :func:`jaxcal.calibrate`'s ``extras`` (``offset`` → ``cable_offset``), sorted."""
        return sorted({"offset": "cable_offset"}.get(e, e) for e in self.estimate)


def measurement_for(data, robot, *, anchor_mm=None, radius_mm: float | None = None, estimate=(), target=None,
                    camera_intrinsics=None, mount: str | None = None, path=None) -> MeasurementSetup:
    """The measurement model of a loaded data file and the extras its calibration estimates, as
    ``jaxcal calibrate`` builds them: the kind is the data's; a keyword left ``None`` takes the
    file's metadata line (``# anchor_mm:``, ``# radius_mm:``, ``# target:``,
    ``# camera_intrinsics:``, ``# mount:``; ``# image_size_px:`` always).

    * cable: the anchor given or the file's; neither: the default anchor as the start, and the
      anchor and the cable offset are estimated.
    * point: spheres (:class:`~jaxcal.FixedPoint` with radii) when ``radius_mm`` is given, the
      radius is estimated, or the file has a ``radius_mm`` line.
    * markers with session labels: a :class:`~jaxcal.SessionMarkers`; without: a
      :class:`~jaxcal.Markers` whose positions start from the data.
    * camera: a :class:`~jaxcal.Camera` with the hand-eye transform and the target pose unknown
      (started from the images); tip to tip with a ``# target_tip: NAME`` line.
    * plane, point: the planes / points from the data's labels, unknown (started from the data).
    * a ``# tip: NAME`` line (a :class:`~jaxcal.KinematicTree`): the model sees that tip
      (``tip=None`` when it is the robot's default tip, :func:`jaxcal.resolve_tip`).

    Args:
        data: a :class:`~jaxcal.Dataset` (:func:`jaxcal.load_csv`), its metadata lines in
            ``data.meta``.
        robot: the robot model (:class:`~jaxcal.DHRobot` or :class:`~jaxcal.SerialChain`).
        anchor_mm: cable data: the draw-wire anchor ``(x, y, z)`` in the base frame, mm.
        radius_mm: point data as spheres: sphere radius plus ball radius, mm (with ``"radius"``
            in ``estimate``: the value the estimate starts from).
        estimate: extras asked for, as ``jaxcal calibrate --estimate`` names them: ``anchor``,
            ``offset`` (cable), ``tool``, ``base`` (position, pose, markers), ``radius`` (point),
            ``intrinsics`` (camera); a list or a comma-separated string.
        target: camera data: ``"checkerboard:COLSxROWS:SQUARE_MM"``, a CSV file of the target
            points (columns ``x_mm, y_mm, z_mm``) or the points themselves ``[N, 3]`` mm.
        camera_intrinsics: camera data: ``fx, fy, cx, cy[, k1, k2, p1, p2[, k3]]`` (px; OpenCV's
            camera matrix and distortion), numbers or a comma-separated string.
        mount: camera data: ``"eye_in_hand"`` (default), ``"eye_to_hand"`` or ``"tip_to_tip"`` (a
            camera on one tip seeing a target on another: the file's ``# target_tip:`` line names
            the target's tip, its ``# tip:`` line the camera's; the default with that line).
        path: the file ``data`` came from: a relative target file is looked for next to it, and
            messages name it.

    Returns:
        :class:`MeasurementSetup`: the model, the extras to estimate, the notes.

    Raises:
        ValueError: an extra that does not apply to the data's kind, an option of another kind
            (an anchor for position data, a radius for plane data), a camera file without its
            target or intrinsics, a malformed metadata line, a ``# tip:`` the robot lacks. The messages name the ``jaxcal
            calibrate`` options the keywords stand for (``--anchor`` for ``anchor_mm``,
            ``--radius-mm``, ``--estimate``, ``--target``, ``--camera`` for ``camera_intrinsics``).
    """
    import numpy as np

    from .._sensors._kind import SetupOptions, sensor_kind

    if isinstance(estimate, str):
        estimate = estimate.split(",")
    estimate = {str(e).strip().lower() for e in estimate if str(e).strip()}
    if anchor_mm is not None:
        anchor_mm = [float(v) for v in np.asarray(anchor_mm, np.float64).ravel()]
        if len(anchor_mm) != 3 or not all(math.isfinite(v) for v in anchor_mm):
            raise ValueError(f"anchor_mm must be 3 finite numbers (x, y, z in mm), got {anchor_mm}")
    estimate_radius = "radius" in estimate
    estimate.discard("radius")
    options = SetupOptions(anchor_mm=None if anchor_mm is None else tuple(anchor_mm), radius_mm=radius_mm,
                           estimate_radius=estimate_radius, target=target, camera_intrinsics=camera_intrinsics,
                           mount=mount, path=path)
    kind = sensor_kind(data.kind)
    measurement, estimate, notes = kind.setup(data, robot, estimate, options)
    measurement = kind.at_file_tip(measurement, data, robot)
    if getattr(measurement, "tip", None) is not None:  # a camera sees no tool point: no group to name
        tool = f"; its tool point is the {measurement.tool_group} group" if getattr(measurement, "sees_tool_point", True) else ""
        notes = (*notes, f"the sensor sees tip {measurement.tip} (the file's '# tip:' line){tool}")
    return MeasurementSetup(measurement, frozenset(estimate), tuple(notes))


def block_from_file(data, robot, *, sigma: float | None = None, name: str | None = None):
    """A data file in hand as a :class:`jaxcal.Block` of a combined fit or plan
    (:func:`jaxcal.calibrate_blocks`, :func:`jaxcal.plan_blocks`): its kind from the file, its
    model and extras as :func:`measurement_for` builds them from the file's metadata lines.

    Args:
        data: a data file's path, or a loaded :class:`~jaxcal.Dataset`.
        robot: the robot model.
        sigma: the readings' noise σ (mm; px for camera data), or ``None``: the file's
            ``# noise_std_mm:`` (``# noise_std_px:``) line.
        name: the block's name (default: the file's name without its suffix; for a Dataset its kind).

    Returns:
        :class:`jaxcal.Block` with ``sigma`` set.

    Raises:
        ValueError: the file does not load, has another number of joints than ``robot``, holds
            marker data (their frames and positions are no block to plan with), has no σ, or its
            model cannot be built (:func:`measurement_for`); the file's own faults are prefixed
            with its path (a Dataset's: the block's name); a missing σ is asked for as
            ``jaxcal plan --with-sigma``, the keyword ``sigma``.
    """
    from .._core._csvfile import number_list
    from .._datasets._dataset import load_csv
    from .._sensors._blocks import Block
    from .._sensors._kind import sensor_kind, sensor_kinds
    from ._blocks import block_extras

    path = None
    if isinstance(data, (str, pathlib.Path)):
        path = data
        where = str(data)
        try:
            data = load_csv(path)
        except ValueError as e:
            raise ValueError(f"{where}: {e}") from None
        name = pathlib.Path(path).stem if name is None else name
    else:
        name = data.kind if name is None else name
        where = name
    kind = sensor_kind(data.kind)
    if data.dof != robot.dof:
        raise ValueError(f"{where}: {data.dof} joint columns but robot {robot.name!r} has {robot.dof} joints")
    if not kind.plannable or data.labels:
        raise ValueError(f"{where}: {kind.name} data of several sessions or markers cannot be planned with; give "
                         + ", ".join(k.name for k in sensor_kinds() if k.plannable) + " files")
    unit = kind.noise_unit
    if sigma is None:
        text = data.meta.get(f"noise_std_{unit}")
        if text is None:
            raise ValueError(f"{where}: give its noise σ ({unit}) with --with-sigma, or a '# noise_std_{unit}: …' "
                             "line in the file")
        sigma = number_list(str(text), 1, f"the file's noise_std_{unit}")[0]
    if not (sigma > 0 and math.isfinite(sigma)):
        raise ValueError(f"{where}: σ must be a finite number > 0, got {sigma}")
    setup = measurement_for(data, robot, path=None if path is None else pathlib.Path(path))
    return Block(name, setup.measurement, data, sigma=float(sigma), extras=block_extras(setup.estimate))
