"""Non-geometric errors: joint compliance under gravity and harmonic transmission errors.

Both are **joint-space** corrections: the kinematics kernels use
``q_eff = q + Δq(q)`` (:func:`jaxcal._models._kinematics.effective_joint_angles`), where ``q`` is the
commanded joint position ``[n, dof]`` (rad) and every correction is a function of the commanded
``q`` (not of each other). Each model is a calibratable group of kind ``"nongeometric"``:

* ``compliance`` (rad/(N·m)) at joints ``J_c``: ``Δq_i = compliance_i · τ_i(q)`` with ``τ`` the
  gravity torque on joint ``i`` (:func:`gravity_torques`) of the **nominal** robot with a nominal
  :class:`MassModel`. The sign convention: ``τ_i`` is the moment gravity exerts about the joint
  axis, and the joint yields in that direction (compliance ≥ 0 physically).
* harmonic transmission error at joints ``J_h``, groups ``h1s, h1c`` (once per revolution) and
  ``h2s, h2c`` (twice) in rad: ``Δq_i = h1s_i sin q_i + h1c_i cos q_i + h2s_i sin 2q_i +
  h2c_i cos 2q_i`` (``q_i`` the commanded joint position, without the DH θ offset).

**Where τ is computed.** Inside the kernel, from the commanded ``q`` and the nominal kinematics,
on every call: it depends on neither the deviations nor the data beyond ``q``, so no dataset,
CSV or sweep layer has to carry it, it stays jittable, and ``jax.jacfwd`` w.r.t. the
deviations sees it as a constant (its cost is one nominal frame chain per residual evaluation,
~ one extra forward kinematics). Using nominal rather than deviated kinematics for τ is a
second-order approximation (relative error ~ the geometric errors, ≤ 1e-3).

A robot turns the models on with ``robot.with_compliance(mass_model, joints=...)`` /
``robot.with_harmonics(joints=..., orders=(1, 2))`` (:class:`NonGeometricMixin`, shared by all
robot types); :func:`nongeometric_groups` adds the groups to ``robot.error_groups()``. A robot
type opts in with three lines: ``NonGeometricMixin`` as a base class, a field
``nongeometric: NonGeometric | None = None``, and ``+ nongeometric_groups(self)`` in its
``error_groups()``; its kernels already call ``effective_joint_angles``. The frames for τ are
computed here for :class:`~jaxcal.DHRobot` and for generic chains (the ``SerialChain``
attributes ``origin_R``, ``origin_t``, ``flange_R``, ``flange_t``, ``prismatic``; the mass model
then defaults to the chain's URDF ``<inertial>`` data); any other robot type provides
``link_frames_soa(q)`` (see :func:`joint_axes_soa`).
"""

from __future__ import annotations

import csv
import json
import math
import os

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core._params import Group
from .._core._trig import dh_joint_terms

__all__ = [
    "MassModel", "NonGeometric", "NonGeometricMixin", "gravity_torques", "nongeometric_groups",
    "joint_axes_soa", "COMPLIANCE_PRIOR_STD", "HARMONIC_PRIOR_STD", "HARMONIC_GROUPS",
]

#: default prior σ of a joint compliance (rad/(N·m)): the order of published joint compliances
#: of large 6R robots (joint stiffnesses ~1e5–1e7 N·m/rad)
COMPLIANCE_PRIOR_STD = 1e-6
#: default prior σ of a harmonic transmission-error amplitude (rad): 0.05°
HARMONIC_PRIOR_STD = math.radians(0.05)
#: harmonic groups by order: (sine, cosine) group names
HARMONIC_GROUPS = {1: ("h1s", "h1c"), 2: ("h2s", "h2c")}
GRAVITY = (0.0, 0.0, -9.81)

# register the group names and kinds, so that group_of("h1s_3") works without a layout
for _g, _u in (("compliance", "rad/(N*m)"),) + tuple((g, "rad") for gs in HARMONIC_GROUPS.values() for g in gs):
    Group.per_joint(_g, 1, _u, kind="nongeometric")

# HSR-JR680 mass model (an ASSUMPTION: the paper and the maker publish no inertial data). Masses
# of an 80 kg-payload-class, ~2 m reach six-axis arm (cf. published data of comparable arms:
# ~500-600 kg total with base), kg per moving link; centres of mass at the midpoint of each
# link's DH segment (see MassModel.default_for), payload 20 kg at the flange.
_PRESET_MASSES = {"hsr_jr680": ((120.0, 80.0, 60.0, 35.0, 8.0, 2.0), 20.0)}


class MassModel(eqx.Module):
    """Nominal mass model for gravity torques.

    Attributes:
        mass: ``[dof]`` mass of each moving link (kg): link ``i`` is moved by joint ``i``.
        com: ``[dof, 3]`` its centre of mass in the link frame (mm): for a DH robot frame ``i``
            (after ``A_i``; Craig's frame ``i`` for modified DH), for other robots the frame
            of the body moved by joint ``i`` (``link_frames_soa``).
        payload_mass: ``[]`` payload at the tool (kg).
        payload_com: ``[3]`` payload centre of mass in the flange frame (mm).
        gravity: ``[3]`` gravity in the robot base frame (m/s²), default ``(0, 0, −9.81)``.
    """

    mass: Float[Array, " dof"]
    com: Float[Array, "dof 3"]
    payload_mass: Float[Array, ""]
    payload_com: Float[Array, " 3"]
    gravity: Float[Array, " 3"]

    @property
    def dof(self) -> int:
        return int(self.mass.shape[0])

    @classmethod
    def from_arrays(cls, mass, com, payload_mass=0.0, payload_com=(0.0, 0.0, 0.0), gravity=GRAVITY) -> MassModel:
        """From host arrays: ``mass`` ``[dof]`` kg, ``com`` ``[dof, 3]`` mm, payload kg / mm, gravity m/s²."""
        m = np.asarray(mass, dtype=np.float64)
        c = np.asarray(com, dtype=np.float64)
        if m.ndim != 1 or c.shape != (m.shape[0], 3):
            raise ValueError(f"mass must be [dof] and com [dof, 3] (mm), got {m.shape} and {c.shape}")
        pc = np.asarray(payload_com, dtype=np.float64)
        g = np.asarray(gravity, dtype=np.float64)
        if pc.shape != (3,) or g.shape != (3,):
            raise ValueError("payload_com and gravity need 3 entries each")
        for name, v in (("mass", m), ("com", c), ("payload_com", pc), ("gravity", g)):
            if not np.all(np.isfinite(v)):
                raise ValueError(f"{name} contains NaN or inf")
        if np.any(m < 0) or float(payload_mass) < 0:
            raise ValueError("masses must be ≥ 0 kg")
        return cls(jnp.asarray(m), jnp.asarray(c), jnp.asarray(float(payload_mass)), jnp.asarray(pc), jnp.asarray(g))

    @classmethod
    def default_for(cls, robot, masses=None, payload_mass=None, payload_com=(0.0, 0.0, 0.0),
                    gravity=GRAVITY) -> MassModel:
        """A plausible mass model for a DH robot: link ``i``'s centre of mass at the midpoint of
        its DH segment (standard DH: between the origins of frames ``i−1`` and ``i``, a point
        fixed in link ``i``; modified DH: half the next row's ``a`` along ``x_i``). ``masses`` ``[dof]`` kg default to the preset's assumed values
        (``hsr_jr680``: 120, 80, 60, 35, 8, 2 kg + 20 kg payload at the flange — an
        **assumption**, no published inertial data); other robots must pass ``masses``."""
        if masses is None:
            if robot.name not in _PRESET_MASSES:
                raise ValueError(f"no assumed masses for robot {robot.name!r}: give its mass model (kg per link) as a "
                                 "file (--compliance FILE on the command line; jaxcal.MassModel.load) or, in "
                                 "Python, MassModel.default_for's masses argument")
            masses, pm = _PRESET_MASSES[robot.name]
            payload_mass = pm if payload_mass is None else payload_mass
        payload_mass = 0.0 if payload_mass is None else payload_mass
        alpha, a, d = (np.asarray(getattr(robot, k), np.float64) for k in ("alpha", "a", "d"))
        com = []
        for i in range(robot.dof):
            ca, sa = math.cos(alpha[i]), math.sin(alpha[i])
            if robot.convention == "standard":
                # origin of frame i-1 in frame i: -Rx(α)ᵀ (a, 0, d)
                v = -np.array([a[i], ca * 0.0 + sa * d[i], -sa * 0.0 + ca * d[i]])
            else:  # Craig: link i runs from frame i along x_i by the next row's a (rough)
                v = np.array([a[i + 1] if i + 1 < robot.dof else 0.0, 0.0, 0.0])
            com.append(0.5 * v)
        return cls.from_arrays(masses, np.stack(com), payload_mass, payload_com, gravity)

    @classmethod
    def from_chain(cls, chain, payload_mass=0.0, payload_com=(0.0, 0.0, 0.0), gravity=GRAVITY) -> MassModel:
        """From a URDF chain's ``<inertial>`` data (``chain.mass`` ``[dof]`` kg, ``chain.com``
        ``[dof, 3]`` mm in the joint frames)."""
        return cls.from_arrays(np.asarray(chain.mass), np.asarray(chain.com), payload_mass, payload_com, gravity)

    @classmethod
    def load(cls, path: str | os.PathLike) -> MassModel:
        """Read a mass model file.

        * JSON: ``{"mass_kg": [...], "com_mm": [[x, y, z], ...], "payload_kg": 0,
          "payload_com_mm": [x, y, z], "gravity_m_s2": [0, 0, -9.81]}`` (the last three optional).
        * CSV with a header ``link,mass_kg,com_x_mm,com_y_mm,com_z_mm``: one row per link
          (``link`` = 1..dof) and optionally a row ``payload`` (com in the flange frame) and a
          row ``gravity`` (its three ``com_*`` columns hold g in m/s², base frame).
        """
        path = os.fspath(path)
        if path.lower().endswith(".json"):
            with open(path) as f:
                obj = json.load(f)
            try:
                return cls.from_arrays(obj["mass_kg"], obj["com_mm"], obj.get("payload_kg", 0.0),
                                       obj.get("payload_com_mm", (0.0, 0.0, 0.0)), obj.get("gravity_m_s2", GRAVITY))
            except KeyError as e:
                raise ValueError(f"{path}: mass model JSON needs {e.args[0]!r}") from None
        with open(path, newline="") as f:
            rows = [r for r in csv.DictReader(f)]
        need = ("link", "mass_kg", "com_x_mm", "com_y_mm", "com_z_mm")
        if not rows or any(k not in rows[0] for k in need):
            raise ValueError(f"{path}: a mass model CSV needs the columns {', '.join(need)}")
        links, payload, gravity = {}, (0.0, (0.0, 0.0, 0.0)), GRAVITY
        for r in rows:
            key = r["link"].strip().lower()
            xyz = tuple(float(r[k]) for k in need[2:])
            if key == "payload":
                payload = (float(r["mass_kg"] or 0.0), xyz)
            elif key == "gravity":
                gravity = xyz
            else:
                links[int(key)] = (float(r["mass_kg"]), xyz)
        dof = len(links)
        if sorted(links) != list(range(1, dof + 1)):
            raise ValueError(f"{path}: links must be numbered 1..{dof}, got {sorted(links)}")
        return cls.from_arrays([links[i + 1][0] for i in range(dof)], [links[i + 1][1] for i in range(dof)],
                               payload[0], payload[1], gravity)

    def to_json(self) -> dict:
        """The JSON form read by :meth:`load`."""
        return {"mass_kg": np.asarray(self.mass).tolist(), "com_mm": np.asarray(self.com).tolist(),
                "payload_kg": float(self.payload_mass), "payload_com_mm": np.asarray(self.payload_com).tolist(),
                "gravity_m_s2": np.asarray(self.gravity).tolist()}


def _rot(u, v, c, s):
    return tuple(c * ui + s * vi for ui, vi in zip(u, v)), tuple(c * vi - s * ui for ui, vi in zip(u, v))


def _dh_link_frames(robot, q):
    """Nominal DH robot: per joint ``i`` the axis (origin ``o``, direction ``z``, three ``[n]``
    each) and the frame of link ``i`` (X, Y, Z, P); plus the flange frame."""
    ct, st, ca, sa, cb, sb, a, d = dh_joint_terms(robot, None, q)
    n = q.shape[0]
    one, zero = jnp.ones((n,), q.dtype), jnp.zeros((n,), q.dtype)
    X, Y, Z, P = (one, zero, zero), (zero, one, zero), (zero, zero, one), (zero, zero, zero)
    axes, frames = [], []
    standard = robot.convention == "standard"
    for i in range(robot.dof):
        hayati = (i + 1) in robot.beta_joints
        if standard:
            axes.append((P, Z))
            X, Y = _rot(X, Y, ct[i], st[i])
            P = tuple(p + d[i] * z + a[i] * x for p, z, x in zip(P, Z, X))
            Y, Z = _rot(Y, Z, ca[i], sa[i])
            if hayati:
                Z, X = _rot(Z, X, cb[i], sb[i])
        else:
            Y, Z = _rot(Y, Z, ca[i], sa[i])
            if hayati:
                Z, X = _rot(Z, X, cb[i], sb[i])
            P = tuple(p + a[i] * x for p, x in zip(P, X))
            axes.append((P, Z))
            X, Y = _rot(X, Y, ct[i], st[i])
            P = tuple(p + d[i] * z for p, z in zip(P, Z))
        frames.append((X, Y, Z, P))
    return axes, frames


def _serial_chain_frames(chain, q):
    """Nominal generic chain (:class:`~jaxcal.SerialChain`: ``origin_R``, ``origin_t``,
    ``flange_R``, ``flange_t``, ``prismatic``): per joint the axis (``z`` of the joint frame
    before motion, through its origin) and the joint frame after motion (the body moved by the
    joint, where ``chain.com`` lives); plus the tip link frame. Dense 3×3 products (host
    constants when concrete, traced when the chain is a jit argument), the same recursion as
    ``SerialChain.frame_soa`` without deviations."""
    n = q.shape[0]
    dtype = q.dtype
    R = jnp.asarray(chain.origin_R).astype(dtype)
    t = jnp.asarray(chain.origin_t).astype(dtype)
    one, zero = jnp.ones((n,), dtype), jnp.zeros((n,), dtype)
    cols = ((one, zero, zero), (zero, one, zero), (zero, zero, one))
    P = (zero, zero, zero)

    def mul(cols, M):  # F ← F·M for a 3×3 M
        return tuple(tuple(sum(cols[m][k] * M[m, c] for m in range(3)) for k in range(3)) for c in range(3))

    axes, frames = [], []
    for i in range(chain.dof):
        P = tuple(P[k] + sum(cols[m][k] * t[i, m] for m in range(3)) for k in range(3))
        X, Y, Z = mul(cols, R[i])
        axes.append((P, Z))
        if chain.prismatic[i]:
            P = tuple(P[k] + Z[k] * q[:, i] for k in range(3))
        else:
            c, s_ = jnp.cos(q[:, i]), jnp.sin(q[:, i])
            X, Y = _rot(X, Y, c, s_)
        cols = (X, Y, Z)
        frames.append((X, Y, Z, P))
    ft = jnp.asarray(chain.flange_t).astype(dtype)
    P = tuple(P[k] + sum(cols[m][k] * ft[m] for m in range(3)) for k in range(3))
    tip = (*mul(cols, jnp.asarray(chain.flange_R).astype(dtype)), P)
    return axes, frames, tip


def joint_axes_soa(robot, q: Float[Array, "n dof"]):
    """Per joint of the nominal robot: ``(o_i, z_i)`` (a point on the axis in mm and the unit
    axis, base frame, three ``[n]`` each) and the frame ``(X, Y, Z, P)`` of the body moved by the
    joint (where :attr:`MassModel.com` is given), as lists over joints, and the flange/tip frame
    (where the payload sits). DH robots and generic chains (``origin_R``...) are handled here;
    other robot types provide ``link_frames_soa(q)`` returning the same triple."""
    if hasattr(robot, "link_frames_soa"):
        return robot.link_frames_soa(q)
    if hasattr(robot, "origin_R"):
        return _serial_chain_frames(robot, q)
    axes, frames = _dh_link_frames(robot, q)
    return axes, frames, frames[-1]


def gravity_torques(robot, mass_model: MassModel, q: Float[Array, "n dof"]) -> Float[Array, "n dof"]:
    """Gravity torque on each joint of the nominal robot at joint positions ``q``.

    ``τ_i = Σ_{j≥i} z_i · ((c_j − o_i) × m_j g)`` (N·m), with ``z_i``/``o_i`` the axis of joint
    ``i``, ``c_j`` the centre of mass of link ``j`` (and the payload, at the flange) in the base
    frame (m). Computed over the batch in structure-of-arrays form from suffix sums
    ``M_i = Σ_{j≥i} m_j``, ``S_i = Σ_{j≥i} m_j c_j``: ``τ_i = z_i · ((S_i − M_i o_i) × g)``.
    Pure, jittable, differentiable in ``q`` and in the mass model.

    Args:
        robot: nominal robot (:class:`~jaxcal.DHRobot` or a robot with ``link_frames_soa``).
        mass_model: :class:`MassModel` with ``robot.dof`` links.
        q: ``[n, dof]`` joint positions (rad).

    Returns:
        ``[n, dof]`` torques (N·m) in the dtype of ``q`` (at a prismatic joint of a generic
        chain: the gravity force along its axis, N).
    """
    if mass_model.dof != robot.dof:
        raise ValueError(f"mass model has {mass_model.dof} links, robot {robot.name!r} has {robot.dof} joints")
    q = jnp.asarray(q)
    dtype = q.dtype
    axes, frames, tip = joint_axes_soa(robot, q)
    m = jnp.asarray(mass_model.mass).astype(dtype)
    c = jnp.asarray(mass_model.com).astype(dtype) * 1e-3  # m
    g = jnp.asarray(mass_model.gravity).astype(dtype)
    pm = jnp.asarray(mass_model.payload_mass).astype(dtype)
    pc = jnp.asarray(mass_model.payload_com).astype(dtype) * 1e-3

    def point(frame, v):  # v [3] in the frame -> base, in m
        X, Y, Z, P = frame
        return tuple(P[k] * 1e-3 + v[0] * X[k] + v[1] * Y[k] + v[2] * Z[k] for k in range(3))

    # suffix sums from the flange inward, starting with the payload
    pay = point(tip, pc)
    M = pm
    S = tuple(pm * pay[k] for k in range(3))
    tau = [None] * robot.dof
    M_at = [None] * robot.dof
    for i in reversed(range(robot.dof)):
        ci = point(frames[i], c[i])
        M = M + m[i]
        M_at[i] = M
        S = tuple(S[k] + m[i] * ci[k] for k in range(3))
        o, z = axes[i]
        r = tuple(S[k] - M * o[k] * 1e-3 for k in range(3))  # Σ m_j (c_j − o_i)
        mom = (r[1] * g[2] - r[2] * g[1], r[2] * g[0] - r[0] * g[2], r[0] * g[1] - r[1] * g[0])
        tau[i] = z[0] * mom[0] + z[1] * mom[1] + z[2] * mom[2]
    for i, p in enumerate(getattr(robot, "prismatic", ())):
        if p:  # a prismatic joint carries the gravity force along its axis (N), not a torque
            z = axes[i][1]
            tau[i] = M_at[i] * (z[0] * g[0] + z[1] * g[1] + z[2] * g[2])
    n = q.shape[0]
    return jnp.stack([jnp.broadcast_to(t, (n,)) for t in tau], axis=-1)


class NonGeometric(eqx.Module):
    """Which non-geometric error models a robot carries (a robot field; ``None`` = none).

    Attributes:
        mass_model: nominal :class:`MassModel` for the compliance model (``None``: no compliance).
        compliance_joints: 1-based joints with a compliance parameter (static).
        harmonic_joints: 1-based joints with harmonic transmission errors (static).
        harmonic_orders: harmonics modelled, subset of ``(1, 2)`` (static).
    """

    mass_model: MassModel | None = None
    compliance_joints: tuple[int, ...] = eqx.field(static=True, default=())
    harmonic_joints: tuple[int, ...] = eqx.field(static=True, default=())
    harmonic_orders: tuple[int, ...] = eqx.field(static=True, default=(1, 2))


def nongeometric_groups(robot) -> tuple[Group, ...]:
    """The robot's non-geometric groups (``compliance``, ``h1s``, ``h1c``, ``h2s``, ``h2c``),
    entries named ``<group>_<joint>`` for the enabled joints only."""
    ng = getattr(robot, "nongeometric", None)
    if ng is None:
        return ()
    out = []
    if ng.mass_model is not None and ng.compliance_joints:
        js = ng.compliance_joints
        out.append(Group("compliance", tuple(f"compliance_{j}" for j in js), ("rad/(N*m)",) * len(js),
                         "nongeometric", (len(js),), COMPLIANCE_PRIOR_STD))
    if ng.harmonic_joints:
        js = ng.harmonic_joints
        for order in ng.harmonic_orders:
            for gname in HARMONIC_GROUPS[order]:
                out.append(Group(gname, tuple(f"{gname}_{j}" for j in js), ("rad",) * len(js),
                                 "nongeometric", (len(js),), HARMONIC_PRIOR_STD))
    return tuple(out)


def _spread(values, joints, dof, dtype):
    """A ``[dof]`` vector with ``values`` at the 1-based ``joints`` and zeros elsewhere."""
    idx = np.asarray(joints, dtype=int) - 1
    return jnp.zeros(values.shape[:-1] + (dof,), dtype).at[..., idx].set(jnp.asarray(values).astype(dtype))


def _compliance_correction(robot, dev, q):
    ng = robot.nongeometric
    tau = gravity_torques(robot, ng.mass_model, q)
    return tau * _spread(dev.compliance, ng.compliance_joints, robot.dof, q.dtype)


def _harmonic_correction(group):
    order = 1 if group.startswith("h1") else 2
    trig = jnp.sin if group.endswith("s") else jnp.cos

    def fn(robot, dev, q):
        coef = _spread(getattr(dev, group), robot.nongeometric.harmonic_joints, robot.dof, q.dtype)
        return coef * trig(order * q)

    return fn


def register_corrections(register) -> None:
    """Register the joint-space corrections with ``register(group, fn)``
    (:func:`jaxcal._models._kinematics.register_joint_correction`; called by that module at import)."""
    register("compliance", _compliance_correction)
    for names in HARMONIC_GROUPS.values():
        for gname in names:
            register(gname, _harmonic_correction(gname))


def _joints(joints, dof, what) -> tuple[int, ...]:
    js = tuple(sorted({int(j) for j in joints}))
    if not js or js[0] < 1 or js[-1] > dof:
        raise ValueError(f"{what} joints must be 1-based joint numbers in 1..{dof}, got {joints!r}")
    return js


class NonGeometricMixin:
    """``with_compliance`` / ``with_harmonics`` for every robot type with a ``nongeometric``
    field (one implementation for DH robots and generic chains)."""

    def with_compliance(self, mass_model: MassModel | str | os.PathLike | None = None, joints=None):
        """A copy with a joint-compliance group (rad/(N·m)) at ``joints``.

        Args:
            mass_model: a :class:`MassModel`, a file for :meth:`MassModel.load`, or ``None``:
                :meth:`MassModel.from_chain` for a chain with inertial data, else
                :meth:`MassModel.default_for` (assumed preset masses).
            joints: 1-based joints; default: every revolute joint whose nominal gravity torque is
                not identically zero over the joint limits (e.g. not a vertical first axis,
                tested on 256 random configurations).
        """
        if mass_model is None:
            mass_model = MassModel.from_chain(self) if hasattr(self, "com") else MassModel.default_for(self)
        elif not isinstance(mass_model, MassModel):
            mass_model = MassModel.load(mass_model)
        if mass_model.dof != self.dof:
            raise ValueError(f"mass model has {mass_model.dof} links, robot {self.name!r} has {self.dof} joints")
        revolute = [not p for p in getattr(self, "prismatic", (False,) * self.dof)]
        if joints is None:
            rng = np.random.default_rng(0)
            lo, hi = np.asarray(self.q_min, np.float64), np.asarray(self.q_max, np.float64)
            q = jnp.asarray(lo + (hi - lo) * rng.random((256, self.dof)))
            tau = np.abs(np.asarray(gravity_torques(self, mass_model, q))).max(axis=0)
            joints = [j + 1 for j in range(self.dof) if revolute[j] and tau[j] > 1e-9 * max(tau.max(), 1e-300)]
            if not joints:
                raise ValueError("no joint carries a gravity torque with this mass model")
        js = _joints(joints, self.dof, "compliance")
        if not all(revolute[j - 1] for j in js):
            raise ValueError("compliance is modelled at revolute joints only")
        ng = self.nongeometric or NonGeometric()
        new = NonGeometric(mass_model, js, ng.harmonic_joints, ng.harmonic_orders)
        return eqx.tree_at(lambda r: r.nongeometric, self, new, is_leaf=lambda x: x is None)

    def with_harmonics(self, joints=None, orders=(1, 2)):
        """A copy with harmonic transmission errors (rad) at ``joints`` (1-based; default all
        revolute joints), ``orders`` ⊂ ``(1, 2)``: groups ``h1s, h1c`` (once per revolution),
        ``h2s, h2c`` (twice)."""
        revolute = [not p for p in getattr(self, "prismatic", (False,) * self.dof)]
        if joints is None:
            joints = [j + 1 for j in range(self.dof) if revolute[j]]
        js = _joints(joints, self.dof, "harmonic")
        if not all(revolute[j - 1] for j in js):
            raise ValueError("harmonic transmission errors are modelled at revolute joints only")
        orders = tuple(sorted({int(o) for o in orders}))
        if not orders or any(o not in HARMONIC_GROUPS for o in orders):
            raise ValueError(f"orders must be a non-empty subset of (1, 2), got {orders}")
        ng = self.nongeometric or NonGeometric()
        new = NonGeometric(ng.mass_model if ng.compliance_joints else None, ng.compliance_joints, js, orders)
        return eqx.tree_at(lambda r: r.nongeometric, self, new, is_leaf=lambda x: x is None)

    def without_nongeometric(self):
        """A copy with no non-geometric error model (the geometric-only robot)."""
        return eqx.tree_at(lambda r: r.nongeometric, self, None, is_leaf=lambda x: x is None)


def nongeometric_to_dict(robot) -> dict | None:
    """JSON form of ``robot.nongeometric`` (``None`` when the robot has none), for result files."""
    ng = getattr(robot, "nongeometric", None)
    if ng is None:
        return None
    return {"mass_model": None if ng.mass_model is None else ng.mass_model.to_json(),
            "compliance_joints": list(ng.compliance_joints), "harmonic_joints": list(ng.harmonic_joints),
            "harmonic_orders": list(ng.harmonic_orders)}


def nongeometric_from_dict(robot, d: dict | None):
    """``robot`` with the models of :func:`nongeometric_to_dict`'s ``d`` (``None``: unchanged)."""
    if not d:
        return robot
    mm = d.get("mass_model")
    mm = None if mm is None else MassModel.from_arrays(mm["mass_kg"], mm["com_mm"], mm.get("payload_kg", 0.0),
                                                       mm.get("payload_com_mm", (0.0, 0.0, 0.0)),
                                                       mm.get("gravity_m_s2", GRAVITY))
    if mm is not None and d.get("compliance_joints"):
        robot = robot.with_compliance(mm, joints=d["compliance_joints"])
    if d.get("harmonic_joints"):
        robot = robot.with_harmonics(d["harmonic_joints"], orders=d.get("harmonic_orders", (1, 2)))
    return robot
