"""Seed sweeps: many seeded trials per method, each chunk of trials one ``jax.vmap``-ed function.

A *trial* is a pure function of one ``jax.random`` key: ``key_i = fold_in(key, i)`` is split into
a data key (simulate the experiment, or split given data) and a method key; the trial calibrates
on the training split and evaluates on the held-out split. Every method sees the same data in
trial ``i`` (paired comparisons).

A sweep is a few compiled units, each one jitted function over a chunk of trials — the trial
``jax.vmap``-ed over the chunk (or, on a single CPU device by default, ``jax.lax.map``-ed: one
trial after the other inside the compiled function, which measured 2–3× faster for LM there):

1. the *data* unit: simulate (or split) the chunk's data and compute the before-calibration
   (nominal) and oracle (true model) test metrics — once per sweep, not once per method
   (simulation takes ~10 s to compile on CPU, mostly its random-number code);
2. one unit per method (or per vmapped hyperparameter grid): calibrate the chunk's training
   splits and evaluate on their test splits.

With several devices the trial axis of every input is sharded over a one-axis mesh and XLA
partitions the vmapped unit along it (plain ``jit`` with ``NamedSharding`` inputs). Not
``jax.shard_map`` (nor ``pmap``): inside it, traced values carry a manual-axis sharding in their
types, and lineax's structure checks (``ShapeDtypeStruct`` equality) then reject optimistix's
linear solves ("Vector and operator structures do not match", lineax issue #185).

Entry point: :func:`sweep` → :class:`SweepResult`.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import itertools
import json
import math
import os
import pathlib
import sys
import time
import warnings
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P
from jaxtyping import Array

from .._calibration._calibrate import Calibrator, resolve_space
from .._calibration._io import measurement_from_dict, measurement_to_dict, robot_from_dict, robot_to_dict
from .._core._buckets import BoundedCache, bucket_size, buckets_enabled, cache_size, release_memory, signature
from .._core._cache import ensure_compilation_cache
from .._core._json import to_jsonable
from .._core._metrics import Floor, Metrics, compute_metrics, statistical_floor
from .._core._params import Deviations, ParameterSpace, layout_for
from .._core._precision import cast_floating, dtype_scope, to_device, warn_if_float32
from .._core._xla import compile_lowered
from .._datasets._dataset import Dataset
from .._fit._diagnostics import error_dims
from .._fit._objective import LOSSES, Objective, resolve_prior
from .._fit._problem import Problem
from .._models._robot import DHRobot
from .._sensors._measurement import CableLength, MeasurementModel
from .._simulation import _simulate as _simulate_mod
from .._simulation._simulate import (
    DEFAULT_NOISE_STD,
    Experiment,
    check_simulation_settings,
    default_anchor,
    simulate_experiment,
)
from ..methods import METHODS, Method, make_method
from ..methods._stages import StageInfo

__all__ = [
    "sweep",
    "load_sweep",
    "SweepResult",
    "SweepRun",
    "PAPER_METHODS",
    "trial_keys",
    "DEFAULT_CHUNK_PER_DEVICE",
    "DEFAULT_CHUNK_PER_ACCELERATOR",
]

#: The paper's compared methods M1–M8 (Table II) as registry names, in the paper's order.
PAPER_METHODS: tuple[str, ...] = ("ga", "ekf", "bso", "lm", "iwoa", "rbfnn", "adam", "adamodw")

#: Default maximum number of trials per device in one vmapped chunk (bounds memory: the RBF
#: network and the population methods hold a few MB per trial at 2 000 samples).
DEFAULT_CHUNK_PER_DEVICE = 16

#: The same on a GPU or TPU (one vmapped chunk of up to 1 024 trials per device). An accelerator
#: runs a vmapped chunk of 16 LM trials about as fast as one of 1 000 (launch-bound: 19 ms for
#: 1 000 trials × 2 000 samples on an H100), so with the CPU's 16 a 1 000-trial sweep cost 63
#: chunks (3.6–4.2 s) instead of one.
DEFAULT_CHUNK_PER_ACCELERATOR = 1024

_FORMAT_VERSION = 1

#: fields of the simulation's static configuration, in order (``jaxcal._simulation._simulate._Config``).
_CONFIG_FIELDS = ("n_samples", "test_fraction", "angle_std_deg", "length_std_mm", "anchor_std_mm", "tool_std_mm",
                  "cable_offset_std_mm", "coverage", "wire_range", "min_height_mm", "oversample")


# ---------------------------------------------------------------------------------------------
# keys


def _as_key(key) -> Array:
    """A typed ``jax.random`` key from a typed key, a legacy ``uint32[2]`` key or an int seed."""
    if isinstance(key, (int, np.integer)):
        return jax.random.key(int(key))
    key = jnp.asarray(key) if not isinstance(key, jax.Array) else key
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        return key
    return jax.random.wrap_key_data(key)


def trial_keys(key, start: int, stop: int) -> Array:
    """Keys of trials ``start … stop−1``: ``fold_in(key, i)`` (trial ``i``'s key does not depend
    on how many trials the sweep has or how they are chunked)."""
    key = _as_key(key)
    return jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.arange(start, stop, dtype=jnp.uint32))


# ---------------------------------------------------------------------------------------------
# data sources (pure in the data key)


class _Split(NamedTuple):
    q_train: Array
    y_train: Array
    q_test: Array
    y_test: Array
    truth: Deviations | None
    #: ``[n_train]``, ``[n_test]``: 1 for a real sample, 0 for a padding row (shape buckets), or None
    w_train: Array | None = None
    w_test: Array | None = None


class _Simulated(eqx.Module):
    """Simulate the paper's experiment from the data key (:func:`simulate_experiment`).

    With ``sizes`` (shape buckets: ``(n_samples, n_test, permutation rounds)`` as int arrays, so
    traced) the options' ``n_samples`` is the bucket and the split arrives padded with zero-weight
    rows (:func:`~jaxcal._simulation._simulate.simulate_padded`): its real rows are exactly the
    unpadded simulation's, and one compiled program serves every sample count of the bucket."""

    robot: DHRobot
    measurement: MeasurementModel
    true_deviations: Deviations | None
    options: tuple = eqx.field(static=True)
    sizes: Array | None = None

    def __call__(self, key) -> _Split:
        # simulate_experiment's core (the public wrapper reads the robot's dimensions with NumPy,
        # which a traced robot cannot provide); identical data for the same key and options.
        o = dict(self.options)
        cfg = _simulate_mod._Config(*(o[f] for f in _CONFIG_FIELDS))
        if self.sizes is not None:
            n, n_test, rounds = self.sizes
            ps = _simulate_mod.simulate_padded(key, self.robot, self.measurement, self.true_deviations,
                                               o["noise_std"], cfg, n, n_test, rounds)
            return _Split(ps.q_train, ps.y_train, ps.q_test, ps.y_test, ps.true_deviations, ps.w_train, ps.w_test)
        ex = _simulate_mod._simulate(key, self.robot, self.measurement, self.true_deviations, o["noise_std"], cfg)
        return _Split(ex.train.q, ex.train.y, ex.test.q, ex.test.y, ex.true_deviations)


class _RandomSplit(eqx.Module):
    """Given data, split at random from the data key (a different split per trial)."""

    q: Array
    y: Array
    n_test: int = eqx.field(static=True)

    def __call__(self, key) -> _Split:
        perm = jax.random.permutation(key, self.q.shape[0])
        tr, te = perm[self.n_test:], perm[: self.n_test]
        return _Split(self.q[tr], self.y[tr], self.q[te], self.y[te], None)


class _FixedSplit(eqx.Module):
    """Given train and test data, the same in every trial (only the method key varies)."""

    q_train: Array
    y_train: Array
    q_test: Array
    y_test: Array
    truth: Deviations | None

    def __call__(self, key) -> _Split:
        del key
        return _Split(self.q_train, self.y_train, self.q_test, self.y_test, self.truth)


# ---------------------------------------------------------------------------------------------
# the pure per-trial functions


class _DataOut(NamedTuple):
    before: Metrics
    oracle: Metrics
    truth: Any
    before_errors: Array
    split: _Split  # the trial's data (input of every method's trial)
    k_method: Array  # uint32 key data of the method key


class _TrialOut(NamedTuple):
    test: Metrics
    train: Metrics
    n_iterations: Array
    iterations_to_converge: Array
    status: Array
    x: Array
    history: Array
    test_errors: Array
    #: staged methods only (``"ga>lm"``): ``[S]`` history index where each stage ended
    stage_ends: Array | None = None


#: the tree structure of a :class:`_TrialOut` (leaf values are placeholders): the template that
#: maps a chunk's flat ``{path: array}`` back to a result (sweep and ``load_sweep`` alike).
_TRIAL_LIKE = _TrialOut(Metrics(0.0, 0.0, 0.0), Metrics(0.0, 0.0, 0.0), 0, 0, 0, 0.0, 0.0, 0.0)


class _DataTrial(eqx.Module):
    """Trial data from the trial key, and the before-calibration (nominal) and oracle (true
    model) metrics on its test split. Runs once per sweep; every method reuses its output."""

    source: eqx.Module
    robot: DHRobot
    measurement: MeasurementModel
    start: Deviations
    space: ParameterSpace = eqx.field(static=True)
    keep_errors: bool = eqx.field(static=True)

    def __call__(self, key, hyper=None) -> _DataOut:
        del hyper
        k_data, k_method = jax.random.split(key)
        s = self.source(k_data)
        test = Problem(self.robot, self.measurement, s.q_test, s.y_test, self.space, self.start, s.w_test)
        e0 = test.sample_errors(test.x0())
        if s.truth is None:
            nan = jnp.full((), jnp.nan, e0.dtype)
            oracle, truth = Metrics(nan, nan, nan), None
        else:
            r = self.measurement.residual(self.robot, s.truth, s.q_test, s.y_test)
            oracle, truth = compute_metrics(self.measurement.sample_error(r), s.w_test), s.truth
        return _DataOut(compute_metrics(e0, s.w_test), oracle, truth,
                        e0 if self.keep_errors else jnp.zeros((0,), e0.dtype),
                        s._replace(truth=None), jax.random.key_data(k_method))


class _MethodTrial(eqx.Module):
    """Calibrate one trial's training split with ``method`` and evaluate on its test split.

    With ``method_name`` set (a traced hyperparameter grid) the method is built inside the trace
    from ``static_hyper`` plus the traced values passed to ``__call__``.
    """

    robot: DHRobot
    measurement: MeasurementModel
    start: Deviations
    method: Method | None
    space: ParameterSpace = eqx.field(static=True)
    method_name: str | None = eqx.field(static=True, default=None)
    static_hyper: tuple = eqx.field(static=True, default=())
    keep_errors: bool = eqx.field(static=True, default=True)
    keep_history: bool = eqx.field(static=True, default=True)
    objective: Objective | None = None

    def __call__(self, split: _Split, k_method, hyper=None) -> _TrialOut:
        if self.method_name is None:
            method = self.method
        else:
            with warnings.catch_warnings():  # traced values in the method's report-only settings
                warnings.filterwarnings("ignore", "A JAX array is being set as static")
                method = make_method(self.method_name, **dict(self.static_hyper), **(hyper or {}))
        cal = Calibrator(self.robot, self.measurement, method, self.start, self.space, self.objective)
        out = cal(split.q_train, split.y_train, jax.random.wrap_key_data(k_method), split.w_train)
        e = method.sample_errors(cal.problem(split.q_test, split.y_test, split.w_test), out.x, out.extra)
        hist = out.history if self.keep_history else out.history[-1:]
        return _TrialOut(
            compute_metrics(e, split.w_test), out.train_metrics, out.n_iterations, out.iterations_to_converge,
            out.status, out.x, hist, e if self.keep_errors else jnp.zeros((0,), e.dtype),
            out.extra.ends if isinstance(out.extra, StageInfo) else None,
        )


def _batched(static, dyn, inputs, hyper, sequential: bool = False):
    """The trial over a chunk: ``inputs`` is a tuple of trial-batched pytrees; with a grid, the
    hyperparameter points form an outer axis. ``jax.vmap`` (all trials at once), or with
    ``sequential`` ``jax.lax.map`` (one trial after the other inside the compiled function)."""
    trial = eqx.combine(dyn, static)
    batch = (lambda f, xs: jax.lax.map(lambda a: f(*a), xs)) if sequential else (lambda f, xs: jax.vmap(f)(*xs))  # noqa: E731
    over_trials = lambda h: batch(lambda *a: trial(*a, h), inputs)  # noqa: E731
    return over_trials(None) if hyper is None else batch(over_trials, (hyper,))


@functools.partial(jax.jit, static_argnums=(0, 1, 2, 3))
def _run_chunk(static, mesh, grid: bool, sequential: bool, dyn, inputs, hyper):
    """One chunk of trials, jitted (module level so compilations are cached by the static part).

    With a ``mesh`` the trial axis of ``inputs`` arrives sharded over the devices and everything
    else replicated; the vmapped trial is partitioned along that axis by XLA (GSPMD), and the
    outputs are constrained to the same sharding.
    """
    out = _batched(static, dyn, inputs, hyper, sequential)
    if mesh is not None:
        spec = P(None, "trials") if grid else P("trials")
        out = jax.lax.with_sharding_constraint(out, NamedSharding(mesh, spec))
    return out


# ---------------------------------------------------------------------------------------------
# results


@dataclasses.dataclass(eq=False)
class SweepRun:
    """Per-trial results of one method (or one grid point) in a sweep. Arrays have a leading
    ``[n_seeds]`` axis (trial ``i`` = seed ``i``).

    Attributes:
        label: display name (``"adamodw"``, ``"adamodw[b3=0.99, weight_decay=0.001]"``, ...).
        method: registry name (or the label of a user's method).
        hyperparameters: the method's settings.
        grid_point: the grid values of this run, or ``None``.
        test: RMSE/MEAN/MAX (mm) on each trial's held-out split, arrays ``[n]``.
        train: RMSE/MEAN/MAX (mm) on the training split.
        n_iterations, iterations_to_converge, status: ``[n]`` ints (:class:`~jaxcal.Status` codes).
        time_per_trial_s: ``[n]`` wall time of the trial's chunk divided by the chunk size
            (compilation excluded; under ``vmap`` a chunk of LM runs lasts until its slowest
            member converges).
        compile_time_s: compilation time of the chunk function (s; 0 when loaded from disk).
        x: ``[n, p]`` calibrated free parameters (rad, mm; ``SweepResult.space`` order).
        history: ``[n, T+1]`` training RMSE per iteration (``[n, 1]``: final only, if not kept).
        test_errors: ``[n, n_test]`` per-sample test errors (mm; signed for wire lengths), or
            an empty ``[n, 0]`` array if not kept.
        stage_ends: staged methods (``"ga>lm"``): ``[n, S]`` history index where each stage
            ended; ``None`` otherwise.
    """

    label: str
    method: str
    hyperparameters: dict
    grid_point: dict | None
    test: Metrics
    train: Metrics
    n_iterations: np.ndarray
    iterations_to_converge: np.ndarray
    status: np.ndarray
    time_per_trial_s: np.ndarray
    compile_time_s: float
    x: np.ndarray
    history: np.ndarray
    test_errors: np.ndarray
    stage_ends: np.ndarray | None = None

    @property
    def n_seeds(self) -> int:
        return int(self.status.shape[0])

    def summary(self) -> dict:
        """Mean and standard deviation over seeds (``ddof=1``) of every scalar per-trial
        quantity, plus status counts: ``{"test_rmse": (mean, std), ..., "status": {...}}``."""
        from .._fit._result import Status

        out = {}
        for split, m in (("test", self.test), ("train", self.train)):
            for f in m._fields:
                out[f"{split}_{f}"] = _mean_std(getattr(m, f))
        for f in ("n_iterations", "iterations_to_converge", "time_per_trial_s"):
            out[f] = _mean_std(getattr(self, f))
        out["time_to_converge_s"] = _mean_std(self.time_to_converge_s)
        codes, counts = np.unique(self.status, return_counts=True)
        out["status"] = {Status(int(c)).name.lower(): int(k) for c, k in zip(codes, counts)}
        return out

    @property
    def time_to_converge_s(self) -> np.ndarray:
        """Estimated time to converge in RMSE: ``time_per_trial_s × iterations_to_converge /
        n_iterations`` (the paper's Table IV "Time (RMSE)"), ``[n]``."""
        its = np.maximum(self.n_iterations, 1)
        return self.time_per_trial_s * np.minimum(self.iterations_to_converge, its) / its


def _mean_std(a) -> tuple[float, float]:
    a = np.asarray(a, dtype=np.float64)
    if a.size == 0:
        return (math.nan, math.nan)
    return float(np.mean(a)), float(np.std(a, ddof=1)) if a.size > 1 else 0.0


@dataclasses.dataclass(eq=False)
class SweepResult:
    """Result of :func:`sweep`.

    Attributes:
        runs: ``{label: SweepRun}`` in the order the methods (then grid points) were given.
        n_seeds: number of trials.
        before: RMSE/MEAN/MAX (mm) of the nominal model ("BC", before calibration) on each
            trial's test split, arrays ``[n]``.
        oracle: the same for the true model (simulation only; NaN for given data): the noise
            level actually present in each test split, the best any method can do there.
        floor: theoretical statistical floor ``Floor(train, test)`` (mm) for σ = ``noise_std``,
            ``p = space.n_free`` and the training size (:func:`~jaxcal.statistical_floor`), or
            ``None`` when the noise level is unknown.
        before_errors: ``[n, n_test]`` per-sample test errors of the nominal model (mm).
        space: the free parameters (the same for every trial and method).
        robot, measurement, start: the nominal models and the start deviations.
        true_deviations: the true deviations per trial (a :class:`Deviations` with a leading
            ``[n]`` axis; simulation only, else ``None``).
        settings: the sweep's settings (JSON-friendly).
    """

    runs: dict[str, SweepRun]
    n_seeds: int
    before: Metrics
    oracle: Metrics
    floor: Floor | None
    before_errors: np.ndarray
    space: ParameterSpace
    robot: DHRobot
    measurement: MeasurementModel
    start: Deviations
    true_deviations: Deviations | None
    settings: dict

    def __getitem__(self, label: str) -> SweepRun:
        try:
            return self.runs[label]
        except KeyError:
            raise KeyError(f"no run {label!r} in this sweep; runs: {list(self.runs)}") from None

    def __iter__(self):
        return iter(self.runs.values())

    @property
    def labels(self) -> list[str]:
        return list(self.runs)

    def deviations(self, label: str, trial: int = 0) -> Deviations:
        """Calibrated deviations of run ``label`` in trial ``trial`` (non-free entries from
        ``start``)."""
        return self.space.from_vector(jnp.asarray(self[label].x[trial]), self.start)

    def true_deviation(self, trial: int = 0) -> Deviations | None:
        """The true deviations of trial ``trial`` (simulation only)."""
        if self.true_deviations is None:
            return None
        return jax.tree.map(lambda a: jnp.asarray(a)[trial], self.true_deviations)

    def summary(self) -> dict:
        """``{"before": ..., "oracle": ..., "floor": ..., "runs": {label: SweepRun.summary()}}``."""
        m = lambda met: {f: _mean_std(getattr(met, f)) for f in met._fields}  # noqa: E731
        return {
            "n_seeds": self.n_seeds,
            "n_free": self.space.n_free,
            "before": m(self.before),
            "oracle": m(self.oracle),
            "floor": None if self.floor is None else self.floor._asdict(),
            "runs": {k: r.summary() | {"hyperparameters": r.hyperparameters, "grid_point": r.grid_point}
                     for k, r in self.runs.items()},
        }

    def __repr__(self) -> str:
        parts = ", ".join(f"{k}: {np.mean(r.test.rmse):.4f}" for k, r in self.runs.items())
        return f"SweepResult(n_seeds={self.n_seeds}, p={self.space.n_free}, mean test RMSE (mm) {{{parts}}})"


# ---------------------------------------------------------------------------------------------
# the sweep


def _progress(enabled: bool, msg: str) -> None:
    if enabled:
        print(f"[jaxcal.sweep] {msg}", file=sys.stderr, flush=True)


def _label_value(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _grid_points(grid: Mapping[str, Sequence]) -> list[dict]:
    names = list(grid)
    for n in names:
        if isinstance(grid[n], (str, bytes)) or not isinstance(grid[n], Sequence) or len(grid[n]) == 0:
            raise ValueError(f"grid values for {n!r} must be a non-empty list, got {grid[n]!r}")
    return [dict(zip(names, combo)) for combo in itertools.product(*(list(grid[n]) for n in names))]


def _is_traceable(values) -> bool:
    """A grid axis whose values are numbers with at least one float is vmapped over (traced);
    others (integers such as ``steps``, strings) change shapes or code and are compiled per value."""
    nums = all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) for v in values)
    return nums and any(isinstance(v, (float, np.floating)) for v in values)


@dataclasses.dataclass
class _RunSpec:
    """One compiled unit: a method (``points`` None) or a method's grid points."""

    name: str  # registry name or user label
    method: Method | None  # plain run
    labels: list[str]
    hyper_reports: list[dict]
    points: list[dict] | None = None
    traced_keys: tuple[str, ...] = ()
    static_hyper: dict = dataclasses.field(default_factory=dict)
    fingerprint_extra: str = ""


def _method_specs(methods, hyperparameters, grid) -> list[_RunSpec]:
    import optax

    hyperparameters = dict(hyperparameters or {})
    grid = dict(grid or {})
    if isinstance(methods, (str, Method, optax.GradientTransformation)):
        methods = [methods]
    items: list[tuple[str | None, Any]]
    if isinstance(methods, Mapping):
        items = list(methods.items())
    else:
        items = [(None, m) for m in methods]
    specs: list[_RunSpec] = []
    for label, m in items:
        if isinstance(m, str) and m.lower() in grid:
            continue  # run as a grid below
        hyper = hyperparameters.get(m, {}) if isinstance(m, str) else {}
        meth = make_method(m, **hyper)
        lab = label or (m.lower() if isinstance(m, str) else meth.label())
        specs.append(_RunSpec(m.lower() if isinstance(m, str) else lab, meth, [lab], [meth.hyperparameters()],
                              fingerprint_extra=repr(sorted(hyper.items()))))
    for name, g in grid.items():
        if not isinstance(name, str) or name.lower() not in METHODS:
            raise ValueError(f"grid keys must be registered method names, got {name!r}; available: {sorted(METHODS)}")
        name = name.lower()
        if not isinstance(g, Mapping) or not g:
            raise ValueError(f"grid[{name!r}] must be a non-empty mapping hyperparameter -> list of values")
        base = dict(hyperparameters.get(name, {}))
        points = _grid_points(g)
        reports, labels = [], []
        for pt in points:
            meth = make_method(name, **(base | pt))  # validates every point eagerly
            reports.append(meth.hyperparameters())
            labels.append(f"{name}[" + ", ".join(f"{k}={_label_value(v)}" for k, v in pt.items()) + "]")
        traced = tuple(k for k in g if _is_traceable(list(g[k])))
        static_keys = [k for k in g if k not in traced]
        # group the points by their static values: one compilation per group, traced axes vmapped
        groups: dict[tuple, list[int]] = {}
        for i, pt in enumerate(points):
            groups.setdefault(tuple((k, pt[k]) for k in static_keys), []).append(i)
        for stat, idx in groups.items():
            specs.append(_RunSpec(
                name, None, [labels[i] for i in idx], [reports[i] for i in idx],
                points=[points[i] for i in idx], traced_keys=traced, static_hyper=base | dict(stat),
                fingerprint_extra=repr(sorted((base | dict(stat)).items())),
            ))
    seen = set()
    for s in specs:
        for lab in s.labels:
            if lab in seen:
                raise ValueError(f"two runs are labelled {lab!r}; pass methods as a dict {{label: method}}")
            seen.add(lab)
    if not specs:
        raise ValueError("no methods to run")
    return specs


def _resolve_devices(devices) -> list:
    if devices is None:
        devs = jax.devices()
    elif isinstance(devices, int):
        devs = jax.devices()[:devices]
        if len(devs) < devices:
            raise ValueError(f"asked for {devices} devices, only {len(jax.devices())} present")
    else:
        devs = list(devices)
    if not devs:
        raise ValueError("no devices")
    return devs


def _chunking(n: int, chunk_size: int | None, n_dev: int, platform: str = "cpu") -> tuple[int, int]:
    """``(per_device, per_chunk)``: trials per device in one vmapped call, and per chunk.

    The per-device batch is balanced (``n`` trials with a cap of 16 run as 2 × 10, not 16 + 4).
    With an explicit ``chunk_size`` it does not depend on the device count, so trial ``i`` is
    computed in the same batch of trials on any number of devices (bitwise-equal results); by
    default the cap is ``min(16, ceil(n / n_dev))`` (1 024 instead of 16 on a GPU or TPU) so that
    every device gets work.
    """
    if chunk_size is None:
        default = DEFAULT_CHUNK_PER_DEVICE if platform == "cpu" else DEFAULT_CHUNK_PER_ACCELERATOR
        cap = min(default, math.ceil(n / n_dev))
    else:
        cap = int(chunk_size)
        if cap < 1:
            raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
    per_device = math.ceil(n / math.ceil(n / cap))
    return per_device, per_device * n_dev


def _robot_fingerprint(robot: DHRobot) -> dict:
    if not isinstance(robot, DHRobot):  # a generic chain: its URDF text, base/tip and tool
        return robot_to_dict(robot)
    return {
        "name": robot.name, "convention": robot.convention, "beta_joints": list(robot.beta_joints),
        **{f: np.asarray(getattr(robot, f), np.float64).round(12).tolist()
           for f in ("alpha", "a", "d", "theta", "beta", "q_min", "q_max", "tool")},
    }


def _array_digest(*arrays) -> str:
    h = hashlib.sha1()
    for a in arrays:
        a = np.ascontiguousarray(np.asarray(a, np.float64))
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _fingerprint(obj) -> str:
    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=repr).encode()).hexdigest()[:16]


class _Store:
    """Chunk files of a sweep in ``out_dir`` (written as each chunk finishes; read to resume)."""

    def __init__(self, out_dir):
        self.root = None if out_dir is None else pathlib.Path(out_dir)
        if self.root is not None:
            self.root.mkdir(parents=True, exist_ok=True)

    def path(self, unit: str, start: int, stop: int) -> pathlib.Path | None:
        if self.root is None:
            return None
        safe = "".join(c if c.isalnum() or c in "-_.=," else "_" for c in unit)
        return self.root / "chunks" / safe / f"trials_{start:06d}-{stop:06d}.npz"

    def exists(self, unit, start, stop) -> bool:
        p = self.path(unit, start, stop)
        return p is not None and p.exists()

    def load(self, unit, start, stop, fingerprint):
        p = self.path(unit, start, stop)
        if p is None or not p.exists():
            return None
        with np.load(p, allow_pickle=False) as f:
            meta = json.loads(str(f["__meta__"]))
            if meta.get("fingerprint") != fingerprint:
                raise ValueError(
                    f"{p} was written by a sweep with other settings (fingerprint {meta.get('fingerprint')} "
                    f"!= {fingerprint}); use another out_dir or delete it"
                )
            arrays = {k: np.array(f[k]) for k in f.files if k != "__meta__"}
        return arrays, meta

    def save(self, unit, start, stop, fingerprint, arrays: dict, meta: dict) -> None:
        p = self.path(unit, start, stop)
        if p is None or jax.process_index() != 0:
            return
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_name(p.stem + ".tmp.npz")
        np.savez(tmp, __meta__=np.asarray(json.dumps(meta | {"fingerprint": fingerprint})), **arrays)
        os.replace(tmp, p)  # atomic: an interrupted write never leaves a half file


def _flatten(tree) -> dict[str, np.ndarray]:
    leaves, _ = jax.tree_util.tree_flatten_with_path(tree)
    return {jax.tree_util.keystr(path): np.asarray(leaf) for path, leaf in leaves}


def _unflatten(like, arrays: dict[str, np.ndarray]):
    leaves, treedef = jax.tree_util.tree_flatten_with_path(like)
    return jax.tree_util.tree_unflatten(treedef, [arrays[jax.tree_util.keystr(p)] for p, _ in leaves])


def _to_host(tree):
    def get(a):
        if isinstance(a, jax.Array) and not a.is_fully_addressable:
            from jax.experimental import multihost_utils

            return np.asarray(multihost_utils.process_allgather(a, tiled=True))
        return np.asarray(a)

    return jax.tree.map(get, tree)


def _put_global(tree, sharding):
    """``jax.device_put(tree, sharding)``, also when the sharding spans devices of other processes
    (multi-process runs after ``jax.distributed.initialize()``, where ``device_put`` refuses a
    non-addressable sharding): every process holds the same host values, and each puts the shards
    of its own devices (``jax.make_array_from_callback``)."""
    if sharding.is_fully_addressable:
        return jax.device_put(tree, sharding)

    def one(x):
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            return x  # already a global array
        if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jax.dtypes.prng_key):
            return jax.random.wrap_key_data(one(jax.random.key_data(x)), impl=jax.random.key_impl(x))
        x = np.asarray(x)
        return jax.make_array_from_callback(x.shape, sharding, lambda idx: x[idx])

    return jax.tree.map(one, tree)


def _one_trial_like(runner, eval_shape, dtype):
    """Shapes of one trial's output: from the unit's compiled chunk (``[chunk, ...]`` outputs), or,
    when every chunk was loaded from disk (nothing compiled), by tracing the trial."""
    if runner.compiled is not None:
        return jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape[1:], a.dtype), runner.compiled.out_info)
    with dtype_scope(dtype):
        return eval_shape()


class _Runner:
    """Compiles and runs the chunks of one unit (data pass, method, or grid group)."""

    def __init__(self, trial: eqx.Module, mesh: Mesh | None, dtype, grid: bool, sequential: bool, device=None):
        self.dyn, self.static = eqx.partition(trial, eqx.is_array)
        self.dyn = cast_floating(self.dyn, dtype)
        if mesh is not None:  # the trial's own arrays are replicated on every device
            self.dyn = _put_global(self.dyn, NamedSharding(mesh, P()))
        elif device is not None:  # one given device (e.g. the CPU of a GPU machine): run there
            self.dyn = jax.device_put(self.dyn, device)
        self.mesh, self.dtype, self.grid, self.sequential = mesh, dtype, grid, sequential
        self.device = device
        if mesh is not None:
            self.platform = mesh.devices.flat[0].platform
        else:
            self.platform = jax.default_backend() if device is None else device.platform
        self.compiled = None
        self._lowered = None
        self._key = None
        self.compile_time_s = 0.0
        self.reused = False

    def _cache_key(self, inputs, hyper):
        """The key of this unit's compiled chunk function in :data:`_COMPILED_CHUNKS`: the static
        part of the trial (a padded simulation's static part is its bucket, not its sample count),
        the mesh or device and the shapes/dtypes of every argument; ``None`` if unhashable."""
        try:
            key = (self.static, self.mesh, None if self.device is None else self.device.id, self.platform,
                   self.grid, self.sequential, str(jnp.dtype(self.dtype)), jax.config.jax_enable_x64,
                   signature(self.dyn), signature(inputs), signature(hyper))
            hash(key)
        except TypeError:
            return None
        return key

    def _place(self, inputs, hyper):
        if self.mesh is None:
            if self.device is not None:
                if any(isinstance(a, jax.ShapeDtypeStruct) for a in jax.tree.leaves(inputs)):  # lowering only
                    return inputs, jax.device_put(hyper, self.device)
                return jax.device_put((inputs, hyper), self.device)
            return inputs, hyper
        rep = NamedSharding(self.mesh, P())
        inputs = _put_global(inputs, NamedSharding(self.mesh, P("trials")))
        return inputs, _put_global(hyper, rep)

    def lower(self, inputs, hyper):
        """Trace and lower the chunk function for ``inputs`` (Python-bound: the main thread), or
        take the compiled function from :data:`_COMPILED_CHUNKS` (an earlier sweep of the same
        unit and shapes in this process: nothing to trace or compile)."""
        t0 = time.perf_counter()
        with dtype_scope(self.dtype):
            inputs, hyper = self._place(inputs, hyper)
            self._key = self._cache_key(inputs, hyper)
            hit = None if self._key is None else _COMPILED_CHUNKS.get(self._key)
            if hit is not None:
                self.compiled, self.reused, self.compile_time_s = hit, True, 0.0
                return
            self._lowered = _run_chunk.lower(self.static, self.mesh, self.grid, self.sequential, self.dyn, inputs, hyper)
        self.compile_time_s = time.perf_counter() - t0

    def compile(self):
        """XLA-compile what :meth:`lower` traced (releases the GIL: units compile in parallel threads)."""
        if self.compiled is not None:  # reused from _COMPILED_CHUNKS
            return
        t0 = time.perf_counter()
        self.compiled = compile_lowered(self._lowered, self.platform)
        self._lowered = None
        self.compile_time_s += time.perf_counter() - t0
        if self._key is not None:
            _COMPILED_CHUNKS.put(self._key, self.compiled)

    def __call__(self, inputs, hyper):
        if self.compiled is None:
            self.lower(inputs, hyper)
            self.compile()
            _forget_traces()
        with dtype_scope(self.dtype):
            inputs, hyper = self._place(inputs, hyper)
            t0 = time.perf_counter()
            out = jax.block_until_ready(self.compiled(self.dyn, inputs, hyper))
            wall = time.perf_counter() - t0
        return _to_host(out), wall


#: compiled chunk functions of this process, least recently used dropped first
#: (``$JAXCAL_SWEEP_CACHE`` entries, default 32: the data unit and a method of 16 shape buckets;
#: each holds an executable, ~14 MB resident on the 2-core CPU for the paper experiment's LM): a
#: second sweep of the same units and shapes — a learning curve over sample counts of one shape
#: bucket, a notebook re-running a cell — compiles nothing.
_COMPILED_CHUNKS = BoundedCache(cache_size("sweep", 32))


def _forget_traces() -> None:
    """Drop ``_run_chunk``'s own trace and lowering caches (tens of MB per unit, never freed by
    JAX; the compiled functions live in :data:`_COMPILED_CHUNKS`) and give freed heap pages back."""
    _run_chunk.clear_cache()
    release_memory()


def sweep(
    methods,
    n_seeds: int = 20,
    *,
    seed: int = 0,
    key=None,
    robot: DHRobot | None = None,
    measurement: MeasurementModel | None = None,
    n_samples: int = 2000,
    noise_std: float | None = DEFAULT_NOISE_STD,
    test_fraction: float = 0.2,
    experiment: Mapping[str, Any] | None = None,
    data=None,
    space: ParameterSpace | str | None = None,
    start: Deviations | None = None,
    hyperparameters: Mapping[str, Mapping[str, Any]] | None = None,
    grid: Mapping[str, Mapping[str, Sequence]] | None = None,
    chunk_size: int | None = None,
    devices=None,
    batching: str = "auto",
    out_dir=None,
    progress: bool = True,
    keep_errors: bool = True,
    keep_history: bool = True,
    prior=None,
    loss: str = "linear",
    loss_scale: float | None = None,
) -> SweepResult:
    """Run ``n_seeds`` seeded trials of each method; each chunk of trials is one jitted ``vmap``.

    Trial ``i`` uses ``key_i = jax.random.fold_in(key, i)`` split into a data key and a method
    key. With simulation (the default) the data key draws a whole experiment
    (:func:`~jaxcal.simulate_experiment`: true deviations, poses, noise, split), so the spread
    over seeds covers robots, poses and noise, as a repeated experiment would; every method sees
    the same data in trial ``i``.

    Args:
        methods: a registry name, a list of names / :class:`~jaxcal.methods.Method` objects /
            optax transformations, or a dict ``{label: method}``.
        n_seeds: number of trials.
        seed, key: base key (``key`` wins; an int, a typed key or a legacy ``uint32[2]`` key).
        robot, measurement: nominal models (default: HSR-JR680, draw-wire at
            :func:`~jaxcal._simulation._simulate.default_anchor`).
        n_samples, noise_std, test_fraction: simulation settings (σ in mm). With given
            ``data``, ``noise_std`` (or ``None``) only sets the statistical-floor row. With shape
            buckets turned on explicitly (:func:`jaxcal.set_buckets` ``(True)``,
            ``JAXCAL_BUCKETS=on``; not by default) and every method paddable, the simulation
            runs at the bucket of ``n_samples`` with zero-weight padding rows: the same data and
            results to round-off, and one compiled program per bucket (a learning curve over
            many ``n_samples`` compiles once per bucket; ``settings["source"]["bucket"]``).
        experiment: other :func:`~jaxcal.simulate_experiment` keywords (``coverage``,
            ``angle_std_deg``, ``anchor_std_mm``, ``true_deviations``, ...).
        data: instead of simulating, a :class:`~jaxcal.Dataset` (split at random per trial with
            ``test_fraction``), a ``(train, test)`` pair of Datasets, or an
            :class:`~jaxcal.Experiment` (fixed split; the truth gives the oracle row).
        space: free parameters, fixed for the whole sweep. Default: chosen at trial 0's training
            poses as :func:`jaxcal.calibrate` chooses them (the identifiable subset; with a
            ``prior`` every parameter it covers and the data-identifiable rest, see
            :func:`jaxcal._calibration._calibrate.resolve_space`); ``"all"`` or a
            :class:`~jaxcal.ParameterSpace` as in :func:`~jaxcal.calibrate`.
        start: starting deviations (default nominal).
        hyperparameters: ``{method name: {setting: value}}``.
        grid: ``{method name: {setting: [values, ...]}}``: run every combination of the values
            (the cartesian product), each as its own run labelled ``name[k=v, ...]``. Axes with
            float values are vmapped over inside one compilation; integer or string axes compile
            once per value.
        chunk_size: maximum trials per device in one vmapped call (default: up to 16 on CPU,
            1 024 on a GPU or TPU, spread evenly over the devices). Batches are balanced (20 trials with a cap of 16 run as
            2 × 10); a chunk is one batch per device, and the last chunk is padded (padded
            trials are computed and dropped). Vectorised code rounds differently for different
            batch sizes (~1e-13 relative; an LM stopping test can then flip by one iteration),
            so pass ``chunk_size`` explicitly for results that are bitwise independent of the
            number of devices.
        devices: devices to spread each chunk over (default: all of ``jax.devices()``), an int
            (the first ``n``), or a list. With more than one, the chunk's keys are sharded over
            the devices (``NamedSharding(Mesh(devices, ("trials",)), P("trials"))``), everything
            else replicated, and XLA partitions the vmapped trial along the trial axis: each
            device computes its own batch, with the same results as one device computing that
            batch (see ``chunk_size``).
        batching: how a device runs its batch of trials inside the chunk's compiled function:
            ``"vmap"`` (all at once, vectorised: what fills a GPU; a vmapped LM batch runs until
            its slowest trial converges), ``"map"`` (``jax.lax.map``: one after the other, no
            batching overhead; on CPU 2–3× faster for LM and half the compile time, equal for
            AdaModW — ``benchmarks/results/sweep_cpu.md``), or ``"auto"``: ``"map"`` on a single
            CPU device, else ``"vmap"``. Several devices always use ``"vmap"`` (XLA partitions a
            vmapped batch over them; a sequential map cannot be split).
        out_dir: directory to write each finished chunk to (``chunks/<run>/trials_a-b.npz``)
            and the settings (``sweep.json``); a rerun with the same settings loads finished
            chunks instead of recomputing them (resume after an interruption);
            :func:`load_sweep` reads the directory back.
        progress: one line per chunk on stderr.
        keep_errors: keep per-sample test errors (``[n, n_test]`` per run; Fig. 4).
        keep_history: keep per-iteration training RMSE (``[n, T+1]`` per run; Fig. 3).
        prior, loss, loss_scale: the objective of every trial, as in :func:`jaxcal.calibrate`,
            with fixed scales (a sweep does not re-estimate them): the prior is weighed against
            ``Prior.noise_std`` or else the sweep's ``noise_std``; the robust loss's scale
            defaults to its constant (1.345 Huber, 2.385 Cauchy) times a clean sample's RMS error
            (that σ for a length, √3·σ for a position's norm).

    Returns:
        :class:`SweepResult`.
    """
    n_seeds = _check_n_seeds(n_seeds)
    ensure_compilation_cache()
    base_key = _as_key(seed if key is None else key)
    dtype = jnp.result_type(float)
    warn_if_float32(dtype, "sweep")
    specs = _method_specs(methods, hyperparameters, grid)
    pad = data is None and _paddable(specs)
    source, robot, measurement, source_settings = _make_source(
        robot, measurement, n_samples, noise_std, test_fraction, experiment, data, dtype, pad)
    start = Deviations.zeros(layout_for(robot, measurement), dtype) if start is None else start.astype(dtype)
    real = None if not pad else (int(n_samples) - int(round(n_samples * test_fraction)),
                                 int(round(n_samples * test_fraction)))
    ex = _Execution.build(n_seeds, chunk_size, devices, batching, dtype, out_dir, progress,
                          None if real is None else real[1])
    prior = resolve_prior(prior)
    if loss not in LOSSES:
        raise ValueError(f"unknown loss {loss!r}; choose one of {list(LOSSES)}")
    settings = _settings(ex, base_key, noise_std, source_settings, robot, measurement, start, keep_errors, keep_history,
                         {"prior": None if prior is None else repr(prior), "loss": loss, "loss_scale": loss_scale})
    common = {k: settings[k] for k in _COMMON_SETTINGS}

    dtrial = _DataTrial(source, robot, measurement, start, ParameterSpace.for_robot(robot, measurement=measurement),
                        keep_errors)
    data_unit = _Unit("_data", _fingerprint(common | {"unit": "data"}), dtrial, None, None, [None])
    early = _plan_before_data(ex)
    if early:
        # on an accelerator: trial 0's data on the host CPU choose the free parameters (step 2)
        # first, so that the data unit compiles together with the method units (step 4)
        dlike, d0 = _trial_zero_on_host(dtrial, base_key, ex.dtype)
        with jax.default_device(jax.local_devices(backend="cpu")[0]):
            space, floor, sizes = _free_parameters(robot, measurement, d0, space, start, prior, noise_std, real)
    else:
        # 1. data pass: every trial's data (simulated or split once, reused by every method), the
        #    before-calibration and oracle metrics, the true deviations
        dlike, dout, dchunks = _data_pass(ex, data_unit, base_key)
        # 2. the free parameters: fixed for the whole sweep (static under jit), from trial 0's poses
        space, floor, sizes = _free_parameters(robot, measurement, dout, space, start, prior, noise_std, real)
    settings |= sizes
    common["space"] = settings["space"]
    # 3. the plan: compiled units (a method, or a group of grid points vmapped together)
    objective = _trial_objective(space, prior, loss, loss_scale, noise_std, dtype, measurement)
    mk = functools.partial(_MethodTrial, robot, measurement, start, keep_errors=keep_errors, keep_history=keep_history,
                           objective=objective)
    units = _plan_units(specs, mk, space, dtype, (dlike.split, dlike.k_method), common)
    settings["runs"] = _run_entries(units)
    if ex.store.root is not None and jax.process_index() == 0:
        (ex.store.root / "sweep.json").write_text(json.dumps(settings, indent=1, default=repr))
    _progress(progress, f"{len(settings['runs'])} run(s); p = {space.n_free} free parameters; "
              f"{settings['n_train']} train / {settings['n_test']} test samples per trial")
    # 4. compile every unit that has chunks to compute: traced one after the other, XLA-compiled in
    #    parallel threads (compilation dominates a cold sweep: ~5 s per method on an H100, ~10–20 s
    #    on 2 CPU cores; XLA releases the GIL while it compiles); on an accelerator the data unit too
    if early:
        abstract = _abstract_method_inputs(dlike, ex)
        runners = _compile_units([data_unit, *units], ex.new_runner,
                                 lambda u: (_data_inputs(base_key, ex.csize, 0),) if u is data_unit else abstract,
                                 lambda u: ex.pending(u.name), progress)
        _, dout, dchunks = _data_pass(ex, data_unit, base_key, runners.get("_data"))
    else:
        first = _method_inputs(dlike, dchunks, ex.csize, 0, 0, min(ex.csize, n_seeds))
        runners = _compile_units(units, ex.new_runner, lambda u: first, lambda u: ex.pending(u.name), progress)
    method_inputs = functools.partial(_method_inputs, dlike, dchunks, ex.csize)
    # 5. every method (or grid group), chunk by chunk
    runs = _run_units(ex, units, method_inputs, runners)
    return SweepResult(
        runs=runs,
        n_seeds=n_seeds,
        before=Metrics(*(np.asarray(v) for v in dout.before)),
        oracle=Metrics(*(np.asarray(v) for v in dout.oracle)),
        floor=floor,
        before_errors=np.asarray(dout.before_errors),  # trimmed to the real test rows (_compute_chunk)
        space=space,
        robot=robot,
        measurement=measurement,
        start=start,
        true_deviations=None if dout.truth is None else jax.tree.map(np.asarray, dout.truth),
        settings=settings,
    )


def _paddable(specs) -> bool:
    """Whether a simulated sweep runs padded to its shape bucket (:mod:`jaxcal._core._buckets`):
    buckets turned on explicitly (:func:`jaxcal.set_buckets`, ``JAXCAL_BUCKETS=on``; not by default),
    JAX's partitionable threefry (the padded simulation's real rows equal the unpadded one's only
    then), and every method paddable (:attr:`Method.paddable`)."""
    if not buckets_enabled(explicit=True) or not jax.config.jax_threefry_partitionable:
        return False
    for s in specs:
        m = s.method if s.method is not None else make_method(s.name, **(s.static_hyper | s.points[0]))
        if not m.paddable:
            return False
    return True


def _check_n_seeds(n_seeds) -> int:
    if isinstance(n_seeds, bool) or not isinstance(n_seeds, (int, np.integer)) or n_seeds < 1:
        raise ValueError(f"n_seeds must be a positive integer, got {n_seeds!r}")
    return int(n_seeds)


@dataclasses.dataclass(frozen=True)
class _Execution:
    """How a sweep's trials run: chunks of ``csize`` trials (``per_device`` on each of ``devs``,
    sharded over ``mesh`` when there are several), ``lax.map`` or ``vmap`` inside a chunk
    (``sequential``), and the chunk store of ``out_dir``."""

    n_seeds: int
    per_device: int
    csize: int
    devs: list
    mesh: Mesh | None
    sequential: bool
    dtype: Any
    store: _Store
    progress: bool
    #: real test rows of a padded simulation (per-sample error arrays are cut to them), or None
    n_test: int | None = None

    @classmethod
    def build(cls, n_seeds, chunk_size, devices, batching, dtype, out_dir, progress, n_test=None) -> _Execution:
        devs = _resolve_devices(devices)
        mesh = Mesh(np.asarray(devs), ("trials",)) if len(devs) > 1 else None
        if batching not in ("auto", "vmap", "map"):
            raise ValueError(f"batching must be 'auto', 'vmap' or 'map', got {batching!r}")
        if batching == "map" and mesh is not None:
            raise ValueError("batching='map' runs on one device; use 'vmap' (or 'auto') with several devices")
        sequential = batching == "map" or (batching == "auto" and mesh is None and devs[0].platform == "cpu")
        per_device, csize = _chunking(n_seeds, chunk_size, len(devs), devs[0].platform)
        return cls(n_seeds, per_device, csize, devs, mesh, sequential, dtype, _Store(out_dir), progress, n_test)

    @property
    def n_chunks(self) -> int:
        return math.ceil(self.n_seeds / self.csize)

    def bounds(self, c: int) -> tuple[int, int]:
        """Trials ``a … b−1`` of chunk ``c``."""
        return c * self.csize, min((c + 1) * self.csize, self.n_seeds)

    def pending(self, unit: str) -> bool:
        """Whether some chunk of ``unit`` is not in the store yet (it has to be computed)."""
        return any(not self.store.exists(unit, *self.bounds(c)) for c in range(self.n_chunks))

    def new_runner(self, trial, hyper) -> _Runner:
        return _Runner(trial, self.mesh, self.dtype, hyper is not None, self.sequential,
                       None if self.mesh is not None else self.devs[0])

    def run_unit(self, unit: str, trial, hyper, fp: str, n_points: int | None, inputs_of, runner=None):
        """Run (or load) every chunk of one compiled unit; returns the merged arrays, the time
        per trial ``[n]``, the compile time, the per-chunk arrays and the runner."""
        runner = self.new_runner(trial, hyper) if runner is None else runner
        chunks, walls = [], []
        for c in range(self.n_chunks):
            arrays, per = self._load_chunk(unit, c, fp, runner)
            if arrays is None:
                arrays, per = self._compute_chunk(unit, c, fp, runner, hyper, n_points, inputs_of)
            chunks.append(arrays)
            walls.append(per)
        axis = 1 if hyper is not None else 0
        merged = {k: np.concatenate([ch[k] for ch in chunks], axis=axis) for k in chunks[0]}
        times = np.concatenate([np.full(b - a, w) for (a, b), w in zip(map(self.bounds, range(self.n_chunks)), walls)])
        return merged, times, runner.compile_time_s, chunks, runner

    def _load_chunk(self, unit: str, c: int, fp: str, runner):
        """``(arrays, time per trial)`` of chunk ``c`` from the store, or ``(None, None)``."""
        a, b = self.bounds(c)
        loaded = self.store.load(unit, a, b, fp)
        if loaded is None:
            return None, None
        arrays, meta = loaded
        if c == 0:
            runner.compile_time_s = meta.get("compile_time_s", 0.0)
        _progress(self.progress, f"{_shown(unit)}: chunk {c + 1}/{self.n_chunks} (trials {a}–{b - 1}) loaded from "
                  f"{self.store.root}")
        return arrays, meta["time_per_trial_s"]

    def _compute_chunk(self, unit: str, c: int, fp: str, runner, hyper, n_points, inputs_of):
        """Compute chunk ``c`` (compiling the unit on first use) and save it to the store."""
        a, b = self.bounds(c)
        fresh = runner.compiled is None
        out, wall = runner(inputs_of(c, a, b), hyper)
        arrays = {k: (v[:, : b - a] if hyper is not None else v[: b - a]) for k, v in _flatten(out).items()}
        if self.n_test is not None:  # padded simulation: per-sample errors of the real test rows only
            arrays = {k: v[..., : self.n_test] if k.endswith(("test_errors", "before_errors")) else v
                      for k, v in arrays.items()}
        per = wall / (self.csize * (n_points or 1))
        self.store.save(unit, a, b, fp, arrays, {"time_per_trial_s": per, "compile_time_s": runner.compile_time_s})
        comp = "" if not fresh else (", compiled program reused" if runner.reused else
                                     f", compiled in {runner.compile_time_s:.1f} s")
        _progress(self.progress, f"{_shown(unit)}: chunk {c + 1}/{self.n_chunks} (trials {a}–{b - 1}) {wall:.2f} s "
                  f"({per * 1e3:.1f} ms/trial){comp}")
        return arrays, per


def _shown(unit: str) -> str:
    return "data" if unit == "_data" else unit


#: the settings every unit's fingerprint includes (a stored chunk is reused only if they match)
_COMMON_SETTINGS = ("format_version", "key_data", "dtype", "chunk_size", "source", "robot", "measurement", "start",
                    "keep_errors", "keep_history", "objective")


def _settings(ex: _Execution, base_key, noise_std, source_settings, robot, measurement, start, keep_errors,
              keep_history, objective: dict) -> dict:
    """The sweep's settings as written to ``sweep.json`` (before the free parameters are known)."""
    return {
        "format_version": _FORMAT_VERSION,
        "n_seeds": ex.n_seeds,
        "key_data": np.asarray(jax.random.key_data(base_key)).tolist(),
        "dtype": str(jnp.dtype(ex.dtype)),
        "chunk_size": ex.csize,
        "per_device_batch": ex.per_device,
        "n_devices": len(ex.devs),
        "batching": "map" if ex.sequential else "vmap",
        "noise_std": None if noise_std is None else float(noise_std),
        "source": source_settings,
        "robot": _robot_fingerprint(robot),
        "robot_dict": robot_to_dict(robot),
        "measurement": {"kind": measurement.kind, "repr": repr(jax.tree.map(np.asarray, measurement))},
        "measurement_dict": measurement_to_dict(measurement),
        "start": _array_digest(start.ravel()),
        "start_values": np.asarray(start.ravel(), np.float64).tolist(),
        "keep_errors": keep_errors,
        "keep_history": keep_history,
        "objective": objective,
    }


def _data_inputs(base_key, csize: int, a: int):
    """The data unit's inputs for the chunk starting at trial ``a``: ``csize`` trial keys."""
    return trial_keys(base_key, a, a + csize)


def _data_pass(ex: _Execution, data_unit: _Unit, base_key, runner=None):
    """Step 1: every trial's data and the before/oracle metrics. Returns the shapes of one
    trial's output (``dlike``), the merged output, and the per-chunk arrays. ``runner``: the data
    unit compiled already (step 4 on an accelerator)."""
    _progress(ex.progress, f"{ex.n_seeds} trial(s) in chunks of {ex.csize} = {len(ex.devs)} device(s) × "
              f"{ex.per_device} ({'lax.map' if ex.sequential else 'vmap'})")
    dtrial = data_unit.trial
    dmerged, _, _, dchunks, runner = ex.run_unit("_data", dtrial, None, data_unit.fingerprint, None,
                                                 lambda c, a, b: (_data_inputs(base_key, ex.csize, a),), runner)
    dlike = _one_trial_like(runner, lambda: eqx.filter_eval_shape(
        lambda t, k: t(k), dtrial, trial_keys(base_key, 0, 1)[0]), ex.dtype)
    return dlike, _unflatten(dlike, dmerged), dchunks


#: whether :func:`sweep` chooses the free parameters before its data pass (from trial 0 computed
#: on the host CPU) and compiles the data unit with the method units: ``None`` = on an accelerator
#: (a single device, the data pass not stored yet), where the data unit's compilation (~10 s on an
#: H100) would otherwise precede the methods'; ``True``/``False`` force it (tests)
_PLAN_BEFORE_DATA: bool | None = None


def _plan_before_data(ex: _Execution) -> bool:
    if ex.mesh is not None or not ex.pending("_data"):
        return False
    if _PLAN_BEFORE_DATA is not None:
        return bool(_PLAN_BEFORE_DATA)
    return ex.devs[0].platform != "cpu"


def _trial_zero_on_host(dtrial, base_key, dtype):
    """Trial 0's data-unit output (leading axis 1, NumPy) computed on the host CPU, and the shapes
    of one trial's output: the same simulation or split as trial 0 of the data pass."""
    cpu = jax.local_devices(backend="cpu")[0]
    runner = _Runner(dtrial, None, dtype, False, True, cpu)
    out, _ = runner((jax.device_put(trial_keys(base_key, 0, 1), cpu),), None)
    return _one_trial_like(runner, None, dtype), out


def _abstract_method_inputs(dlike, ex: _Execution):
    """A method unit's chunk inputs as shapes (``jax.ShapeDtypeStruct`` on the sweep's device):
    enough to lower and compile it before the data pass has run."""
    sharding = jax.sharding.SingleDeviceSharding(ex.devs[0])
    return jax.tree.map(lambda s: jax.ShapeDtypeStruct((ex.csize, *s.shape), s.dtype, sharding=sharding),
                        (dlike.split, dlike.k_method))


def _free_parameters(robot, measurement, dout, space, start, prior, noise_std, real=None):
    """Step 2: the free parameters chosen at trial 0's training poses, the statistical floor
    (or ``None``), and the settings entries they add. ``real``: ``(n_train, n_test)`` of a padded
    simulation (its real rows come first)."""
    n_train, n_test = (dout.split.q_train.shape[1], dout.split.q_test.shape[1]) if real is None else real
    n_train, n_test = int(n_train), int(n_test)
    # padded: the identifiability program pads to the sweep's own train rows (one program per bucket)
    n_to = None if real is None else int(dout.split.q_train.shape[1])
    q0 = to_device(dout.split.q_train[0][:n_train])  # not jnp.asarray: no copy program per shape
    space, report = resolve_space(robot, measurement, q0, space, start, prior=prior, n_to=n_to)
    if n_train * measurement.size <= space.n_free + 1:
        raise ValueError(
            f"too few samples: {n_train} training sample(s) give {n_train * measurement.size} residuals "
            f"for {space.n_free} free parameters"
        )
    # p of the floor: what the data identify (under a prior the free set also holds what only the prior sets)
    p_floor = space.n_free if report is None else report.rank
    floor = None if noise_std is None else statistical_floor(float(noise_std), p_floor, n_train, measurement.size)
    return space, floor, {"n_train": n_train, "n_test": n_test, "space": list(space.free_names),
                          "identifiability": None if report is None else report.to_dict()}


def _trial_objective(space, prior, loss, loss_scale, noise_std, dtype, measurement=None) -> Objective | None:
    """The objective every trial minimises (``None``: plain least squares), with fixed scales (a
    robust loss's default scale: its constant times a clean sample's RMS error,
    :func:`~jaxcal._fit._diagnostics.error_dims` of ``measurement``, as :func:`jaxcal.calibrate`)."""
    if prior is None and loss == "linear":
        return None
    sigma = prior.noise_std if prior is not None and prior.noise_std is not None else noise_std
    if sigma is None:
        raise ValueError("a prior or robust loss in a sweep of given data needs noise_std (mm) or Prior.noise_std")
    dims = 1 if measurement is None or loss == "linear" or loss_scale is not None else error_dims(measurement)
    scale = loss_scale if loss_scale is not None else (LOSSES[loss] * math.sqrt(dims) * sigma
                                                        if loss != "linear" else None)
    objective = Objective.build(space, prior, sigma, loss, scale, dtype)
    return None if objective.plain_least_squares else objective


def _plan_units(specs, mk, space, dtype, trial_args, common) -> list[_Unit]:
    """Step 3: the compiled units: one per plain method, one per group of grid points that can be
    vmapped together, one per point of a grid the method needs concrete values for."""
    units: list[_Unit] = []
    for s in specs:
        fp = _fingerprint(common | {"unit": s.name, "labels": s.labels, "hyper": to_jsonable(s.hyper_reports),
                                    "extra": s.fingerprint_extra})
        if s.points is None:
            units.append(_Unit(s.labels[0], fp, mk(s.method, space), None, s, [None]))
            continue
        trial, hyper = _grid_trial(s, mk, space, dtype, trial_args)
        if hyper is None:  # the method needs concrete values: one compilation per point
            for i, (lab, pt) in enumerate(zip(s.labels, s.points)):
                sub = dataclasses.replace(s, labels=[lab], hyper_reports=[s.hyper_reports[i]], points=[pt])
                units.append(_Unit(lab, _fingerprint([fp, lab]), mk(make_method(s.name, **(s.static_hyper | pt)), space),
                                   None, sub, [None]))
        else:
            unit = s.labels[0] if len(s.labels) == 1 else f"{s.name}-grid-{fp[:8]}"
            units.append(_Unit(unit, fp, trial, hyper, s, list(range(len(s.points)))))
    return units


def _run_entries(units) -> list[dict]:
    """``sweep.json``'s ``runs``: one entry per run (label, method, unit, grid point)."""
    return [
        {"label": lab, "method": u.spec.name, "unit": u.name, "grid_index": g,
         "hyperparameters": to_jsonable(u.spec.hyper_reports[i]),
         "grid_point": None if u.spec.points is None else to_jsonable(u.spec.points[i])}
        for u in units for i, (lab, g) in enumerate(zip(u.spec.labels, u.grid_index))
    ]


def _method_inputs(dlike, dchunks, csize: int, c: int, a: int, b: int):
    """A method unit's inputs for chunk ``c`` (trials ``a … b−1``): the data pass's splits and
    method keys, the last chunk padded to ``csize`` by repeating its last trial."""
    d = _unflatten(dlike, dchunks[c])
    pad = lambda x: np.concatenate([x, np.repeat(x[-1:], a + csize - b, axis=0)]) if b - a < csize else x  # noqa: E731
    return jax.tree.map(pad, (d.split, d.k_method))


def _run_units(ex: _Execution, units, method_inputs, runners) -> dict[str, SweepRun]:
    """Step 5: every unit chunk by chunk, split into its runs (one per grid point)."""
    runs: dict[str, SweepRun] = {}
    for u in units:
        merged, times, ct, _, _ = ex.run_unit(u.name, u.trial, u.hyper, u.fingerprint,
                                              None if u.hyper is None else len(u.grid_index), method_inputs,
                                              runners.get(u.name))
        for i, (lab, g) in enumerate(zip(u.spec.labels, u.grid_index)):
            part = merged if g is None else {k: v[g] for k, v in merged.items()}
            pt = None if u.spec.points is None else u.spec.points[i]
            runs[lab] = _make_run(lab, u.spec.name, u.spec.hyper_reports[i], pt, part, times, ct)
    return runs


def _compile_units(units, new_runner, inputs_of, needed, progress: bool) -> dict:
    """``{unit name: compiled _Runner}`` for the units ``needed(unit)`` says will run a chunk
    (``inputs_of(unit)``: its first chunk's inputs, or their shapes):
    lowered in this thread, then compiled by a thread pool (one thread per unit, at most the
    number of CPU cores; ``JAXCAL_COMPILE_THREADS`` overrides, 1 = one after the other)."""
    todo = [u for u in units if needed(u)]
    if not todo:
        return {}
    runners = {}
    for u in todo:
        r = new_runner(u.trial, u.hyper)
        r.lower(inputs_of(u), u.hyper)
        runners[u.name] = r
    workers = int(os.environ.get("JAXCAL_COMPILE_THREADS") or min(len(todo), os.cpu_count() or 1))
    t0 = time.perf_counter()
    if workers <= 1 or len(todo) == 1:
        for r in runners.values():
            r.compile()
    else:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(lambda r: r.compile(), runners.values()))
    _forget_traces()
    reused = sum(r.reused for r in runners.values())
    if len(todo) > 1:
        _progress(progress, f"{len(todo)} units compiled in {time.perf_counter() - t0:.1f} s ({workers} thread(s))"
                  + (f"; {reused} reused from earlier sweeps" if reused else ""))
    return runners


@dataclasses.dataclass
class _Unit:
    name: str
    fingerprint: str
    trial: eqx.Module
    hyper: dict | None
    spec: _RunSpec
    grid_index: list


def _make_run(label, name, report, point, merged, times, compile_time) -> SweepRun:
    out = _unflatten(_TRIAL_LIKE, merged)
    return SweepRun(
        label=label, method=name, hyperparameters=to_jsonable(report), grid_point=None if point is None else to_jsonable(point),
        test=Metrics(*(np.asarray(v) for v in out.test)), train=Metrics(*(np.asarray(v) for v in out.train)),
        n_iterations=np.asarray(out.n_iterations), iterations_to_converge=np.asarray(out.iterations_to_converge),
        status=np.asarray(out.status), time_per_trial_s=np.asarray(times), compile_time_s=float(compile_time),
        x=np.asarray(out.x), history=np.asarray(out.history), test_errors=np.asarray(out.test_errors),
        stage_ends=_stage_ends(merged),
    )


def _stage_ends(merged: dict) -> np.ndarray | None:
    """The ``stage_ends`` leaf of a flattened :class:`_TrialOut` (absent for single methods)."""
    for k, v in merged.items():
        if k.endswith("stage_ends"):
            return np.asarray(v)
    return None


def _grid_trial(s: _RunSpec, mk, space, dtype, trial_args):
    """The vmapped-grid trial and its ``[G]`` hyperparameter arrays, or ``(None, None)`` when the
    method cannot be built from traced hyperparameters (then each point compiles on its own)."""
    if not s.traced_keys:
        return None, None
    hyper = {k: jnp.asarray([float(pt[k]) for pt in s.points], dtype) for k in s.traced_keys}
    trial = mk(None, space, method_name=s.name, static_hyper=tuple(sorted(s.static_hyper.items())))
    try:
        with dtype_scope(dtype):
            eqx.filter_eval_shape(lambda t, a, h: t(*a, h), trial, trial_args, jax.tree.map(lambda a: a[0], hyper))
    except Exception:  # noqa: BLE001 - the method needs concrete values: compile per point instead
        return None, None
    return trial, hyper


def _make_source(robot, measurement, n_samples, noise_std, test_fraction, experiment, data, dtype, pad=False):
    """``(source, robot, measurement, settings)``; with ``pad`` a simulation runs padded to the shape
    bucket of ``n_samples`` (:class:`_Simulated`; ``settings["bucket"]`` says so)."""
    experiment = dict(experiment or {})
    if data is None:
        from ..robots import hsr_jr680

        robot = hsr_jr680() if robot is None else robot
        measurement = CableLength(default_anchor(robot)) if measurement is None else measurement
        truth = experiment.pop("true_deviations", None)
        if noise_std is None:
            raise ValueError("simulation needs noise_std (mm)")
        options = _simulation_options(robot, n_samples, noise_std, test_fraction, experiment)
        settings = {"kind": "simulated", **{k: to_jsonable(v) for k, v in options.items()},
                    "true_deviations": None if truth is None else _array_digest(truth.ravel()), "bucket": None}
        sizes = None
        if pad:
            n, n_test = options["n_samples"], int(round(options["n_samples"] * options["test_fraction"]))
            settings["bucket"] = bucket_size(n)
            sizes = jnp.asarray([n, n_test, _simulate_mod.permutation_rounds(n)], jnp.int32)
            options = options | {"n_samples": settings["bucket"]}
        return (_Simulated(robot, measurement, truth, tuple(sorted(options.items())), sizes), robot, measurement,
                settings)
    if experiment:
        raise ValueError("experiment options apply to simulation; they cannot be combined with data=")
    if isinstance(data, Experiment):
        robot = data.robot if robot is None else robot
        measurement = data.measurement if measurement is None else measurement
        _check_kind(data.train, measurement)
        src = _FixedSplit(data.train.q, data.train.y, data.test.q, data.test.y, data.true_deviations)
        settings = {"kind": "experiment", "digest": _array_digest(data.train.q, data.train.y, data.test.q, data.test.y)}
        return src, robot, measurement, settings
    if robot is None or measurement is None:
        raise ValueError("with given data, pass robot= and measurement= (the nominal models the data come from)")
    if isinstance(data, Dataset):
        _check_kind(data, measurement)
        n_test = int(round(data.n * test_fraction))
        if not (0 < n_test < data.n):
            raise ValueError(f"test_fraction={test_fraction} leaves no test or no training data for {data.n} samples")
        src = _RandomSplit(jnp.asarray(data.q, dtype), jnp.asarray(data.y, dtype), n_test)
        settings = {"kind": "dataset", "test_fraction": float(test_fraction), "digest": _array_digest(data.q, data.y)}
        return src, robot, measurement, settings
    if isinstance(data, (tuple, list)) and len(data) == 2 and all(isinstance(d, Dataset) for d in data):
        train, test = data
        _check_kind(train, measurement)
        _check_kind(test, measurement)
        src = _FixedSplit(jnp.asarray(train.q, dtype), jnp.asarray(train.y, dtype),
                          jnp.asarray(test.q, dtype), jnp.asarray(test.y, dtype), None)
        settings = {"kind": "split", "digest": _array_digest(train.q, train.y, test.q, test.y)}
        return src, robot, measurement, settings
    raise TypeError("data must be None (simulate), a Dataset, a (train, test) pair of Datasets or an Experiment")


def _simulation_options(robot, n_samples, noise_std, test_fraction, experiment) -> dict:
    """Every :func:`simulate_experiment` setting (defaults filled in, validated like it does)."""
    import inspect

    sig = inspect.signature(simulate_experiment)
    allowed = {n for n, p in sig.parameters.items() if p.kind is inspect.Parameter.KEYWORD_ONLY} - {
        "measurement", "true_deviations", "n_samples", "noise_std", "test_fraction"}
    unknown = set(experiment) - allowed
    if unknown:
        raise TypeError(f"unknown experiment option(s) {sorted(unknown)}; valid: {sorted(allowed)}")
    o = {n: sig.parameters[n].default for n in allowed} | dict(experiment)
    check_simulation_settings(n_samples, test_fraction, noise_std, o["oversample"])
    reach = robot.reach_mm()
    wr = o.pop("wire_range_mm")
    o["wire_range"] = (0.05 * reach, 1.2 * reach) if wr is None else tuple(float(v) for v in wr)
    o.update(n_samples=int(n_samples), noise_std=float(noise_std), test_fraction=float(test_fraction))
    missing = set(_CONFIG_FIELDS) - set(o)
    if missing:  # simulate_experiment changed: fail loudly rather than simulate something else
        raise RuntimeError(f"jaxcal._experiments._sweep is out of date with simulate_experiment (missing {sorted(missing)})")
    return o


def _check_kind(data: Dataset, measurement: MeasurementModel) -> None:
    if data.kind != measurement.kind:
        raise ValueError(f"data are {data.kind!r} measurements but the measurement model is {measurement.kind!r}")


def load_sweep(out_dir, *, partial: bool = False):
    """Rebuild a :class:`SweepResult` from a sweep's ``out_dir``.

    Args:
        out_dir: the directory passed to ``sweep(..., out_dir=)``.
        partial: load only the trials finished by every run of an interrupted sweep (default:
            raise if any chunk is missing; rerun ``sweep`` with the same settings to resume).
    """
    root = pathlib.Path(out_dir)
    meta_path = root / "sweep.json"
    if not meta_path.exists():
        raise FileNotFoundError(f"{root} holds no sweep (no sweep.json)")
    st = json.loads(meta_path.read_text())
    robot = robot_from_dict(st["robot_dict"])
    measurement = measurement_from_dict(st["measurement_dict"])
    n, csize = int(st["n_seeds"]), int(st["chunk_size"])
    store = _Store(root)

    def chunks(unit):
        out = []
        for a in range(0, n, csize):
            b = min(a + csize, n)
            p = store.path(unit, a, b)
            if not p.exists():
                break
            with np.load(p, allow_pickle=False) as f:
                meta = json.loads(str(f["__meta__"]))
                out.append(({k: np.array(f[k]) for k in f.files if k != "__meta__"}, meta, b - a))
        return out

    units = {"_data": chunks("_data")}
    for r in st["runs"]:
        units[r["unit"]] = chunks(r["unit"])
    done = min(sum(c[2] for c in ch) for ch in units.values())
    if done < n and not partial:
        raise ValueError(f"{root}: the sweep is incomplete ({done} of {n} trials in every run); rerun the sweep "
                         "with the same settings to resume it, or pass partial=True")
    if done == 0:
        raise ValueError(f"{root}: no finished trials")

    def merge(unit, axis):
        ch = units[unit]
        merged, times, k = {}, [], 0
        for arrays, meta, m in ch:
            if k >= done:
                break
            take = min(m, done - k)
            for key, v in arrays.items():
                merged.setdefault(key, []).append(v[:, :take] if axis == 1 else v[:take])
            times.append(np.full(take, meta["time_per_trial_s"]))
            k += take
        return ({key: np.concatenate(v, axis=axis) for key, v in merged.items()}, np.concatenate(times),
                float(ch[0][1].get("compile_time_s", 0.0)))

    dtype = np.float64 if st["dtype"] == "float64" else np.float32
    layout = layout_for(robot, measurement)
    has_truth = st["source"]["kind"] in ("simulated", "experiment")
    met = Metrics(0.0, 0.0, 0.0)
    dlike = _DataOut(met, met, Deviations.zeros(layout) if has_truth else None, 0.0,
                     _Split(0.0, 0.0, 0.0, 0.0, None), 0)
    dmerged, _, _ = merge("_data", 0)
    dout = _unflatten(dlike, dmerged)
    runs = {}
    for r in st["runs"]:
        axis = 1 if r["grid_index"] is not None else 0
        merged, times, ct = merge(r["unit"], axis)
        if axis == 1:
            merged = {k: v[r["grid_index"]] for k, v in merged.items()}
        out = _unflatten(_TRIAL_LIKE, merged)
        runs[r["label"]] = SweepRun(
            label=r["label"], method=r["method"], hyperparameters=r["hyperparameters"], grid_point=r["grid_point"],
            test=Metrics(*out.test), train=Metrics(*out.train), n_iterations=out.n_iterations,
            iterations_to_converge=out.iterations_to_converge, status=out.status, time_per_trial_s=times,
            compile_time_s=ct, x=out.x, history=out.history, test_errors=out.test_errors,
            stage_ends=_stage_ends(merged),
        )
    space = ParameterSpace.from_names(layout, st["space"])
    start = Deviations.unravel(jnp.asarray(np.asarray(st["start_values"], dtype)), layout)
    noise = st["noise_std"]
    floor = None if noise is None else statistical_floor(float(noise), space.n_free, int(st["n_train"]),
                                                         measurement.size)
    settings = dict(st)
    settings["n_seeds"] = done
    return SweepResult(
        runs=runs, n_seeds=done, before=Metrics(*dout.before), oracle=Metrics(*dout.oracle), floor=floor,
        before_errors=dout.before_errors, space=space, robot=robot, measurement=measurement, start=start,
        true_deviations=dout.truth, settings=settings,
    )
