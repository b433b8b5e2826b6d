"""A fleet in one program: :func:`calibrate_many` calibrates many units of one robot model.

A production line calibrates every unit of one model with the same sensor and the same
settings. :func:`calibrate_many` runs the per-unit host steps of :func:`jaxcal.calibrate`
(data checks, closed-form extras, identifiability and the choice of free parameters, the
re-estimated noise and robust scales, the diagnostics) for each unit — ``calibrate`` is written
as a generator of its solves (:func:`~jaxcal._calibration._calibrate._calibration_steps`) so both share one
code path — and the expensive part, the compiled solve (:class:`~jaxcal.Calibrator`), for all
units at once, as **one** compiled program over their data (``batching="vmap"``: vectorised
with ``jax.vmap``; ``"map"``, the default on a CPU: ``jax.lax.map``, one unit after the other
inside the program):

* every unit's samples are padded with zero-weight rows (:func:`~jaxcal._core._buckets.pad_rows`) to
  one row count, the shape bucket (:func:`~jaxcal._core._buckets.bucket_size`, smallest 256) of the
  largest unit, so units of different sizes share the program and padded rows change nothing;
* each unit keeps its own start (deviations, extras from the data), prior scale, robust scale,
  free-parameter set and status; units whose free sets differ (rare: the identifiability of
  their poses differs) run as separate programs, one per free set;
* each solve request of :func:`jaxcal.calibrate` becomes one batch: with a prior or a robust loss
  (``objective="measured"``) ``calibrate`` re-estimates the noise σ and the loss scale over a
  few rounds; the units still iterating run the next round together (the batch keeps the fleet's
  size, so one compiled program serves every round: vectorised, finished units' slots repeat
  another unit's inputs; mapped, they are skipped);
* a unit that cannot be calibrated — NaN/inf readings, too few samples — gets ``None`` in
  ``results`` and its error in its summary row; a solve that diverges or fails keeps its result
  with that status (flagged in the summary); the others go on either way.

Each unit's result equals :func:`jaxcal.calibrate` on that unit alone to round-off (the
padded, batched program sums in another order: tests/calibration/test_fleet.py; at most 1e-10 relative
over 100 units in the benchmark). On a CPU the units run in chunks (:func:`default_chunk_size`),
pipelined: a chunk's batched solves run in a worker thread while the host steps of the next
chunk run beside them. Speed (``benchmarks/results/fleet_speed_cpu.md``, 100 units × 1 000
samples, plain LM, the busy 2-core CPU): a warm ``calibrate_many`` was 1.1–1.3× faster than a
loop of warm ``calibrate`` calls. That is no real speed-up, and host batching cannot give one here:
each unit's own identifiability and solve programs alone take 57 % of the loop's CPU time. What
it gives there is one compilation per fleet (bucket and free set), one call with per-unit failures
contained, and the summary table; the vectorised program is what fills a GPU.
"""

from __future__ import annotations

import functools
import time
import warnings
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import equinox as eqx
import jax
import numpy as np

from .._core._buckets import BoundedCache, bucket_size, buckets_enabled, cache_size, release_memory, signature
from .._core._metrics import format_table, statistical_floor
from .._core._precision import cast_floating, dtype_scope
from .._core._xla import compile_lowered, jit, target_platform
from .._fit._result import CalibrationResult, Status
from ._calibrate import _calibration_steps
from ._calibrator import CalibrationOutput
from ._programs import _Launched, _pad_to_bucket

__all__ = ["calibrate_many", "FleetResult", "FleetSummary", "UnitRow"]


class UnitRow(NamedTuple):
    """One unit of a :class:`FleetSummary` (lengths in mm).

    Attributes:
        unit: the unit's name.
        n: training samples.
        status: ``"converged"``, ``"max_steps"``, ... (:class:`~jaxcal.Status` in lower case), or
            ``"error"`` when the unit could not be calibrated (see ``error``).
        rmse_mm, max_mm: train RMSE and largest per-sample error after the fit.
        noise_std_mm: residual σ̂ of the fit (its uncertainty estimate).
        floor_mm: the statistical floor of the train RMSE (:func:`jaxcal.statistical_floor`) for
            the sensor noise ``noise_std`` given to :func:`calibrate_many` and the fit's effective
            parameters; ``None`` without ``noise_std``.
        floor_ratio: ``rmse_mm / floor_mm`` (about 1 for a correct model; ``None`` without a floor).
        plausible: the unit's result passes its plausibility checks (:attr:`CalibrationResult.plausible`:
            its deviations and the result as a whole — σ̂, extras, not worse than the start —
            as for :func:`jaxcal.calibrate`); ``False`` for a unit without a result.
        out_of_tolerance: train RMSE above ``tolerance_mm``, the unit failed / did not converge
            (``status`` not ``converged`` or ``still_improving``), or its result is not
            ``plausible``; ``False`` without a tolerance unless failed or implausible.
        warnings: the number of diagnostic warnings of the fit (``result.warnings``).
        error: why the unit has no result (``None`` otherwise).
    """

    unit: str
    n: int
    status: str
    rmse_mm: float | None
    max_mm: float | None
    noise_std_mm: float | None
    floor_mm: float | None
    floor_ratio: float | None
    plausible: bool
    out_of_tolerance: bool
    warnings: int
    error: str | None


class FleetSummary(NamedTuple):
    """The fleet at a glance: one :class:`UnitRow` per unit, in input order."""

    rows: tuple
    tolerance_mm: float | None = None
    noise_std_mm: float | None = None

    HEADERS = ("unit", "n", "status", "RMSE/mm", "MAX/mm", "σ̂/mm", "floor/mm", "RMSE/floor", "plausible",
               "out of tolerance", "warnings", "error")

    @property
    def flagged(self) -> tuple:
        """Names of the units out of tolerance (or failed)."""
        return tuple(r.unit for r in self.rows if r.out_of_tolerance)

    def table(self, markdown: bool = False) -> str:
        """The rows as a plain-text (or Markdown) table, with a title line counting the flagged units."""
        tol = "" if self.tolerance_mm is None else f", tolerance {self.tolerance_mm:g} mm train RMSE"
        title = (f"{len(self.rows)} units, {len(self.flagged)} flagged (failed, not converged, implausible{tol}); "
                 + ("no floor (no sensor σ given: --noise-std MM on the command line, noise_std in Python)"
                  if self.noise_std_mm is None else
                    f"floor for sensor σ {self.noise_std_mm:g} mm"))
        rows = [(r.unit, r.n, r.status, r.rmse_mm, r.max_mm, r.noise_std_mm, r.floor_mm, r.floor_ratio,
                 "yes" if r.plausible else "NO", "YES" if r.out_of_tolerance else "no", r.warnings, r.error or "") for r in self.rows]
        return format_table(rows, self.HEADERS, markdown=markdown, title=title)

    def to_csv(self, path) -> None:
        """Write the rows as CSV (one line per unit; empty cells for ``None``)."""
        import csv

        with open(path, "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(UnitRow._fields)
            for r in self.rows:
                w.writerow(["" if v is None else v for v in r])

    def __str__(self) -> str:
        return self.table()


class FleetResult(NamedTuple):
    """What :func:`calibrate_many` returns: ``results, summary = calibrate_many(...)``.

    Attributes:
        results: one :class:`~jaxcal.CalibrationResult` per unit, in input order; ``None`` for a
            unit that could not be calibrated (its error is in ``summary``).
        summary: :class:`FleetSummary`.
        compile_time_s: seconds spent compiling the batched programs.
        solve_time_s: seconds the batched solves ran (all units, all rounds).
    """

    results: list
    summary: FleetSummary
    compile_time_s: float = 0.0
    solve_time_s: float = 0.0


def calibrate_many(robot, measurement, datasets, method="lm", *, names=None, tolerance_mm: float | None = None,
                   noise_std: float | None = None, batching: str = "auto", chunk_size: int | None = None,
                   **kwargs) -> FleetResult:
    """Calibrate many units of one robot model, their solves as one compiled program.

    Args:
        robot: the nominal robot model every unit is an instance of.
        measurement: the measurement model (one sensor set-up for the fleet; per-unit sensor
            unknowns such as the anchor are estimated per unit with ``extras=``).
        datasets: ``[data_1, ..., data_k]``, each a :class:`~jaxcal.Dataset` or a ``(q [n_i, dof]
            rad, y)`` pair; the units may have different sample counts ``n_i``.
        method: as in :func:`jaxcal.calibrate`; a method that cannot pad its rows (mini-batch
            gradient descent, the RBF network) is batched only over units of equal size.
        names: one name per unit for the summary (default ``"1"``, ``"2"``, ...).
        tolerance_mm: flag units whose train RMSE exceeds this (mm) in the summary.
        noise_std: the sensor's noise σ per reading (mm), for the statistical floor column and the
            units' plausibility checks (σ̂ against it, as a file's ``# noise_std_mm:`` line does for
            :func:`jaxcal.calibrate`).
        batching: how the one compiled program runs the units (as :func:`jaxcal.sweep`'s
            ``batching``): ``"vmap"`` (all at once, vectorised: what fills a GPU; a vmapped
            Levenberg–Marquardt batch iterates until its slowest unit converges), ``"map"``
            (``jax.lax.map``: one unit after the other inside the program, each as long as it
            needs), or ``"auto"`` (default): ``"map"`` on a CPU, else ``"vmap"``.
        chunk_size: units per batched program (default :func:`default_chunk_size`: a quarter of
            the fleet on a CPU, at least 16; the whole fleet with ``"vmap"``). The chunks are
            pipelined: while one chunk's compiled solves run (in a worker thread), the host steps
            of the next chunk — data checks, identifiability, diagnostics — run beside them, so
            a 2-core CPU computes both at once. Every chunk (and every round) runs the same
            compiled program; results do not depend on it.
        **kwargs: every other keyword of :func:`jaxcal.calibrate` (``key``, ``extras``,
            ``prior``, ``loss``, ``objective``, ``free``, ``fix``, ``checks``, the method's
            hyperparameters, ...), the same for every unit. ``throw`` is not accepted: a unit's
            failure is reported in its row, never raised.

    Returns:
        :class:`FleetResult` ``(results, summary, compile_time_s, solve_time_s)``: ``results[i]``
        equals ``calibrate(robot, measurement, datasets[i], method, **kwargs)`` to round-off
        (its ``wall_time_s`` and ``compile_time_s`` are the unit's share of the batched
        program's); warnings of a unit are issued with its name in front.
    """
    if batching not in ("auto", "vmap", "map"):
        raise ValueError(f"batching must be 'auto', 'vmap' or 'map', got {batching!r}")
    sequential = batching == "map" or (batching == "auto" and jax.devices()[0].platform == "cpu")
    if "throw" in kwargs:
        raise TypeError("calibrate_many has no throw=: a unit that fails is reported in the summary, not raised")
    datasets = list(datasets)
    k = len(datasets)
    if k == 0:
        raise ValueError("calibrate_many needs at least one dataset")
    names = [str(i + 1) for i in range(k)] if names is None else [str(n) for n in names]
    if len(names) != k:
        raise ValueError(f"{len(names)} names for {k} datasets")
    size = default_chunk_size(k, sequential) if chunk_size is None else int(chunk_size)
    if size < 1:
        raise ValueError(f"chunk_size must be at least 1, got {chunk_size!r}")
    size = min(size, k)
    # every unit's result is checked as a whole as calibrate() checks it (CalibrationResult.plausible), with
    # noise_std as the sensor's noise σ̂ is compared with; an implausible unit is flagged
    steps = [_calibration_steps(robot, measurement, d, method, sensor_noise_std=noise_std, **kwargs)
             for d in datasets]
    pending, results, errors = {}, [None] * k, [None] * k

    def advance(i, launched, stacklevel=3):  # warnings point at calibrate_many's caller
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                pending[i] = steps[i].send(launched)
            except StopIteration as done:
                results[i] = done.value
                pending.pop(i, None)
            except Exception as e:  # noqa: BLE001 - a unit's failure is its own (reported in its row)
                errors[i] = f"{type(e).__name__}: {e}"
                pending.pop(i, None)
        for w in caught:
            warnings.warn(f"unit {names[i]}: {w.message}", w.category, stacklevel=stacklevel)

    chunks = [range(s, min(s + size, k)) for s in range(0, k, size)]
    for i in chunks[0]:
        advance(i, None)
    if not pending and all(e is not None for e in errors[:size]) and len(set(errors[:size])) == 1:
        for c in chunks[1:]:  # the first chunk failed alike before any solve: does every unit?
            for i in c:
                advance(i, None)
        if not pending and len(set(errors)) == 1:
            # every unit failed alike before any solve: a usage error (an unknown method, extra, ...)
            raise ValueError(f"every unit failed: {errors[0]}")
        chunks = [range(0, k)]  # all advanced
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxcal-fleet") as worker:
        pipe = _Pipeline(worker, size, sequential, advance, pending, max(map(_rows_of, datasets)))
        for c, chunk in enumerate(chunks):
            if c > 0:
                for i in chunk:  # host steps beside the previous chunk's solves
                    advance(i, None)
            current = pipe.start([i for i in chunk if i in pending])
            pipe.collect(before=current)  # the earlier chunks' results (and next rounds) while this one solves
        pipe.collect()
    rows = tuple(_row(names[i], datasets[i], results[i], errors[i], tolerance_mm, noise_std) for i in range(k))
    return FleetResult(results, FleetSummary(rows, tolerance_mm, noise_std), pipe.compile_s, pipe.solve_s)


def default_chunk_size(k: int, sequential: bool) -> int:
    """Units per batched program of :func:`calibrate_many` for ``k`` units: with ``sequential``
    (``batching="map"``, a CPU) a quarter of the fleet, at least 16 (four chunks pipeline the
    host steps of one beside the solves of another; smaller chunks add launches); vectorised
    (``"vmap"``, what fills a GPU) the whole fleet."""
    return k if not sequential else min(k, max(16, -(-k // 4)))


class _Pipeline:
    """The batches in flight of :func:`calibrate_many`: :meth:`start` groups units' pending
    requests into :class:`_Batch` es and launches them in ``worker`` (a thread: the compiled
    solves run beside the host steps of other units); :meth:`collect` waits for the oldest
    batches and advances their units, launching the next round of those still iterating."""

    def __init__(self, worker, size, sequential, advance, pending, rows: int = 0):
        self.worker, self.size, self.sequential, self.advance, self.pending = worker, size, sequential, advance, pending
        self.rows = rows  # the fleet's largest row count: every chunk pads to its bucket
        self.flight: deque = deque()
        self.compile_s = self.solve_s = 0.0

    def start(self, units) -> list:
        """Launch the pending requests of ``units``; the batches launched."""
        if not units:
            return []
        batches = _batches({i: self.pending[i] for i in units}, self.size, self.sequential, self.rows)
        for batch in batches:
            batch.launch(self.worker)
            self.compile_s += batch.compile_s
            self.flight.append(batch)
        return batches

    def collect(self, before=()) -> None:
        """Advance the units of the batches in flight, oldest first (the worker runs them in that
        order), up to the first of ``before`` (default: all)."""
        while self.flight and not any(self.flight[0] is b for b in before):
            batch = self.flight.popleft()
            for j, i in enumerate(batch.units):
                self.advance(i, _Share(batch, j), stacklevel=4)  # advance ← collect ← calibrate_many
            self.solve_s += batch.run_s or 0.0
            self.start([i for i in batch.units if i in self.pending])


def _n_rows(q) -> int:
    return int(q.shape[0])


def _rows_of(data) -> int:
    """The row count of a unit's data (a :class:`Dataset` or a ``(q, y)`` pair); 0 where it has none
    (the unit fails with its own error)."""
    try:
        return int(np.shape(data.q if hasattr(data, "q") else data[0])[0])
    except (TypeError, IndexError, ValueError):
        return 0


class _Batch:
    """The pending solves of several units with one static part and one set of shapes, run as one
    compiled program (vmapped or mapped). Leaves every unit shares (the same object: the robot, the
    key) are passed once, unbatched; the others are stacked along a new leading axis, padded to
    ``size`` units by repeating the first (one program for every chunk and round, however many
    units are still iterating)."""

    def __init__(self, units, static, treedef, leaves_per_unit, own, size, sequential):
        self.units, self.static, self.treedef, self.size, self.sequential = units, static, treedef, size, sequential
        self.leaves_per_unit, self.own = leaves_per_unit, own
        self.future = self.host = None
        self.compile_s = self.run_s = 0.0

    def launch(self, worker=None):
        """Compile (cached) and start the batch: in ``worker`` (a thread pool; the host goes on
        meanwhile), or here and now without one."""
        first = self.leaves_per_unit[0]
        axes, leaves = [], []
        for j, leaf in enumerate(first):
            column = [u[j] for u in self.leaves_per_unit]
            if not self.own[j] and all(c is leaf for c in column):
                axes.append(None)
                leaves.append(leaf)
                continue
            column += [leaf] * (self.size - len(column))  # slots of finished units
            axes.append(0)
            if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
                leaves.append(jax.numpy.stack(column))
            else:
                leaves.append(jax.device_put(np.stack([np.asarray(c) for c in column])))
        axes = tuple(axes)
        active = jax.device_put(np.arange(self.size) < len(self.units))
        t0 = time.perf_counter()
        ck = (self.static, self.treedef, axes, self.sequential, tuple((tuple(x.shape), str(x.dtype)) for x in leaves),
              target_platform(), jax.config.jax_enable_x64)
        compiled = _COMPILED_MANY.get(ck)
        if compiled is None:
            compiled = compile_lowered(_run_batched.lower(self.static, self.treedef, axes, self.sequential,
                                                          tuple(leaves), active))
            _COMPILED_MANY.put(ck, compiled)
            _run_batched.clear_cache()
            release_memory()
        t1 = time.perf_counter()
        self.compile_s = t1 - t0
        self.leaves_per_unit = None  # the stacked copies are all the solve needs
        self.t_started = t1

        def run():
            # on the host as NumPy: what calibrate's host steps read (status, x, history, metrics,
            # the Jacobian products); timed here, where the program runs
            t = time.perf_counter()
            out = jax.block_until_ready(compiled(tuple(leaves), active))
            host = jax.tree_util.tree_map(
                lambda a: a if jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key) else np.asarray(a), out)
            return host, time.perf_counter() - t

        if worker is None:
            self.host, self.run_s = run()
        else:
            self.future = worker.submit(run)

    def result(self, j: int) -> CalibrationOutput:
        """Unit ``j``'s output (blocks on the batch the first time)."""
        if self.host is None:
            self.host, self.run_s = self.future.result()
        # only the deviations, the next round's start and the result's, go back to the device
        # (a device_put costs ~0.2 ms per leaf on the 2-core CPU)
        out = jax.tree_util.tree_map(lambda a: a[j], self.host)
        return out._replace(deviations=jax.device_put(out.deviations))


class _Share(_Launched):
    """Unit ``j``'s share of a launched :class:`_Batch` (what :func:`_calibration_steps` is sent)."""

    def __init__(self, batch: _Batch, j: int):
        n = len(batch.units)
        super().__init__(None, batch.compile_s / n, batch.t_started)
        self.batch, self.j = batch, j

    def wait(self):
        out = self.batch.result(self.j)
        return out, self.batch.run_s / len(self.batch.units)


def _batches(pending: dict, size: int, sequential: bool, rows: int = 0) -> list[_Batch]:
    """The pending requests ``{unit: (cal, q, y, key)}`` grouped into :class:`_Batch` es of at most
    ``size`` units: padded to one row count (the bucket of the largest unit, or of ``rows``, the
    fleet's largest, so that every chunk runs one program whatever buckets the process used
    before; methods that cannot pad keep theirs) on the host, then grouped by static part and
    leaf shapes."""
    # the process's bucket rule (a later round of fewer units reuses the bucket of the first);
    # with buckets off still one padded size per batch (the fine grid)
    n_rows = max(rows, *(_n_rows(r[1]) for r in pending.values()))
    width = max(r[0].measurement.size for r in pending.values())
    n_to = bucket_size(n_rows, width=width) if buckets_enabled() else bucket_size(n_rows, minimum=256, width=width)
    groups: dict = {}
    for i, (cal, q, y, key) in pending.items():
        with dtype_scope(q.dtype):
            cal, q, y, w = _pad_to_bucket(cal, q, y, n_to if cal.method.paddable else None, host=True)
            dyn, static = eqx.partition(cal, eqx.is_array)
            dyn = cast_floating(dyn, q.dtype)
        paths, treedef = jax.tree_util.tree_flatten_with_path((dyn, q, y, key, w))
        leaves = [leaf for _, leaf in paths]
        gk = (static, treedef, signature(leaves))
        if gk not in groups:
            groups[gk] = ([], static, treedef, [], tuple(_own(path) for path, _ in paths))
        groups[gk][0].append(i)
        groups[gk][3].append(leaves)
    out = []
    for units, static, treedef, leaves, own in groups.values():
        for s in range(0, len(units), size):
            out.append(_Batch(units[s:s + size], static, treedef, leaves[s:s + size], own, size, sequential))
    return out


#: the :class:`~jaxcal.Calibrator` fields that belong to one unit (always batched, even where two
#: units hold the same object, so that a batch of one unit runs the same program)
_UNIT_FIELDS = ("start", "objective", "start_jacobian", "free")


def _own(path) -> bool:
    """Whether the leaf at ``path`` of ``(calibrator, q, y, key, weight)`` is the unit's own (data,
    start, objective), not the fleet's (robot, measurement, method, key) when all units share it."""
    top = path[0].idx
    if top in (1, 2, 4):  # q, y, weight
        return True
    return top == 0 and len(path) > 1 and getattr(path[1], "name", None) in _UNIT_FIELDS


@functools.partial(jit, static_argnums=(0, 1, 2, 3))
def _run_batched(static, treedef, axes, sequential: bool, leaves, active) -> CalibrationOutput:
    """The :class:`~jaxcal.Calibrator` over the units of a :class:`_Batch`: ``jax.vmap``-ed, or
    with ``sequential`` ``jax.lax.map``-ed (one unit after the other inside the program, each
    solve's loop as long as that unit needs; the slots of finished units (``active`` False) are
    skipped by ``lax.cond``)."""

    def one(leaves):
        dyn, q, y, key, w = jax.tree_util.tree_unflatten(treedef, leaves)
        return eqx.combine(dyn, static)(q, y, key, w)

    if not sequential:
        return jax.vmap(one, in_axes=(list(axes),))(list(leaves))
    mapped = [j for j, a in enumerate(axes) if a == 0]

    def body(xs):
        unit_leaves, on = xs
        full = list(leaves)
        for j, x in zip(mapped, unit_leaves):
            full[j] = x
        shape = jax.eval_shape(one, full)
        return jax.lax.cond(on, one, lambda _: jax.tree_util.tree_map(
            lambda s: jax.numpy.zeros(s.shape, s.dtype), shape), full)

    return jax.lax.map(body, ([leaves[j] for j in mapped], active))


#: compiled fleet programs (a least-recently-used cache; ``$JAXCAL_CALIBRATE_MANY_CACHE``)
_COMPILED_MANY = BoundedCache(cache_size("calibrate_many", 8))


def _row(name, data, res: CalibrationResult | None, error, tolerance_mm, noise_std) -> UnitRow:
    n = _data_rows(data)
    if res is None:
        return UnitRow(name, n, "error", None, None, None, None, None, False, True, 0, error)
    m = res.train_metrics
    unc = res.uncertainty
    sigma = None if unc is None else float(unc.noise_std)
    floor = ratio = None
    if noise_std is not None and unc is not None:
        p = float(unc.effective_parameters)
        try:
            floor = statistical_floor(noise_std, p, n, res.measurement.size).train
            ratio = m.rmse / floor
        except ValueError:
            floor = None
    bad = res.status not in (Status.CONVERGED, Status.STILL_IMPROVING) or not res.plausible
    out = bad or (tolerance_mm is not None and not (m.rmse <= tolerance_mm))
    return UnitRow(name, n, res.status.name.lower(), float(m.rmse), float(m.max), sigma, floor, ratio,
                   bool(res.plausible), bool(out), len(res.warnings), None)


def _data_rows(data) -> int:
    try:
        q = data.q if hasattr(data, "q") else data[0]
        return int(np.shape(q)[0])
    except (TypeError, IndexError, KeyError):
        return 0

