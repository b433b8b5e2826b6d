"""The compiled solves of :func:`~jaxcal._calibration._calibrate.calibrate`: the program space
of a masked solve and its run-time masks, the data padded to their shape bucket, the cache of
compiled calibrators (in memory, and on disk through :mod:`jaxcal._core._exported`), compiling
the first solve ahead on a background thread, and launching a solve without waiting for it."""

from __future__ import annotations

import dataclasses
import time

import equinox as eqx
import jax
import numpy as np

from .._core import _exported
from .._core._buckets import BoundedCache, cache_size, pad_model_rows, release_memory, signature
from .._core._cache import switched_off
from .._core._metrics import Metrics
from .._core._params import ParameterSpace
from .._core._precision import cast_floating, dtype_scope, to_device
from .._core._xla import ahead_enabled, compile_ahead, compile_lowered, take_ahead, target_platform
from .._fit._problem import entry_count
from ._calibrator import CalibrationOutput, Calibrator, _run_calibrator

__all__ = ["_Launched", "_launch", "_compile_ahead", "_pad_to_bucket"]


def _program_space(robot, measurement, cand: ParameterSpace, space: ParameterSpace) -> ParameterSpace:
    """The parameter space of the compiled solve of a :attr:`~jaxcal.methods.Method.maskable`
    method: the robot's default candidates (every DH deviation, β at Hayati joints), the
    candidates ``cand`` (requested extras, ``free=``) and the free ``space``, in layout order. The
    free set is a run-time mask inside it (:class:`Calibrator` ``free=``), so every selection of
    one set-up — identifiability, its re-selection at the solution, ``free=``/``fix=``, the
    robust/MAP rounds, an evaluation registering the extras with the robot fixed — runs the same
    compiled program."""
    keep = set(ParameterSpace.for_robot(robot, measurement=measurement).free_names)
    keep |= set(cand.free_names) | set(space.free_names)
    return ParameterSpace.from_names(space.layout, [n for n in space.layout.names if n in keep])


def _solve_space(prog: ParameterSpace | None, space: ParameterSpace, dtype):
    """``(program space, columns, mask)`` of a solve of the free ``space``: with a program space
    ``prog`` (:func:`_program_space`; a masked solve), ``prog``, the free parameters' columns in it
    and the run-time 0/1 mask; else (``prog=None``) ``(space, None, None)``."""
    if prog is None:
        return space, None, None
    key = (prog.free_names, space.free_names, np.dtype(dtype))
    got = _MASKS.get(key)
    if got is None:
        free = set(space.free_names)
        columns = np.asarray([i for i, n in enumerate(prog.free_names) if n in free])
        mask = np.zeros(prog.n_free)
        mask[columns] = 1.0
        got = (columns, to_device(mask, dtype))
        _MASKS.put(key, got)
    return (prog, *got)


#: the masks of the last free sets :func:`_solve_space` met (device arrays; a warm call reuses its own)
_MASKS = BoundedCache(8)


def _program_columns(J, cand: ParameterSpace, prog: ParameterSpace):
    """A Jacobian ``J`` ``[N, p]`` of the candidates ``cand`` as the program space ``prog``'s
    ``[N, P]`` (zero columns for the parameters outside ``cand``: a mask holds them). Where the
    two are the same (the default candidates), ``J`` itself."""
    if prog.free_names == cand.free_names:
        return J
    index = {n: i for i, n in enumerate(prog.free_names)}
    out = np.zeros((J.shape[0], prog.n_free), J.dtype)
    out[:, [index[n] for n in cand.free_names]] = np.asarray(J)
    return jax.device_put(out)


def _mask_output(out: CalibrationOutput, columns: np.ndarray) -> CalibrationOutput:
    """A masked solve's output on its free parameters alone (``columns`` of the program space):
    ``x`` and the Jacobian products of ``gram`` restricted to them, as an unmasked solve gives."""
    x = np.asarray(out.x)[columns]
    gram = out.gram
    if gram is not None:
        d, A, G, rss, r, e, comp = gram
        sub = np.ix_(columns, columns)
        comp = None if comp is None else np.asarray(comp)[:, columns][:, :, columns]
        gram = (np.asarray(d)[columns], np.asarray(A)[sub], np.asarray(G)[sub], rss, r, e, comp)
    return out._replace(x=x, gram=gram)


def _masked(meth) -> bool:
    """Whether :func:`calibrate` runs ``meth`` with the free set as a run-time mask
    (``$JAXCAL_FREE_MASK=off`` turns it off: one program per free set, as before)."""
    return meth.maskable and not switched_off("JAXCAL_FREE_MASK")



#: compiled calibrators by (static part, dynamic shapes/dtypes): a warm ``calibrate`` call skips
#: tracing and lowering (``jit.lower`` re-traces on every call; ~10–30 ms on 2 CPU cores). A
#: least-recently-used cache of at most 16 programs (``$JAXCAL_CALIBRATE_CACHE``): with shape
#: buckets one model and method need one program per bucket, and memory
#: stays flat however many sample counts a session calibrates.
_COMPILED = BoundedCache(cache_size("calibrate", 16))


def _pad_to_bucket(cal: Calibrator, q, y, n_to: int | None = None, host: bool = False):
    """``(cal, q, y, weight)``: the data padded with zero-weight rows to their bucket size
    (:func:`~jaxcal._core._buckets.bucket_size`) when the method allows it (:attr:`Method.paddable`;
    weights all 1 at a bucket size exactly), the measurement model's per-row arrays
    (:meth:`MeasurementModel.pad_rows`) and the start Jacobian (if any) padded to match;
    unchanged with ``weight=None`` otherwise. ``n_to``: pad to this row count instead (a paddable
    method; :func:`jaxcal.calibrate_many` pads every unit to one size). ``host``: ``q``, ``y``,
    ``weight`` and a padded start Jacobian as NumPy arrays (a caller that stacks units on the
    host first)."""
    n, measurement = int(q.shape[0]), cal.measurement
    w = None
    new = {}  # fields replaced (one dataclasses.replace: ~3x cheaper than eqx.tree_at per field)
    if cal.method.paddable:
        padded, q, y, w = pad_model_rows(measurement, q, y, n_to, host=host)
        if padded is not measurement:
            new["measurement"] = padded
    n_to = int(q.shape[0])
    J = cal.start_jacobian
    rows, rows_to = entry_count(measurement, n), entry_count(new.get("measurement", measurement), n_to)
    if J is None and cal.start_jacobian_given is not None:  # zeros stand in (Calibrator.start_jacobian_given)
        new["start_jacobian"] = _zero_jacobian((rows_to, cal.space.n_free), q.dtype, host)
    elif J is not None and J.shape[0] != rows_to:
        # computed on the real rows, or on another padding (the identifiability program pads
        # whatever the method): the real rows on the host (padding rows' entries come last), zero
        # rows for this padding
        Jn = np.asarray(J)[:rows]
        if rows_to != rows:
            Jn = np.concatenate([Jn, np.zeros((rows_to - rows, Jn.shape[1]), Jn.dtype)])
        new["start_jacobian"] = Jn if host else jax.device_put(Jn)
    if new:
        cal = dataclasses.replace(cal, **new)
    return cal, q, y, w


#: the last zero start Jacobians :func:`_pad_to_bucket` made, by (shape, dtype, host)
_ZERO_JACOBIAN = BoundedCache(4)


def _zero_jacobian(shape: tuple, dtype, host: bool):
    """Zeros ``shape`` standing in for a start Jacobian not given (NumPy with ``host``, else on
    the device); the last few are kept (every masked solve of one set-up has the same shape)."""
    key = (shape, np.dtype(dtype), host)
    z = _ZERO_JACOBIAN.get(key)
    if z is None:
        z = np.zeros(shape, dtype)
        z = z if host else jax.device_put(z)
        _ZERO_JACOBIAN.put(key, z)
    return z


def _launch(cal: Calibrator, q, y, key):
    """Compile (cached) and start ``cal`` without waiting for it (JAX dispatches asynchronously):
    ``(output, compile_s, t_started)``; the caller may do host work, then blocks on ``output``.
    The data are padded to their shape bucket (:func:`_pad_to_bucket`); the output is the
    unpadded run's, except ``gram``'s residual vector, which carries the padding rows (zeros) at
    its end. A compilation :func:`_compile_ahead` started for the same program is waited for;
    ``compile_s`` is then its own duration on the background thread (the call may have waited
    for none of it), not the wait."""
    with dtype_scope(q.dtype):
        cal, q, y, w, dyn, stat, ck = _solve_inputs(cal, q, y, key)
        t0 = time.perf_counter()
        ahead = take_ahead(_AHEAD, ck)  # a compilation _compile_ahead started: waited for
        compiled = None if ahead is None else ahead[0]
        if compiled is None and ck is not None:
            compiled = _COMPILED.get(ck)
        if compiled is None:
            compiled = _build_solve(cal, dyn, stat, q, y, key, w, ck)
        t1 = time.perf_counter()
        out = compiled(dyn, q, y, key, w)
    return out, (t1 - t0 if ahead is None else ahead[1]), t1


def _solve_inputs(cal: Calibrator, q, y, key, host: bool = False):
    """``(cal, q, y, weight, dynamic part, static part, cache key or None)`` of a solve: the data
    padded to their bucket, the calibrator split for ``jit``. ``host``: the padded data as NumPy
    arrays (enough to know the program and to compile it; no transfer to the device)."""
    cal, q, y, w = _pad_to_bucket(cal, q, y, host=host)
    dyn, stat = eqx.partition(cal, eqx.is_array)
    dyn = cast_floating(dyn, q.dtype)
    try:
        ck = (stat, signature((dyn, q, y, key, w)), target_platform(), jax.config.jax_enable_x64)
        hash(ck)
    except TypeError:  # unhashable static part: no cache
        ck = None
    return cal, q, y, w, dyn, stat, ck


def _build_solve(cal: Calibrator, dyn, stat, q, y, key, w, ck):
    """The compiled solve: kept on disk (a fresh process skips tracing), else traced and lowered
    here; remembered under ``ck``."""
    compiled = (_stored_calibrator(cal, dyn, stat, q, y, key, w) if ck is not None else None) or \
        compile_lowered(_run_calibrator.lower(dyn, stat, q, y, key, w))
    if ck is not None:
        _COMPILED.put(ck, compiled)
        # the executable is all a later call needs: drop the trace (jaxpr, lowering) that
        # jax.jit keeps per shape, tens of MB for a solve, never freed otherwise
        _run_calibrator.clear_cache()
    release_memory()
    return compiled


#: solves being compiled on a background thread (:func:`_compile_ahead`), by cache key
_AHEAD: dict = {}
#: summaries of the set-ups :func:`_compile_ahead` has met in this process
_AHEAD_SEEN: set = set()


def _compile_ahead(seen, make) -> None:
    """Start compiling the solve ``make()`` gives (``(Calibrator, q, y, key)``) on a background
    thread while :func:`calibrate` does its other work (closed-form extras, the identifiability
    program): XLA compiles without holding Python's lock, so on a machine with a second core the
    two programs compile at once. :func:`_launch` waits for it. Nothing happens when the program
    is compiled already, where ``JAXCAL_COMPILE_AHEAD=off`` or on a single core.

    ``seen``: a hashable summary of the set-up; one this process met before has its program
    already (a warm call), and nothing is made, padded or hashed (~0.3 ms of a ~6 ms warm
    calibrate). A set-up that shares its summary but not its program just compiles in the
    calling thread, as without this function."""
    if not ahead_enabled() or seen in _AHEAD_SEEN:
        return
    _AHEAD_SEEN.add(seen)
    cal, q, y, key = make()
    with dtype_scope(q.dtype):
        cal, q, y, w, dyn, stat, ck = _solve_inputs(cal, q, y, key, host=True)
    if ck is None or _COMPILED.get(ck) is not None:
        return

    def build():  # (program, seconds it took)
        t = time.perf_counter()
        with dtype_scope(q.dtype):
            return _build_solve(cal, dyn, stat, q, y, key, w, ck), time.perf_counter() - t

    compile_ahead(_AHEAD, ck, build)


def _output_structure(cal: Calibrator):
    """The pytree structure of ``cal``'s :class:`CalibrationOutput`, known without tracing for a
    method whose run carries no extra state (``extra=None``; LM): checked against the traced one
    when a program is stored (:func:`~jaxcal._core._exported.compile_stored`)."""
    z = 0
    robust = cal.objective is not None and cal.objective.loss != "linear"  # gram_at's per-sample errors
    comp = z if len(cal.measurement.components) > 1 else None  # gram_at's per-component grams
    gram = (z, z, z, z, z, z if robust else None, comp) if cal.report else None
    dev = cal.start if cal.report else None
    radius = z if cal.trust_radius is not None else None  # a trust region's step size at the end
    template = CalibrationOutput(z, z, z, z, z, Metrics(*(z for _ in Metrics._fields)), None, gram, dev, radius)
    return jax.tree_util.tree_structure(template)


def _stored_calibrator(cal: Calibrator, dyn, stat, q, y, key, w):
    """``cal``'s solve as a program kept on disk by :mod:`jaxcal._core._exported` (a fresh process
    skips tracing and lowering it), or ``None``: a method with extra state or a configuration
    without a plain description (a user's callable), or the layer turned off."""
    if not (cal.method.maskable and _exported.enabled()):
        return None
    description = _exported.plain_description((stat, cal.space))  # the space with its layout
    if description is None:
        return None

    def solve(dyn, q, y, key, w):
        return eqx.combine(dyn, stat)(q, y, key, w)

    return _exported.compile_stored("calibrate", solve, (dyn, q, y, key, w), description, compile_lowered,
                                    _output_structure(cal))


class _Launched:
    """A solve started by a driver of :func:`_calibration_steps`: ``out`` (possibly still
    computing), ``compile_s``; :meth:`wait` gives ``(output, run seconds)``. ``run_s`` given: the
    output is ready (a share of a batched solve, :func:`jaxcal.calibrate_many`)."""

    def __init__(self, out, compile_s: float, t_started: float, run_s: float | None = None):
        self.out, self.compile_s, self.t_started, self.run_s = out, compile_s, t_started, run_s

    def wait(self):
        if self.run_s is not None:
            return self.out, self.run_s
        out = jax.block_until_ready(self.out)
        return out, time.perf_counter() - self.t_started

