"""Forward kinematics over a whole batch, in structure-of-arrays form.

Each rotation column and the position are kept as separate ``[n]`` arrays and updated joint by
joint with closed-form products by elementary rotations, instead of multiplying ``[n, 4, 4]``
matrices per sample. On CPU this is ~15x faster for residuals and Jacobians and
it makes ``jax.jacfwd`` Jacobians w.r.t. the calibration parameters cheap.

Positions (``fk_position``, the draw-wire and position measurement models) need no frame: the
tool point is carried from the flange inward through each joint transform (two plane rotations
and two additions per joint), which halved the ``jacfwd`` Jacobian (2 000 × 24, float64:
2.5 ms → 1.2 ms, ``benchmarks/results/kinematics_cpu.md``). ``fk_pose`` and the pose model use
the frame chain.
"""

from __future__ import annotations

import inspect

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core._buckets import bucket_size, buckets_enabled, pad_rows
from .._core._params import Deviations
from .._core._precision import uncommitted
from .._core._trig import angle_sum_trig, dh_joint_terms, materialised, shared_joint_trig
from .._core._xla import jit
from ._nongeometric import register_corrections
from ._robot import DHRobot

__all__ = [
    "fk_position", "fk_pose", "tool_point_soa", "check_joint_angles", "rotvec_to_matrix",
    "effective_joint_angles", "register_joint_correction", "materialised", "angle_sum_trig", "shared_joint_trig",
]

Vec3 = tuple  # three [n] arrays (or python floats before the first joint)

#: joint-space (non-geometric) error models: group name -> ``fn(robot, deviations, q) -> Δq [n, dof]``
_JOINT_CORRECTIONS: dict = {}


def register_joint_correction(group: str, fn) -> None:
    """Register a joint-space error model: when a :class:`~jaxcal.Deviations` has the group
    ``group``, every kinematics kernel uses ``q + fn(robot, deviations, q)`` (``[n, dof]``) as
    the joint positions. This is how non-geometric errors (compliance, transmission errors)
    enter the forward kinematics of every robot type."""
    _JOINT_CORRECTIONS[group] = fn


register_corrections(register_joint_correction)  # compliance and harmonic errors (jaxcal._models._nongeometric)


def effective_joint_angles(robot, dev, q: Float[Array, "n dof"]) -> Float[Array, "n dof"]:
    """``q`` plus every registered joint-space correction whose group ``dev`` has (``q`` itself
    when there is none, so plain geometric models compute exactly what they did). Every
    correction is a function of the commanded ``q`` (they add, none sees another's output)."""
    if dev is None:
        return q
    q_eff = q
    for group, fn in _JOINT_CORRECTIONS.items():
        if group in dev.values:
            q_eff = q_eff + fn(robot, dev, q)
    return q_eff


def check_joint_angles(robot: DHRobot, q) -> Array:
    """Validate the joint-angle array's shape (``[n, dof]`` or ``[dof]``, rad) and return it."""
    q = jnp.asarray(q)
    if q.ndim not in (1, 2) or q.shape[-1] != robot.dof:
        raise ValueError(
            f"joint angles must have shape [n, {robot.dof}] (or [{robot.dof}]) for robot "
            f"{robot.name!r} with {robot.dof} joints, got {q.shape}"
        )
    if not jnp.issubdtype(q.dtype, jnp.floating):
        q = q.astype(jnp.result_type(float))
    return q


def _rot(u: Vec3, v: Vec3, c, s) -> tuple[Vec3, Vec3]:
    """Columns (u, v) of R after R ← R·G, G a plane rotation by (c, s) taking u toward v."""
    u2 = tuple(c * ui + s * vi for ui, vi in zip(u, v))
    v2 = tuple(c * vi - s * ui for ui, vi in zip(u, v))
    return u2, v2


def _axpy(p: Vec3, k, u: Vec3) -> Vec3:
    return tuple(pi + k * ui for pi, ui in zip(p, u))


def _joint_terms(robot: DHRobot, dev: Deviations | None, q: Float[Array, "n dof"]):
    """cos/sin of θ + q_eff (``[dof, n]``), of α and β (``[dof]``), and a, d (``[dof]``, mm) of the
    deviated robot, in the dtype of ``q``; ``q_eff`` is ``q`` with the registered joint-space
    corrections (:func:`effective_joint_angles`)."""
    return dh_joint_terms(robot, dev, effective_joint_angles(robot, dev, q))


def _tip_kwargs(robot, tip) -> dict:
    """``{"tip": tip}`` for a robot with named tips (:class:`~jaxcal.KinematicTree`), ``{}`` for
    ``tip=None`` (the robot's one tip, or a tree's default tip)."""
    if tip is None:
        return {}
    if not robot.tip_names():
        raise ValueError(f"robot {robot.name!r} has one tip: tip={tip!r} names a tip of a kinematic tree "
                         "(jaxcal.load_urdf with tips)")
    return {"tip": tip}


def _chain(robot: DHRobot, dev: Deviations | None, q: Float[Array, "n dof"], tip: str | None = None):
    """Flange frame as SoA: columns X, Y, Z and origin P, each a triple of ``[n]`` arrays
    (``tip``: that tip's link frame, for a robot with named tips)."""
    if hasattr(robot, "frame_soa"):  # other robot types bring their own kernel
        return robot.frame_soa(dev, q, **_tip_kwargs(robot, tip))
    ct, st, ca, sa, cb, sb, a, d = _joint_terms(robot, dev, q)
    X: Vec3 = (1.0, 0.0, 0.0)
    Y: Vec3 = (0.0, 1.0, 0.0)
    Z: Vec3 = (0.0, 0.0, 1.0)
    P: Vec3 = (0.0, 0.0, 0.0)
    standard = robot.convention == "standard"
    for i in range(robot.dof):
        hayati = (i + 1) in robot.beta_joints
        if standard:  # Rz(θ) Tz(d) Tx(a) Rx(α) [Ry(β)]
            X, Y = _rot(X, Y, ct[i], st[i])
            P = _axpy(_axpy(P, d[i], Z), a[i], X)
            Y, Z = _rot(Y, Z, ca[i], sa[i])
            if hayati:
                Z, X = _rot(Z, X, cb[i], sb[i])
        else:  # Craig: Rx(α) [Ry(β)] Tx(a) Rz(θ) Tz(d)
            Y, Z = _rot(Y, Z, ca[i], sa[i])
            if hayati:
                Z, X = _rot(Z, X, cb[i], sb[i])
            P = _axpy(P, a[i], X)
            X, Y = _rot(X, Y, ct[i], st[i])
            P = _axpy(P, d[i], Z)
    n = q.shape[0]
    full = lambda v: tuple(jnp.broadcast_to(jnp.asarray(c, q.dtype), (n,)) for c in v)  # noqa: E731
    return full(X), full(Y), full(Z), full(P)


def _tool_vector(robot: DHRobot, dev: Deviations | None, dtype, tip: str | None = None) -> Float[Array, " 3"]:
    """The tool point in the flange frame (nominal + Δtool, mm); ``tip``: that tip's
    (:meth:`jaxcal.KinematicTree.tool_vector`)."""
    if tip is not None:
        kw = _tip_kwargs(robot, tip)
        return robot.tool_vector(dev, dtype, **kw)
    t = jnp.asarray(robot.tool).astype(dtype)
    if dev is not None:
        t = t + jnp.asarray(dev.tool).astype(dtype)
    return t


def _tool_offset(robot: DHRobot, dev: Deviations | None, frame, dtype, tip: str | None = None) -> Vec3:
    X, Y, Z, P = frame
    t = _tool_vector(robot, dev, dtype, tip)
    return tuple(P[k] + t[0] * X[k] + t[1] * Y[k] + t[2] * Z[k] for k in range(3))


def _point_in_base(robot: DHRobot, dev: Deviations | None, q: Float[Array, "n dof"], point, *,
                   scalar_consumer: bool = False, tip: str | None = None) -> Vec3:
    """A point given in the flange frame (``[3]``, mm), expressed in the base frame: three ``[n]``.

    Applied from the flange inward, ``p ← A_i(q_i)·p`` for ``i = dof … 1``, each joint
    transform acting on a point rather than on a frame: a point needs two plane rotations and
    two additions per joint where a frame needs three columns rotated (~4x the arithmetic),
    and ``jax.jacfwd`` pushes every tangent through the same cheap recursion. Equal to the
    flange frame of :func:`_chain` applied to the point (tested to round-off). Other robot
    types bring their own kernel (``robot.point_in_base``; ``scalar_consumer``: see
    :func:`tool_point_soa`).
    """
    if hasattr(robot, "point_in_base"):
        return robot.point_in_base(dev, q, point, fused=scalar_consumer, **_tip_kwargs(robot, tip))
    ct, st, ca, sa, cb, sb, a, d = _joint_terms(robot, dev, q)
    x, y, z = (point[k] for k in range(3))
    standard = robot.convention == "standard"
    for i in reversed(range(robot.dof)):
        hayati = (i + 1) in robot.beta_joints
        if standard:  # Rz(θ) Tz(d) Tx(a) Rx(α) [Ry(β)] · p
            if hayati:
                z, x = cb[i] * z - sb[i] * x, sb[i] * z + cb[i] * x
            y, z = ca[i] * y - sa[i] * z, sa[i] * y + ca[i] * z
            x, z = x + a[i], z + d[i]
            x, y = ct[i] * x - st[i] * y, st[i] * x + ct[i] * y
        else:  # Craig: Rx(α) [Ry(β)] Tx(a) Rz(θ) Tz(d) · p
            z = z + d[i]
            x, y = ct[i] * x - st[i] * y, st[i] * x + ct[i] * y
            x = x + a[i]
            if hayati:
                z, x = cb[i] * z - sb[i] * x, sb[i] * z + cb[i] * x
            y, z = ca[i] * y - sa[i] * z, sa[i] * y + ca[i] * z
    n = q.shape[0]
    return tuple(jnp.broadcast_to(c, (n,)) for c in (x, y, z))


def tool_point_soa(robot: DHRobot, dev: Deviations | None, q: Float[Array, "n dof"], *, tool: bool = True,
                   scalar_consumer: bool = False, tip: str | None = None) -> Vec3:
    """Tool point (or, with ``tool=False``, the flange origin) in the base frame as three
    ``[n]`` arrays (mm). ``q`` must be ``[n, dof]``.

    ``scalar_consumer=True`` promises that the caller folds the three coordinates into one value
    per sample (a distance): robots with a choice of kernels (:class:`~jaxcal.SerialChain`) then
    use their fully fused elementwise one, which is fast under ``jax.jacfwd`` for one output but
    which XLA CPU recomputes per output when three coordinates are kept. ``tip``: that tip of a
    :class:`~jaxcal.KinematicTree` (its tool point and its tip link origin; default: the
    robot's one tip, a tree's default tip)."""
    t = _tool_vector(robot, dev, q.dtype, tip) if tool else jnp.zeros(3, q.dtype)
    return _point_in_base(robot, dev, q, t, scalar_consumer=scalar_consumer, tip=tip)


def fk_position(
    robot: DHRobot,
    q: Float[Array, "n dof"],
    deviations: Deviations | None = None,
    *,
    tool: bool = True,
    tip: str | None = None,
) -> Float[Array, "n 3"]:
    """Position of the tool point (``tool=True``) or flange origin in the base frame.

    Pure and jittable; differentiable in ``deviations`` (use ``jax.jacfwd``).

    Args:
        robot: nominal model.
        q: joint angles ``[n, dof]`` or ``[dof]`` (rad).
        deviations: Δ from nominal (``None`` = nominal robot).
        tool: include the tool point offset (nominal + Δtool).
        tip: a tip of a :class:`~jaxcal.KinematicTree` (``None``: the robot's one tip, a
            tree's default tip).

    Returns:
        ``[n, 3]`` (or ``[3]``) positions in mm, in the dtype of ``q``.
    """
    q = check_joint_angles(robot, q)
    single = q.ndim == 1
    q2 = q[None] if single else q
    out = jnp.stack(tool_point_soa(robot, deviations, q2, tool=tool, tip=tip), axis=-1)
    return out[0] if single else out


def fk_pose(
    robot: DHRobot,
    q: Float[Array, "n dof"],
    deviations: Deviations | None = None,
    *,
    tool: bool = False,
    tip: str | None = None,
) -> Float[Array, "n 4 4"]:
    """Homogeneous transform ``T_base_flange`` (paper eq. 2), or ``T_base_tool`` with ``tool=True``
    (flange orientation, origin at the tool point).

    Args:
        robot: nominal model.
        q: joint angles ``[n, dof]`` or ``[dof]`` (rad).
        deviations: Δ from nominal (``None`` = nominal robot).
        tool: move the origin to the tool point.
        tip: a tip of a :class:`~jaxcal.KinematicTree` (``None``: the robot's one tip, a
            tree's default tip).

    Returns:
        ``[n, 4, 4]`` (or ``[4, 4]``) transforms, translation in mm.
    """
    q = check_joint_angles(robot, q)
    single = q.ndim == 1
    q2 = q[None] if single else q
    X, Y, Z, P = frame = _chain(robot, deviations, q2, tip)
    if tool:
        P = _tool_offset(robot, deviations, frame, q2.dtype, tip)
    R = jnp.stack([jnp.stack(X, -1), jnp.stack(Y, -1), jnp.stack(Z, -1)], axis=-1)  # [n,3,3]
    top = jnp.concatenate([R, jnp.stack(P, -1)[..., None]], axis=-1)  # [n,3,4]
    bottom = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 0.0, 1.0], q.dtype), top.shape[:-2] + (1, 4))
    T = jnp.concatenate([top, bottom], axis=-2)
    return T[0] if single else T


def rotvec_to_matrix(w: Float[Array, "... 3"]) -> Float[Array, "... 3 3"]:
    """Rotation matrix ``exp([w]×)`` of a rotation vector ``w`` (rad; Rodrigues' formula).

    Differentiable everywhere, including ``w = 0`` (series expansions below θ² = 1e-8), so
    ``jax.jacfwd`` of a frame at the nominal (zero) correction is exact.
    """
    w = jnp.asarray(w)
    t2 = jnp.sum(w * w, axis=-1)[..., None, None]
    small = t2 < 1e-8
    t2s = jnp.where(small, 1.0, t2)
    th = jnp.sqrt(t2s)
    a = jnp.where(small, 1.0 - t2 / 6.0, jnp.sin(th) / th)
    b = jnp.where(small, 0.5 - t2 / 24.0, (1.0 - jnp.cos(th)) / t2s)
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    o = jnp.zeros_like(x)
    K = jnp.stack([jnp.stack([o, -z, y], -1), jnp.stack([z, o, -x], -1), jnp.stack([-y, x, o], -1)], -2)
    eye = jnp.eye(3, dtype=w.dtype)
    return eye + a * K + b * (K @ K)


def _host_kinematics(fn):
    """``fn`` (:func:`fk_position` or :func:`fk_pose`) compiled for host-side callers that evaluate
    the kinematics outside ``jit`` (op by op they run as hundreds of small XLA programs), its rows
    padded to their shape bucket (:func:`~jaxcal._core._buckets.bucket_size`; ``JAXCAL_BUCKETS=off``:
    as given) so that one program serves the training rows, the held-out rows and every other
    count of a bucket; NumPy out (``[n, 3]`` mm, ``[n, 4, 4]``). ``tool`` defaults as in ``fn``
    (the tool point for :func:`fk_position`, the flange for :func:`fk_pose`); ``tip``: a tip of a
    :class:`~jaxcal.KinematicTree` (``None``: the robot's one tip, a tree's default tip)."""
    compiled = jit(fn, static_argnames=("tool", "tip"))
    default = inspect.signature(fn).parameters["tool"].default  # fk_position: the tool point; fk_pose: the flange

    def call(robot, q, deviations=None, *, tool: bool = default, tip: str | None = None) -> np.ndarray:
        n = int(q.shape[0])
        n_to = bucket_size(n) if buckets_enabled() else n
        if n_to != n:
            q = pad_rows(q, None, n_to)[0]
        at = {} if tip is None else {"tip": tip}  # a kinematic tree's tip (static: one program per tip)
        # uncommitted: a fit's deviations and fresh ones run one program (jax.jit compiles per placement)
        return np.asarray(compiled(robot, q, uncommitted(deviations), tool=tool, **at))[:n]

    call.__name__ = call.__qualname__ = f"{fn.__name__}_jit"
    call.__doc__ = f":func:`{fn.__name__}` for host-side callers (compiled once per shape bucket; NumPy out)."
    return call


fk_position_jit = _host_kinematics(fk_position)
fk_pose_jit = _host_kinematics(fk_pose)
