"""Robot model: a nominal Denavit–Hartenberg table with joint limits, as a pytree."""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core._host_method import host_method
from .._core._precision import to_device
from ._abstract import AbstractRobot
from ._nongeometric import NonGeometric, NonGeometricMixin, nongeometric_groups

__all__ = ["DHRobot", "sample_joint_angles"]

_CONVENTIONS = ("standard", "modified")


def _as_vector(name: str, values, dof: int | None) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be a 1-D sequence (one value per joint), got shape {arr.shape}")
    if dof is not None and arr.shape[0] != dof:
        raise ValueError(f"{name} has {arr.shape[0]} entries but the robot has {dof} joints")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf: {arr}")
    return arr


def replace_tool(robot, tool_mm: Sequence[float]):
    """A copy of ``robot`` (any robot type with a ``tool`` field) with another nominal tool point
    ``[3]`` mm in its last link's frame."""
    tool = to_device(np.asarray(tool_mm, dtype=np.float64))
    if tool.shape != (3,):
        raise ValueError(f"tool_mm must have 3 entries, got shape {tool.shape}")
    return eqx.tree_at(lambda r: r.tool, robot, tool)


class DHRobot(NonGeometricMixin, AbstractRobot):
    """A serial robot with revolute joints described by a nominal DH table.

    Lengths are in mm and angles in radians. Joint ``i`` (1-based, as in DH tables) has the
    link transform

    * ``convention="standard"`` (Denavit–Hartenberg, the paper's eq. 1):
      ``A_i = Rz(θ_i + q_i) · Tz(d_i) · Tx(a_i) · Rx(α_i) · Ry(β_i)``
    * ``convention="modified"`` (Craig): ``A_i = Rx(α_i) · Ry(β_i) · Tx(a_i) · Rz(θ_i + q_i) · Tz(d_i)``,
      where row ``i`` holds Craig's ``α_{i-1}, a_{i-1}``.

    ``Ry(β_i)`` is Hayati's extra rotation for nearly parallel consecutive axes (Hayati &
    Mirmirani, 1985); it is applied only at the joints listed in ``beta_joints`` and
    ``β = 0`` reduces exactly to plain DH. The flange frame is the last link frame; the tool
    point (where a draw-wire is attached, or a tracker target sits) is ``tool`` [3] mm in the
    flange frame.

    Attributes:
        alpha: ``[dof]`` link twists α (rad).
        a: ``[dof]`` link lengths a (mm).
        d: ``[dof]`` link offsets d (mm).
        theta: ``[dof]`` joint-angle offsets θ (rad); the joint angle is ``θ_i + q_i``.
        beta: ``[dof]`` nominal Hayati β (rad), usually zeros.
        q_min, q_max: ``[dof]`` joint limits (rad).
        tool: ``[3]`` nominal tool point in the flange frame (mm).
        convention: ``"standard"`` or ``"modified"`` (static).
        beta_joints: 1-based joint numbers that carry a Hayati β (static).
        name: display name (static).
        nongeometric: the non-geometric error models (joint compliance, harmonic transmission
            errors; :meth:`with_compliance`, :meth:`with_harmonics`), or ``None``.
    """

    alpha: Float[Array, " dof"]
    a: Float[Array, " dof"]
    d: Float[Array, " dof"]
    theta: Float[Array, " dof"]
    beta: Float[Array, " dof"]
    q_min: Float[Array, " dof"]
    q_max: Float[Array, " dof"]
    tool: Float[Array, " 3"]
    convention: str = eqx.field(static=True, default="standard")
    beta_joints: tuple[int, ...] = eqx.field(static=True, default=())
    name: str = eqx.field(static=True, default="robot")
    nongeometric: NonGeometric | None = None

    def __check_init__(self):
        if self.convention not in _CONVENTIONS:
            raise ValueError(f"convention must be one of {_CONVENTIONS}, got {self.convention!r}")
        dof = self.alpha.shape[0]
        for j in self.beta_joints:
            if not (1 <= j <= dof):
                raise ValueError(f"beta_joints uses 1-based joint numbers in 1..{dof}, got {j}")

    @property
    def dof(self) -> int:
        """Number of joints."""
        return int(self.alpha.shape[0])

    @classmethod
    def from_degrees(
        cls,
        *,
        alpha_deg: Sequence[float],
        a_mm: Sequence[float],
        d_mm: Sequence[float],
        theta_deg: Sequence[float],
        q_min_deg: Sequence[float] | None = None,
        q_max_deg: Sequence[float] | None = None,
        tool_mm: Sequence[float] = (0.0, 0.0, 0.0),
        beta_deg: Sequence[float] | None = None,
        convention: str = "standard",
        beta_joints: Sequence[int] = (),
        name: str = "robot",
    ) -> DHRobot:
        """Build a robot from a DH table written in degrees and mm (the usual table format).

        Joint limits default to ±180°. Arrays are stored in the default float dtype
        (float64 when x64 is enabled).
        """
        alpha = _as_vector("alpha_deg", alpha_deg, None)
        dof = alpha.shape[0]
        if dof < 1:
            raise ValueError("a robot needs at least one joint")
        a = _as_vector("a_mm", a_mm, dof)
        d = _as_vector("d_mm", d_mm, dof)
        theta = _as_vector("theta_deg", theta_deg, dof)
        beta = _as_vector("beta_deg", np.zeros(dof) if beta_deg is None else beta_deg, dof)
        q_min = _as_vector("q_min_deg", [-180.0] * dof if q_min_deg is None else q_min_deg, dof)
        q_max = _as_vector("q_max_deg", [180.0] * dof if q_max_deg is None else q_max_deg, dof)
        if np.any(q_min >= q_max):
            raise ValueError(f"joint limits need q_min < q_max, got q_min={q_min}, q_max={q_max}")
        tool = np.asarray(tool_mm, dtype=np.float64)
        if tool.shape != (3,) or not np.all(np.isfinite(tool)):
            raise ValueError(f"tool_mm must be 3 finite numbers, got {tool_mm!r}")
        r = np.deg2rad
        return cls(
            alpha=to_device(r(alpha)),
            a=to_device(a),
            d=to_device(d),
            theta=to_device(r(theta)),
            beta=to_device(r(beta)),
            q_min=to_device(r(q_min)),
            q_max=to_device(r(q_max)),
            tool=to_device(tool),
            convention=convention,
            beta_joints=tuple(int(j) for j in beta_joints),
            name=name,
        )

    def error_groups(self) -> tuple:
        """The robot's calibratable groups: DH deviations α, a, d, θ, β (``[dof]`` each), then
        any non-geometric groups (``compliance``, ``h1s``...; see :meth:`with_compliance` and
        :meth:`with_harmonics`). A measurement model adds its sensor extras after these."""
        from .._core._params import Layout

        return Layout.dh(self.dof).groups[:5] + nongeometric_groups(self)

    def with_hayati(self, *joints: int) -> DHRobot:
        """A copy with Hayati's β enabled at the given 1-based joints (β stays 0 nominally)."""
        merged = tuple(sorted(set(self.beta_joints) | {int(j) for j in joints}))
        return DHRobot(
            self.alpha, self.a, self.d, self.theta, self.beta, self.q_min, self.q_max,
            self.tool, convention=self.convention, beta_joints=merged, name=self.name,
            nongeometric=self.nongeometric,
        )

    def with_tool(self, tool_mm: Sequence[float]) -> DHRobot:
        """A copy with another nominal tool point ``[3]`` mm in the flange frame."""
        return replace_tool(self, tool_mm)

    @host_method
    def nominal_lengths(self) -> dict[str, float]:
        """``{entry: nominal value}`` (mm) of the robot's length entries: the DH ``a_i`` and
        ``d_i``. What a uniform scaling of every length of a set-up multiplies
        (:func:`jaxcal._calibration._blocks.length_scale_direction`); the tool point is the
        layout's ``tool`` group, not the robot's."""
        out = {f"a_{i + 1}": float(v) for i, v in enumerate(np.asarray(self.a, np.float64))}
        return out | {f"d_{i + 1}": float(v) for i, v in enumerate(np.asarray(self.d, np.float64))}

    @host_method
    def reach_mm(self) -> float:
        """A generous bound on the distance from the base origin to the tool point (mm)."""
        return float(
            np.sum(np.abs(np.asarray(self.a))) + np.sum(np.abs(np.asarray(self.d)))
            + np.linalg.norm(np.asarray(self.tool))
        )

    def dh_table_deg(self) -> np.ndarray:
        """The nominal table as ``[dof, 4]`` columns α/°, a/mm, d/mm, θ/° (the paper's Table I)."""
        return self.dh_rows_deg()

    def dh_rows_deg(self, deviations=None) -> np.ndarray:
        """The DH table ``[dof, 4]`` (α/°, a/mm, d/mm, θ/°, angles not wrapped) at ``deviations``
        (nominal + deviation, on the host: an eager ``jnp`` sum is a compiled program per shape);
        ``None``: the nominal table."""
        alpha, a, d, theta = (np.asarray(getattr(self, g)) if deviations is None else
                              np.asarray(getattr(self, g)) + np.asarray(getattr(deviations, g))
                              for g in ("alpha", "a", "d", "theta"))
        return np.stack([np.rad2deg(alpha), a, d, np.rad2deg(theta)], axis=1)

    def geometry_dict(self) -> dict:
        """JSON-friendly DH table: degrees/mm, limits in degrees, tool point in mm, convention
        and Hayati joints."""
        deg = lambda a: np.rad2deg(np.asarray(a, np.float64)).tolist()  # noqa: E731
        return {
            "name": self.name,
            "convention": self.convention,
            "beta_joints": list(self.beta_joints),
            "alpha_deg": deg(self.alpha),
            "a_mm": np.asarray(self.a, np.float64).tolist(),
            "d_mm": np.asarray(self.d, np.float64).tolist(),
            "theta_deg": deg(self.theta),
            "beta_deg": deg(self.beta),
            "q_min_deg": deg(self.q_min),
            "q_max_deg": deg(self.q_max),
            "tool_mm": np.asarray(self.tool, np.float64).tolist(),
        }

    def fingerprint(self) -> dict:
        """The table in rad/mm rounded to 1e-12, name, convention and Hayati joints (a sweep's
        stored chunks are reused for an equal robot)."""
        return {
            "name": self.name, "convention": self.convention, "beta_joints": list(self.beta_joints),
            **{f: np.asarray(getattr(self, f), np.float64).round(12).tolist()
               for f in ("alpha", "a", "d", "theta", "beta", "q_min", "q_max", "tool")},
        }


def sample_joint_angles(
    key: Array, robot: DHRobot, n: int, *, coverage: float = 1.0, ranges=None, dtype=None
) -> Float[Array, "n dof"]:
    """``[n, dof]`` joint angles uniform over the central ``coverage`` fraction of each range.

    ``ranges``: optional ``(lo, hi)`` pair of ``[dof]`` arrays (rad) used instead of the
    robot's joint limits.
    """
    dtype = dtype or jnp.result_type(float)
    lo, hi = (robot.q_min, robot.q_max) if ranges is None else ranges
    lo, hi = jnp.asarray(lo).astype(dtype), jnp.asarray(hi).astype(dtype)
    mid, half = (lo + hi) / 2, (hi - lo) / 2 * coverage
    return jax.random.uniform(key, (n, robot.dof), dtype, mid - half, mid + half)
