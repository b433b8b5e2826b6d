"""Shape buckets: one compiled program per model and *bucket* of sample counts, not per count.

XLA compiles a program for fixed array shapes, so a calibration compiled for 1 400 samples is
compiled again for 1 401. A notebook user fitting subsets of different sizes (a learning curve)
paid a full compilation (seconds) and ~28 MB of resident memory per new sample count. jaxcal
therefore pads the samples of its compiled programs (the identifiability program, the solve of
:func:`jaxcal.calibrate` and its residual evaluations) to a **bucket size** with zero-weight rows.
On by default.

* **The first bucket** of a process is the smallest size of a fine grid at or above ``n``: eight
  steps per octave above the smallest bucket ``b`` (default 256): ``b·2^k·(8 + j)/8``, ``j = 0..7``
  (256, 288, 320, ..., 1 536, 1 664, 1 792, ...), so the padding is at most 1/9 (11 %) of the
  bucket — a user who calibrates one data size pays almost nothing for it (the paper experiment's
  1 600 training samples run as 1 664 rows). Below ``b`` samples every count pads to ``b``.
* **Wide rows** (more than :data:`WIDE_ROW` = 6 residual entries per sample: a camera view's
  image points, many markers) have a smaller smallest bucket, ``b·6/width`` rounded down to a
  power of two (a 9×6 checkerboard's 108 entries per view: 8 views), so that padding to the
  smallest bucket never adds more than ``6·b`` residual entries: 30 camera views run as 30
  rows, not 256 (8.5 times the residuals, the Jacobian and every step of the solve).
* **Later sizes reuse**: a count ``n`` runs in the smallest bucket this process has used already
  that holds it and is at most :data:`REUSE_FACTOR` (2) × ``n``; only when there is none a new
  bucket is made, and once the process has used one bucket above ``b``, new buckets come from the
  octave grid ``b·2^k`` (a session that varies its sizes — a learning curve, a sweep of hold-outs —
  compiles about one program set per octave, whatever order the sizes come in). The choice
  depends on what the process ran before, which changes results only by round-off (below).
* padded rows repeat the first sample (finite kinematics, no NaN in a derivative) and carry
  weight 0 (:attr:`jaxcal.Problem.weight`): every residual, Jacobian row and sample error of
  theirs is multiplied by 0, and every mean divides by the count of real rows. So the padded
  fit equals the unpadded one to round-off (the order of a few sums changes), and every
  statistic — RMSE, MEAN, MAX, the loss, the column scales, σ̂, the robust scale, the
  uncertainty and effective parameters, the identifiability — sees the real rows only.
* **Turning it off**: ``JAXCAL_BUCKETS=off`` (or :func:`set_buckets` ``(False)``) gives one program
  per sample count, bit for bit the computations without padding; ``JAXCAL_BUCKETS=MIN`` (an
  integer) sets another smallest bucket. Simulated sweeps (:func:`jaxcal.sweep`) pad their
  simulation only when buckets are turned on explicitly (``JAXCAL_BUCKETS=on`` or
  :func:`set_buckets` ``(True)``): their seeded data are then drawn on the padded rows.

Methods whose result depends on the row count itself do not pad (:attr:`Method.paddable`):
mini-batch gradient descent (``batch_size=``: the batches are drawn from the rows) and the RBF
network (its centres and ridge fit use the rows).
"""

from __future__ import annotations

import math
import os
import weakref

import numpy as np

from ._cache import OFF_WORDS

__all__ = ["bucket_size", "buckets_enabled", "set_buckets", "pad_rows", "pad_model_rows", "clear_compiled", "ENV_VAR",
           "REUSE_FACTOR", "FINE_STEPS", "WIDE_ROW"]

#: environment variable: ``off`` (no padding), ``on`` or the smallest bucket (an integer, default 256).
ENV_VAR = "JAXCAL_BUCKETS"

#: a count reuses a bucket the process has used already when the bucket is at most this × the count
REUSE_FACTOR = 2.0

#: steps per octave of the first bucket's grid (padding at most ``1/(FINE_STEPS + 1)`` of the bucket)
FINE_STEPS = 8

#: residual entries per sample up to which the smallest bucket is the configured one (a pose's 6);
#: wider rows scale it down (:func:`smallest_bucket`)
WIDE_ROW = 6

_SETTING: dict = {}

#: bucket sizes above the smallest bucket that this process has used (see the module docstring)
_USED: set[int] = set()


def _parse_setting() -> tuple[int | None, bool]:
    """``(smallest bucket or None when off, explicitly turned on)``."""
    if "value" in _SETTING:
        v = _SETTING["value"]
        return v, v is not None
    text = os.environ.get(ENV_VAR, "").strip().lower()
    if text in ("on", "true", "yes"):
        return 256, True
    if text in ("",):
        return 256, False  # on by default
    if text in OFF_WORDS:
        return None, False
    try:
        v = int(text)
    except ValueError:
        raise ValueError(f"{ENV_VAR} must be 'on', 'off' or the smallest bucket size (an integer), got {text!r}"
                         ) from None
    if v < 1:
        raise ValueError(f"{ENV_VAR} must be >= 1, got {v}")
    return v, True


def _min_bucket() -> int | None:
    """The smallest bucket, or ``None`` when padding is off."""
    return _parse_setting()[0]


def smallest_bucket(minimum: int, width: int = 1) -> int:
    """The smallest bucket for samples of ``width`` residual entries each: ``minimum`` up to
    :data:`WIDE_ROW` entries, else ``minimum·WIDE_ROW/width`` rounded down to a power of two (at
    least 1), so the smallest bucket holds at most ``WIDE_ROW·minimum`` residual entries."""
    minimum, width = int(minimum), max(int(width), 1)
    if width <= WIDE_ROW:
        return minimum
    return max(1, 1 << math.floor(math.log2(max(minimum * WIDE_ROW / width, 1.0))))


def set_buckets(enabled: bool | int | None = True) -> None:
    """Turn shape bucketing on (``True``, smallest bucket 256, or an integer smallest bucket) or
    off (``False``) for this process, overriding ``$JAXCAL_BUCKETS``; ``None`` returns to the
    environment's setting (on by default). Forgets the buckets used so far."""
    _USED.clear()
    if enabled is None:
        _SETTING.pop("value", None)
    elif enabled is True:
        _SETTING["value"] = 256
    elif enabled is False:
        _SETTING["value"] = None
    else:
        v = int(enabled)
        if v < 1:
            raise ValueError(f"the smallest bucket must be >= 1, got {v}")
        _SETTING["value"] = v


def buckets_enabled(explicit: bool = False) -> bool:
    """Whether padding is on; ``explicit=True``: only when turned on explicitly (environment or
    :func:`set_buckets`), not by default (what simulated sweeps require)."""
    b, on = _parse_setting()
    return on if explicit else b is not None


def fine_bucket(n: int, minimum: int = 256) -> int:
    """The smallest size ``minimum·2^k·(FINE_STEPS + j)/FINE_STEPS`` (``j = 0..FINE_STEPS−1``) that
    is ``≥ n``; ``minimum`` for ``n ≤ minimum``."""
    n, b = int(n), int(minimum)
    if n <= b:
        return b
    k = math.floor(math.log2(n / b))
    base = b << k
    for j in range(FINE_STEPS + 1):
        size = -(-base * (FINE_STEPS + j) // FINE_STEPS)
        if size >= n:
            return size
    return b << (k + 1)  # pragma: no cover - log2 round-off


def octave_bucket(n: int, minimum: int = 256) -> int:
    """The smallest ``minimum·2^k ≥ n``."""
    n, b = int(n), int(minimum)
    size = b
    while size < n:
        size *= 2
    return size


def bucket_size(n: int, minimum: int | None = None, *, width: int = 1) -> int:
    """The padded sample count for ``n`` samples (``n`` itself with padding off).

    With ``minimum`` given: the fine grid's bucket (:func:`fine_bucket`), a pure function of
    ``n``. Without (what jaxcal's programs use): the process's bucket rule of the module
    docstring — a bucket already used that holds ``n`` and is at most :data:`REUSE_FACTOR` × ``n``,
    else a new one (fine grid for the process's first bucket above the smallest, octave grid
    after it), which is then remembered. ``width``: residual entries per sample (the measurement
    model's ``size``); wide samples (a camera view) have a smaller smallest bucket
    (:func:`smallest_bucket`)."""
    n = int(n)
    if minimum is not None:
        return n if n <= 0 else fine_bucket(n, smallest_bucket(minimum, width))
    b = _min_bucket()
    if b is None or n <= 0:
        return n
    b = smallest_bucket(b, width)
    if n <= b:
        return b
    fits = [s for s in _USED if n <= s <= REUSE_FACTOR * n]
    if fits:
        return min(fits)
    size = fine_bucket(n, b) if not _USED else octave_bucket(n, b)
    _USED.add(size)
    return size


def pad_rows(q, y, n_to: int, host: bool = False):
    """``(q, y, weight)`` padded to ``n_to`` rows on the host (NumPy; no device program per
    shape): the extra rows repeat row 0 and ``weight`` is 1 for the real rows, 0 for the padding
    (``y`` may be ``None``). At ``n_to`` equal to the row count, ``q`` and ``y`` as given and
    weights all 1: one program serves every count of a bucket, the bucket size included.
    ``host``: return the padded arrays (and the weights) as NumPy arrays, not device arrays (a
    caller that stacks many units on the host first, :func:`jaxcal.calibrate_many`)."""
    import jax

    # the same (immutable) device arrays padded again — identifiability, then the solve of one
    # calibrate call, or a calibration repeated on the same data — reuse the last padding
    memo = not host and isinstance(q, jax.Array) and (y is None or isinstance(y, jax.Array))
    if memo:
        last = _LAST_PADDING.get("entry")
        same_y = last is not None and (last[1] is None if y is None else last[1] is not None and last[1]() is y)
        if same_y and last[0]() is q and last[2] == n_to:
            return last[3]
    put = (lambda a: a) if host else jax.device_put
    n = int(q.shape[0])
    if n_to < n:
        raise ValueError(f"cannot pad {n} rows to {n_to}")
    if n_to == n:  # a bucket size exactly: weights all 1 (the same program as the padded counts)
        out = q, y, put(np.ones(n, np.asarray(q).dtype))
    else:
        # jax.device_put, not jnp.asarray: the latter compiles a small copy program per shape
        def pad(a):
            a = np.asarray(a)
            return put(np.concatenate([a, np.broadcast_to(a[:1], (n_to - n, *a.shape[1:]))]))

        w = np.zeros(n_to, np.asarray(q).dtype)
        w[:n] = 1.0
        out = pad(q), None if y is None else pad(y), put(w)
    if memo:
        _LAST_PADDING["entry"] = (weakref.ref(q), None if y is None else weakref.ref(y), n_to, out)
    return out


#: the last :func:`pad_rows` of device arrays: ``(weakref q, weakref y or None, n_to, result)``
_LAST_PADDING: dict = {}


def pad_model_rows(measurement, q, y, n_to: int | None = None, host: bool = False):
    """``(measurement, q, y, weight)`` for a program over the rows of a measurement model: padded
    to the shape bucket of ``q``'s rows (:func:`bucket_size` at the model's row width ``size``),
    or to ``n_to``, by :func:`pad_rows`, the model's per-row arrays padded to match
    (``measurement.pad_rows``); as given with ``weight=None`` where buckets are off and no
    ``n_to`` is given. ``host``: as :func:`pad_rows`."""
    if not (buckets_enabled() or n_to is not None):
        return measurement, q, y, None
    n = int(q.shape[0])
    n_to = bucket_size(n, width=measurement.size) if n_to is None else int(n_to)
    q, y, w = pad_rows(q, y, n_to, host=host)
    return measurement.pad_rows(n, n_to), q, y, w


class BoundedCache:
    """A least-recently-used dict of at most ``maxsize`` entries (compiled programs: each holds
    its executable, several MB; an unbounded cache grew ~28 MB per sample count)."""

    def __init__(self, maxsize: int):
        from collections import OrderedDict

        self.maxsize = int(maxsize)
        self._d: OrderedDict = OrderedDict()
        self.hits = self.misses = self.evictions = 0
        _CACHES.add(self)

    def get(self, key):
        try:
            v = self._d[key]
        except KeyError:
            self.misses += 1
            return None
        self._d.move_to_end(key)
        self.hits += 1
        return v

    def put(self, key, value) -> None:
        self._d[key] = value
        self._d.move_to_end(key)
        while len(self._d) > self.maxsize:
            self._d.popitem(last=False)
            self.evictions += 1

    def clear(self) -> None:
        self._d.clear()

    def __getitem__(self, key):
        v = self.get(key)
        if v is None:
            raise KeyError(key)
        return v

    def __setitem__(self, key, value) -> None:
        self.put(key, value)

    def __len__(self) -> int:
        return len(self._d)

    def __contains__(self, key) -> bool:
        return key in self._d


#: every :class:`BoundedCache` of the process (weakly held), for :func:`clear_compiled`
_CACHES: weakref.WeakSet = weakref.WeakSet()


def clear_compiled() -> None:
    """Free every compiled program this process holds: jaxcal's bounded caches (``calibrate``,
    ``calibrate_many``, ``sweep`` units, the identifiability program, ...) and JAX's own
    (``jax.clear_caches()``: every ``jax.jit``'s traces and executables), then give the freed heap
    pages back to the operating system. On XLA:CPU a compiled program holds ~3–16 MB resident
    (the paper experiment's identifiability program and LM solve); a notebook session or a test
    run that compiled hundreds of programs can drop them all here. The next call of each
    program compiles it again (or loads it from the persistent compilation cache where that is
    on, as on the command line)."""
    import gc

    import jax

    for c in list(_CACHES):
        c.clear()
    _LAST_PADDING.clear()
    jax.clear_caches()
    gc.collect()
    release_memory()


def cache_size(name: str, default: int) -> int:
    """A cache bound from ``$JAXCAL_<NAME>_CACHE`` (an integer ≥ 1), else ``default``."""
    text = os.environ.get(f"JAXCAL_{name.upper()}_CACHE", "").strip()
    if not text:
        return default
    v = int(text)
    if v < 1:
        raise ValueError(f"JAXCAL_{name.upper()}_CACHE must be >= 1, got {v}")
    return v


def signature(tree) -> tuple:
    """A hashable key of a pytree's structure and array shapes/dtypes (the static fields of
    ``equinox`` modules are in the structure)."""
    import jax

    leaves, treedef = jax.tree_util.tree_flatten(tree)
    return treedef, tuple((leaf.shape, leaf.dtype) if hasattr(leaf, "shape") else ("py", type(leaf))
                          for leaf in leaves)


class LeanJit:
    """``jax.jit(fn)`` for host-side callers, with bounded memory: compiled executables are kept
    in a least-recently-used cache of ``maxsize`` entries, keyed by the static arguments and the
    shapes/dtypes of the others, and ``jax.jit``'s own per-shape trace (the jaxpr and its
    lowering, tens of MB for the identifiability program, never freed by JAX) is dropped after
    each compilation. Called with tracers (inside another ``jit``), it is plain ``jax.jit(fn)``."""

    def __init__(self, fn, *, static_argnames=(), maxsize: int = 16):
        import functools
        import inspect

        import jax

        self.jitted = jax.jit(fn, static_argnames=static_argnames)  # options: compile_lowered below
        self.static = tuple(static_argnames)
        self.cache = BoundedCache(maxsize)
        self._sig = inspect.signature(fn)
        functools.update_wrapper(self, fn)

    def __call__(self, *args, **kwargs):
        import jax

        bound = self._sig.bind(*args, **kwargs)
        bound.apply_defaults()
        dyn = {k: v for k, v in bound.arguments.items() if k not in self.static}
        if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(dyn)):
            return self.jitted(*args, **kwargs)
        from ._xla import target_platform

        try:
            key = (tuple((k, bound.arguments[k]) for k in self.static), signature(dyn), target_platform(),
                   jax.config.jax_enable_x64)
            hash(key)
        except TypeError:
            return self.jitted(*args, **kwargs)
        compiled = self.cache.get(key)
        if compiled is None:
            from ._xla import compile_lowered

            # kept on disk (a fresh process skips tracing), else traced and lowered here
            compiled = self._stored(bound.arguments, dyn, compile_lowered) or \
                compile_lowered(self.jitted.lower(**bound.arguments))
            self.cache.put(key, compiled)
            self.jitted.clear_cache()
            release_memory()
        return compiled(**dyn)

    def _stored(self, arguments: dict, dyn: dict, compile_lowered):
        """The program as kept on disk by :mod:`jaxcal._core._exported` (a fresh process skips
        tracing it), called as ``program(**dyn)``; ``None`` when it cannot be kept."""
        from . import _exported

        if not _exported.enabled():
            return None
        static = {k: arguments[k] for k in self.static}
        description = _exported.plain_description(static)  # which dynamic argument is None: the in_tree
        if description is None:
            return None
        names = sorted(dyn)
        jitted = self.jitted

        def fn(*values):
            return jitted(**static, **dict(zip(names, values)))

        program = _exported.compile_stored(f"{self.__module__}.{self.__qualname__}", fn,
                                           tuple(dyn[k] for k in names), description, compile_lowered)
        if program is None:
            return None
        return lambda **kw: program(*(kw[k] for k in names))

    def clear_cache(self) -> None:
        self.cache.clear()
        self.jitted.clear_cache()


def resident_mb(pid="self") -> float | None:
    """Resident memory (MB) of process ``pid`` (default this one) from ``/proc``; ``None`` where
    it cannot be read (not Linux, or the process is gone). For the test run's memory guard
    (``tests/conftest.py``) and the memory benchmarks."""
    import os

    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
    except OSError:
        return None


def release_memory() -> None:
    """Give the C heap's free pages back to the operating system (glibc ``malloc_trim``; nothing
    elsewhere). XLA's compiler allocates and frees hundreds of MB per compilation; glibc keeps
    the freed pages, so a session's resident memory grew ~20 MB per compilation although the
    memory was free (measured on the 2-core CPU: 8 calibrations of new sizes, +178 MB resident,
    +55 MB after ``malloc_trim``). Called after each of jaxcal's own compilations (they take
    seconds; this takes milliseconds)."""
    global _TRIM
    if _TRIM is None:
        import ctypes
        import ctypes.util
        import sys

        _TRIM = False
        if sys.platform.startswith("linux"):
            try:
                _TRIM = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
            except (OSError, AttributeError):
                _TRIM = False
    if _TRIM:
        _TRIM(0)


_TRIM = None
