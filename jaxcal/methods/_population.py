"""Helpers shared by the search-box methods (GA, BSO, IWOA, EKF) and the RBF network.

* :class:`BoxSearch` — base class holding the search box: every population method starts from a
  box of ±``box_angle_deg`` (angles), ±``box_length_mm`` (DH lengths) and ±``box_extra_mm``
  (anchor, tool, cable offset) around the start, converted to the scaled coordinates ``z``
  (:func:`box_half_width_z`); the EKF uses the same box for its prior covariance.
* the initial population (evaluated, like every generation, in one batched forward-kinematics
  call: ``ScaledProblem.rmse_batch``), the best-so-far :class:`~jaxcal.methods.RawRun` of a
  population run, and the random-number helpers that draw one ``jax.random.uniform`` block per generation;
* hyperparameter checks with messages that name the parameter.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._fit._result import Status
from ._base import Method, RawRun, ScaledProblem, default_half_width

__all__ = [
    "BoxSearch",
    "box_half_width_z",
    "check_box",
    "check_positive",
    "check_unit_interval",
    "initial_population",
    "finish_population_run",
    "start_rmse",
    "uniform_parts",
    "normal_from_uniform",
    "uniform_index",
]


def box_half_width_z(problem: ScaledProblem, angle_deg: float, length_mm: float, extra_mm: float) -> Array:
    """Half-widths ``[p]`` in ``z`` of the physical box ±``angle_deg`` / ±``length_mm`` /
    ±``extra_mm`` (anchor, tool, cable offset) around the start."""
    hw = default_half_width(problem.problem.space, angle_deg, length_mm, extra_mm)
    return problem.half_width_z(hw)


def check_box(angle_deg: float, length_mm: float, extra_mm: float) -> None:
    """``ValueError`` unless the box half-widths are finite and positive."""
    for name, v in (("box_angle_deg", angle_deg), ("box_length_mm", length_mm), ("box_extra_mm", extra_mm)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a finite number > 0 (search box half-width), got {v!r}")


def check_positive(name: str, value, *, integer: bool = False, minimum=None, allow_zero: bool = False) -> None:
    """``ValueError`` with a clear message for a non-positive (or too small) hyperparameter."""
    ok_type = isinstance(value, int) if integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok_type or (not integer and not math.isfinite(value)):
        kind = "an integer" if integer else "a finite number"
        raise ValueError(f"{name} must be {kind}, got {value!r}")
    if minimum is not None:
        if value < minimum:
            raise ValueError(f"{name} must be >= {minimum}, got {value}")
    elif value < 0 or (value == 0 and not allow_zero):
        raise ValueError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {value}")


def check_unit_interval(name: str, value, *, open_low: bool = False) -> None:
    """``ValueError`` unless ``value`` lies in ``[0, 1]`` (``(0, 1]`` with ``open_low``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (0.0 <= value <= 1.0) or (open_low and value == 0):
        raise ValueError(f"{name} must be in {'(0, 1]' if open_low else '[0, 1]'}, got {value!r}")


def initial_population(key: Array, half_width: Float[Array, " p"], size: int) -> Float[Array, "P p"]:
    """``[size, p]`` candidates uniform in the box ``±half_width``; row 0 is the start ``z = 0``."""
    p = half_width.shape[0]
    u = jax.random.uniform(key, (size, p), half_width.dtype, -1.0, 1.0)
    return (u * half_width).at[0].set(0.0)


def finish_population_run(
    rmse0: Array, best_history: Float[Array, " T"], z_best: Float[Array, " p"], extra=None
) -> RawRun:
    """RawRun from a per-generation best-so-far history ``[T]`` (without the start).

    ``history[0]`` is the start's RMSE; status COMPLETED, or DIVERGED where the history is
    non-finite (no finite candidate ever found); the returned ``z`` is the best found (the start
    where nothing finite was found).
    """
    hist = jnp.concatenate([rmse0[None], best_history])
    finite = jnp.isfinite(hist)
    ok = jnp.all(finite) & jnp.all(jnp.isfinite(z_best))
    n_gen = best_history.shape[0]
    # first non-finite entry - 1 (as the gradient methods count iterations before a divergence)
    first_bad = jnp.argmax(~finite)
    n_it = jnp.where(ok, n_gen, jnp.maximum(first_bad - 1, 0))
    z = jnp.where(jnp.all(jnp.isfinite(z_best)) & jnp.isfinite(hist[-1]), z_best, jnp.zeros_like(z_best))
    status = jnp.where(ok, int(Status.COMPLETED), int(Status.DIVERGED))
    return RawRun(z, hist, jnp.asarray(n_it), status, extra)


def start_rmse(problem: ScaledProblem) -> Array:
    """RMSE at ``z = 0`` (``inf`` if non-finite), entry 0 of every history."""
    r = problem.rmse(jnp.zeros(problem.n_free, problem.dtype))
    return jnp.where(jnp.isfinite(r), r, jnp.inf)


def uniform_parts(key: Array, shapes, dtype) -> list[Array]:
    """Uniform ``[0, 1)`` arrays of the given shapes from ONE ``jax.random.uniform`` draw.

    One draw per generation instead of one per operator: each random-bit generator (and
    ``randint``) is a separate threefry kernel for XLA to compile; sharing one draw cut the
    GA's compilation by ~40 % (measured, XLA:CPU), at no cost in randomness.
    """
    sizes = [math.prod(s) for s in shapes]
    u = jax.random.uniform(key, (sum(sizes),), dtype)
    out, i = [], 0
    for shape, n in zip(shapes, sizes):
        out.append(u[i : i + n].reshape(shape))
        i += n
    return out


def normal_from_uniform(u: Array) -> Array:
    """Standard normals from uniforms ``u`` in [0, 1) (inverse CDF, as ``jax.random.normal``)."""
    lo = jnp.nextafter(jnp.asarray(-1.0, u.dtype), jnp.asarray(0.0, u.dtype))
    return math.sqrt(2.0) * jax.scipy.special.erfinv(jnp.maximum(2.0 * u - 1.0, lo))


def uniform_index(u: Array, n: int) -> Array:
    """Integers uniform in ``[0, n)`` from uniforms ``u`` in ``[0, 1)``."""
    return jnp.clip(jnp.floor(u * n), 0, n - 1).astype(jnp.int32)


class BoxSearch(Method):
    """A :class:`~jaxcal.methods.Method` searching (or, for the EKF, with a prior) inside a box
    around the start.

    Fields (keyword-only, after the subclass's own fields):
        box_angle_deg: half-width for angles (°).
        box_length_mm: half-width for DH lengths (mm).
        box_extra_mm: half-width for the draw-wire extras: anchor, tool point, cable offset (mm).
    """

    box_angle_deg: float = eqx.field(default=2.0, kw_only=True)
    box_length_mm: float = eqx.field(default=5.0, kw_only=True)
    box_extra_mm: float = eqx.field(default=50.0, kw_only=True)

    def __check_init__(self):
        check_box(self.box_angle_deg, self.box_length_mm, self.box_extra_mm)

    def box_half_width_z(self, problem: ScaledProblem) -> Float[Array, " p"]:
        """Half-widths ``[p]`` of this method's box in ``problem``'s scaled coordinates."""
        return box_half_width_z(problem, self.box_angle_deg, self.box_length_mm, self.box_extra_mm)
