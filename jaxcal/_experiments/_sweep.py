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

Entry point: :func:`sweep` → :class:`SweepResult`. This module runs the steps in order; the parts
live beside it: the trial and its data sources in :mod:`._sweep_trials`, the methods and grids as
compiled units and the free-parameter choice in :mod:`._sweep_units`, chunking, batching,
compiling and the chunk store in :mod:`._sweep_chunks`, and the results with :func:`load_sweep` in
:mod:`._sweep_results`.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._calibration._io import measurement_to_dict, robot_to_dict
from .._core._cache import ensure_compilation_cache
from .._core._metrics import Metrics
from .._core._params import Deviations, ParameterSpace, layout_for
from .._core._precision import warn_if_float32
from .._fit._objective import LOSSES, resolve_prior
from .._models._abstract import AbstractRobot
from .._sensors._measurement import MeasurementModel
from .._simulation._simulate import DEFAULT_NOISE_STD
from ._sweep_chunks import (
    DEFAULT_CHUNK_PER_ACCELERATOR,
    DEFAULT_CHUNK_PER_DEVICE,
    _compile_units,
    _Execution,
    _one_trial_like,
    _progress,
    _Runner,
    _unflatten,
)
from ._sweep_results import PAPER_METHODS, SweepResult, SweepRun, _make_run, load_sweep
from ._sweep_trials import _array_digest, _as_key, _DataTrial, _make_source, _MethodTrial, trial_keys
from ._sweep_units import (
    _fingerprint,
    _free_parameters,
    _method_specs,
    _paddable,
    _plan_units,
    _run_entries,
    _trial_objective,
    _Unit,
)

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

_FORMAT_VERSION = 1


def sweep(
    methods,
    n_seeds: int = 20,
    *,
    seed: int = 0,
    key=None,
    robot: AbstractRobot | None = None,
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
    if prior is not None and prior.scale_by == "evidence":
        raise ValueError("a sweep runs one fixed prior in every trial; the evidence chooses a prior's scale per fit "
                         "in jaxcal.calibrate (prior 'evidence' there): give the sweep a fixed prior ('default' or "
                         "a jaxcal.Prior)")
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


def _check_n_seeds(n_seeds) -> int:
    if isinstance(n_seeds, bool) or not isinstance(n_seeds, (int, np.integer)) or n_seeds < 1:
        raise ValueError(f"n_seeds must be a positive integer, got {n_seeds!r}")
    return int(n_seeds)


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
        "robot": robot.fingerprint(),
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
