"""Messy "real" data, simulated: what a real draw-wire or tracker session looks like.

:func:`simulate_experiment` reproduces the paper's idealised experiment: the anchor is known,
joints sweep their whole range, readings are exact apart from Gaussian noise, and the model
holds the truth. Real data is different, and every difference is a feature the
library must handle; this module simulates each of them from one ``jax.random`` key, so those
features can be tested without real data:

=====================================  ===========================================================
mess                                   what it imitates
=====================================  ===========================================================
narrow joint coverage                  a real session visits a small part of the workspace
                                       (wrist joints moving 10–20°): ``joint_ranges_deg``
quantised joint readings               controllers log joint angles at 0.1°: the robot moves to
                                       the exact commanded angle, the file says the rounded one
unknown anchor / sensor frame          the wire exit point is guessed (500 mm off is possible);
                                       a tracker measures in its own frame, not the base frame:
                                       initial errors of ~150 mm instead of the simulation's 4 mm
unknown cable zero offset              the wire's zero is not where the model assumes
unmodelled joint compliance            gravity bends the joints (0.01–0.03° at the shoulder):
                                       a systematic error the DH model cannot absorb
unmodelled gear error                  once-per-revolution transmission error on each joint
gross outliers                         a mis-read or slipped wire: one such row among 40 turned
                                       an unguarded LM into 10⁷ mm parameters
unmeasured workspace                   calibrations are used where nobody measured: ``far`` is
                                       a test set over the whole joint limits
=====================================  ===========================================================

The readings come from the TRUE model (nominal + :attr:`MessyExperiment.true_deviations`) at
the ACTUAL joint angles ``q_actual = q_cmd + gear(q_cmd) + compliance(q_cmd)``
(:func:`actual_joint_angles`); the recorded joint readings are ``q_cmd`` rounded to the
quantum. So with the compliance, gear error, quantisation, noise and outliers switched off,
the true deviations reproduce the readings to round-off (tested).

:func:`region_split` / :func:`region_folds` split a data set by a joint's reading, for
"train on one half of the workspace, test on the other" validation (validate by
workspace region, not only by a random split).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core._params import Deviations
from .._core._precision import warn_if_float32
from .._datasets._dataset import Dataset
from .._models._kinematics import tool_point_soa
from .._models._robot import DHRobot, sample_joint_angles
from .._sensors._measurement import CableLength, MeasurementModel, Position
from ._simulate import check_simulation_settings, default_anchor, draw_deviations, workspace_mask

__all__ = [
    "MessyExperiment",
    "simulate_messy",
    "region_split",
    "region_folds",
    "gravity_torques",
    "actual_joint_angles",
    "default_compliance",
    "default_joint_ranges_deg",
]

#: half-width (deg) of the default visited range of joints 1..6, centred in the joint limits:
#: a real draw-wire session (wrist joints moving 16°). Joints beyond the 6th: 45°.
DEFAULT_HALF_RANGE_DEG = (45.0, 30.0, 30.0, 8.0, 8.0, 45.0)
#: point-mass gravity model (see :func:`gravity_torques`): kg per metre of link length …
LINK_MASS_KG_PER_M = 20.0
#: … and the wrist + payload mass at the wrist centre (kg): a 20 kg-class arm.
WRIST_MASS_KG = 30.0
GRAVITY_M_S2 = 9.81
#: the default compliance bends the shoulder (joint 2) by this much at its median gravity
#: torque over the joint limits (deg), see :func:`default_compliance`.
DEFAULT_SHOULDER_DEFLECTION_DEG = 0.02
#: default σ of the cable's true zero offset (mm) when ``cable_offset_mm`` is not given.
CABLE_OFFSET_STD_MM = 20.0
#: candidate poses drawn per kept pose (most are kept: the filter rejects few).
_OVERSAMPLE = 8
#: poses used to set the default compliance (fixed, so the default does not depend on the key).
_N_REFERENCE_POSES = 512


class _FrozenDict(dict):
    """A dict that can sit in a static pytree field (hashable; do not mutate)."""

    def __hash__(self):  # pragma: no cover - only used by jit caches
        return hash(tuple(sorted((k, repr(v)) for k, v in self.items())))


class MessyExperiment(eqx.Module):
    """A simulated "real" calibration session; the simulation knows the truth.

    Attributes:
        robot: the nominal robot (DH table from the data sheet).
        measurement: the NOMINAL measurement model the user would build:
            :class:`~jaxcal.CableLength` with the guessed anchor (mm, base frame), or
            :class:`~jaxcal.Position` with the guessed sensor frame (identity).
        true_deviations: the truth relative to ``robot`` and ``measurement``: DH deviations
            (rad, mm; β at the robot's Hayati joints); cable: ``anchor`` = true − guessed
            anchor (mm), ``cable_offset`` = the wire's true zero offset (mm); position:
            ``base_rotation`` (rad, rotation vector) and ``base_translation`` (mm) with
            ``R_true = exp(base_rotation)·R_guess`` and ``t_true = t_guess + base_translation``
            (exactly how :meth:`Position.predict` applies them). ``tool``: the attachment's
            offset ``tool_offset_mm`` (zero by default).
        train, test: a random split of the measured poses (narrow coverage); joint readings
            ``q`` ``[n, dof]`` rad (quantised), readings ``y`` mm (``[n]`` lengths or
            ``[n, 3]`` positions). ``train`` holds the outliers.
        far: ``far_samples`` poses over the whole joint limits (inside the sensor's range), with
            the same noise and unmodelled errors but no outliers: the "unmeasured workspace".
        outlier_rows: row indices into ``train`` that carry a gross error (sorted).
        noise_std: ``[]`` Gaussian noise σ on each reading (mm).
        settings: the options used, defaults resolved (``joint_ranges_deg``,
            ``compliance_deg_per_knm`` per joint, ``cable_offset_mm``, …) plus the drawn
            ``gear_phase_rad`` per joint, so :func:`actual_joint_angles` can replay the truth.
    """

    robot: DHRobot
    measurement: MeasurementModel
    true_deviations: Deviations
    train: Dataset
    test: Dataset
    far: Dataset
    outlier_rows: tuple[int, ...] = eqx.field(static=True)
    noise_std: Float[Array, ""]
    settings: dict = eqx.field(static=True)

    def describe(self) -> str:
        """A few lines on the session: sizes, coverage, guess errors, unmodelled errors."""
        s = self.settings
        span = np.rad2deg(np.ptp(np.asarray(self.train.q, np.float64), axis=0))
        nominal = _rms(self.measurement.residual(self.robot, None, self.train.q, self.train.y))
        inlier = np.setdiff1d(np.arange(self.train.n), self.outlier_rows)
        truth_test = _rms(self.measurement.residual(self.robot, self.true_deviations, self.test.q, self.test.y))
        guess = _session(self.measurement.kind).guess_words(self.true_deviations)
        c = np.asarray(s["compliance_deg_per_knm"])
        lines = [
            f"messy {self.measurement.kind} session on {self.robot.name}: train {self.train.n} "
            f"({len(self.outlier_rows)} outliers at rows {list(self.outlier_rows)}), test {self.test.n}, "
            f"far {self.far.n} (whole joint limits)",
            "joint coverage of train (deg): " + ", ".join(f"q{j + 1} {v:.0f}" for j, v in enumerate(span))
            + f"; readings quantised to {s['quantization_deg']}°",
            f"{guess}; noise σ = {float(self.noise_std):g} mm",
            f"unmodelled: gear error {s['gear_error_deg']}° per revolution, compliance "
            f"{np.array2string(c, precision=3)} deg/kN·m",
            f"RMS residual of the nominal model on train: {nominal:.1f} mm (inliers: "
            f"{_rms(self.measurement.residual(self.robot, None, self.train.q[inlier], self.train.y[inlier])):.1f} mm); "
            f"of the true parameters on test: {truth_test:.3f} mm",
        ]
        return "\n".join(lines)


def _rms(r) -> float:
    r = np.asarray(r, np.float64)
    return float(np.sqrt(np.mean(r * r))) if r.size else float("nan")


# -- the unmodelled physics (NumPy: a model of the mess, not a calibration model) -------------
# Written in NumPy in the dtype of the joint angles: it runs once per simulation, and eager JAX
# would compile every small operation anew for each batch shape (seconds on a 2-core CPU).
def _h(rot: np.ndarray, x=0.0, z=0.0, axis: str = "z") -> np.ndarray:
    """``[..., 4, 4]`` homogeneous transforms: a rotation by ``rot`` (rad, any shape) about
    ``axis`` followed by nothing, or a translation ``(x, 0, z)`` when ``rot`` is zero-d zero."""
    rot = np.asarray(rot)
    c, s = np.cos(rot), np.sin(rot)
    T = np.zeros(rot.shape + (4, 4), rot.dtype)
    T[..., 3, 3] = 1
    i, j, k = {"z": (0, 1, 2), "x": (1, 2, 0), "y": (2, 0, 1)}[axis]
    T[..., i, i], T[..., i, j], T[..., j, i], T[..., j, j], T[..., k, k] = c, -s, s, c, 1
    T[..., 0, 3], T[..., 2, 3] = x, z
    return T


def _joint_axes(robot: DHRobot, q: np.ndarray):
    """Nominal joint axes: unit directions ``z`` ``[dof, n, 3]``, a point on each axis ``o``
    ``[dof, n, 3]`` (mm) and the flange origin ``[n, 3]`` (mm), all in the base frame.

    Plain 4×4 products (the fast structure-of-arrays chain gives only the flange). Joint ``j``
    turns about z of the frame in which ``Rz(θ_j + q_j)`` acts.
    """
    dtype = q.dtype
    g = {k: np.asarray(getattr(robot, k)).astype(dtype) for k in ("alpha", "a", "d", "theta", "beta")}
    T = np.broadcast_to(np.eye(4, dtype=dtype), (q.shape[0], 4, 4))
    zs, os = [], []
    zero = np.zeros((), dtype)
    for i in range(robot.dof):
        B = _h(g["beta"][i], axis="y") if (i + 1) in robot.beta_joints else np.eye(4, dtype=dtype)
        joint = _h(g["theta"][i] + q[:, i])
        if robot.convention == "standard":  # Rz(θ) Tz(d) Tx(a) Rx(α) [Ry(β)]
            zs.append(T[:, :3, 2])
            os.append(T[:, :3, 3])
            T = T @ joint @ (_h(zero, g["a"][i], g["d"][i]) @ _h(g["alpha"][i], axis="x") @ B)
        else:  # Rx(α) [Ry(β)] Tx(a) Rz(θ) Tz(d)
            T = T @ (_h(g["alpha"][i], axis="x") @ B @ _h(zero, g["a"][i]))
            zs.append(T[:, :3, 2])
            os.append(T[:, :3, 3])
            T = T @ joint @ _h(zero, 0.0, g["d"][i])
    return np.stack(zs), np.stack(os), T[:, :3, 3]


def gravity_torques(
    robot: DHRobot,
    q: Float[Array, "n dof"],
    *,
    link_mass_kg_per_m: float = LINK_MASS_KG_PER_M,
    wrist_mass_kg: float = WRIST_MASS_KG,
) -> Float[Array, "n dof"]:
    """Gravity torque about each joint axis, ``[n, dof]`` (kN·m), of a point-mass arm, in the
    dtype of ``q`` (``[n, dof]`` rad).

    The mass model (nominal kinematics, gravity along −z of the base frame, base upright):

    * link ``j`` is a point mass of ``link_mass_kg_per_m × ℓ_j`` (20 kg/m) at the midpoint
      between the point on joint ``j``'s axis and the one on joint ``j+1``'s (the flange origin
      after the last joint); ``ℓ_j`` is their distance (``√(a_j² + d_j²)`` for standard DH);
    * the wrist and payload, ``wrist_mass_kg`` (30 kg) at the wrist centre (the point on joint
      ``dof−1``'s axis: the intersection of the wrist axes of a spherical wrist), carried by
      every joint but the last.

    ``τ_j = Σ_{masses beyond joint j} z_j · ((p_mass − o_j) × m·g)`` with ``g = (0, 0, −9.81)``
    m/s². Joint 1 of an upright robot feels none (its axis is vertical). For the HSR-JR680
    (a 20 kg-class arm) the link masses are 14, 18, 4, 21, 0, 4 kg plus 30 kg at the wrist, and
    the shoulder torque in the default session is ~0.46 kN·m (median). Not jittable (NumPy).
    """
    qn = np.asarray(q)
    if not np.issubdtype(qn.dtype, np.floating):
        qn = qn.astype(np.dtype(jnp.result_type(float)))
    dtype = qn.dtype
    z, o, flange = _joint_axes(robot, qn)
    dof = robot.dof
    ends = np.concatenate([o[1:], flange[None]], axis=0)  # [dof, n, 3]
    mid = (o + ends) / 2
    link_len_m = np.linalg.norm(ends - o, axis=-1) / 1000.0  # [dof, n] (the same for every n)
    link_force = dtype.type(link_mass_kg_per_m * GRAVITY_M_S2) * link_len_m  # N, downward
    wrist = o[max(dof - 2, 0)]
    wrist_force = dtype.type(wrist_mass_kg * GRAVITY_M_S2)

    def moment(zj, oj, p, f):
        # z · ((p − o) × (0, 0, −f)) = −f·(z_x·r_y − z_y·r_x)   [N·mm]
        r = p - oj
        return -f * (zj[..., 0] * r[..., 1] - zj[..., 1] * r[..., 0])

    tau = []
    for j in range(dof):
        t = sum(moment(z[j], o[j], mid[k], link_force[k]) for k in range(j, dof))
        if j < dof - 1:
            t = t + moment(z[j], o[j], wrist, wrist_force)
        tau.append(t / dtype.type(1e6))  # N·mm → kN·m
    return jnp.asarray(np.stack(tau, axis=-1).astype(dtype))


def default_compliance(robot: DHRobot, dtype=None) -> Float[Array, " dof"]:
    """Default joint compliance ``[dof]`` (deg per kN·m): the same for every joint, chosen so
    the median shoulder (joint 2) gravity deflection over 512 poses uniform in the joint limits
    is :data:`DEFAULT_SHOULDER_DEFLECTION_DEG` (0.02°).

    Scaling by the robot's own torques keeps the effect modest for every preset, small arms
    and large: 0.047 (HSR-JR680: a shoulder stiffness of 1.2·10⁶ N·m/rad, the order of real
    20 kg-class arms), 0.103 (PUMA 560), 0.149 (UR5), 0.180 (IRB 120) deg/kN·m. Median shoulder
    deflection in the default narrow session (measured, key 0): 0.022° (HSR-JR680), 0.009°
    (PUMA 560), 0.051° (UR5: the middle of its ±360° limits holds the arm stretched out
    horizontally), 0.015° (IRB 120); over the whole limits ~0.02° for all. Fixed poses
    (key 0, float64), so the default depends on neither the experiment's key nor the dtype.
    """
    dtype = dtype or jnp.result_type(float)
    lo, hi = np.asarray(robot.q_min, np.float64), np.asarray(robot.q_max, np.float64)
    u = np.random.default_rng(0).uniform(size=(_N_REFERENCE_POSES, robot.dof))
    tau = np.abs(np.asarray(gravity_torques(robot, lo + (hi - lo) * u), np.float64))
    ref = float(np.median(tau[:, 1 if robot.dof > 1 else 0]))
    c = DEFAULT_SHOULDER_DEFLECTION_DEG / ref if ref > 0 else 0.0
    return jnp.full((robot.dof,), c, dtype)


def actual_joint_angles(
    robot: DHRobot,
    q_cmd: Float[Array, "n dof"],
    *,
    gear_error_deg: float,
    gear_phase_rad,
    compliance_deg_per_knm,
) -> Float[Array, "n dof"]:
    """Where the joints really are, ``[n, dof]`` rad, when commanded to ``q_cmd`` (rad).

    ``q_actual = q_cmd + gear_error_deg·sin(q_cmd + φ) + c·τ(q_cmd)`` (the two error terms in
    degrees, converted): a once-per-revolution transmission error with phase ``φ``
    (``gear_phase_rad``, ``[dof]``) and the gravity deflection of joint compliance ``c``
    (``[dof]`` deg/kN·m) under the torques of :func:`gravity_torques`. With both zero it
    returns ``q_cmd`` exactly. Computed in NumPy in the dtype of ``q_cmd``; not jittable.
    """
    q = np.asarray(q_cmd)
    if not np.issubdtype(q.dtype, np.floating):
        q = q.astype(np.dtype(jnp.result_type(float)))
    dtype = q.dtype
    deg = dtype.type(math.pi / 180.0)
    phase = np.asarray(gear_phase_rad).astype(dtype)
    c = np.broadcast_to(np.asarray(compliance_deg_per_knm).astype(dtype), (robot.dof,))
    gear = dtype.type(gear_error_deg) * np.sin(q + phase)
    bend = c * np.asarray(gravity_torques(robot, q)) if np.any(c != 0) else np.zeros_like(q)
    return jnp.asarray(q + deg * (gear + bend))


def _quantize(q: np.ndarray, quantum_deg: float) -> np.ndarray:
    """Joint readings: ``q`` (rad) rounded to multiples of ``quantum_deg`` degrees."""
    if quantum_deg == 0:
        return q
    step = q.dtype.type(quantum_deg)
    return np.deg2rad(np.round(np.rad2deg(q) / step) * step)


# -- settings -----------------------------------------------------------------------------
def default_joint_ranges_deg(robot: DHRobot) -> tuple[tuple[float, float], ...]:
    """The default visited ranges (deg): centred in the joint limits, half-widths
    :data:`DEFAULT_HALF_RANGE_DEG` (45, 30, 30, 8, 8, 45)°, clipped to the limits."""
    lo, hi = np.rad2deg(np.asarray(robot.q_min, np.float64)), np.rad2deg(np.asarray(robot.q_max, np.float64))
    out = []
    for j in range(robot.dof):
        half = DEFAULT_HALF_RANGE_DEG[j] if j < len(DEFAULT_HALF_RANGE_DEG) else 45.0
        mid = (lo[j] + hi[j]) / 2
        out.append((float(max(mid - half, lo[j])), float(min(mid + half, hi[j]))))
    return tuple(out)


def _nonneg(name: str, value) -> float:
    v = float(value)
    if not (math.isfinite(v) and v >= 0):
        raise ValueError(f"{name} must be a finite non-negative number, got {value!r}")
    return v


def _check_ranges(robot: DHRobot, ranges) -> tuple[tuple[float, float], ...]:
    r = np.asarray(ranges, dtype=np.float64)
    if r.shape != (robot.dof, 2):
        raise ValueError(f"joint_ranges_deg must be {robot.dof} (lo, hi) pairs in degrees, got shape {r.shape}")
    lim_lo = np.rad2deg(np.asarray(robot.q_min, np.float64))
    lim_hi = np.rad2deg(np.asarray(robot.q_max, np.float64))
    for j, (lo, hi) in enumerate(r):
        if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
            raise ValueError(f"joint_ranges_deg[{j}] = ({lo}, {hi}): need finite lo < hi (deg)")
        if lo < lim_lo[j] - 1e-9 or hi > lim_hi[j] + 1e-9:
            raise ValueError(
                f"joint_ranges_deg[{j}] = ({lo}, {hi}) is outside joint {j + 1}'s limits "
                f"({lim_lo[j]:g}, {lim_hi[j]:g}) deg"
            )
    return tuple((float(lo), float(hi)) for lo, hi in r)


def _check_compliance(robot: DHRobot, value, dtype) -> np.ndarray:
    if value is None:
        return np.asarray(default_compliance(robot, dtype), np.float64)
    c = np.broadcast_to(np.asarray(value, np.float64), (robot.dof,)) if np.ndim(value) == 0 else np.asarray(value, np.float64)
    if c.shape != (robot.dof,) or not np.all(np.isfinite(c)) or np.any(c < 0):
        raise ValueError(
            f"compliance_deg_per_knm must be a non-negative number or {robot.dof} of them "
            f"(deg per kN·m), got {value!r}"
        )
    return c.copy()


def _unit(key, dtype):
    v = jax.random.normal(key, (3,), dtype)
    return v / jnp.linalg.norm(v)


# -- the simulator ------------------------------------------------------------------------
def simulate_messy(
    key: Array,
    robot: DHRobot | None = None,
    *,
    measurement: str = "cable",
    n_samples: int = 1000,
    noise_std: float = 0.3,
    test_fraction: float = 0.2,
    angle_std_deg: float = 0.2,
    length_std_mm: float = 0.6,
    joint_ranges_deg: Sequence[tuple[float, float]] | None = None,
    quantization_deg: float = 0.1,
    anchor_guess_error_mm: float = 500.0,
    base_guess_error_mm: float = 400.0,
    base_guess_error_deg: float = 10.0,
    cable_offset_mm: float | None = None,
    tool_offset_mm=(0.0, 0.0, 0.0),
    compliance_deg_per_knm=None,
    gear_error_deg: float = 0.01,
    n_outliers: int = 2,
    outlier_mm: tuple[float, float] = (30.0, 300.0),
    far_samples: int = 500,
) -> MessyExperiment:
    """Simulate a messy "real" calibration session from a ``jax.random`` key.

    1. True DH deviations from :func:`~jaxcal._simulation._simulate.draw_deviations` (``angle_std_deg``,
       ``length_std_mm``; β at the robot's Hayati joints).
    2. The sensor: ``measurement="cable"``: the true anchor is
       :func:`~jaxcal._simulation._simulate.default_anchor` (``(reach/2, 0, 0)`` mm), the user's guess is
       ``anchor_guess_error_mm`` away in a random direction, and the wire has a true zero
       offset ``cable_offset_mm`` (default: drawn from N(0, 20 mm)). ``"position"``: the user
       guesses the identity sensor frame; the tracker's true frame is rotated by
       ``base_guess_error_deg`` about a random axis and shifted by ``base_guess_error_mm`` in a
       random direction. For both, the wire (or the tracker's reflector) is attached
       ``tool_offset_mm`` ``[3]`` (flange frame) from the robot's nominal tool point, an
       offset the user does not know (default: exactly at it).
    3. ``n_samples`` commanded poses ``q_cmd`` uniform in ``joint_ranges_deg`` (default
       :func:`default_joint_ranges_deg`: ±45°, ±30°, ±30°, ±8°, ±8°, ±45° about the middle of
       the limits), keeping those whose true tool point is above the base plane and (cable)
       at a wire length in ``[0.05, 1.2]·reach``; likewise ``far_samples`` poses over the
       whole joint limits.
    4. Readings of the true model at the actual angles (:func:`actual_joint_angles`: gear
       error of amplitude ``gear_error_deg`` with a random phase per joint, and gravity
       deflection of compliance ``compliance_deg_per_knm``, default
       :func:`default_compliance`), plus Gaussian noise σ = ``noise_std`` mm on every reading.
       The recorded joint readings are ``q_cmd`` rounded to ``quantization_deg`` (0 = exact).
    5. A random train/test split (``test_fraction``), then ``n_outliers`` train rows get a gross
       error of random sign and magnitude uniform in ``outlier_mm`` (cable: on the length;
       position: on one random coordinate); their rows are ``outlier_rows``.

    Computes in the default float dtype (float64 with x64 on; float32 works, and warns).
    Pure in ``key``: the same key and settings give bit-identical data. Runs eagerly (not
    jittable: sizes depend on the workspace filter).

    Raises:
        ValueError: naming the option, for a bad setting (negative noise or errors, joint
            ranges outside the limits or with lo ≥ hi, ``n_outliers`` larger than the train
            set, unknown ``measurement``, …) or when too few poses pass the workspace filter.

    Returns:
        :class:`MessyExperiment`.
    """
    from ..robots import hsr_jr680

    robot = hsr_jr680() if robot is None else robot
    dtype = jnp.result_type(float)
    opt = _checked_options(
        robot, dtype, measurement=measurement, n_samples=n_samples, noise_std=noise_std, test_fraction=test_fraction,
        angle_std_deg=angle_std_deg, length_std_mm=length_std_mm, joint_ranges_deg=joint_ranges_deg,
        quantization_deg=quantization_deg, anchor_guess_error_mm=anchor_guess_error_mm,
        base_guess_error_mm=base_guess_error_mm, base_guess_error_deg=base_guess_error_deg,
        cable_offset_mm=cable_offset_mm, tool_offset_mm=tool_offset_mm, compliance_deg_per_knm=compliance_deg_per_knm,
        gear_error_deg=gear_error_deg, n_outliers=n_outliers, outlier_mm=outlier_mm, far_samples=far_samples)
    if not isinstance(key, jax.core.Tracer):
        warn_if_float32(dtype, "simulate_messy")
    keys = _Keys(*jax.random.split(key, 11))
    session = _session(opt.measurement)
    truth = _truth_and_guess(keys, robot, opt, dtype, session)  # 1–2
    sensor = _Sensor.build(keys, robot, truth, opt, dtype)
    rad = np.deg2rad(np.asarray(opt.ranges))
    q, y = sensor.measure(keys.q, keys.noise, opt.n_samples, (rad[:, 0], rad[:, 1]), "joint_ranges_deg")  # 3–4
    train, test, rows = _split_with_outliers(keys, q, y, truth.model.kind, opt, robot, dtype)  # 5
    far = _far_set(keys, sensor, opt, robot, dtype)
    return MessyExperiment(
        robot=robot, measurement=truth.model, true_deviations=truth.dev, train=train, test=test, far=far,
        outlier_rows=tuple(int(r) for r in rows), noise_std=sensor.sigma,
        settings=_settings_record(opt, truth.dev, sensor.phase, session),
    )


class _Options(NamedTuple):
    """:func:`simulate_messy`'s settings, checked and normalised (floats, the joint ranges in
    degrees, the compliance ``[dof]`` in °/(kN·m), the train/test sizes)."""

    measurement: str
    n_samples: int
    noise_std: float
    test_fraction: float
    angle_std_deg: float
    length_std_mm: float
    ranges: tuple
    quantization_deg: float
    anchor_guess_error_mm: float
    base_guess_error_mm: float
    base_guess_error_deg: float
    cable_offset_mm: float | None
    tool_offset: np.ndarray
    compliance: np.ndarray
    gear_error_deg: float
    n_train: int
    n_test: int
    n_outliers: int
    outlier_mm: tuple[float, float]
    far_samples: int


def _checked_options(robot: DHRobot, dtype, **o) -> _Options:
    """The settings of :func:`simulate_messy`, each checked (a ``ValueError`` naming the option)."""
    _session(o["measurement"])  # a kind with a messy session, else ValueError
    check_simulation_settings(o["n_samples"], o["test_fraction"], o["noise_std"], _OVERSAMPLE)
    nonneg = {k: _nonneg(k, o[k]) for k in ("angle_std_deg", "length_std_mm", "quantization_deg",
                                            "anchor_guess_error_mm", "base_guess_error_mm", "base_guess_error_deg")}
    if nonneg["base_guess_error_deg"] > 180:
        raise ValueError(f"base_guess_error_deg must be at most 180, got {nonneg['base_guess_error_deg']}")
    gear_error_deg = _nonneg("gear_error_deg", o["gear_error_deg"])
    tool_offset = np.asarray(o["tool_offset_mm"], np.float64)
    if tool_offset.shape != (3,) or not np.all(np.isfinite(tool_offset)):
        raise ValueError(f"tool_offset_mm must be 3 finite numbers (mm, flange frame), got {o['tool_offset_mm']!r}")
    cable_offset_mm = o["cable_offset_mm"]
    if cable_offset_mm is not None and not math.isfinite(float(cable_offset_mm)):
        raise ValueError(f"cable_offset_mm must be a finite number (mm) or None, got {cable_offset_mm!r}")
    joint_ranges_deg = o["joint_ranges_deg"]
    ranges = default_joint_ranges_deg(robot) if joint_ranges_deg is None else _check_ranges(robot, joint_ranges_deg)
    compliance = _check_compliance(robot, o["compliance_deg_per_knm"], dtype)
    n_samples, n_outliers = o["n_samples"], o["n_outliers"]
    n_test = int(round(n_samples * o["test_fraction"]))
    n_train = n_samples - n_test
    if int(n_outliers) != n_outliers or not (0 <= n_outliers <= n_train):
        raise ValueError(f"n_outliers must be an integer in [0, {n_train}] (the train size), got {n_outliers!r}")
    lo_out, hi_out = (float(v) for v in o["outlier_mm"])
    if not (math.isfinite(hi_out) and 0 <= lo_out <= hi_out):
        raise ValueError(f"outlier_mm must be a (low, high) magnitude range with 0 <= low <= high (mm), "
                         f"got {o['outlier_mm']!r}")
    far_samples = o["far_samples"]
    if int(far_samples) != far_samples or far_samples < 0:
        raise ValueError(f"far_samples must be a non-negative integer, got {far_samples!r}")
    return _Options(
        measurement=o["measurement"], n_samples=n_samples, noise_std=o["noise_std"], test_fraction=o["test_fraction"],
        ranges=ranges, cable_offset_mm=cable_offset_mm, tool_offset=tool_offset, compliance=compliance,
        gear_error_deg=gear_error_deg, n_train=n_train, n_test=n_test, n_outliers=int(n_outliers),
        outlier_mm=(lo_out, hi_out), far_samples=int(far_samples), **nonneg)


class _Keys(NamedTuple):
    """The eleven keys of one :func:`simulate_messy` call (``jax.random.split(key, 11)``, in order)."""

    dev: Array
    sensor1: Array
    sensor2: Array
    offset: Array
    phase: Array
    q: Array
    noise: Array
    split: Array
    out: Array
    far_q: Array
    far_noise: Array


class _Truth(NamedTuple):
    """The true deviations, the user's nominal sensor model, and the workspace filter's anchor
    (mm, cable only) and wire-length range (mm)."""

    dev: Deviations
    model: MeasurementModel
    anchor_for_filter: Array | None
    wire_range: tuple[float, float]


class MessySession:
    """The sensor of a messy session (:func:`simulate_messy`): how its true set-up is drawn, the
    user's guess of it, and the words for :meth:`MessyExperiment.describe`. A sensor kind offers
    one by naming it (:attr:`SensorKind.messy <jaxcal._sensors._kind.SensorKind>`, ``"module:object"``:
    the hook by which the sensors, a floor below, name their session here)."""

    def truth(self, keys: _Keys, robot: DHRobot, opt: _Options, dev: Deviations, dtype) -> _Truth:
        """Step 2: the true deviations ``dev`` with the sensor's set-up errors, the nominal model
        the user builds from a guess, and the workspace filter's anchor and wire-length range."""
        raise NotImplementedError

    def guess_words(self, dev: Deviations) -> str:
        """How far the user's guess of the set-up is off, in words."""
        raise NotImplementedError

    def cable_offset_mm(self, dev: Deviations) -> float | None:
        """The true zero offset of a draw wire (mm) for :attr:`MessyExperiment.settings`, or ``None``."""
        return None


class _CableSession(MessySession):
    """A draw wire: the true anchor :func:`default_anchor`, guessed ``anchor_guess_error_mm`` away,
    and a zero offset of the wire."""

    def truth(self, keys, robot, opt, dev, dtype):
        true_anchor = default_anchor(robot).astype(dtype)
        anchor_error = jnp.asarray(opt.anchor_guess_error_mm, dtype) * _unit(keys.sensor1, dtype)
        if opt.cable_offset_mm is None:
            offset = jnp.asarray(CABLE_OFFSET_STD_MM, dtype) * jax.random.normal(keys.offset, (), dtype)
        else:
            offset = jnp.asarray(opt.cable_offset_mm, dtype)
        dev = eqx.tree_at(lambda d: (d.anchor, d.cable_offset), dev, (anchor_error, offset))
        reach = robot.reach_mm()
        return _Truth(dev, CableLength(true_anchor - anchor_error), true_anchor, (0.05 * reach, 1.2 * reach))

    def guess_words(self, dev):
        return (f"anchor guess off by {float(jnp.linalg.norm(dev.anchor)):.0f} mm, "
                f"cable zero offset {float(dev.cable_offset):+.1f} mm")

    def cable_offset_mm(self, dev):
        return float(dev.cable_offset)


class _TrackerSession(MessySession):
    """A tracker (tool positions): the identity sensor frame guessed, the true one rotated by
    ``base_guess_error_deg`` and shifted by ``base_guess_error_mm``."""

    def truth(self, keys, robot, opt, dev, dtype):
        model = Position(jnp.eye(3, dtype=dtype), jnp.zeros(3, dtype))
        rotvec = jnp.asarray(math.radians(opt.base_guess_error_deg), dtype) * _unit(keys.sensor1, dtype)
        shift = jnp.asarray(opt.base_guess_error_mm, dtype) * _unit(keys.sensor2, dtype)
        dev = eqx.tree_at(lambda d: (d.base_rotation, d.base_translation), dev, (rotvec, shift))
        return _Truth(dev, model, None, (0.0, math.inf))

    def guess_words(self, dev):
        return (f"sensor frame guess off by {math.degrees(float(jnp.linalg.norm(dev.base_rotation))):.1f}° "
                f"and {float(jnp.linalg.norm(dev.base_translation)):.0f} mm")


#: the sessions the cable and position kinds name (``SensorKind.messy``)
CABLE_SESSION = _CableSession()
TRACKER_SESSION = _TrackerSession()


def _session(measurement: str) -> MessySession:
    """The :class:`MessySession` the kind ``measurement`` names.

    Raises:
        ValueError: no kind of that name offers a messy session; the message names those that do.
    """
    from .._sensors._kind import resolve_hook, sensor_kind, sensor_kinds

    try:
        hook = sensor_kind(measurement).messy
    except ValueError:  # no kind of that name
        hook = None
    if hook is None:
        offered = sorted(k.name for k in sensor_kinds() if k.messy is not None)
        raise ValueError(f"measurement must be {' or '.join(repr(k) for k in offered)}, got {measurement!r}")
    return resolve_hook(hook)


def _truth_and_guess(keys: _Keys, robot: DHRobot, opt: _Options, dtype, session: MessySession) -> _Truth:
    """Steps 1–2: the true DH deviations (and tool offset), the true sensor set-up, and the
    nominal model the user builds from a guess of it (:meth:`MessySession.truth`: a draw wire's
    anchor ``anchor_guess_error_mm`` away, a tracker's frame ``base_guess_error_mm``/``_deg``)."""
    dev = draw_deviations(keys.dev, robot, angle_std_deg=opt.angle_std_deg, length_std_mm=opt.length_std_mm,
                          dtype=dtype)
    if np.any(opt.tool_offset != 0):
        dev = dev.replace(tool=jnp.asarray(opt.tool_offset, dtype))
    return session.truth(keys, robot, opt, dev, dtype)


class _Sensor(NamedTuple):
    """The true robot and sensor of a session, measuring poses (steps 3–4)."""

    robot: DHRobot
    truth: _Truth
    phase: Array  # [dof] gear-error phase (rad)
    sigma: Array  # noise σ (mm)
    n_cand: int  # candidate poses drawn per set
    quantization_deg: float
    errors: dict
    dtype: object

    @classmethod
    def build(cls, keys: _Keys, robot: DHRobot, truth: _Truth, opt: _Options, dtype) -> _Sensor:
        phase = jax.random.uniform(keys.phase, (robot.dof,), dtype, 0.0, 2 * math.pi)
        errors = dict(gear_error_deg=opt.gear_error_deg, gear_phase_rad=phase, compliance_deg_per_knm=opt.compliance)
        # one candidate count for both sets: the same array shapes, so JAX compiles its few eager
        # operations once
        n_cand = _OVERSAMPLE * max(opt.n_samples, opt.far_samples)
        return cls(robot, truth, phase, jnp.asarray(opt.noise_std, dtype), n_cand, opt.quantization_deg, errors, dtype)

    def measure(self, k_q, k_noise, n: int, joint_ranges, what: str) -> tuple[np.ndarray, np.ndarray]:
        """``n`` kept poses: quantised readings ``q`` ``[n, dof]`` (rad) and noisy readings ``y``
        (mm) of the truth at the actual joint angles."""
        robot, t = self.robot, self.truth
        cand = sample_joint_angles(k_q, robot, self.n_cand, ranges=joint_ranges, dtype=self.dtype)
        q_act = actual_joint_angles(robot, cand, **self.errors)
        ok = np.asarray(workspace_mask(tool_point_soa(robot, t.dev, q_act), t.anchor_for_filter, t.wire_range))
        idx = np.flatnonzero(ok)[:n]
        if idx.size < n:
            raise ValueError(
                f"simulate_messy: only {idx.size} of {self.n_cand} candidate poses for {what} have the tool "
                "above the base plane (and the wire in range); choose other joint_ranges_deg"
            )
        y = np.asarray(t.model.predict(robot, t.dev, q_act))[idx]
        noise = np.asarray(self.sigma * jax.random.normal(k_noise, (self.n_cand, *t.model.sample_shape), self.dtype))[:n]
        return _quantize(np.asarray(cand)[idx], self.quantization_deg), y + noise


def _split_with_outliers(keys: _Keys, q, y, kind: str, opt: _Options, robot: DHRobot, dtype):
    """Step 5: a random train/test split, then ``n_outliers`` gross errors in train rows (a scalar
    reading such as a wire length: on the reading; a position: on one random coordinate). Returns
    ``(train, test, rows)``."""
    k_rows, k_sign, k_mag, k_coord = jax.random.split(keys.out, 4)
    perm = np.asarray(jax.random.permutation(keys.split, opt.n_samples))
    te, tr = perm[:opt.n_test], perm[opt.n_test:]
    q_tr, y_tr = q[tr], y[tr].copy()
    n_train, n_out = opt.n_train, opt.n_outliers
    rows = np.sort(np.asarray(jax.random.permutation(k_rows, n_train))[:n_out])
    sign = np.where(np.asarray(jax.random.bernoulli(k_sign, 0.5, (n_train,)))[:n_out], 1.0, -1.0)
    err = (sign * np.asarray(jax.random.uniform(k_mag, (n_train,), dtype, *opt.outlier_mm))[:n_out]).astype(y.dtype)
    if y_tr.ndim == 1:
        y_tr[rows] += err
    else:
        y_tr[rows, np.asarray(jax.random.randint(k_coord, (n_train,), 0, 3))[:n_out]] += err
    return (_dataset(q_tr, y_tr, kind, robot, "train", dtype), _dataset(q[te], y[te], kind, robot, "test", dtype),
            rows)


def _dataset(q, y, kind: str, robot: DHRobot, split: str, dtype) -> Dataset:
    meta = {"source": "simulate_messy", "robot": robot.name}
    return Dataset(jnp.asarray(q, dtype), jnp.asarray(y, dtype), kind, {**meta, "split": split})


def _far_set(keys: _Keys, sensor: _Sensor, opt: _Options, robot: DHRobot, dtype) -> Dataset:
    """``far_samples`` poses over the whole joint limits: the unmeasured workspace."""
    if opt.far_samples:
        q_far, y_far = sensor.measure(keys.far_q, keys.far_noise, opt.far_samples, None, "far_samples")
    else:
        q_far, y_far = np.zeros((0, robot.dof)), np.zeros((0, *sensor.truth.model.sample_shape))
    return _dataset(q_far, y_far, sensor.truth.model.kind, robot, "far", dtype)


def _settings_record(opt: _Options, dev: Deviations, phase, session: MessySession) -> _FrozenDict:
    """:attr:`MessyExperiment.settings`: every setting as plain Python values."""
    return _FrozenDict(
        measurement=opt.measurement, n_samples=opt.n_samples, noise_std=float(opt.noise_std),
        test_fraction=float(opt.test_fraction), angle_std_deg=opt.angle_std_deg, length_std_mm=opt.length_std_mm,
        joint_ranges_deg=opt.ranges, quantization_deg=opt.quantization_deg,
        anchor_guess_error_mm=opt.anchor_guess_error_mm, base_guess_error_mm=opt.base_guess_error_mm,
        base_guess_error_deg=opt.base_guess_error_deg,
        cable_offset_mm=session.cable_offset_mm(dev),
        tool_offset_mm=tuple(float(v) for v in opt.tool_offset),
        compliance_deg_per_knm=tuple(float(c) for c in opt.compliance), gear_error_deg=opt.gear_error_deg,
        gear_phase_rad=tuple(float(p) for p in np.asarray(phase)), n_outliers=opt.n_outliers,
        outlier_mm=opt.outlier_mm, far_samples=opt.far_samples,
    )


# -- validation by workspace region ---------------------------------------------------------
def region_split(data: Dataset, joint: int, *, at: float | None = None) -> tuple[Dataset, Dataset]:
    """Split ``data`` by one joint's reading: ``(low, high)`` with ``q_joint < at`` and
    ``q_joint ≥ at``.

    Args:
        data: the data set (``q`` ``[n, dof]`` rad).
        joint: 1-based joint number.
        at: threshold (rad); default the median of that joint's readings.

    For "train on one half of the workspace, test on the other" validation:
    a random split tests interpolation, a region split tests extrapolation.

    Raises:
        ValueError: bad joint number, or a half would be empty.
    """
    if int(joint) != joint or not (1 <= joint <= data.dof):
        raise ValueError(f"joint must be a 1-based joint number in 1..{data.dof}, got {joint!r}")
    qj = np.asarray(data.q[:, int(joint) - 1], np.float64)
    thr = float(np.median(qj)) if at is None else float(at)
    low = qj < thr
    if low.all() or not low.any():
        raise ValueError(
            f"region_split: joint {joint} readings (rad, {qj.min():.4g}..{qj.max():.4g}) all lie on one "
            f"side of at={thr:.4g}; one half would be empty"
        )
    return data.subset(jnp.asarray(np.flatnonzero(low))), data.subset(jnp.asarray(np.flatnonzero(~low)))


def region_folds(data: Dataset, joints: Sequence[int] = (1, 2, 3)) -> list[tuple[Dataset, Dataset]]:
    """``(train, test)`` pairs splitting ``data`` at the median of each joint in ``joints``
    (1-based), both ways: ``[(low₁, high₁), (high₁, low₁), (low₂, high₂), …]``."""
    folds = []
    for j in joints:
        low, high = region_split(data, j)
        folds += [(low, high), (high, low)]
    return folds
