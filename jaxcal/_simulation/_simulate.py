"""The paper's experiment, simulated: a "true" robot, a draw-wire sensor with noise, a split."""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core._cache import ensure_compilation_cache
from .._core._params import Deviations, Layout, layout_for
from .._core._precision import to_device, warn_if_float32
from .._core._xla import filter_jit
from .._datasets._dataset import Dataset, mm_joints_metadata
from .._datasets._split import permutation_rounds
from .._models._abstract import AbstractRobot
from .._models._kinematics import rotvec_to_matrix, tool_point_soa
from .._models._robot import sample_joint_angles
from .._sensors._measurement import CableLength, Markers, MeasurementModel, Pose, Position, default_anchor

__all__ = ["Experiment", "simulate_experiment", "default_anchor", "draw_deviations", "add_orientation_noise"]

#: Defaults, chosen to resemble the paper's Table V deviations and Table III errors.
DEFAULT_NOISE_STD = 0.5  # mm; the paper does not give its sensor noise (see simulate_experiment)
DEFAULT_ANGLE_STD_DEG = 0.2
DEFAULT_LENGTH_STD_MM = 0.6


class Experiment(eqx.Module):
    """A simulated calibration experiment; the simulation knows the truth.

    Attributes:
        robot: nominal robot (what the calibration starts from).
        measurement: nominal measurement model (e.g. :class:`CableLength` with nominal anchor).
        true_deviations: the deviations of the "true" robot (and sensor extras) from nominal.
        train, test: the two splits.
        noise_std: Gaussian measurement noise σ (mm).
    """

    robot: AbstractRobot
    measurement: MeasurementModel
    true_deviations: Deviations
    train: Dataset
    test: Dataset
    noise_std: Float[Array, ""]


def workspace_mask(p, anchor, wire_range: tuple[float, float], min_height_mm: float = 0.0):
    """``[n]`` bool: tool points ``p`` (three ``[n]`` arrays, mm, base frame) at least
    ``min_height_mm`` high and, when ``anchor`` (``[3]`` mm) is given, at a wire length
    ``‖p − anchor‖`` within ``wire_range`` (mm)."""
    ok = p[2] >= min_height_mm
    if anchor is not None:
        dist = jnp.sqrt(sum((p[k] - anchor[k]) ** 2 for k in range(3)))
        ok = ok & (dist >= wire_range[0]) & (dist <= wire_range[1])
    return ok


def draw_deviations(
    key: Array,
    robot: AbstractRobot,
    *,
    angle_std_deg: float = DEFAULT_ANGLE_STD_DEG,
    length_std_mm: float = DEFAULT_LENGTH_STD_MM,
    anchor_std_mm: float = 0.0,
    tool_std_mm: float = 0.0,
    cable_offset_std_mm: float = 0.0,
    dtype=None,
) -> Deviations:
    """Random "true" deviations: Gaussian DH errors (and optional sensor extras).

    β is drawn only at the robot's Hayati joints. Magnitudes default to those of the paper's
    Table V (tenths of a degree; tenths of a mm to ~2 mm). A robot that is not a plain DH
    table (a generic chain) gets every geometric entry its ``free_by_default`` allows drawn
    with ``angle_std_deg`` (rad entries) or ``length_std_mm`` (mm entries); non-geometric
    groups stay zero.
    """
    dtype = dtype or jnp.result_type(float)
    k = jax.random.split(key, 8)
    dof = robot.dof
    # a traced σ (simulate_experiment's float settings are arguments of its program): the same
    # float64 product as math.radians (CPython multiplies by the double nearest π/180)
    ang = angle_std_deg * (math.pi / 180) if _tracing(angle_std_deg) else math.radians(angle_std_deg)
    n = lambda kk, shape, s: s * jax.random.normal(kk, shape, dtype)  # noqa: E731
    layout = layout_for(robot)
    if not _dh_table(robot):
        vals = {"anchor": n(k[5], (3,), anchor_std_mm), "tool": n(k[6], (3,), tool_std_mm),
                "cable_offset": n(k[7], (), cable_offset_std_mm)}
        allow = getattr(robot, "free_by_default", lambda name: True)
        geo = [g for g in layout.groups if g.kind == "geometric"]
        for kk, g in zip(jax.random.split(k[0], len(geo)), geo):
            std = jnp.asarray([(ang if u == "rad" else length_std_mm if u == "mm" else 0.0) if allow(nm) else 0.0
                               for nm, u in zip(g.names, g.units)], dtype).reshape(g.shape)
            vals[g.name] = std * jax.random.normal(kk, g.shape, dtype)
        return Deviations(vals, layout)
    beta_on = jnp.asarray([(j + 1) in robot.beta_joints for j in range(dof)], dtype)
    out = Deviations.from_dh(
        alpha=n(k[0], (dof,), ang),
        a=n(k[1], (dof,), length_std_mm),
        d=n(k[2], (dof,), length_std_mm),
        theta=n(k[3], (dof,), ang),
        beta=n(k[4], (dof,), ang) * beta_on,
        anchor=n(k[5], (3,), anchor_std_mm),
        tool=n(k[6], (3,), tool_std_mm),
        cable_offset=n(k[7], (), cable_offset_std_mm),
    )
    return out if layout == out.layout else Deviations(out.values, layout)  # + zero non-geometric groups


def _dh_table(robot) -> bool:
    """Whether :func:`draw_deviations` draws ``robot``'s deviations as a DH table's (not a generic
    chain's, entry by entry)."""
    return layout_for(robot).groups[:5] == Layout.dh(robot.dof).groups[:5]


def check_simulation_settings(n_samples: int, test_fraction: float, noise_std: float, oversample: float) -> None:
    """Raise ``ValueError`` naming the first bad setting of :func:`simulate_experiment`."""
    if n_samples < 2:
        raise ValueError(f"n_samples must be at least 2, got {n_samples}")
    if not (0.0 < test_fraction < 1.0):
        raise ValueError(f"test_fraction must be in (0, 1), got {test_fraction}")
    if noise_std < 0 or not math.isfinite(noise_std):
        raise ValueError(f"noise_std must be a finite non-negative number (mm), got {noise_std}")
    if oversample < 1:
        raise ValueError("oversample must be >= 1")


def simulate_experiment(
    key: Array,
    robot: AbstractRobot | None = None,
    *,
    n_samples: int = 2000,
    noise_std: float = DEFAULT_NOISE_STD,
    test_fraction: float = 0.2,
    measurement: MeasurementModel | None = None,
    true_deviations: Deviations | None = None,
    angle_std_deg: float = DEFAULT_ANGLE_STD_DEG,
    length_std_mm: float = DEFAULT_LENGTH_STD_MM,
    anchor_std_mm: float = 0.0,
    tool_std_mm: float = 0.0,
    cable_offset_std_mm: float = 0.0,
    coverage: float = 1.0,
    wire_range_mm: tuple[float, float] | None = None,
    min_height_mm: float = 0.0,
    oversample: int = 8,
) -> Experiment:
    """Simulate the paper's experiment (Section IV-A) from a ``jax.random`` key.

    1. A "true" robot = nominal + deviations drawn by :func:`draw_deviations` (or given).
    2. ``n_samples`` joint configurations uniform over the joint limits (``coverage`` shrinks
       the ranges), keeping those whose true tool point is above ``min_height_mm`` and whose
       wire length lies in ``wire_range_mm`` (default ``[0.05, 1.2]·reach``).
    3. Readings of the true robot (wire length from the anchor, or positions for a
       :class:`Position` model, poses for :class:`Pose` (noise on the position only), marker
       positions for :class:`Markers`) plus Gaussian noise σ = ``noise_std``; other models raise
       ``TypeError`` (contact, distance and camera data have their own simulators).
    4. A random train/test split (``test_fraction``).

    The paper does not state its sensor noise. The default σ = 0.5 mm puts the statistical floor
    just below the paper's best test RMSE (0.646 mm); the default deviations give a
    before-calibration RMSE of about 3–6 mm, as in Table III (4.56 mm).

    Pure in ``key`` (same key ⇒ bit-identical data) and vectorised; it can be ``jax.vmap``-ed
    over keys. If too few candidate poses pass the workspace filter it raises (an
    ``equinox`` runtime error under ``jit``); increase ``oversample`` or relax the filter.

    Returns:
        :class:`Experiment` with ``train`` (``n_samples − n_test``) and ``test`` datasets.
    """
    from ..robots import hsr_jr680

    robot = hsr_jr680() if robot is None else robot
    check_simulation_settings(n_samples, test_fraction, noise_std, oversample)
    measurement = CableLength(default_anchor(robot)) if measurement is None else measurement
    noise_on(measurement)  # a model it cannot simulate: TypeError now, naming the right simulator
    reach = robot.reach_mm()
    wire_range = (0.05 * reach, 1.2 * reach) if wire_range_mm is None else tuple(map(float, wire_range_mm))
    dtype = jnp.result_type(float)
    eager = not _tracing(key)
    if eager:
        warn_if_float32(dtype, "simulate_experiment")
        ensure_compilation_cache()  # its program takes seconds to compile: kept on disk like calibrate's
    cfg = _Config(n_samples, test_fraction, angle_std_deg, length_std_mm, anchor_std_mm, tool_std_mm,
                  cable_offset_std_mm, coverage, wire_range, min_height_mm, oversample, flag_short=eager)
    # the float settings and σ as arguments of the program, not constants in it: calls that differ
    # only in them share one compiled program, with bit-identical data
    traced = cfg.traced(dtype, deviations=_dh_table(robot))
    if eager and true_deviations is None:
        true_deviations = _draw_experiment_deviations(key, robot, traced.deviation_stds())
    out = _simulate(key, robot, measurement, true_deviations, _traced_float(noise_std, dtype), traced)
    if not eager:  # under jit/vmap: equinox's runtime error checks the workspace filter
        return out
    ex, short = out
    if bool(short):
        raise ValueError(TOO_FEW_POSES)
    return ex


def _tracing(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def _traced_float(x, dtype):
    """``x`` (a number) as a ``dtype`` scalar array, so that ``(equinox.)jit`` traces it instead of
    compiling it in as a constant (rounded from float64 once, as a Python float constant is); a
    tracer as it is."""
    return x if _tracing(x) else to_device(np.asarray(x, np.float64), dtype)


class _Config(eqx.Module):
    """A simulation's settings. The sizes (``n_samples``, ``test_fraction``: the split's sizes,
    ``oversample``) and ``flag_short`` are static; the float settings are pytree leaves: Python
    floats are static under ``(equinox.)jit`` all the same (constants of the program, as inside
    :mod:`jaxcal._experiments._sweep_trials` or with the whole config static), arrays
    (:meth:`traced`) are its arguments."""

    n_samples: int = eqx.field(static=True)
    test_fraction: float = eqx.field(static=True)
    angle_std_deg: float
    length_std_mm: float
    anchor_std_mm: float
    tool_std_mm: float
    cable_offset_std_mm: float
    coverage: float
    wire_range: tuple[float, float]
    min_height_mm: float
    oversample: int = eqx.field(static=True)
    #: report too few poses inside the workspace filter as an output flag, checked on the host by
    #: the caller, instead of equinox's runtime error: a program with that error holds a host
    #: callback, and JAX's persistent compilation cache keeps no such program (the simulation then
    #: compiled again, ~17 s on 2 CPU cores, in every new process)
    flag_short: bool = eqx.field(static=True, default=False)

    def deviation_stds(self) -> dict:
        """The σ keywords of :func:`draw_deviations`."""
        return dict(angle_std_deg=self.angle_std_deg, length_std_mm=self.length_std_mm,
                    anchor_std_mm=self.anchor_std_mm, tool_std_mm=self.tool_std_mm,
                    cable_offset_std_mm=self.cable_offset_std_mm)

    def traced(self, dtype, deviations: bool = True) -> _Config:
        """This config with its float settings as ``dtype`` scalar arrays (traced by ``jit``), in
        float64, bit-identical data. Some stay Python floats, where a traced value would change
        the data: all of them in float32 (the angle's σ is converted to radians in float64 on the
        host, ``math.radians``, then rounded once, which a float32 traced value cannot reproduce;
        float32 simulations are rare, and warned about), and, with ``deviations=False`` (a generic
        chain: :func:`draw_deviations` builds a σ array per entry), the angle and length σ (traced,
        a chain's drawn deviations came out 1 ulp apart from the constant σ array's in some
        entries)."""
        if jnp.dtype(dtype) != jnp.float64:
            return self
        f = lambda x: _traced_float(x, dtype)  # noqa: E731
        g = f if deviations else (lambda x: x)  # noqa: E731
        return dataclasses.replace(
            self, angle_std_deg=g(self.angle_std_deg), length_std_mm=g(self.length_std_mm),
            anchor_std_mm=f(self.anchor_std_mm), tool_std_mm=f(self.tool_std_mm),
            cable_offset_std_mm=f(self.cable_offset_std_mm), coverage=f(self.coverage),
            wire_range=tuple(map(f, self.wire_range)), min_height_mm=f(self.min_height_mm))


def add_orientation_noise(y, std_rad: float, seed: int) -> np.ndarray:
    """Pose readings ``y`` ``[n, 4, 4]`` (NumPy) with each orientation turned by ``exp([σ·u]×)``
    about the tool frame's axes, ``u ~ N(0, I₃)`` per row from ``numpy.random.default_rng([seed,
    1])``: an orientation noise of σ = ``std_rad`` (rad) per axis, which the pose residual's
    ``δθ`` sees as such. :func:`simulate_experiment` leaves orientations exact (noise on the
    position only); ``jaxcal simulate --orientation-noise-deg`` adds this after it (the positions
    as before). ``y`` itself where ``std_rad`` is 0."""
    y = np.asarray(y, np.float64)
    if not std_rad > 0:
        return y
    u = np.random.default_rng([int(seed), 1]).standard_normal((y.shape[0], 3))
    out = y.copy()
    out[:, :3, :3] = y[:, :3, :3] @ np.asarray(rotvec_to_matrix(to_device(float(std_rad) * u)), np.float64)
    return out


def noise_on(measurement: MeasurementModel) -> str:
    """Where :func:`simulate_experiment` puts its noise for ``measurement``: ``"readings"`` (every
    entry: draw-wire lengths, positions, marker positions) or ``"position"`` (a pose's position;
    its orientation stays exact). Other models raise ``TypeError`` naming their simulators (marker
    readings were once taken for poses here: their noise fell out of bounds and was dropped)."""
    if isinstance(measurement, Pose):
        return "position"
    if isinstance(measurement, (CableLength, Position, Markers)):
        return "readings"
    raise TypeError(
        f"simulate_experiment simulates draw-wire, position, pose and marker readings, not {measurement.kind!r} "
        "data; use jaxcal.simulate_contact (plane, point), simulate_distance or simulate_camera")


#: the message of a simulation with too few poses inside the workspace filter
TOO_FEW_POSES = ("simulate_experiment: too few joint configurations inside the workspace filter; "
                 "raise `oversample`, widen `wire_range_mm` or lower `min_height_mm`")


def _experiment_deviations(k_dev, robot, stds: dict) -> Deviations:
    """The experiment's true deviations drawn from ``k_dev`` with ``stds``
    (:meth:`_Config.deviation_stds`)."""
    return draw_deviations(k_dev, robot, **stds, dtype=jnp.result_type(float))


@filter_jit
def _draw_experiment_deviations(key, robot, stds: dict) -> Deviations:
    """The deviations :func:`_draw_readings` draws from ``key`` when none are given (bit-identical),
    as a program of their own: one per robot structure, shared by every sample count and
    measurement model. Drawn inside the simulation program, XLA fused the draws' threefry hash and
    inverse erf into every kernel that reads the deviations: a new sample count's simulation
    compiled in 5.3–6.3 s instead of 2.2–2.5 s (2-core CPU, ``benchmarks/bench_simulate_compile.py``)."""
    return _experiment_deviations(jax.random.split(key, 4)[0], robot, stds)  # k_dev, as _draw_readings splits


def _draw_readings(key, robot, measurement, true_deviations, noise_std, cfg: _Config, n_real=None):
    """The experiment's draws before the split: ``(true_deviations, q, y, k_split, short)`` with
    ``cfg.n_samples`` rows; ``short`` (with ``cfg.flag_short``, else ``None``) is whether too few
    poses passed the workspace filter, for the caller to check (else equinox's runtime error).

    ``n_real`` (a traced int ``≤ cfg.n_samples``; shape buckets, :func:`simulate_padded`): only the
    first ``n_real·oversample`` candidate poses may be picked, and the first ``n_real`` rows equal
    those of a simulation of ``n_real`` samples: ``jax.random``'s draws are prefixes of longer
    draws of the same key (threefry in its partitionable mode, JAX's default; checked by
    ``tests/simulation/test_simulate.py``). The rows after them are filler."""
    dtype = jnp.result_type(float)
    k_dev, k_q, k_noise, k_split = jax.random.split(key, 4)
    if true_deviations is None:
        true_deviations = _experiment_deviations(k_dev, robot, cfg.deviation_stds())
    true_deviations = true_deviations.astype(dtype)
    n_cand = cfg.n_samples * cfg.oversample
    cand = sample_joint_angles(k_q, robot, n_cand, coverage=cfg.coverage, dtype=dtype)
    p = tool_point_soa(robot, true_deviations, cand)
    anchor = jnp.asarray(getattr(measurement, "anchor", jnp.zeros(3)), dtype) + true_deviations.anchor
    ok = workspace_mask(p, anchor, cfg.wire_range, cfg.min_height_mm)
    need = cfg.n_samples
    if n_real is not None:
        ok = ok & (jnp.arange(n_cand) < n_real * cfg.oversample)
        need = n_real
    (idx,) = jnp.nonzero(ok, size=cfg.n_samples, fill_value=0)
    n_ok = jnp.sum(ok)
    short = n_ok < need  # with cfg.flag_short returned for the caller to check on the host
    if not cfg.flag_short:
        idx = eqx.error_if(idx, short, TOO_FEW_POSES)
    q = cand[idx]
    y_true = measurement.predict(robot, true_deviations, q)
    sigma = jnp.asarray(noise_std, dtype)
    if noise_on(measurement) == "position":  # a pose: the orientation readings stay exact
        noise = sigma * jax.random.normal(k_noise, y_true[:, :3, 3].shape, dtype)
        y = y_true.at[:, :3, 3].add(noise)
    else:
        y = y_true + sigma * jax.random.normal(k_noise, y_true.shape, dtype)
    return true_deviations, q, y, k_split, (short if cfg.flag_short else None)


@filter_jit
def _simulate(key, robot, measurement, true_deviations, noise_std, cfg: _Config):
    """The :class:`Experiment`; with ``cfg.flag_short`` the pair ``(experiment, too_few_poses)``."""
    true_deviations, q, y, k_split, short = _draw_readings(key, robot, measurement, true_deviations, noise_std, cfg)
    dtype = jnp.result_type(float)
    data = Dataset(q, y, measurement.kind, {"source": "simulate_experiment", "robot": robot.name,
                                            **mm_joints_metadata(robot)})
    n_test = int(round(cfg.n_samples * cfg.test_fraction))
    perm = jax.random.permutation(k_split, cfg.n_samples)
    train = data.subset(perm[n_test:])
    test = data.subset(perm[:n_test])
    ex = Experiment(robot, measurement, true_deviations, train, test, jnp.asarray(noise_std, dtype))
    return (ex, short) if cfg.flag_short else ex


# ---------------------------------------------------------------------------------------------
# padded to a shape bucket (jaxcal.sweep over many sample counts)


def masked_permutation(key, n_cap: int, n_real, n_rounds) -> Array:
    """``[n_cap]`` int: ``jax.random.permutation(key, n_real)`` followed by ``n_real … n_cap−1``,
    for a traced ``n_real`` (and its :func:`permutation_rounds` ``n_rounds``) under one static
    ``n_cap``. It repeats ``permutation``'s rounds of sorting by fresh random 32-bit keys, with the
    keys of the positions ``≥ n_real`` set to the largest value: a stable sort keeps them last, and
    the keys of the real positions are prefixes of the longer draws, so the real part is the very
    permutation of ``n_real`` elements (``tests/simulation/test_simulate.py`` checks this against
    ``jax.random.permutation`` for many sizes)."""
    x = jnp.arange(n_cap)
    n_real, n_rounds = (jnp.asarray(v).astype(x.dtype) for v in (n_real, n_rounds))
    real = x < n_real
    top = jnp.asarray(np.iinfo(np.uint32).max, jnp.uint32)
    for r in range(permutation_rounds(n_cap)):
        key, sub = jax.random.split(key)
        sort_keys = jnp.where(real, jax.random.bits(sub, (n_cap,), jnp.uint32), top)
        _, shuffled = jax.lax.sort_key_val(sort_keys, x, is_stable=True)
        x = jnp.where(r < n_rounds, shuffled, x)
    return x


class PaddedSplit(NamedTuple):
    """A simulated experiment padded to a shape bucket (:func:`simulate_padded`): the real rows
    first, then filler rows with weight 0 (they repeat a real row)."""

    true_deviations: Deviations
    q_train: Array
    y_train: Array
    w_train: Array
    q_test: Array
    y_test: Array
    w_test: Array


def padded_split_sizes(n_cap: int, test_fraction: float) -> tuple[int, int]:
    """``(train rows, test rows)`` of a :func:`simulate_padded` of bucket ``n_cap``: the largest
    split sizes of any sample count ``≤ n_cap`` (both grow with the count)."""
    n_test = int(round(n_cap * test_fraction))
    return n_cap - n_test, n_test


def simulate_padded(key, robot, measurement, true_deviations, noise_std, cfg: _Config, n_real, n_test, n_rounds
                    ) -> PaddedSplit:
    """:func:`simulate_experiment` of ``n_real`` samples (traced, with its ``n_test`` =
    ``round(n_real·test_fraction)`` and :func:`permutation_rounds` ``n_rounds``) inside arrays of
    the bucket ``cfg.n_samples``: the real rows of each split are exactly those of
    ``simulate_experiment(key, n_samples=n_real)``, in the same order, and the rest has weight 0.
    One compiled program serves every sample count of the bucket (shape buckets)."""
    n_real, n_test, n_rounds = (jnp.asarray(v).astype(jnp.result_type(int)) for v in (n_real, n_test, n_rounds))
    true_deviations, q, y, k_split, _ = _draw_readings(key, robot, measurement, true_deviations, noise_std, cfg,
                                                    n_real)
    cap_train, cap_test = padded_split_sizes(cfg.n_samples, cfg.test_fraction)
    perm = masked_permutation(k_split, cfg.n_samples, n_real, n_rounds)
    dtype = jnp.result_type(float)

    def take(offset, n, cap):
        i = jnp.arange(cap)
        real = i < n
        rows = jnp.where(real, perm[jnp.clip(offset + i, 0, cfg.n_samples - 1)], perm[0])
        return q[rows], y[rows], real.astype(dtype)

    q_tr, y_tr, w_tr = take(n_test, n_real - n_test, cap_train)
    q_te, y_te, w_te = take(0, n_test, cap_test)
    return PaddedSplit(true_deviations, q_tr, y_tr, w_tr, q_te, y_te, w_te)
