"""Calibration parameters: deviations Δ from the nominal model as named groups, a free mask,
flattening.

Every calibratable quantity belongs to a :class:`Group` (DH errors, per-joint geometric errors
of a generic chain, sensor extras, base/tool frames, non-geometric errors...). A
:class:`Layout` is the ordered tuple of groups of one robot + measurement set-up; it fixes the
flat vector's order, entry names and units. :class:`Deviations` holds one array per group and
:class:`ParameterSpace` says which flat entries are free. Solvers, identifiability, priors,
uncertainty, sweeps, reports and the CLI see only the flat vector and the names, so adding an
error model is adding a group.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Iterable, Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._host_method import host_method
from ._precision import canonical_numpy, to_device


def _traced(*xs) -> bool:
    """Whether any of ``xs`` is a JAX tracer (inside ``jit``/``vmap``/``grad``).

    Outside a trace the bookkeeping below (zeros, ravel, gathers of free entries) runs in NumPy
    and hands the result to JAX with ``jax.device_put`` (a host-to-device copy): executed op by op
    in JAX, each is a small XLA program — ~60 per ``calibrate`` call, each compiled (or loaded
    from the persistent cache) once per process and dispatched at ~20–50 µs per call."""
    return any(isinstance(x, jax.core.Tracer) for x in xs)


__all__ = [
    "Deviations", "ParameterSpace", "Group", "Layout", "layout_for", "GROUPS", "EXTRA_GROUPS",
    "STANDARD_EXTRAS", "group_of", "group_kind",
]

_KINDS = ("geometric", "extra", "nongeometric")
#: entry name -> group name, for names that do not follow "<group>_<joint>" (vector components)
_COMPONENT_OF: dict[str, str] = {}
#: group name -> kind, for every group ever defined
_KIND_OF: dict[str, str] = {}


@dataclasses.dataclass(frozen=True)
class Group:
    """One named group of calibratable quantities.

    Attributes:
        name: group name (``"alpha"``, ``"anchor"``, ``"compliance"``, ``"marker_2"``...).
        names: flat entry names, e.g. ``("alpha_1", …, "alpha_6")`` or ``("anchor_x", …)``.
        units: one unit per entry (``"rad"``, ``"mm"``, ``"rad/(N*m)"``...).
        kind: ``"geometric"`` (the robot's geometry), ``"extra"`` (sensor / set-up: anchor,
            tool point, cable offset, sensor-to-base frame, markers) or ``"nongeometric"``
            (compliance, transmission errors).
        shape: the value's shape: ``()`` for a scalar, ``(k,)`` for ``k`` entries.
        prior_std: default prior σ of every entry in its unit (e.g. a compliance in rad/(N·m));
            ``None``: :class:`jaxcal.Prior`'s angle/length σ by unit for robot groups, none for
            extras and for other units.
    """

    name: str
    names: tuple[str, ...]
    units: tuple[str, ...]
    kind: str
    shape: tuple[int, ...]
    prior_std: float | None = None

    def __post_init__(self):
        if self.kind not in _KINDS:
            raise ValueError(f"group kind must be one of {_KINDS}, got {self.kind!r}")
        if len(self.units) != len(self.names) or math.prod(self.shape) != len(self.names):
            raise ValueError(f"group {self.name!r}: {len(self.names)} names, {len(self.units)} units, shape {self.shape}")
        _KIND_OF[self.name] = self.kind
        for n in self.names:
            if not _per_joint_name(n, self.name):
                _COMPONENT_OF[n] = self.name

    @property
    def size(self) -> int:
        return len(self.names)

    @classmethod
    def per_joint(cls, name: str, dof: int, units: str | Sequence[str], kind: str = "geometric",
                  prior_std: float | None = None) -> Group:
        """``dof`` entries named ``f"{name}_{j}"`` (``j`` = 1..dof); ``units`` one or per joint."""
        units = (units,) * dof if isinstance(units, str) else tuple(units)
        return cls(name, tuple(f"{name}_{j + 1}" for j in range(dof)), units, kind, (dof,), prior_std)

    @classmethod
    def vector(cls, name: str, components: Sequence[str], unit: str, kind: str = "extra",
               prior_std: float | None = None) -> Group:
        """A vector group whose entries are named ``components``."""
        return cls(name, tuple(components), (unit,) * len(components), kind, (len(components),), prior_std)

    @classmethod
    def scalar(cls, name: str, unit: str, kind: str = "extra", prior_std: float | None = None) -> Group:
        """A single entry named like the group."""
        return cls(name, (name,), (unit,), kind, (), prior_std)


def _per_joint_name(entry: str, group: str) -> bool:
    head, _, tail = entry.rpartition("_")
    return head == group and tail.isdigit()


#: the sensor/set-up extras every layout carries (unused ones simply stay fixed)
STANDARD_EXTRAS: tuple[Group, ...] = (
    Group.vector("anchor", ("anchor_x", "anchor_y", "anchor_z"), "mm"),
    Group.vector("tool", ("tool_x", "tool_y", "tool_z"), "mm"),
    Group.scalar("cable_offset", "mm"),
    Group.vector("base_rotation", ("base_rx", "base_ry", "base_rz"), "rad"),
    Group.vector("base_translation", ("base_x", "base_y", "base_z"), "mm"),
)
_DH_GROUPS = (("alpha", "rad"), ("a", "mm"), ("d", "mm"), ("theta", "rad"), ("beta", "rad"))
for _g, _u in _DH_GROUPS:
    _KIND_OF[_g] = "geometric"

#: The DH layout's groups in the order of the flat vector, with their per-entry unit.
GROUPS: tuple[tuple[str, str], ...] = _DH_GROUPS + tuple((g.name, g.units[0]) for g in STANDARD_EXTRAS)
#: the standard groups that describe the sensor/setup rather than the robot (the "extras")
EXTRA_GROUPS = tuple(g.name for g in STANDARD_EXTRAS)


def group_of(name: str) -> str:
    """The group a parameter name belongs to (``"d_3"`` → ``"d"``, ``"base_rx"`` →
    ``"base_rotation"``, ``"marker_2_x"`` → ``"marker_2"``); unknown names raise."""
    if name in _COMPONENT_OF:
        return _COMPONENT_OF[name]
    head, _, tail = name.rpartition("_")
    if tail.isdigit() and head in _KIND_OF:
        return head
    if name in _KIND_OF:
        return name
    raise ValueError(f"unknown parameter name {name!r}")


def group_kind(name: str) -> str:
    """``"geometric"``, ``"extra"`` or ``"nongeometric"`` for a parameter (or group) name."""
    g = name if name in _KIND_OF else group_of(name)
    return _KIND_OF[g]


@dataclasses.dataclass(frozen=True)
class Layout:
    """The ordered groups of one robot + measurement set-up: the flat vector's order, names and
    units. Static and hashable (equal layouts compare equal, so jitted code is not recompiled).

    Attributes:
        groups: the groups in flat-vector order.
        dof: number of joints of the robot.
    """

    groups: tuple[Group, ...]
    dof: int

    def __post_init__(self):
        seen: set[str] = set()
        for g in self.groups:
            if g.name in seen:
                raise ValueError(f"group {g.name!r} appears twice in the layout")
            seen.add(g.name)
        names = [n for g in self.groups for n in g.names]
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise ValueError(f"parameter names appear twice in the layout: {dup}")

    @classmethod
    def dh(cls, dof: int) -> Layout:
        """The DH layout: α, a, d, θ, β per joint, then :data:`STANDARD_EXTRAS` (made once per
        ``dof``: layouts are immutable)."""
        return _dh_layout(cls, int(dof))

    @classmethod
    def coerce(cls, layout_or_dof) -> Layout:
        if isinstance(layout_or_dof, Layout):
            return layout_or_dof
        if isinstance(layout_or_dof, (int, np.integer)):
            return cls.dh(int(layout_or_dof))
        raise TypeError(f"expected a Layout or a number of joints, got {type(layout_or_dof).__name__}")

    def extend(self, groups: Iterable[Group]) -> Layout:
        return Layout(self.groups + tuple(groups), self.dof)

    @functools.cached_property
    def names(self) -> tuple[str, ...]:
        return tuple(n for g in self.groups for n in g.names)

    @functools.cached_property
    def units(self) -> tuple[str, ...]:
        return tuple(u for g in self.groups for u in g.units)

    @functools.cached_property
    def kinds(self) -> tuple[str, ...]:
        return tuple(g.kind for g in self.groups for _ in g.names)

    @functools.cached_property
    def entry_groups(self) -> tuple[str, ...]:
        """The group name of every flat entry."""
        return tuple(g.name for g in self.groups for _ in g.names)

    @functools.cached_property
    def size(self) -> int:
        return sum(g.size for g in self.groups)

    @functools.cached_property
    def group_names(self) -> tuple[str, ...]:
        return tuple(g.name for g in self.groups)

    def group(self, name: str) -> Group:
        for g in self.groups:
            if g.name == name:
                return g
        raise KeyError(f"no group {name!r} in this layout; groups: {', '.join(self.group_names)}")

    def group_of(self, entry: str) -> str:
        for g in self.groups:
            if entry in g.names:
                return g.name
        raise ValueError(f"unknown parameter name {entry!r}; valid names: {list(self.names)}")

    def slice(self, name: str) -> slice:
        i = 0
        for g in self.groups:
            if g.name == name:
                return slice(i, i + g.size)
            i += g.size
        raise KeyError(f"no group {name!r} in this layout")


def layout_for(robot, measurement=None) -> Layout:
    """The layout of ``robot`` measured by ``measurement``: the robot's geometric groups, the
    :data:`STANDARD_EXTRAS`, the robot's non-geometric groups, then the measurement's own
    extra groups (e.g. marker positions). A DH robot with a standard sensor gives
    :meth:`Layout.dh`."""
    own = _call_method(robot, "error_groups")
    own = tuple(own) if own is not None else Layout.dh(robot.dof).groups[:5]
    meas = tuple(_call_method(measurement, "extra_groups") or ())
    geo = tuple(g for g in own if g.kind == "geometric")
    rest = tuple(g for g in own if g.kind != "geometric")
    return _cached_layout(geo + STANDARD_EXTRAS + rest + meas, robot.dof)


def _call_method(obj, name: str):
    """``obj.name()`` through the class, or ``None`` if ``obj`` (may be ``None``) has no such
    method. Reading a method off an ``equinox.Module`` instance builds a ``BoundMethod`` module
    (~15 µs); ``layout_for`` runs several times per calibration."""
    method = getattr(type(obj), name, None)
    return None if obj is None or method is None else method(obj)


#: equal group tuples give the same (immutable) Layout object: building one validates every
#: group, and ``layout_for`` runs several times per calibration
_cached_layout = functools.lru_cache(maxsize=256)(Layout)


@functools.lru_cache(maxsize=64)
def _dh_layout(cls, dof: int) -> Layout:
    return cls(tuple(Group.per_joint(g, dof, u) for g, u in _DH_GROUPS) + STANDARD_EXTRAS, dof)


class Deviations(eqx.Module):
    """Deviations Δ of every calibratable quantity from its nominal value (zero = nominal), one
    array per :class:`Group` of a :class:`Layout`.

    Calibration optimises these, which keeps the unknowns small and makes weight decay mean
    "shrink toward the nominal robot". Groups read as attributes (``dev.alpha``, ``dev.anchor``,
    ``dev.compliance``); arrays may carry leading batch axes (e.g. one row per sweep trial).

    The DH layout (:meth:`Layout.dh`) has:
        alpha, a, d, theta, beta: ``[dof]`` DH deviations (rad, mm, mm, rad, rad).
        anchor: ``[3]`` deviation of the draw-wire anchor from its nominal position (mm,
            base frame).
        tool: ``[3]`` deviation of the tool point from its nominal position (mm, flange frame).
        cable_offset: ``[]`` the draw-wire's zero offset (mm), added to the predicted length.
        base_rotation: ``[3]`` rotation vector (rad) correcting the orientation of the robot base
            in the sensor frame (position/pose sensors: ``R_sensor_base = exp(base_rotation)·R₀``).
        base_translation: ``[3]`` correction of the robot base origin in the sensor frame (mm):
            ``t_sensor_base = t₀ + base_translation``.

    Attributes:
        arrays: one array ``[*batch, *group.shape]`` per group, in layout order (a tuple, so
            that a partitioned-out static part stays hashable); :attr:`values` is the dict view.
        layout: the groups (static).
    """

    arrays: tuple[Array, ...]
    layout: Layout = eqx.field(static=True)

    def __init__(self, values: Mapping[str, Array] | None = None, layout: Layout | int | None = None, dtype=None):
        values = dict(values or {})
        if layout is None:
            raise TypeError("Deviations needs a layout (a Layout or a number of joints for the DH layout)")
        layout = Layout.coerce(layout)
        unknown = set(values) - set(layout.group_names)
        if unknown:
            raise ValueError(f"unknown parameter groups {sorted(unknown)}; this layout has {list(layout.group_names)}")
        traced = _traced(*values.values())
        asarray = jnp.asarray if traced else to_device
        lead, dt = (), dtype
        for g in layout.groups:
            if g.name in values:
                v = asarray(values[g.name], dtype)
                lead = v.shape[: v.ndim - len(g.shape)]
                dt = v.dtype if dt is None else dt
                break
        out = {}
        for g in layout.groups:
            if g.name in values:
                v = values[g.name]
                v = v if (isinstance(v, jax.Array) and not traced and v.dtype == dt) else asarray(v, dt)
                if v.shape[v.ndim - len(g.shape):] != g.shape:
                    raise ValueError(f"group {g.name!r} must have shape {list(g.shape)} (+ batch axes), got {list(v.shape)}")
                out[g.name] = v
            elif traced:
                out[g.name] = jnp.zeros(lead + g.shape, dt)
            else:
                out[g.name] = to_device(np.zeros(lead + g.shape), dt)
        self.arrays = tuple(out[g.name] for g in layout.groups)
        self.layout = layout

    @property
    def values(self) -> dict[str, Array]:
        """``{group name: array}`` in layout order."""
        return dict(zip(self.layout.group_names, self.arrays))

    def __getattr__(self, name: str):
        if name.startswith("__") or name in ("arrays", "layout", "values"):
            raise AttributeError(name)
        names = self.layout.group_names
        if name in names:
            return self.arrays[names.index(name)]
        raise AttributeError(f"Deviations has no group {name!r}; groups: {list(names)}")

    @classmethod
    def zeros(cls, layout: Layout | int, dtype=None) -> Deviations:
        """All-zero deviations (the nominal model) for a layout (or a ``dof``-joint DH robot).

        Made once per layout and dtype and then shared (deviations are immutable): building them
        puts one small array per group on the device (~0.3 ms for the DH layout), and a
        calibration asks for them several times."""
        dtype = jax.dtypes.canonicalize_dtype(jnp.result_type(float) if dtype is None else dtype)
        return _zeros(cls, Layout.coerce(layout), np.dtype(dtype))

    @classmethod
    def from_dh(cls, alpha, a, d, theta, beta, anchor, tool, cable_offset, base_rotation=None,
                base_translation=None) -> Deviations:
        """DH-layout deviations from their arrays (the order of :data:`GROUPS`)."""
        vals = dict(alpha=alpha, a=a, d=d, theta=theta, beta=beta, anchor=anchor, tool=tool, cable_offset=cable_offset)
        if base_rotation is not None:
            vals["base_rotation"] = base_rotation
        if base_translation is not None:
            vals["base_translation"] = base_translation
        return cls(vals, Layout.dh(int(jnp.shape(alpha)[-1])))

    def replace(self, **groups) -> Deviations:
        """A copy with the given groups replaced."""
        vals = dict(self.values)
        for k, v in groups.items():
            if k not in vals:
                raise ValueError(f"unknown parameter group {k!r}; groups: {list(vals)}")
            vals[k] = jnp.asarray(v, vals[k].dtype)
        return Deviations(vals, self.layout)

    @property
    def dof(self) -> int:
        return self.layout.dof

    def ravel(self) -> Float[Array, "... size"]:
        """All entries as one flat vector in layout order (``[*batch, layout.size]``)."""
        if _traced(*self.arrays):
            parts = [v.reshape(v.shape[: v.ndim - len(g.shape)] + (g.size,))
                     for g, v in zip(self.layout.groups, self.arrays)]
            return jnp.concatenate(parts, axis=-1)
        return to_device(self._ravel_numpy())

    @host_method
    def _ravel_numpy(self) -> np.ndarray:
        """:meth:`ravel` in NumPy (concrete arrays only)."""
        parts = [np.asarray(v).reshape(v.shape[: v.ndim - len(g.shape)] + (g.size,))
                 for g, v in zip(self.layout.groups, self.arrays)]
        return np.concatenate(parts, axis=-1)

    @classmethod
    def unravel(cls, flat: Float[Array, "... size"], layout: Layout | int) -> Deviations:
        """Inverse of :meth:`ravel`."""
        layout = Layout.coerce(layout)
        flat = jnp.asarray(flat) if _traced(flat) else canonical_numpy(flat)
        if flat.shape[-1] != layout.size:
            raise ValueError(f"expected a flat vector of {layout.size} entries, got shape {flat.shape}")
        parts, i = {}, 0
        for g in layout.groups:
            parts[g.name] = flat[..., i : i + g.size].reshape(flat.shape[:-1] + g.shape)
            i += g.size
        return cls(parts, layout)

    @host_method
    def astype(self, dtype) -> Deviations:
        if not _traced(*self.arrays) and all(v.dtype == jax.dtypes.canonicalize_dtype(dtype) for v in self.arrays):
            return self
        return Deviations(self.values, self.layout, dtype=dtype)

    def named(self) -> dict[str, float]:
        """``{entry name: value}`` (unbatched deviations only)."""
        return dict(zip(self.layout.names, np.asarray(self._ravel_numpy(), np.float64).tolist()))


@functools.lru_cache(maxsize=64)
def _zeros(cls, layout: Layout, dtype: np.dtype) -> Deviations:
    # concrete arrays even when first asked for inside a jit trace: a traced value kept in this
    # cache would leak into every later use (UnexpectedTracerError)
    with jax.ensure_compile_time_eval():
        return cls({}, layout, dtype=dtype)


@dataclasses.dataclass(frozen=True, eq=False)
class ParameterSpace:
    """Which deviations are free, and the map between :class:`Deviations` and a flat vector.

    A static (non-pytree) description, safe to close over in jitted code.

    Attributes:
        layout: the groups (a :class:`Layout`; a number of joints means the DH layout).
        free: ``[layout.size]`` bool mask over :meth:`Deviations.ravel` entries.
        names: all entry names, e.g. ``"alpha_1"``, ``"d_3"``, ``"anchor_x"``, ``"cable_offset"``,
            ``"base_rx"``, ``"base_z"``.
        units: unit per entry (``"rad"``, ``"mm"``...).
    """

    layout: Layout
    free: np.ndarray
    names: tuple[str, ...] = dataclasses.field(init=False)
    units: tuple[str, ...] = dataclasses.field(init=False)

    def __post_init__(self):
        layout = Layout.coerce(self.layout)
        object.__setattr__(self, "layout", layout)
        names, units = layout.names, layout.units
        free = np.asarray(self.free, dtype=bool)
        if free.shape != (len(names),):
            raise ValueError(f"free mask must have shape ({len(names)},), got {free.shape}")
        free.setflags(write=False)
        object.__setattr__(self, "free", free)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "units", units)

    @property
    def dof(self) -> int:
        return self.layout.dof

    # -- construction ---------------------------------------------------------------------
    @classmethod
    def for_robot(
        cls,
        robot,
        *,
        measurement=None,
        dh: bool = True,
        beta: bool = True,
        anchor: bool = False,
        tool: bool = False,
        cable_offset: bool = False,
        base: bool = False,
        nongeometric: bool = True,
        measurement_extras: bool = True,
    ) -> ParameterSpace:
        """Free the robot's geometric deviations (``dh``: DH robots all 4·dof, β at the Hayati
        joints; other robots what ``robot.free_by_default(name)`` says), its non-geometric
        groups, the measurement's own extra groups (e.g. marker positions), and the optional
        standard extras (anchor position, tool point, cable zero offset, sensor-to-base frame
        ``base`` = rotation and translation, 6 parameters). ``tool`` frees the tool point the
        measurement sees: its ``tool_group`` (``tool@<tip>`` for a model on another tip of a
        :class:`~jaxcal.KinematicTree`, the standard ``tool`` otherwise)."""
        layout = layout_for(robot, measurement)
        # the tool point the measurement sees: the standard ``tool``, or ``tool@<tip>`` for another
        # tip of a kinematic tree (a measurement extra that ``tool`` frees instead)
        tool_group = "tool" if measurement is None else getattr(measurement, "tool_group", "tool")
        std = {"anchor": anchor, "tool": tool and tool_group == "tool", "cable_offset": cable_offset,
               "base_rotation": base, "base_translation": base}
        meas_groups = {g.name for g in _call_method(measurement, "extra_groups") or ()}
        beta_joints = getattr(robot, "beta_joints", ())
        by_default = getattr(robot, "free_by_default", None)
        free = np.zeros(layout.size, dtype=bool)
        i = 0
        for g in layout.groups:
            for n in g.names:
                if g.name in std:
                    f = std[g.name]
                elif g.name == tool_group:
                    f = tool
                elif g.name in meas_groups:
                    f = measurement_extras
                elif g.kind == "nongeometric":
                    f = nongeometric
                elif g.name == "beta":
                    f = beta and int(n.rsplit("_", 1)[1]) in beta_joints
                else:
                    f = dh and (by_default is None or bool(by_default(n)))
                free[i] = f
                i += 1
        return cls(layout, free)

    @classmethod
    def from_names(cls, layout: Layout | int, names: Iterable[str]) -> ParameterSpace:
        """A space whose free entries are exactly ``names`` (unknown names raise)."""
        layout = Layout.coerce(layout)
        all_names = layout.names
        index = {n: i for i, n in enumerate(all_names)}
        free = np.zeros(len(all_names), dtype=bool)
        for n in names:
            if n not in index:
                raise ValueError(f"unknown parameter name {n!r}; valid names: {list(all_names)}")
            free[index[n]] = True
        return cls(layout, free)

    def restrict(self, keep: np.ndarray) -> ParameterSpace:
        """A sub-space keeping only the currently free entries where ``keep`` ([n_free]) is true."""
        keep = np.asarray(keep, dtype=bool)
        if keep.shape != (self.n_free,):
            raise ValueError(f"keep must have shape ({self.n_free},), got {keep.shape}")
        free = np.zeros_like(self.free)
        free[self.free_index[keep]] = True
        return ParameterSpace(self.layout, free)

    # -- views ----------------------------------------------------------------------------
    # the views below are computed once (the space is immutable: ``free`` is read-only)
    @functools.cached_property
    def n_free(self) -> int:
        return int(self.free.sum())

    @functools.cached_property
    def free_index(self) -> np.ndarray:
        index = np.flatnonzero(self.free)
        index.setflags(write=False)
        return index

    @functools.cached_property
    def free_names(self) -> tuple[str, ...]:
        return tuple(self.names[i] for i in self.free_index)

    @functools.cached_property
    def free_units(self) -> tuple[str, ...]:
        return tuple(self.units[i] for i in self.free_index)

    # -- maps -----------------------------------------------------------------------------
    def to_vector(self, deviations: Deviations) -> Float[Array, " p"]:
        """The free entries of ``deviations`` as a flat ``[p]`` vector."""
        if _traced(*deviations.arrays):
            return deviations.ravel()[..., self.free_index]
        return to_device(self.to_vector_numpy(deviations))

    def to_vector_numpy(self, deviations: Deviations) -> np.ndarray:
        """:meth:`to_vector` in NumPy, for host-side code (concrete deviations only)."""
        return deviations._ravel_numpy()[..., self.free_index]

    def from_vector(self, x: Float[Array, " p"], base: Deviations | None = None) -> Deviations:
        """Deviations whose free entries are ``x`` ``[p]`` and the others come from ``base``
        (zeros by default)."""
        if _traced(x, *(() if base is None else base.arrays)):
            x = jnp.asarray(x)
            self._check_length(x)
            if base is None:
                flat = jnp.zeros(x.shape[:-1] + (self.free.size,), dtype=x.dtype)
            else:
                flat = jnp.asarray(base.ravel(), dtype=x.dtype)
            flat = flat.at[..., self.free_index].set(x)
            return Deviations.unravel(flat, self.layout)
        x = canonical_numpy(x)
        self._check_length(x)
        if base is None:
            flat = np.zeros(x.shape[:-1] + (self.free.size,), dtype=x.dtype)
        else:  # broadcast base over x's batch axes, as the traced branch's .at[].set does
            flat = np.array(np.broadcast_to(base._ravel_numpy().astype(x.dtype), x.shape[:-1] + (self.free.size,)))
        flat[..., self.free_index] = x
        return Deviations.unravel(flat, self.layout)

    def _check_length(self, x) -> None:
        if x.shape[-1] != self.n_free:
            raise ValueError(f"expected {self.n_free} free parameters, got vector of shape {x.shape}")

    def __eq__(self, other) -> bool:
        return (
            isinstance(other, ParameterSpace)
            and self.layout == other.layout
            and np.array_equal(self.free, other.free)
        )

    def __hash__(self) -> int:
        return hash((self.layout, self.free.tobytes()))

    def __repr__(self) -> str:
        return f"ParameterSpace(dof={self.dof}, free={list(self.free_names)})"
