"""Shape buckets: one compiled program per model and *bucket* of sample counts, not per count.

XLA compiles a program for fixed array shapes, so a calibration compiled for 1 400 samples is
compiled again for 1 401. A notebook user fitting subsets of different sizes (a learning curve)
paid a full compilation (seconds) and ~28 MB of resident memory per new sample count. jaxcal
therefore pads the samples of its compiled programs (the identifiability program and the solve
of :func:`jaxcal.calibrate`) to a **bucket size** with zero-weight rows:

* the rule (:func:`bucket_size`): ``n`` is rounded up to the next of ``256·2^k`` and
  ``384·2^k`` (``k ≥ 0``): 256, 384, 512, 768, 1 024, 1 536, 2 048, 3 072, 4 096, 6 144, ...
  (the halfway steps keep the padding below a third of the bucket); below 256 samples every
  count pads to 256. Counts that are a bucket size exactly are not padded at all.
* padded rows repeat the first sample (finite kinematics, no NaN in a derivative) and carry
  weight 0 (:attr:`jaxcal.Problem.weight`): every residual, Jacobian row and sample error of
  theirs is multiplied by 0, and every mean divides by the count of real rows. So the padded
  fit equals the unpadded one to round-off (the order of a few sums changes), and every
  statistic — RMSE, MEAN, MAX, the loss, the column scales, σ̂, the robust scale, the
  uncertainty and effective parameters, the identifiability — sees the real rows only.
* **Off by default** (one program per sample count, results bit for bit as before padding
  existed): on the 2-core CPU the padding rows cost the warm paper-experiment fit (1 600 →
  2 048 rows) 17.9 instead of 11.4 ms of CPU, which breaks the warm-``calibrate`` speed goal
  (≥ 15× scipy). Turn it on where compilations dominate — a learning curve over many sample
  counts, a notebook session: ``JAXCAL_BUCKETS=on`` (smallest bucket 256), ``JAXCAL_BUCKETS=MIN``
  (another smallest bucket) or :func:`set_buckets` ``(True)``; ``off`` turns it off again.

Methods whose result depends on the row count itself do not pad (:attr:`Method.paddable`):
mini-batch gradient descent (``batch_size=``: the batches are drawn from the rows) and the RBF
network (its centres and ridge fit use the rows).
"""

from __future__ import annotations

import math
import os
import weakref

import numpy as np

__all__ = ["bucket_size", "buckets_enabled", "set_buckets", "pad_rows", "clear_compiled", "ENV_VAR"]

#: environment variable: ``off`` (no padding) or the smallest bucket (an integer, default 256).
ENV_VAR = "JAXCAL_BUCKETS"

_SETTING: dict = {}


def _min_bucket() -> int | None:
    """The smallest bucket, or ``None`` when padding is off."""
    if "value" in _SETTING:
        return _SETTING["value"]
    text = os.environ.get(ENV_VAR, "").strip().lower()
    if text in ("on", "true", "yes"):
        return 256
    if text in ("", "off", "none", "false", "0", "no"):  # off by default: see the module docstring
        return None
    try:
        v = int(text)
    except ValueError:
        raise ValueError(f"{ENV_VAR} must be 'off' or the smallest bucket size (an integer), got {text!r}") from None
    if v < 1:
        raise ValueError(f"{ENV_VAR} must be >= 1, got {v}")
    return v


def set_buckets(enabled: bool | int = True) -> None:
    """Turn shape bucketing on (``True``, smallest bucket 256, or an integer smallest bucket) or
    off (``False``) for this process; overrides ``$JAXCAL_BUCKETS``."""
    if enabled is True:
        _SETTING["value"] = 256
    elif enabled is False or enabled is None:
        _SETTING["value"] = None
    else:
        v = int(enabled)
        if v < 1:
            raise ValueError(f"the smallest bucket must be >= 1, got {v}")
        _SETTING["value"] = v


def buckets_enabled() -> bool:
    return _min_bucket() is not None


def bucket_size(n: int, minimum: int | None = None) -> int:
    """The padded sample count for ``n`` samples: the smallest of ``b·2^k`` and ``1.5·b·2^k``
    (``b`` = ``minimum``, default 256) that is ``≥ n``; ``n`` itself with padding off."""
    n = int(n)
    b = _min_bucket() if minimum is None else minimum
    if b is None or n <= 0:
        return n
    if n <= b:
        return b
    k = math.floor(math.log2(n / b))
    for size in (b << k, (3 * b << k) // 2, b << (k + 1)):
        if size >= n:
            return size
    return b << (k + 1)  # pragma: no cover - log2 round-off


def pad_rows(q, y, n_to: int):
    """``(q, y, weight)`` padded to ``n_to`` rows on the host (NumPy; no device program per
    shape): the extra rows repeat row 0 and ``weight`` is 1 for the real rows, 0 for the padding
    (``y`` may be ``None``). At ``n_to`` equal to the row count, ``q`` and ``y`` as given and
    weights all 1: one program serves every count of a bucket, the bucket size included.
    ``weight`` is ``None`` (and ``q``, ``y`` are returned as given) when ``n_to`` equals the
    row count."""
    import jax

    n = int(q.shape[0])
    if n_to == n:  # a bucket size exactly: weights all 1 (the same program as the padded counts)
        return q, y, jax.device_put(np.ones(n, np.asarray(q).dtype))
    if n_to < n:
        raise ValueError(f"cannot pad {n} rows to {n_to}")

    # jax.device_put, not jnp.asarray: the latter compiles a small copy program per shape
    def pad(a):
        a = np.asarray(a)
        return jax.device_put(np.concatenate([a, np.broadcast_to(a[:1], (n_to - n, *a.shape[1:]))]))

    w = np.zeros(n_to, np.asarray(q).dtype)
    w[:n] = 1.0
    return pad(q), None if y is None else pad(y), jax.device_put(w)


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
    return treedef, tuple((tuple(leaf.shape), str(leaf.dtype)) if hasattr(leaf, "shape") else ("py", type(leaf))
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

        self.jitted = jax.jit(fn, static_argnames=static_argnames)
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
        try:
            key = (tuple((k, bound.arguments[k]) for k in self.static), signature(dyn), jax.default_backend(),
                   jax.config.jax_enable_x64)
            hash(key)
        except TypeError:
            return self.jitted(*args, **kwargs)
        compiled = self.cache.get(key)
        if compiled is None:
            compiled = self.jitted.lower(**bound.arguments).compile()
            self.cache.put(key, compiled)
            self.jitted.clear_cache()
            release_memory()
        return compiled(**dyn)

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
