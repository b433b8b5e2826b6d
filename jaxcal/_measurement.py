"""Measurement models: what a sensor reads for given joint angles and parameters.

Each model is a small pytree with ``predict`` (the sensor reading), ``residual``
(``prediction − measured``, ``[n, m]``) and ``sample_error`` (one error per sample for the
RMSE/MEAN/MAX metrics). :func:`residuals` flattens any of them to the ``[n·m]`` vector that
least-squares solvers and gradient methods work on.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._kinematics import _chain, _tool_offset, check_joint_angles, tool_point_soa
from ._params import Deviations
from ._robot import DHRobot

__all__ = ["MeasurementModel", "CableLength", "Position", "Pose", "residuals", "predict"]


class MeasurementModel(eqx.Module):
    """Abstract base of measurement models (an ``eqx.Module``: a pytree)."""

    #: short name used in data files and on the command line.
    kind: ClassVar[str]
    #: residual entries per sample (``m``).
    size: ClassVar[int]
    #: measurement shape per sample (``()`` for a scalar).
    sample_shape: ClassVar[tuple[int, ...]]

    @abc.abstractmethod
    def predict(self, robot: DHRobot, deviations: Deviations | None, q: Float[Array, "n dof"]):
        """Predicted reading for joint angles ``q`` ``[n, dof]`` (rad)."""

    def residual(self, robot, deviations, q, y) -> Float[Array, "n m"]:
        """``prediction − measured`` as ``[n, m]`` (mm)."""
        return (self.predict(robot, deviations, q) - y).reshape(q.shape[0], self.size)

    def sample_error(self, residual: Float[Array, "n m"]) -> Float[Array, " n"]:
        """One signed (m = 1) or non-negative (m > 1, Euclidean norm) error per sample (mm)."""
        if self.size == 1:
            return residual[:, 0]
        return jnp.linalg.norm(residual, axis=-1)

    def check_measurements(self, y, n: int) -> None:
        """Raise ``ValueError`` unless ``y`` has shape ``[n, *sample_shape]`` and is finite."""
        shape = tuple(np.shape(y))
        want = (n, *self.sample_shape)
        if shape != want:
            raise ValueError(
                f"{self.kind} measurements must have shape {list(want)} for {n} samples, got {list(shape)}"
            )
        if not np.all(np.isfinite(np.asarray(y))):
            bad = np.flatnonzero(~np.isfinite(np.asarray(y)).reshape(n, -1).all(axis=1))
            raise ValueError(f"{self.kind} measurements contain NaN/inf at samples {bad[:10].tolist()}")


class CableLength(MeasurementModel):
    """Draw-wire (cable-extension) sensor: length from a fixed anchor to the tool point.

    ``L = ‖p_tool(q) − (anchor + Δanchor)‖ + cable_offset``: the paper's sensor. The anchor
    (wire exit point, base frame), the tool point where the wire attaches (flange frame) and
    the cable's zero offset can be estimated as extras through :class:`~jaxcal.Deviations`.

    Attributes:
        anchor: ``[3]`` nominal anchor position in the base frame (mm).
    """

    anchor: Float[Array, " 3"]
    kind: ClassVar[str] = "cable"
    size: ClassVar[int] = 1
    sample_shape: ClassVar[tuple[int, ...]] = ()

    def __init__(self, anchor):
        anchor = jnp.asarray(anchor)
        if anchor.shape != (3,):
            raise ValueError(f"anchor must be a [3] position in mm, got shape {anchor.shape}")
        self.anchor = anchor

    def predict(self, robot, deviations, q) -> Float[Array, " n"]:
        """Wire lengths ``[n]`` (mm)."""
        q = check_joint_angles(robot, q)
        p = tool_point_soa(robot, deviations, q)
        anchor = self.anchor.astype(q.dtype)
        offset = jnp.zeros((), q.dtype)
        if deviations is not None:
            anchor = anchor + deviations.anchor.astype(q.dtype)
            offset = deviations.cable_offset.astype(q.dtype)
        sq = sum((p[k] - anchor[k]) ** 2 for k in range(3))
        return jnp.sqrt(sq) + offset


class Position(MeasurementModel):
    """3-D position of the tool point in the base frame (e.g. a laser tracker), ``[n, 3]`` mm."""

    kind: ClassVar[str] = "position"
    size: ClassVar[int] = 3
    sample_shape: ClassVar[tuple[int, ...]] = (3,)

    def predict(self, robot, deviations, q) -> Float[Array, "n 3"]:
        q = check_joint_angles(robot, q)
        return jnp.stack(tool_point_soa(robot, deviations, q), axis=-1)


class Pose(MeasurementModel):
    """Full pose ``T_base_tool`` ``[n, 4, 4]`` (flange orientation, origin at the tool point).

    The residual per sample is ``[Δp (mm, 3), orientation_scale · δθ (3)]`` with
    ``δθ = ½ vee(R_mᵀR_p − R_pᵀR_m)`` the small-angle rotation error (rad): ``orientation_scale``
    (mm/rad) sets how many mm of position error one radian of orientation error is worth.
    ``sample_error`` is the position error norm (mm).
    """

    orientation_scale: float = eqx.field(static=True, default=1000.0)
    kind: ClassVar[str] = "pose"
    size: ClassVar[int] = 6
    sample_shape: ClassVar[tuple[int, ...]] = (4, 4)

    def predict(self, robot, deviations, q) -> Float[Array, "n 4 4"]:
        from ._kinematics import fk_pose

        return fk_pose(robot, q, deviations, tool=True)

    def residual(self, robot, deviations, q, y) -> Float[Array, "n 6"]:
        q = check_joint_angles(robot, q)
        frame = _chain(robot, deviations, q)
        p = jnp.stack(_tool_offset(robot, deviations, frame, q.dtype), axis=-1)
        Rp = jnp.stack([jnp.stack(c, -1) for c in frame[:3]], axis=-1)  # [n,3,3]
        Rm, pm = y[:, :3, :3], y[:, :3, 3]
        E = jnp.einsum("nji,njk->nik", Rm, Rp)  # R_mᵀ R_p
        w = 0.5 * jnp.stack([E[:, 2, 1] - E[:, 1, 2], E[:, 0, 2] - E[:, 2, 0], E[:, 1, 0] - E[:, 0, 1]], -1)
        return jnp.concatenate([p - pm, self.orientation_scale * w], axis=-1)

    def sample_error(self, residual):
        return jnp.linalg.norm(residual[:, :3], axis=-1)


def predict(measurement: MeasurementModel, robot: DHRobot, deviations: Deviations | None, q):
    """The sensor reading ``measurement`` predicts (same as ``measurement.predict``)."""
    return measurement.predict(robot, deviations, q)


def residuals(
    measurement: MeasurementModel,
    robot: DHRobot,
    deviations: Deviations | None,
    q: Float[Array, "n dof"],
    y,
) -> Float[Array, " n*m"]:
    """Flat residual vector ``prediction − measured``, ``[n·m]`` (mm).

    Pure and jittable; ``jax.jacfwd`` of this w.r.t. the free parameters is the
    identification Jacobian (the paper's ``U`` in eq. 5).
    """
    return measurement.residual(robot, deviations, q, y).reshape(-1)
