"""Accuracy metrics (paper Section IV-A), the statistical floor, and plain-text tables."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

__all__ = [
    "Metrics",
    "rmse",
    "mean_abs_error",
    "max_abs_error",
    "compute_metrics",
    "metrics_numpy",
    "statistical_floor",
    "format_table",
    "robust_scale",
]


def rmse(errors: Float[Array, " n"]) -> Float[Array, ""]:
    """Root mean square ``sqrt(mean(e²))`` (mm).

    The paper prints RMSE as ``Σᵢ sqrt((1/n)(Cᵢ − Ĉᵢ)²)``, which is garbled (it equals
    ``sqrt(n)·MEAN``); jaxcal uses the standard definition.
    """
    e = jnp.asarray(errors)
    return jnp.sqrt(jnp.mean(e * e))


def mean_abs_error(errors: Float[Array, " n"]) -> Float[Array, ""]:
    """MEAN: mean absolute error ``(1/n) Σ|eᵢ|`` (mm)."""
    return jnp.mean(jnp.abs(jnp.asarray(errors)))


def max_abs_error(errors: Float[Array, " n"]) -> Float[Array, ""]:
    """MAX: largest absolute error ``max|eᵢ|`` (mm)."""
    return jnp.max(jnp.abs(jnp.asarray(errors)))


class Metrics(NamedTuple):
    """RMSE, MEAN and MAX of per-sample errors (mm). A pytree; fields may be batched."""

    rmse: Float[Array, ...]
    mean: Float[Array, ...]
    max: Float[Array, ...]


def compute_metrics(errors: Float[Array, " n"], weight: Float[Array, " n"] | None = None) -> Metrics:
    """RMSE/MEAN/MAX of per-sample errors ``[n]`` (e.g. ``measurement.sample_error``). Jittable.

    ``weight``: ``[n]`` 1 for a real sample, 0 for a padding row (shape buckets); the
    metrics are then those of the real rows alone."""
    if weight is None:
        return Metrics(rmse(errors), mean_abs_error(errors), max_abs_error(errors))
    e = jnp.abs(jnp.asarray(errors))
    real = weight > 0
    e = jnp.where(real, e, 0.0)
    n = jnp.sum(weight)
    return Metrics(jnp.sqrt(jnp.sum(e * e) / n), jnp.sum(e) / n, jnp.max(e))


def metrics_numpy(errors) -> Metrics:
    """RMSE/MEAN/MAX (Python floats, mm) of per-sample errors, in NumPy on the host: for callers
    outside ``jit`` (a result's :meth:`~jaxcal.CalibrationResult.evaluate`, the command line),
    where the same three reductions as eager JAX operations are five small XLA programs, each
    compiled (or loaded from the persistent cache) once per process and shape."""
    e = np.abs(np.asarray(errors, np.float64))
    return Metrics(float(np.sqrt(np.mean(e * e))), float(np.mean(e)), float(np.max(e)))


class Floor(NamedTuple):
    """Best achievable RMS error with Gaussian noise σ (least squares, correct model)."""

    train: float
    test: float


def statistical_floor(noise_std: float, n_params: int, n_train: int, size: int = 1) -> Floor:
    """The statistical floor for RMSE.

    With ``N = n_train·size`` residuals, ``p`` identifiable parameters and i.i.d. Gaussian
    noise σ per residual entry, least squares leaves an expected mean square residual of
    ``σ²(1 − p/N)`` on training data, and a fresh pose has expected mean square error
    ``σ²(1 + p/(N − p − 1))`` (prediction variance of a linear model with Gaussian regressors).
    Per-sample errors combine ``size`` entries (the Euclidean norm for positions), so both are
    multiplied by ``sqrt(size)``.

    Args:
        noise_std: σ per measured entry (mm).
        n_params: number of identifiable free parameters ``p``.
        n_train: number of training samples.
        size: residual entries per sample (1 for cable length, 3 for position).

    Returns:
        ``Floor(train, test)`` RMSE in mm.
    """
    N = n_train * size
    if N <= n_params + 1:
        raise ValueError(f"need more residuals ({N}) than parameters + 1 ({n_params + 1})")
    s = noise_std * math.sqrt(size)
    return Floor(s * math.sqrt(1.0 - n_params / N), s * math.sqrt(1.0 + n_params / (N - n_params - 1)))


def _fmt(v) -> str:
    if isinstance(v, str):
        return v
    if v is None:
        return "—"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    v = float(v)
    if not math.isfinite(v):
        return str(v)
    if v != 0 and (abs(v) < 1e-3 or abs(v) >= 1e5):
        return f"{v:.3e}"
    return f"{v:.4f}"


def format_table(
    rows: Sequence[Sequence], headers: Sequence[str], *, markdown: bool = False, title: str | None = None
) -> str:
    """Format rows as an aligned plain-text (or Markdown) table. Floats get 4 decimals."""
    cells = [[_fmt(c) for c in r] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h) for i, h in enumerate(headers)]
    lines = []
    if title:
        lines.append(title if not markdown else f"**{title}**\n")
    if markdown:
        lines.append("| " + " | ".join(h.ljust(w) for h, w in zip(headers, widths)) + " |")
        lines.append("|" + "|".join("-" * (w + 2) for w in widths) + "|")
        lines += ["| " + " | ".join(c.ljust(w) for c, w in zip(r, widths)) + " |" for r in cells]
    else:
        lines.append("  ".join(h.rjust(w) for h, w in zip(headers, widths)))
        lines.append("  ".join("-" * w for w in widths))
        lines += ["  ".join(c.rjust(w) for c, w in zip(r, widths)) for r in cells]
    return "\n".join(lines)


def robust_scale(errors) -> float:
    """σ̂ = 1.4826·median(|e − median(e)|) of per-sample errors (mm): consistent for Gaussian
    noise, unmoved by up to half the samples being outliers (for signed errors; non-negative
    error norms of m-dimensional residuals use ``1.4826·median(e)/sqrt(m)``-like behaviour — the
    caller passes signed entries where it can)."""
    e = np.asarray(errors, dtype=np.float64).ravel()
    e = e[np.isfinite(e)]
    if e.size == 0:
        return math.nan
    return float(1.4826 * np.median(np.abs(e - np.median(e))))
