"""Generic serial chains: revolute and prismatic joints with fixed transforms between them.

A :class:`SerialChain` is the robot model for anything that is not (or not only) a DH table: a
URDF chain from a base link to a tip link (:func:`jaxcal.load_urdf`), or a DH robot rebuilt as a
chain (:func:`jaxcal.chain_from_dh`). Lengths are in **mm** and angles in rad inside jaxcal (the
URDF loader converts metres at the file edge). Prismatic joint positions are in mm.

Kinematics. Every joint ``i`` has a constant *origin* ``O_i = (R_o, t_o)`` from the previous
joint frame (the base link frame for ``i = 1``) to the joint frame before motion. The loader
rotates every joint frame so that its axis is the local ``z`` (the alignment ``R_a`` with
``R_a·e_z = axis`` is absorbed into this joint's origin and ``R_aᵀ`` into the next one, host
side), so the joint motion is always ``Rz(q)`` (revolute) or ``Tz(q)`` (prismatic). Fixed joints
between two moving joints are folded into the next origin; fixed joints after the last moving
joint form the ``flange`` transform ``F = (R_f, t_f)`` from the last joint frame to the tip link
frame. The tool point ``tool`` [3] mm is given in the tip link frame.

Error model (the ``"geometric"`` groups of :meth:`SerialChain.error_groups`), per joint ``i``::

    revolute:   T_i = Tr(t_o + [dx, dy, dz]) · R_o · Rx(drx) · Ry(dry) · Rz(q_i + offset)
    prismatic:  T_i = Tr(t_o + [dx, dy, dz]) · R_o · Rx(drx) · Ry(dry) · Rz(drz) · Tz(q_i + offset)

and the tip transform (the ``"geometric"`` groups ``tip_translation``, ``tip_rotation``)::

    tip:        F = Tr(t_f + [tip_dx, tip_dy, tip_dz]) · R_f · Rx(tip_drx) · Ry(tip_dry) · Rz(tip_drz)

``dx, dy, dz`` (mm, in the previous joint frame) and ``drx, dry, drz`` (rad) are a full
6-parameter error of each fixed transform; at a revolute joint the ``z`` rotation cannot be told
apart from the joint offset, so it is merged into ``offset`` (rad) and ``drz`` has no effect
there (it is not free by default). At a prismatic joint ``offset`` is in mm.

The tip errors ``tip_dx, tip_dy, tip_dz`` (mm, in the last joint frame) and ``tip_drx, tip_dry,
tip_drz`` (rad, about the tip link frame's axes) are the same 6-parameter error of the last
link's fixed transform (where a DH robot's ``a_n, α_n`` and the flange's ``d`` live): without
them nothing after the last joint's motion can be corrected, and a mechanical flange is as
imprecise as the other links (a URDF robot ended 24 % above the statistical
floor on tool-point data without them). All six are free by default; which of them the data
can see is left to the identifiability QR: ``tip_dz`` always acts like a translation of the last
joint along its axis, and on the positions of one tool point the tip rotation acts like a tip
translation (pose data see it).

Six errors per transform are not minimal: a chain has at most ``4R + 2P + 6`` independent
kinematic parameters (Everett, Driels & Mooring 1987), less what the measurement cannot see, so
the identifiability QR (:func:`jaxcal.identifiability`, ``KEEP_PREFERENCE``) picks the
identifiable subset with the real measurement model, preferring joint offsets, then
translations, then rotations, then the tip's translation and rotation. This set is chosen over
DH-style 4-parameter errors because it stays well conditioned for any axis layout (parallel,
intersecting or skew axes need no Hayati special case) and every parameter names a
physical correction of one URDF ``<origin>``.

The kernel works on a point in structure-of-arrays form (three ``[n]`` arrays) from the tip
inward, like the DH kernel: per joint one plane rotation by ``q`` and three
additions. Nominal FK (no deviations) applies the constant ``R_o`` with its exact zeros and ones
skipped statically (URDF origins are mostly signed permutations). With deviations, the per-joint
constant ``R_o·Rx(drx)·Ry(dry)`` is formed as a ``[3, 3]`` matrix and applied as one matrix
product to the stacked ``[3, n]`` point, which makes XLA materialise the point per joint: fully
fused elementwise updates were as fast for a single output (a wire length) but made XLA CPU
recompute the whole chain per output under ``jax.jacfwd`` when the three coordinates are
stacked (a position residual): 1.7 s instead of 10 ms for 2 000 × 36 (measured here, Nov 2026).
The tip error enters once, on the constant tool point (``point_in_base``: a ``[3]`` vector, before
the batch) or on the final frame (``frame_soa``: one dense ``[3, 3]`` product instead of the
sparse ``R_f``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core._host_method import host_method
from .._core._precision import to_device
from ._abstract import AbstractRobot
from ._nongeometric import NonGeometric, NonGeometricMixin, nongeometric_groups
from ._robot import replace_tool

__all__ = ["SerialChain", "GEOMETRIC_GROUPS", "TIP_GROUPS", "correction_entries", "rpy_matrix", "matrix_rpy"]

JOINT_TYPES = ("revolute", "prismatic")
#: per-joint geometric error groups of a chain, in layout order, with their units
#: (``"rad|mm"``: rad at revolute joints, mm at prismatic joints).
GEOMETRIC_GROUPS: tuple[tuple[str, str], ...] = (
    ("offset", "rad|mm"), ("dx", "mm"), ("dy", "mm"), ("dz", "mm"),
    ("drx", "rad"), ("dry", "rad"), ("drz", "rad"),
)
#: the tip transform's error groups (last joint frame → tip link frame), in layout order after
#: the per-joint groups: ``(group, entry names, unit)``.
TIP_GROUPS: tuple[tuple[str, tuple[str, str, str], str], ...] = (
    ("tip_translation", ("tip_dx", "tip_dy", "tip_dz"), "mm"),
    ("tip_rotation", ("tip_drx", "tip_dry", "tip_drz"), "rad"),
)
_SNAP = 1e-12


def _register_group_names() -> None:
    """Register the chain's group names and kinds, so that ``group_of("offset_1")`` works before
    any chain's layout is made (a prior file or a previous result of a URDF robot, read first)."""
    from .._core._params import Group

    for g, _unit in GEOMETRIC_GROUPS:
        Group.per_joint(g, 1, "rad", kind="geometric")
    for g, names, unit in TIP_GROUPS:
        Group.vector(g, names, unit, kind="geometric")


_register_group_names()


def joint_error_groups(joint_units: Sequence[str]) -> list:
    """The per-joint geometric groups (:data:`GEOMETRIC_GROUPS`: ``offset, dx, dy, dz, drx, dry,
    drz``), one entry per joint of ``joint_units`` (``"rad"`` / ``"mm"`` per joint; ``offset`` takes
    the joint's unit), entries ``<group>_<joint>`` (1-based)."""
    from .._core._params import Group

    return [Group.per_joint(g, len(joint_units), tuple(joint_units) if unit == "rad|mm" else unit, kind="geometric")
            for g, unit in GEOMETRIC_GROUPS]


def tip_error_groups(label: str | None = None) -> list:
    """The tip transform's groups (:data:`TIP_GROUPS`); with a ``label`` (a tip of a kinematic
    tree) renamed ``<group>@<label>`` with entries ``<entry>@<label>`` (``tip_dx@left_tool``), so
    that every tip has its own errors and they still rank and select as their family."""
    from .._core._params import Group

    at = "" if label is None else f"@{label}"
    return [Group.vector(g + at, tuple(n + at for n in names), unit, kind="geometric") for g, names, unit in TIP_GROUPS]


def joint_free_by_default(prismatic: Sequence[bool], entry_name: str) -> bool:
    """``drz_j`` at a revolute joint ``j`` duplicates the joint offset: never free by default;
    every other entry is (``prismatic``: per joint, static)."""
    group, _, j = entry_name.rpartition("_")
    if group == "drz" and j.isdigit():
        return prismatic[int(j) - 1]
    return True


def origin_lengths(origin_t) -> dict[str, float]:
    """``{dx_i, dy_i, dz_i: nominal value}`` (mm) of joint origins ``origin_t`` ``[dof, 3]``: the
    per-joint length entries of :meth:`SerialChain.nominal_lengths`."""
    t = np.asarray(origin_t, np.float64)
    return {f"{c}_{i + 1}": float(t[i, k]) for k, c in enumerate(("dx", "dy", "dz")) for i in range(t.shape[0])}

Vec3 = tuple


def rpy_matrix(rpy) -> np.ndarray:
    """URDF roll-pitch-yaw (rad) → rotation matrix ``Rz(yaw)·Ry(pitch)·Rx(roll)`` ``[3, 3]``."""
    r, p, y = (float(v) for v in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def matrix_rpy(R) -> np.ndarray:
    """Rotation matrix ``[3, 3]`` → URDF roll, pitch, yaw (rad), the inverse of :func:`rpy_matrix`."""
    R = np.asarray(R, dtype=np.float64)
    sp = -R[2, 0]
    if abs(sp) < 1.0 - 1e-12:
        return np.array([np.arctan2(R[2, 1], R[2, 2]), np.arcsin(sp), np.arctan2(R[1, 0], R[0, 0])])
    # gimbal lock: roll and yaw share one axis, put it all in yaw
    p = np.pi / 2 if sp > 0 else -np.pi / 2
    return np.array([0.0, p, np.arctan2(-R[0, 1], R[1, 1])])


def align_z(axis) -> np.ndarray:
    """A rotation ``R_a`` ``[3, 3]`` with ``R_a·e_z = axis / |axis|`` (identity for +z, and a
    signed permutation for the other coordinate axes, so aligned URDF origins stay sparse)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    z = a
    # pick x as the coordinate axis least parallel to z, orthogonalised: exact for ±e_x, ±e_y, ±e_z
    helper = np.eye(3)[int(np.argmin(np.abs(a)))]
    if np.allclose(np.abs(a), [0, 0, 1]):
        helper = np.array([1.0, 0.0, 0.0])
    elif np.allclose(np.abs(a), [1, 0, 0]):
        helper = np.array([0.0, 1.0, 0.0])
    elif np.allclose(np.abs(a), [0, 1, 0]):
        helper = np.array([0.0, 0.0, 1.0])
    x = helper - np.dot(helper, z) * z
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return snap(np.stack([x, y, z], axis=1))


def snap(R) -> np.ndarray:
    """Round entries within 1e-12 of 0 or ±1 to exactly that (cos(π/2) = 6e-17 becomes 0), so
    the kernel can skip them statically; changes positions by < 1e-12 relative."""
    R = np.array(R, dtype=np.float64)
    R[np.abs(R) < _SNAP] = 0.0
    R[np.abs(R - 1.0) < _SNAP] = 1.0
    R[np.abs(R + 1.0) < _SNAP] = -1.0
    return R


def _pattern(R) -> tuple[tuple[int, ...], ...]:
    """Static sparsity code of a 3×3 matrix: 0 = exact zero, 1 / −1 = exact ±1, 2 = general."""
    R = np.asarray(R)
    code = lambda v: 0 if v == 0.0 else (1 if v == 1.0 else (-1 if v == -1.0 else 2))  # noqa: E731
    return tuple(tuple(code(float(R[i, j])) for j in range(3)) for i in range(3))


_IDENTITY = ((1, 0, 0), (0, 1, 0), (0, 0, 1))


def _rx_j(c, s):
    o, z = jnp.ones_like(c), jnp.zeros_like(c)
    return jnp.stack([jnp.stack([o, z, z]), jnp.stack([z, c, -s]), jnp.stack([z, s, c])])


def _ry_j(c, s):
    o, z = jnp.ones_like(c), jnp.zeros_like(c)
    return jnp.stack([jnp.stack([c, z, s]), jnp.stack([z, o, z]), jnp.stack([-s, z, c])])


def _matvec(R, pat, v: Vec3) -> Vec3:
    """``R·v`` with the static pattern's zeros and ones skipped (``R`` traced ``[3, 3]``)."""
    if pat == _IDENTITY:
        return v
    out = []
    for i in range(3):
        acc = None
        for j in range(3):
            c = pat[i][j]
            if c == 0:
                continue
            term = v[j] if c == 1 else (-v[j] if c == -1 else R[i, j] * v[j])
            acc = term if acc is None else acc + term
        out.append(acc if acc is not None else 0.0 * v[0])
    return tuple(out)


def _frame_mul(cols: tuple[Vec3, Vec3, Vec3], R, pat) -> tuple[Vec3, Vec3, Vec3]:
    """Columns of ``F·R`` from the columns of ``F`` (each a triple): column j = Σ_k R[k, j]·F_k,
    i.e. per component c the row ``(F_0[c], F_1[c], F_2[c])`` times ``R`` (:func:`_matvec` with
    ``Rᵀ``)."""
    if pat == _IDENTITY:
        return cols
    pat_t = tuple(zip(*pat))
    rows = [_matvec(R.T, pat_t, tuple(cols[k][c] for k in range(3))) for c in range(3)]  # rows[c][j]
    return tuple(tuple(rows[c][j] for c in range(3)) for j in range(3))


def _dev_get(dev, name: str):
    """The ``[dof]`` deviation group ``name`` of ``dev`` (a :class:`~jaxcal.Deviations` with
    named groups, a mapping, or ``None``), or ``None`` when absent."""
    if dev is None:
        return None
    values = dev if isinstance(dev, Mapping) else getattr(dev, "values", None)
    if isinstance(values, Mapping):
        return values.get(name)
    return getattr(dev, name, None)


def correction_entries(chain, deviations) -> list[tuple[str, float, str]]:
    """``(name, value, unit)`` of every geometric correction of ``chain`` in ``deviations``, for
    tables: group by group (:data:`GEOMETRIC_GROUPS`), joint by joint, then the tip transform
    (:data:`TIP_GROUPS`: ``tip_dx … tip_drz``); angles in degrees (``unit`` ``"deg"``), lengths
    and prismatic-joint offsets in mm; ``drz`` at prismatic joints only (at a revolute joint it
    is the joint offset). A group the deviations lack reads 0."""
    out = []
    for g, unit in GEOMETRIC_GROUPS:
        vals = _dev_get(deviations, g)
        for j in range(chain.dof):
            if g == "drz" and not chain.prismatic[j]:
                continue
            deg = unit == "rad" or (unit == "rad|mm" and not chain.prismatic[j])
            v = 0.0 if vals is None else float(np.asarray(vals)[j])
            out.append((f"{g}_{j + 1}", float(np.degrees(v)) if deg else v, "deg" if deg else "mm"))
    for g, names, unit in TIP_GROUPS:
        vals = _dev_get(deviations, g)
        for k, n in enumerate(names):
            v = 0.0 if vals is None else float(np.asarray(vals)[k])
            out.append((n, float(np.degrees(v)) if unit == "rad" else v, "deg" if unit == "rad" else "mm"))
    return out


def _rxyz_j(a, b, c):
    """``Rx(a)·Ry(b)·Rz(c)`` ``[3, 3]`` from traced scalars (rad)."""
    ca, sa, cb, sb, cc, sc = jnp.cos(a), jnp.sin(a), jnp.cos(b), jnp.sin(b), jnp.cos(c), jnp.sin(c)
    return jnp.stack([
        jnp.stack([cb * cc, -cb * sc, sb]),
        jnp.stack([sa * sb * cc + ca * sc, -sa * sb * sc + ca * cc, -sa * cb]),
        jnp.stack([-ca * sb * cc + sa * sc, ca * sb * sc + sa * cc, ca * cb]),
    ])


class SerialChain(NonGeometricMixin, AbstractRobot):
    """A serial chain of revolute and prismatic joints with fixed transforms between them.

    Kinematics: joint ``i`` has a constant origin ``O_i = (R_o, t_o)`` from the previous joint
    frame (the base link frame for ``i = 1``); every joint axis is aligned to its frame's ``z``, so
    the joint motion is ``Rz(q)`` (revolute) or ``Tz(q)`` (prismatic, mm). Fixed joints between
    moving joints are folded into the next origin, those after the last one into the flange
    transform ``F = (R_f, t_f)`` to the tip link frame; the tool point is in the tip link frame.

    Error model (the ``"geometric"`` groups of :meth:`error_groups`), per joint and at the tip:

        revolute:   T_i = Tr(t_o + [dx, dy, dz]) · R_o · Rx(drx) · Ry(dry) · Rz(q_i + offset)
        prismatic:  T_i = Tr(t_o + [dx, dy, dz]) · R_o · Rx(drx) · Ry(dry) · Rz(drz) · Tz(q_i + offset)
        tip:        F = Tr(t_f + [tip_dx, tip_dy, tip_dz]) · R_f · Rx(tip_drx) · Ry(tip_dry) · Rz(tip_drz)

    ``dx, dy, dz`` (mm, previous joint frame) and ``drx, dry, drz`` (rad) are a full 6-parameter
    error of each fixed transform; at a revolute joint ``drz`` cannot be told from ``offset``
    (rad; mm at a prismatic joint) and is not free by default. This is more than the at most
    ``4R + 2P + 6`` independent parameters of a chain (Everett, Driels & Mooring 1987), so
    :func:`jaxcal.identifiability` picks the identifiable subset with the real measurement model
    (joint offsets first, then translations, rotations, the tip's translation and rotation); the
    set stays well conditioned for parallel, intersecting or skew axes alike, and every
    parameter corrects one URDF ``<origin>``.

    Build it with :func:`jaxcal.load_urdf`, :func:`jaxcal.chain_from_dh` or
    :meth:`SerialChain.build`. Axes are aligned to the joint frames' ``z`` (the alignment is kept
    in ``align`` for export).

    Attributes:
        origin_R: ``[dof, 3, 3]`` rotation of each joint origin (previous joint frame → joint frame).
        origin_t: ``[dof, 3]`` translation of each joint origin (mm, previous joint frame).
        flange_R, flange_t: ``[3, 3]``, ``[3]`` mm: nominal last joint frame → tip link frame
            (corrected by the ``tip_translation`` / ``tip_rotation`` deviations).
        align: ``[dof, 3, 3]`` ``R_a`` per joint (URDF child-link frame = joint frame · ``R_aᵀ``).
        q_min, q_max: ``[dof]`` joint limits (rad; mm for prismatic joints).
        tool: ``[3]`` nominal tool point in the tip link frame (mm).
        mass: ``[dof]`` mass moved by each joint's link (kg; links fixed to it on the path merged).
        com: ``[dof, 3]`` its centre of mass in the joint frame (mm).
        joint_types: ``"revolute"`` / ``"prismatic"`` per joint (static).
        joint_names, link_names: URDF joint names and the child link of each joint (static).
        base, tip: base and tip link names (static).
        name: display name (static).
        urdf: the URDF text the chain was loaded from, for export and result files (static).
        dh: ``(convention, alpha, a, d, theta, beta, beta_joints)`` of the DH table the chain was
            built from (static, rad / mm), or ``None``.
        nongeometric: joint compliance / harmonic transmission-error models
            (:meth:`with_compliance`, :meth:`with_harmonics`), or ``None``.
    """

    origin_R: Float[Array, "dof 3 3"]
    origin_t: Float[Array, "dof 3"]
    flange_R: Float[Array, "3 3"]
    flange_t: Float[Array, " 3"]
    align: Float[Array, "dof 3 3"]
    q_min: Float[Array, " dof"]
    q_max: Float[Array, " dof"]
    tool: Float[Array, " 3"]
    mass: Float[Array, " dof"]
    com: Float[Array, "dof 3"]
    joint_types: tuple[str, ...] = eqx.field(static=True)
    patterns: tuple = eqx.field(static=True)
    flange_pattern: tuple = eqx.field(static=True)
    joint_names: tuple[str, ...] = eqx.field(static=True, default=())
    link_names: tuple[str, ...] = eqx.field(static=True, default=())
    base: str = eqx.field(static=True, default="base")
    tip: str = eqx.field(static=True, default="tip")
    name: str = eqx.field(static=True, default="chain")
    urdf: str | None = eqx.field(static=True, default=None)
    dh: tuple | None = eqx.field(static=True, default=None)
    nongeometric: NonGeometric | None = None

    @classmethod
    def build(
        cls,
        *,
        origin_R: Sequence,
        origin_t: Sequence,
        joint_types: Sequence[str],
        q_min: Sequence[float],
        q_max: Sequence[float],
        flange_R=None,
        flange_t=None,
        align=None,
        tool=(0.0, 0.0, 0.0),
        mass=None,
        com=None,
        joint_names: Sequence[str] | None = None,
        link_names: Sequence[str] | None = None,
        base: str = "base",
        tip: str = "tip",
        name: str = "chain",
        urdf: str | None = None,
        dh: tuple | None = None,
    ) -> SerialChain:
        """Build a chain from host arrays (axes already along each joint frame's ``z``).

        Rotations are snapped (entries within 1e-12 of 0/±1 made exact) and their sparsity
        recorded statically for the kernel. Arrays are stored in the default float dtype.
        """
        R = np.stack([snap(r) for r in np.asarray(origin_R, dtype=np.float64).reshape(-1, 3, 3)])
        dof = R.shape[0]
        if dof < 1:
            raise ValueError("a chain needs at least one moving joint")
        t = np.asarray(origin_t, dtype=np.float64).reshape(dof, 3)
        types = tuple(str(s) for s in joint_types)
        if len(types) != dof or any(s not in JOINT_TYPES for s in types):
            raise ValueError(f"joint_types must be {dof} of {JOINT_TYPES}, got {types}")
        for k, r in enumerate(R):
            if not (np.allclose(r.T @ r, np.eye(3), atol=1e-9) and np.linalg.det(r) > 0):
                raise ValueError(f"origin_R[{k}] is not a rotation matrix")
        fR = snap(np.eye(3) if flange_R is None else flange_R)
        ft = np.zeros(3) if flange_t is None else np.asarray(flange_t, dtype=np.float64)
        al = np.stack([np.eye(3)] * dof) if align is None else np.asarray(align, dtype=np.float64)
        lo = np.asarray(q_min, dtype=np.float64)
        hi = np.asarray(q_max, dtype=np.float64)
        if lo.shape != (dof,) or hi.shape != (dof,) or np.any(lo >= hi):
            raise ValueError(f"joint limits need {dof} values each with q_min < q_max, got {lo}, {hi}")
        m = np.zeros(dof) if mass is None else np.asarray(mass, dtype=np.float64)
        c = np.zeros((dof, 3)) if com is None else np.asarray(com, dtype=np.float64).reshape(dof, 3)
        tl = np.asarray(tool, dtype=np.float64)
        if tl.shape != (3,) or not np.all(np.isfinite(tl)):
            raise ValueError(f"tool must be 3 finite numbers (mm), got {tool!r}")
        jn = tuple(joint_names) if joint_names is not None else tuple(f"joint_{i + 1}" for i in range(dof))
        ln = tuple(link_names) if link_names is not None else tuple(f"link_{i + 1}" for i in range(dof))
        return cls(
            origin_R=to_device(R), origin_t=to_device(t), flange_R=to_device(fR),
            flange_t=to_device(ft), align=to_device(al), q_min=to_device(lo), q_max=to_device(hi),
            tool=to_device(tl), mass=to_device(m), com=to_device(c), joint_types=types,
            patterns=tuple(_pattern(r) for r in R), flange_pattern=_pattern(fR), joint_names=jn,
            link_names=ln, base=base, tip=tip, name=name, urdf=urdf, dh=dh,
        )

    # ------------------------------------------------------------------ robot protocol
    @property
    def dof(self) -> int:
        """Number of moving joints."""
        return int(self.origin_t.shape[0])

    @property
    def prismatic(self) -> tuple[bool, ...]:
        """Per joint: ``True`` for a prismatic joint (static)."""
        return tuple(s == "prismatic" for s in self.joint_types)

    def joint_units(self) -> tuple[str, ...]:
        """Unit of each joint coordinate: ``"rad"`` or ``"mm"``."""
        return tuple("mm" if p else "rad" for p in self.prismatic)

    def error_groups(self):
        """The chain's geometric error groups (``offset, dx, dy, dz, drx, dry, drz``, one entry
        per joint; ``offset`` is rad at revolute and mm at prismatic joints), then the tip
        transform's ``tip_translation`` ``[3]`` mm (``tip_dx, tip_dy, tip_dz``) and
        ``tip_rotation`` ``[3]`` rad (``tip_drx, tip_dry, tip_drz``), then the non-geometric groups.
        Their default prior σ is :class:`jaxcal.Prior`'s by unit (0.5°, 2 mm)."""
        return tuple(joint_error_groups(self.joint_units()) + tip_error_groups()) + nongeometric_groups(self)

    def free_by_default(self, entry_name: str) -> bool:
        """``drz`` at a revolute joint duplicates the joint offset: never free by default (every
        other joint and tip entry is)."""
        return joint_free_by_default(self.prismatic, entry_name)

    def default_tip(self) -> str | None:
        """The chain's tip link (the flange a measurement model sees)."""
        return self.tip

    def with_tool(self, tool_mm: Sequence[float]) -> SerialChain:
        """A copy with another nominal tool point ``[3]`` mm in the tip link frame."""
        return replace_tool(self, tool_mm)

    def geometry_dict(self) -> dict:
        """JSON-friendly chain that :func:`jaxcal._models._urdf.chain_from_dict` rebuilds exactly:
        base and tip link names, tool point (mm), joint names and types, and the geometry as it
        came — the URDF text a chain was loaded from (``"urdf"``), the DH table (rad / mm) of a
        chain built from one (``"dh"``), or, for a chain built by hand (:meth:`build`), its
        arrays (``"origins"``: joint origins, flange, axis alignments, limits, masses and centres
        of mass, link names; mm / rad / kg)."""
        out = {
            "type": "serial_chain",
            "name": self.name,
            "base": self.base,
            "tip": self.tip,
            "tool_mm": np.asarray(self.tool, np.float64).tolist(),
            "joint_names": list(self.joint_names),
            "joint_types": list(self.joint_types),
        }
        if self.dh is not None:
            conv, alpha, a, d, theta, beta, bj = self.dh
            out["dh"] = {"convention": conv, "alpha_rad": list(alpha), "a_mm": list(a), "d_mm": list(d),
                         "theta_rad": list(theta), "beta_rad": list(beta), "beta_joints": list(bj),
                         "q_min": np.asarray(self.q_min, np.float64).tolist(),
                         "q_max": np.asarray(self.q_max, np.float64).tolist()}
        elif self.urdf is not None:
            out["urdf"] = self.urdf
        else:
            f = lambda a: np.asarray(a, np.float64).tolist()  # noqa: E731
            out["origins"] = {"origin_R": f(self.origin_R), "origin_t_mm": f(self.origin_t),
                              "flange_R": f(self.flange_R), "flange_t_mm": f(self.flange_t), "align": f(self.align),
                              "q_min": f(self.q_min), "q_max": f(self.q_max), "mass_kg": f(self.mass),
                              "com_mm": f(self.com), "link_names": list(self.link_names)}
        return out

    @host_method
    def nominal_lengths(self) -> dict[str, float]:
        """``{entry: nominal value}`` (mm) of the chain's length entries: ``dx_i, dy_i, dz_i`` are
        deviations of joint origin ``i``'s translation (the nominal ``origin_t[i]``), ``tip_dx …
        tip_dz`` of the flange translation; a prismatic joint's ``offset`` (mm) has nominal 0.
        What a uniform scaling of every length of a set-up multiplies
        (:func:`jaxcal._calibration._blocks.length_scale_direction`); the tool point is the
        layout's ``tool`` group, not the robot's."""
        return origin_lengths(self.origin_t) | dict(zip(TIP_GROUPS[0][1], (float(v) for v in np.asarray(self.flange_t, np.float64))))

    @host_method
    def reach_mm(self) -> float:
        """A generous bound on the distance from the base origin to the tool point (mm):
        origin lengths + prismatic strokes + flange + tool."""
        t = np.asarray(self.origin_t)
        stroke = sum(max(abs(float(lo)), abs(float(hi)))
                     for lo, hi, p in zip(np.asarray(self.q_min), np.asarray(self.q_max), self.prismatic) if p)
        return float(np.sum(np.linalg.norm(t, axis=1)) + stroke + np.linalg.norm(np.asarray(self.flange_t))
                     + np.linalg.norm(np.asarray(self.tool)))

    # ------------------------------------------------------------------ kinematics
    def _terms(self, dev, q):
        """Per joint (lists over joints): q + offset ``[n]``, (cos, sin) of drx, dry, drz, origin
        translation + (dx, dy, dz), in the dtype of ``q``; ``rot["q"]``: (cos, sin) of q + offset
        ``[dof, n]`` (:func:`~jaxcal._models._kinematics.angle_sum_trig`; used at revolute joints)."""
        from ._kinematics import angle_sum_trig, effective_joint_angles

        dtype = q.dtype
        cast = lambda x: jnp.asarray(x).astype(dtype)  # noqa: E731
        if dev is not None and not isinstance(dev, Mapping):
            q = effective_joint_angles(self, dev, q)  # joint-space (non-geometric) corrections first
        groups = {g: _dev_get(dev, g) for g, _ in GEOMETRIC_GROUPS}
        groups = {g: None if v is None else cast(v) for g, v in groups.items()}
        offset = groups["offset"]
        trig = None if all(self.prismatic) else angle_sum_trig(q, jnp.zeros(self.dof, dtype) if offset is None else offset)
        qq = q.T if offset is None else q.T + offset[:, None]  # [dof, n]
        t = cast(self.origin_t)
        dt = [groups[g] for g in ("dx", "dy", "dz")]
        if any(v is not None for v in dt):
            t = t + jnp.stack([jnp.zeros(self.dof, dtype) if v is None else v for v in dt], axis=1)
        rot = {}
        for g in ("drx", "dry", "drz"):
            v = groups[g]
            rot[g] = None if v is None else (jnp.cos(v), jnp.sin(v))
        rot["q"] = trig
        return qq, t, rot, cast(self.origin_R)

    def _local(self, i, qq, rot, x, y, z):
        """``x, y, z ← Rx(drx)·Ry(dry)·[Rz(drz)·Tz(q) | Rz(q)] · (x, y, z)`` for joint ``i``."""
        if self.prismatic[i]:
            z = z + qq[i]
            if rot["drz"] is not None:
                c, s = rot["drz"][0][i], rot["drz"][1][i]
                x, y = c * x - s * y, s * x + c * y
        else:
            c, s = rot["q"][0][i], rot["q"][1][i]
            x, y = c * x - s * y, s * x + c * y
        if rot["dry"] is not None:
            c, s = rot["dry"][0][i], rot["dry"][1][i]
            z, x = c * z - s * x, s * z + c * x
        if rot["drx"] is not None:
            c, s = rot["drx"][0][i], rot["drx"][1][i]
            y, z = c * y - s * z, s * y + c * z
        return x, y, z

    @staticmethod
    def _error_rotation(i, R, rot):
        """``R_o·Rx(drx)·Ry(dry)`` of joint ``i`` as a ``[3, 3]`` array."""
        M = R[i]
        if rot["drx"] is not None:
            M = M @ _rx_j(*[v[i] for v in rot["drx"]])
        if rot["dry"] is not None:
            M = M @ _ry_j(*[v[i] for v in rot["dry"]])
        return M

    def _tip(self, dev, dtype):
        """The (deviated) tip transform for the kernels: ``(M, pattern, t)`` with ``M`` ``[3, 3]``
        = ``R_f`` (sparse ``pattern``) or ``R_f·Rx·Ry·Rz`` of ``tip_rotation`` (dense), and ``t``
        ``[3]`` mm = ``t_f + tip_translation``, in ``dtype``."""
        M = jnp.asarray(self.flange_R).astype(dtype)
        t = jnp.asarray(self.flange_t).astype(dtype)
        pattern = self.flange_pattern
        dt, dr = _dev_get(dev, "tip_translation"), _dev_get(dev, "tip_rotation")
        if dt is not None:
            t = t + jnp.asarray(dt).astype(dtype)
        if dr is not None:
            dr = jnp.asarray(dr).astype(dtype)
            M = M @ _rxyz_j(dr[0], dr[1], dr[2])
            pattern = ((2, 2, 2),) * 3
        return M, pattern, t

    def point_in_base(self, dev, q: Float[Array, "n dof"], point, *, fused: bool = False) -> Vec3:
        """A point ``[3]`` (mm) in the tip link frame, in the base link frame: three ``[n]`` arrays.

        Applied from the tip inward, ``p ← F·p`` (the deviated tip transform), then
        ``p ← O_i·M_i(q_i)·p`` for ``i = dof … 1`` (``O_i`` the deviated joint origin, ``M_i`` the
        joint motion with its error rotation; the class docstring's error model); jittable and ``jax.jacfwd``-friendly in ``dev``. ``fused=True``: every joint
        as elementwise plane rotations (the error rotations too) and the sparse constant origin,
        one XLA fusion — the fastest ``jacfwd`` when the caller reduces the three coordinates to
        one value per sample (draw-wire: 2 000 × 36 Jacobian 1.5 ms vs 13 ms); with three
        outputs kept, XLA CPU recomputes such a chain per output, so the default materialises
        each joint's error rotation as a matrix product.
        """
        qq, t, rot, R = self._terms(dev, q)
        fR, fpat, ft = self._tip(dev, q.dtype)  # the tip transform on the constant point [3]
        x, y, z = _matvec(fR, fpat, tuple(point[k] for k in range(3)))
        x, y, z = x + ft[0], y + ft[1], z + ft[2]
        n = q.shape[0]
        for i in reversed(range(self.dof)):
            if dev is None or fused:  # sparse constant rotations, plain elementwise updates
                x, y, z = self._local(i, qq, rot, x, y, z)
                x, y, z = _matvec(R[i], self.patterns[i], (x, y, z))
                x, y, z = x + t[i, 0], y + t[i, 1], z + t[i, 2]
                continue
            # with deviations: the joint motion elementwise, then the per-joint constant
            # M = R_o·Rx(drx)·Ry(dry) ([3, 3]) as one matrix product on the stacked point: XLA
            # materialises it per joint. (Three separate [n] outputs fused across joints made
            # XLA CPU recompute the chain per output under jacfwd: seconds instead of ms.)
            x, y, z = self._local(i, qq, {**rot, "drx": None, "dry": None}, x, y, z)
            P = self._error_rotation(i, R, rot) @ jnp.stack([jnp.broadcast_to(c, (n,)) for c in (x, y, z)])
            P = P + t[i][:, None]
            x, y, z = P[0], P[1], P[2]
        n = q.shape[0]
        return tuple(jnp.broadcast_to(c, (n,)) for c in (x, y, z))

    def frame_soa(self, dev, q: Float[Array, "n dof"]):
        """Tip link frame in the base frame as SoA: columns X, Y, Z and origin P (mm), each a
        triple of ``[n]`` arrays (``T_base_tip``, with the joint and tip errors of ``dev``)."""
        qq, t, rot, R = self._terms(dev, q)
        n = q.shape[0]
        one = jnp.ones((n,), q.dtype)
        zero = jnp.zeros((n,), q.dtype)
        cols = ((one, zero, zero), (zero, one, zero), (zero, zero, one))
        P = (zero, zero, zero)

        def rot_cols(u, v, c, s):  # F ← F·G, G rotating u toward v by (c, s)
            return (tuple(c * a + s * b for a, b in zip(u, v)), tuple(c * b - s * a for a, b in zip(u, v)))

        for i in range(self.dof):
            if dev is None:
                P = tuple(P[k] + cols[0][k] * t[i, 0] + cols[1][k] * t[i, 1] + cols[2][k] * t[i, 2] for k in range(3))
                X, Y, Z = _frame_mul(cols, R[i], self.patterns[i])
            else:  # materialised per joint as matrix products (see point_in_base)
                C = jnp.stack([jnp.stack(c) for c in cols])  # [col, component, n]
                Pm = jnp.stack(P) + jnp.einsum("jkn,j->kn", C, t[i])
                C = jnp.einsum("jkn,jl->lkn", C, self._error_rotation(i, R, rot))
                X, Y, Z = ((C[j, 0], C[j, 1], C[j, 2]) for j in range(3))
                P = (Pm[0], Pm[1], Pm[2])
            if self.prismatic[i]:
                if rot["drz"] is not None:
                    X, Y = rot_cols(X, Y, rot["drz"][0][i], rot["drz"][1][i])
                P = tuple(P[k] + Z[k] * qq[i] for k in range(3))
            else:
                X, Y = rot_cols(X, Y, rot["q"][0][i], rot["q"][1][i])
            cols = (X, Y, Z)
        fR, fpat, ft = self._tip(dev, q.dtype)
        P = tuple(P[k] + cols[0][k] * ft[0] + cols[1][k] * ft[1] + cols[2][k] * ft[2] for k in range(3))
        X, Y, Z = _frame_mul(cols, fR, fpat)
        return X, Y, Z, P

    # ------------------------------------------------------------------ host-side helpers
    def origins_numpy(self, dev=None) -> list[np.ndarray]:
        """The (deviated) joint origins as host ``[4, 4]`` transforms (mm), joint frames, with
        the error rotations ``Rx(drx)·Ry(dry)[·Rz(drz)]`` and the joint offset folded in (so that
        ``T_i(q) = origins[i] · M(q_i)`` with the plain joint motion ``M``)."""
        out = []
        get = lambda g: None if _dev_get(dev, g) is None else np.asarray(_dev_get(dev, g), dtype=np.float64)  # noqa: E731
        off, drx, dry, drz = get("offset"), get("drx"), get("dry"), get("drz")
        dts = [get(g) for g in ("dx", "dy", "dz")]
        for i in range(self.dof):
            T = np.eye(4)
            T[:3, :3] = np.asarray(self.origin_R[i])
            T[:3, 3] = np.asarray(self.origin_t[i]) + np.array([0.0 if v is None else v[i] for v in dts])
            E = np.eye(4)
            ax = 0.0 if drx is None else drx[i]
            ay = 0.0 if dry is None else dry[i]
            E[:3, :3] = _rx(ax) @ _ry(ay)
            if self.prismatic[i]:
                if drz is not None:
                    E[:3, :3] = E[:3, :3] @ _rz(drz[i])
                if off is not None:
                    E[:3, 3] = E[:3, :3] @ np.array([0.0, 0.0, off[i]])
            elif off is not None:
                E[:3, :3] = E[:3, :3] @ _rz(off[i])
            out.append(T @ E)
        return out

    def tip_numpy(self, dev=None) -> np.ndarray:
        """The (deviated) tip transform ``F`` (last joint frame → tip link frame) as a host
        ``[4, 4]`` transform (mm): ``Tr(t_f + tip_translation)·R_f·Rx·Ry·Rz(tip_rotation)``."""
        T = np.eye(4)
        T[:3, :3] = np.asarray(self.flange_R, np.float64)
        T[:3, 3] = np.asarray(self.flange_t, np.float64)
        dt, dr = _dev_get(dev, "tip_translation"), _dev_get(dev, "tip_rotation")
        if dt is not None:
            T[:3, 3] += np.asarray(dt, np.float64)
        if dr is not None:
            a, b, c = np.asarray(dr, np.float64)
            T[:3, :3] = T[:3, :3] @ _rx(a) @ _ry(b) @ _rz(c)
        return T


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
