"""Calibration parameters: deviations Δ from the nominal model, a free mask, flattening."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._robot import DHRobot

__all__ = ["Deviations", "ParameterSpace", "GROUPS", "EXTRA_GROUPS", "group_of"]

#: Parameter groups in the order of the flat vector, with their per-entry unit.
GROUPS: tuple[tuple[str, str], ...] = (
    ("alpha", "rad"),
    ("a", "mm"),
    ("d", "mm"),
    ("theta", "rad"),
    ("beta", "rad"),
    ("anchor", "mm"),
    ("tool", "mm"),
    ("cable_offset", "mm"),
    ("base_rotation", "rad"),
    ("base_translation", "mm"),
)
_PER_JOINT = ("alpha", "a", "d", "theta", "beta")
#: the components of the three-vector groups, as they appear in parameter names
_COMPONENTS = {
    "anchor": ("anchor_x", "anchor_y", "anchor_z"),
    "tool": ("tool_x", "tool_y", "tool_z"),
    "base_rotation": ("base_rx", "base_ry", "base_rz"),
    "base_translation": ("base_x", "base_y", "base_z"),
}
#: groups that describe the sensor/setup rather than the robot (the "extras")
EXTRA_GROUPS = ("anchor", "tool", "cable_offset", "base_rotation", "base_translation")


class Deviations(eqx.Module):
    """Deviations Δ of every calibratable quantity from its nominal value (zero = nominal).

    Calibration optimises these, which keeps the unknowns small and makes weight decay mean
    "shrink toward the nominal robot".

    Attributes:
        alpha, a, d, theta, beta: ``[dof]`` DH deviations (rad, mm, mm, rad, rad).
        anchor: ``[3]`` deviation of the draw-wire anchor from its nominal position (mm,
            base frame).
        tool: ``[3]`` deviation of the tool point from its nominal position (mm, flange frame).
        cable_offset: ``[]`` the draw-wire's zero offset (mm), added to the predicted length.
        base_rotation: ``[3]`` rotation vector (rad) correcting the orientation of the robot base
            in the sensor frame (position/pose sensors: ``R_sensor_base = exp(base_rotation)·R₀``).
        base_translation: ``[3]`` correction of the robot base origin in the sensor frame (mm):
            ``t_sensor_base = t₀ + base_translation``.
    """

    alpha: Float[Array, " dof"]
    a: Float[Array, " dof"]
    d: Float[Array, " dof"]
    theta: Float[Array, " dof"]
    beta: Float[Array, " dof"]
    anchor: Float[Array, " 3"]
    tool: Float[Array, " 3"]
    cable_offset: Float[Array, ""]
    base_rotation: Float[Array, " 3"]
    base_translation: Float[Array, " 3"]

    def __init__(self, alpha, a, d, theta, beta, anchor, tool, cable_offset, base_rotation=None,
                 base_translation=None):
        self.alpha, self.a, self.d, self.theta, self.beta = alpha, a, d, theta, beta
        self.anchor, self.tool, self.cable_offset = anchor, tool, cable_offset
        dtype = jnp.result_type(anchor)
        lead = jnp.shape(anchor)[:-1]
        self.base_rotation = jnp.zeros(lead + (3,), dtype) if base_rotation is None else base_rotation
        self.base_translation = jnp.zeros(lead + (3,), dtype) if base_translation is None else base_translation

    @classmethod
    def zeros(cls, dof: int, dtype=None) -> Deviations:
        """All-zero deviations (the nominal model) for a ``dof``-joint robot."""
        z = lambda *s: jnp.zeros(s, dtype=dtype)  # noqa: E731
        return cls(z(dof), z(dof), z(dof), z(dof), z(dof), z(3), z(3), z(), z(3), z(3))

    @property
    def dof(self) -> int:
        return int(self.alpha.shape[-1])

    def ravel(self) -> Float[Array, " 5*dof+13"]:
        """All entries as one flat vector in :data:`GROUPS` order."""
        return jnp.concatenate(
            [jnp.atleast_1d(getattr(self, g)) for g, _ in GROUPS], axis=-1
        )

    @classmethod
    def unravel(cls, flat: Float[Array, " 5*dof+13"], dof: int) -> Deviations:
        """Inverse of :meth:`ravel`."""
        parts, i = {}, 0
        for g, _ in GROUPS:
            size = dof if g in _PER_JOINT else (3 if g in _COMPONENTS else 1)
            parts[g] = flat[..., i : i + size]
            i += size
        parts["cable_offset"] = parts["cable_offset"][..., 0]
        return cls(**parts)

    def astype(self, dtype) -> Deviations:
        return Deviations(*(jnp.asarray(getattr(self, g), dtype) for g, _ in GROUPS))


def _full_names(dof: int, groups: bool = False):
    """``(names, units)`` of every entry of :meth:`Deviations.ravel` (``groups=True``: each
    entry's group instead of its unit)."""
    names, units, of = [], [], []
    for g, unit in GROUPS:
        if g in _PER_JOINT:
            new = [f"{g}_{j + 1}" for j in range(dof)]
        elif g in _COMPONENTS:
            new = list(_COMPONENTS[g])
        else:
            new = [g]
        names += new
        units += [unit] * len(new)
        of += [g] * len(new)
    return (names, of) if groups else (names, units)


def group_of(name: str) -> str:
    """The :data:`GROUPS` entry a parameter name belongs to (``"d_3"`` → ``"d"``,
    ``"base_rx"`` → ``"base_rotation"``)."""
    for g, comps in _COMPONENTS.items():
        if name in comps:
            return g
    if name == "cable_offset":
        return name
    g = name.rsplit("_", 1)[0]
    if g in _PER_JOINT:
        return g
    raise ValueError(f"unknown parameter name {name!r}")


@dataclasses.dataclass(frozen=True, eq=False)
class ParameterSpace:
    """Which deviations are free, and the map between :class:`Deviations` and a flat vector.

    A static (non-pytree) description, safe to close over in jitted code.

    Attributes:
        dof: number of joints.
        free: ``[5*dof+13]`` bool mask over :meth:`Deviations.ravel` entries.
        names: all entry names, e.g. ``"alpha_1"``, ``"d_3"``, ``"anchor_x"``, ``"cable_offset"``,
            ``"base_rx"``, ``"base_z"``.
        units: ``"rad"`` or ``"mm"`` per entry.
    """

    dof: int
    free: np.ndarray
    names: tuple[str, ...] = dataclasses.field(init=False)
    units: tuple[str, ...] = dataclasses.field(init=False)

    def __post_init__(self):
        names, units = _full_names(self.dof)
        free = np.asarray(self.free, dtype=bool)
        if free.shape != (len(names),):
            raise ValueError(f"free mask must have shape ({len(names)},), got {free.shape}")
        free.setflags(write=False)
        object.__setattr__(self, "free", free)
        object.__setattr__(self, "names", tuple(names))
        object.__setattr__(self, "units", tuple(units))

    # -- construction ---------------------------------------------------------------------
    @classmethod
    def for_robot(
        cls,
        robot: DHRobot,
        *,
        dh: bool = True,
        beta: bool = True,
        anchor: bool = False,
        tool: bool = False,
        cable_offset: bool = False,
        base: bool = False,
    ) -> ParameterSpace:
        """Free the DH deviations (all 4·dof), β at the robot's Hayati joints, and the
        optional extras (anchor position, tool point, cable zero offset, sensor-to-base frame
        ``base`` = rotation and translation, 6 parameters)."""
        dof = robot.dof
        free = np.zeros(5 * dof + 13, dtype=bool)
        for i, (n, g) in enumerate(zip(*_full_names(dof, groups=True))):
            if g in ("alpha", "a", "d", "theta"):
                free[i] = dh
            elif g == "beta":
                free[i] = beta and int(n.rsplit("_", 1)[1]) in robot.beta_joints
            else:
                free[i] = {"anchor": anchor, "tool": tool, "cable_offset": cable_offset,
                           "base_rotation": base, "base_translation": base}[g]
        return cls(dof, free)

    @classmethod
    def from_names(cls, dof: int, names: Iterable[str]) -> ParameterSpace:
        """A space whose free entries are exactly ``names`` (unknown names raise)."""
        all_names, _ = _full_names(dof)
        index = {n: i for i, n in enumerate(all_names)}
        free = np.zeros(len(all_names), dtype=bool)
        for n in names:
            if n not in index:
                raise ValueError(f"unknown parameter name {n!r}; valid names: {all_names}")
            free[index[n]] = True
        return cls(dof, free)

    def restrict(self, keep: np.ndarray) -> ParameterSpace:
        """A sub-space keeping only the currently free entries where ``keep`` ([n_free]) is true."""
        keep = np.asarray(keep, dtype=bool)
        if keep.shape != (self.n_free,):
            raise ValueError(f"keep must have shape ({self.n_free},), got {keep.shape}")
        free = np.zeros_like(self.free)
        free[self.free_index[keep]] = True
        return ParameterSpace(self.dof, free)

    # -- views ----------------------------------------------------------------------------
    @property
    def n_free(self) -> int:
        return int(self.free.sum())

    @property
    def free_index(self) -> np.ndarray:
        return np.flatnonzero(self.free)

    @property
    def free_names(self) -> tuple[str, ...]:
        return tuple(self.names[i] for i in self.free_index)

    @property
    def free_units(self) -> tuple[str, ...]:
        return tuple(self.units[i] for i in self.free_index)

    # -- maps -----------------------------------------------------------------------------
    def to_vector(self, deviations: Deviations) -> Float[Array, " p"]:
        """The free entries of ``deviations`` as a flat ``[p]`` vector."""
        return deviations.ravel()[..., self.free_index]

    def from_vector(self, x: Float[Array, " p"], base: Deviations | None = None) -> Deviations:
        """Deviations whose free entries are ``x`` ``[p]`` and the others come from ``base``
        (zeros by default)."""
        x = jnp.asarray(x)
        if x.shape[-1] != self.n_free:
            raise ValueError(f"expected {self.n_free} free parameters, got vector of shape {x.shape}")
        if base is None:
            flat = jnp.zeros(x.shape[:-1] + (self.free.size,), dtype=x.dtype)
        else:
            flat = jnp.asarray(base.ravel(), dtype=x.dtype)
        flat = flat.at[..., self.free_index].set(x)
        return Deviations.unravel(flat, self.dof)

    def __eq__(self, other) -> bool:
        return (
            isinstance(other, ParameterSpace)
            and self.dof == other.dof
            and np.array_equal(self.free, other.free)
        )

    def __hash__(self) -> int:
        return hash((self.dof, self.free.tobytes()))

    def __repr__(self) -> str:
        return f"ParameterSpace(dof={self.dof}, free={list(self.free_names)})"
