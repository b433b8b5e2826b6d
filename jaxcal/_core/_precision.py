"""Floating-point precision policy.

Calibration resolves parameter changes of ~1e-4 mm on lengths of ~1e3 mm, a ratio near
float32's resolution (~6e-8 relative), so jaxcal is meant to run in float64. JAX computes in
float32 unless the global flag ``jax_enable_x64`` is on, and flipping a global flag on import
would silently change every other JAX computation in the user's process. The policy is:

* ``import jaxcal`` changes nothing global.
* Every function computes in the dtype of its inputs (joint angles decide; parameters are cast
  to it), so float32 and float64 both work and tests cover both.
* :func:`enable_x64` is the one switch users call (the ``jaxcal`` command line calls it).
* Entry points that run a calibration (:func:`jaxcal.calibrate`, :func:`jaxcal.simulate_experiment`)
  warn once with :class:`PrecisionWarning` when they run in float32.
"""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "PrecisionWarning",
    "enable_x64",
    "x64_enabled",
    "default_float",
    "warn_if_float32",
    "dtype_scope",
    "cast_floating",
    "canonical_numpy",
    "to_device",
]


class PrecisionWarning(UserWarning):
    """Calibration is running in float32; results may lose ~1e-3 mm of accuracy."""


def enable_x64(enabled: bool = True) -> None:
    """Turn JAX's float64 support on (``jax.config.update("jax_enable_x64", True)``).

    Call this once at the start of a program, before creating arrays. It is global for the
    process, which is why ``import jaxcal`` does not do it for you.
    """
    jax.config.update("jax_enable_x64", bool(enabled))


def x64_enabled() -> bool:
    """Whether JAX currently creates float64 arrays by default."""
    return bool(jax.config.jax_enable_x64)


def default_float():
    """``jnp.float64`` when x64 is enabled, else ``jnp.float32``."""
    return jnp.float64 if x64_enabled() else jnp.float32


_warned: set[str] = set()


def warn_if_float32(dtype, where: str) -> None:
    """Warn once per call site when a calibration computation runs in float32."""
    if jnp.dtype(dtype) == jnp.float32 and where not in _warned:
        _warned.add(where)
        warnings.warn(
            f"{where} is running in float32: calibration residuals are ~1e-3 of a mm, near "
            "float32 resolution on metre-scale lengths. Call jaxcal.enable_x64() (or "
            'jax.config.update("jax_enable_x64", True)) at program start for float64.',
            PrecisionWarning,
            stacklevel=3,
        )


def dtype_scope(dtype):
    """Context for tracing a float32 run while x64 is enabled: ``jax.enable_x64(False)``.

    Some library code (optimistix's LM damping, optax counters) creates default-dtype scalars;
    with x64 on those are float64 and break float32 runs. Tracing a float32 calibration with
    x64 off keeps every intermediate in float32. For float64 it does nothing.
    """
    import contextlib

    if jnp.dtype(dtype) == jnp.float32 and x64_enabled():
        return jax.enable_x64(False)
    return contextlib.nullcontext()


def cast_floating(tree, dtype):
    """Cast every floating-point array leaf of ``tree`` to ``dtype`` (other leaves unchanged)."""

    def cast(x):
        if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jnp.floating) and x.dtype != dtype:
            return x.astype(dtype)
        return x

    return jax.tree.map(cast, tree)


def canonical_numpy(x, dtype=None) -> np.ndarray:
    """``x`` as NumPy in ``dtype`` (default: ``x``'s own) canonicalised as JAX does (float64 →
    float32 without x64): the host-side counterpart of a JAX array."""
    a = np.asarray(x)
    return a.astype(jax.dtypes.canonicalize_dtype(a.dtype if dtype is None else dtype), copy=False)


def uncommitted(tree):
    """``tree`` with each committed JAX array (the output of a compiled program) replaced by an
    uncommitted copy of its host values (``jax.device_put`` without a device), other leaves as
    they are. ``jax.jit`` compiles one program per placement of its arguments as well as per
    shape, so a host-side function called once with a result's parameters and once with freshly
    made ones compiled twice (``jaxcal evaluate``: ``sample_errors_at``, 0.16 s each on 2 CPU
    cores). For small arrays (parameters): the copy goes through the host."""
    def one(leaf):
        if isinstance(leaf, jax.Array) and getattr(leaf, "committed", False):
            return jax.device_put(np.asarray(leaf))
        return leaf

    return jax.tree_util.tree_map(one, tree)


def to_device(x, dtype=None) -> jax.Array:
    """``x`` (NumPy or array-like) as a JAX array by ``jax.device_put``, in ``dtype``
    canonicalised as JAX does (:func:`canonical_numpy`).

    For host-side code outside ``jit``: there ``jnp.asarray`` of a NumPy array (or ``.astype``)
    runs a small compiled program per shape — compiled, or loaded from the persistent cache,
    once per process and dispatched at ~20–50 µs — and ``jax.device_put`` does not. A JAX array
    already in that dtype is returned as it is (no round trip through the host).
    """
    if isinstance(x, jax.Array) and x.dtype == jax.dtypes.canonicalize_dtype(x.dtype if dtype is None else dtype):
        return x
    return jax.device_put(canonical_numpy(x, dtype))
