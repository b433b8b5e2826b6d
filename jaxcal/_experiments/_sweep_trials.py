"""A sweep's trial: pure functions of one ``jax.random`` key (:mod:`jaxcal._experiments._sweep`).

Trial ``i``'s key ``fold_in(key, i)`` (:func:`trial_keys`) is split into a data key and a method
key. The data key gives the trial's data through a *source* (:func:`_make_source`): the paper's
experiment simulated from it (:class:`_Simulated`), given data split at random
(:class:`_RandomSplit`) or a fixed split (:class:`_FixedSplit`). :class:`_DataTrial` turns it into
the split and the before-calibration and oracle metrics (once per sweep); :class:`_MethodTrial`
calibrates the training split with a method and evaluates on the test split.
"""

from __future__ import annotations

import hashlib
import warnings
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._calibration._calibrate import Calibrator
from .._core._buckets import bucket_size
from .._core._json import to_jsonable
from .._core._metrics import Metrics, compute_metrics
from .._core._params import Deviations, ParameterSpace
from .._datasets._dataset import Dataset
from .._fit._objective import Objective
from .._fit._problem import Problem
from .._models._abstract import AbstractRobot
from .._sensors._measurement import CableLength, MeasurementModel
from .._simulation import _simulate as _simulate_mod
from .._simulation._simulate import (
    Experiment,
    check_simulation_settings,
    default_anchor,
    simulate_experiment,
)
from ..methods import Method, make_method
from ..methods._stages import StageInfo

__all__ = ["trial_keys"]


#: fields of the simulation's static configuration, in order (``jaxcal._simulation._simulate._Config``).
_CONFIG_FIELDS = ("n_samples", "test_fraction", "angle_std_deg", "length_std_mm", "anchor_std_mm", "tool_std_mm",
                  "cable_offset_std_mm", "coverage", "wire_range", "min_height_mm", "oversample")


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

    robot: AbstractRobot
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
    robot: AbstractRobot
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

    robot: AbstractRobot
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


def _array_digest(*arrays) -> str:
    h = hashlib.sha1()
    for a in arrays:
        a = np.ascontiguousarray(np.asarray(a, np.float64))
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


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
            settings["bucket"] = bucket_size(n, width=measurement.size)
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
        raise ValueError("with given data, give the robot and measurement arguments (the nominal models the data come from)")
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
        raise RuntimeError(f"jaxcal._experiments._sweep_trials is out of date with simulate_experiment (missing {sorted(missing)})")
    return o


def _check_kind(data: Dataset, measurement: MeasurementModel) -> None:
    if data.kind != measurement.kind:
        raise ValueError(f"data are {data.kind!r} measurements but the measurement model is {measurement.kind!r}")
