"""The common machinery of calibration methods: scaled problems, raw runs, the registry."""

from __future__ import annotations

import abc
import dataclasses
import math
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._problem import Problem

__all__ = [
    "ScaledProblem",
    "RawRun",
    "Method",
    "register_method",
    "METHODS",
    "make_method",
    "default_half_width",
    "finish_history",
    "DIVERGENCE_FACTOR",
]

#: A run is declared diverged when its RMSE exceeds this multiple of the starting RMSE.
DIVERGENCE_FACTOR = 1e3


class ScaledProblem(eqx.Module):
    """A :class:`~jaxcal.Problem` in scaled coordinates ``z``: ``x = x_start + scale ⊙ z``.

    ``scale_j = sqrt(N) / ‖J_j‖`` (``J`` the identification Jacobian at ``x_start``, ``N``
    residuals), so a unit step in any ``z_j`` changes the RMS residual by about 1 mm whatever
    the parameter's unit (rad or mm). All methods work in ``z``; ``z = 0`` is the start
    (the nominal robot by default), so weight decay shrinks toward it.
    """

    problem: Problem
    x_start: Float[Array, " p"]
    scale: Float[Array, " p"]

    @classmethod
    def build(cls, problem: Problem, x_start: Float[Array, " p"] | None = None) -> ScaledProblem:
        x_start = problem.x0() if x_start is None else jnp.asarray(x_start, problem.dtype)
        J = problem.jacobian(x_start)
        # sqrt(sum(J²)) rather than jnp.linalg.norm: the latter's column reduction is ~10x
        # slower on XLA:CPU for a [N, p] Jacobian (measured, JAX 0.10)
        norms = jnp.sqrt(jnp.sum(J * J, axis=0))
        n = J.shape[0]
        scale = jnp.where(norms > 0, math.sqrt(n) / jnp.where(norms > 0, norms, 1.0), 1.0)
        return cls(problem, x_start, scale)

    @property
    def n_free(self) -> int:
        return int(self.x_start.shape[0])

    @property
    def dtype(self):
        return self.problem.dtype

    def x(self, z: Float[Array, " p"]) -> Float[Array, " p"]:
        """Physical free parameters (rad, mm) for scaled ``z``."""
        return self.x_start + self.scale * z

    def z(self, x: Float[Array, " p"]) -> Float[Array, " p"]:
        return (x - self.x_start) / self.scale

    def residual(self, z: Float[Array, " p"]) -> Float[Array, " N"]:
        """Flat residuals ``[N]`` (mm) at scaled ``z``."""
        return self.problem.residual(self.x(z))

    def rmse(self, z: Float[Array, " p"]) -> Float[Array, ""]:
        """Training RMSE over the per-sample errors (mm)."""
        e = self.problem.sample_errors(self.x(z))
        return jnp.sqrt(jnp.mean(e * e))

    def loss(self, z: Float[Array, " p"]) -> Float[Array, ""]:
        """``½·mean(r²)`` (mm²), the objective of the gradient methods."""
        r = self.residual(z)
        return 0.5 * jnp.mean(r * r)

    def jacobian(self, z: Float[Array, " p"]) -> Float[Array, "N p"]:
        """``∂residual/∂z`` by ``jax.jacfwd``."""
        return jax.jacfwd(self.residual)(z)

    def residual_and_jacobian(self, z: Float[Array, " p"], problem: Problem | None = None):
        """``(r [N], ∂r/∂z [N, p])`` from one ``jax.jacfwd`` pass (the residual is its primal).

        ``problem`` (default: the training problem) lets mini-batches reuse the scaling.
        """
        pr = self.problem if problem is None else problem
        f = lambda z: (pr.residual(self.x(z)),) * 2  # noqa: E731
        J, r = jax.jacfwd(f, has_aux=True)(z)
        return r, J

    def loss_and_grad(self, z: Float[Array, " p"], problem: Problem | None = None):
        """``(½·mean(r²), ∇_z)`` in forward mode: ``Jᵀr/N`` from one ``jacfwd`` pass.

        With p ≪ N this is ~3x faster on CPU than reverse mode (``jax.value_and_grad``).
        ``problem`` (default: the training problem) lets mini-batches reuse it.
        """
        r, J = self.residual_and_jacobian(z, problem)
        n = r.shape[0]
        return 0.5 * jnp.sum(r * r) / n, jnp.sum(J * r[:, None], axis=0) / n

    def rmse_batch(self, Z: Float[Array, "P p"]) -> Float[Array, " P"]:
        """Training RMSE of ``P`` candidates in one batched (``jax.vmap``-ed) FK call
        (non-finite → ``inf``).

        The mean over samples is a matrix–vector product on purpose: on XLA:CPU (JAX 0.10) a
        row reduction (``jnp.mean(e², axis=-1)``, ``jnp.sum``, ``einsum``) of the vmapped
        errors is lowered to a reduction fusion that recomputes the kinematic chain per output
        and ran ~14x slower (1600 samples, P = 64: 127 ms vs 9 ms).
        """
        e = jax.vmap(lambda z: self.problem.sample_errors(self.x(z)))(Z)  # [P, n]
        n = e.shape[-1]
        r = jnp.sqrt((e * e) @ jnp.full((n,), 1.0 / n, e.dtype))
        return jnp.where(jnp.isfinite(r), r, jnp.inf)

    def half_width_z(self, half_width_x: Float[Array, " p"]) -> Float[Array, " p"]:
        """Box half-widths in ``z`` for physical half-widths ``[p]`` (rad/mm)."""
        return jnp.asarray(half_width_x, self.dtype) / self.scale


def default_half_width(space, angle_deg: float = 2.0, length_mm: float = 5.0, extra_mm: float = 50.0) -> np.ndarray:
    """Physical search box half-widths ``[p]`` for population methods: ±2° on angles, ±5 mm on
    DH lengths, ±50 mm on anchor/tool/cable offset (covers Table V's deviations with margin)."""
    out = []
    for name, unit in zip(space.free_names, space.free_units):
        if unit == "rad":
            out.append(math.radians(angle_deg))
        elif name.startswith(("anchor", "tool", "cable")):
            out.append(extra_mm)
        else:
            out.append(length_mm)
    return np.asarray(out)


class RawRun(NamedTuple):
    """What a method's pure ``run`` returns (a pytree; batched under ``vmap``).

    Attributes:
        z: ``[p]`` final (best) scaled parameters.
        history: ``[max_iterations + 1]`` training RMSE, entry 0 the start.
        n_iterations: iterations run.
        status: :class:`~jaxcal.Status` code.
        extra: method-specific pytree (or ``None``).
    """

    z: Float[Array, " p"]
    history: Float[Array, " T"]
    n_iterations: Int[Array, ""]
    status: Int[Array, ""]
    extra: Any = None


def finish_history(history: Array, n_iterations: Array) -> Array:
    """Repeat the value at ``n_iterations`` after it (keeps NaN from a divergence)."""
    idx = jnp.arange(history.shape[0])
    return jnp.where(idx > n_iterations, history[n_iterations], history)


class Method(eqx.Module):
    """Abstract calibration method: a pure, jittable, vmappable ``run(problem, key)``."""

    #: registry name.
    name: ClassVar[str] = "method"

    @property
    @abc.abstractmethod
    def max_iterations(self) -> int:
        """Length of the history minus one."""

    @abc.abstractmethod
    def run(self, problem: ScaledProblem, key: Array) -> RawRun:
        """Calibrate; must be a pure function of ``(problem, key)`` and the method's fields."""

    def hyperparameters(self) -> dict[str, Any]:
        """Settings reported in results (numbers and strings)."""
        out = {}
        # dataclasses.fields: instance fields only (no ClassVars such as ``name``); the
        # keyword-only ones (e.g. the search box of BoxSearch) after the method's own
        for f in sorted(dataclasses.fields(self), key=lambda f: f.kw_only is True):
            v = getattr(self, f.name)
            if isinstance(v, (int, float, str, bool, type(None))):
                out[f.name] = v
        return out

    def label(self) -> str:
        return type(self).name

    def sample_errors(self, problem: Problem, x: Float[Array, " p"], extra: Any) -> Float[Array, " n"]:
        """Per-sample errors (mm) of the calibrated model on ``problem``'s data (pure, vmappable).

        Default: the calibrated kinematic model at free parameters ``x``. Methods whose model
        is more than the kinematics (the RBF network) override this, using ``extra``.
        """
        del extra
        return problem.sample_errors(x)


#: name → factory(**hyperparameters) → Method
METHODS: dict[str, Callable[..., Method]] = {}


def register_method(name: str):
    """Decorator registering a :class:`Method` factory (usually the class) under ``name``."""

    def deco(factory):
        METHODS[name] = factory
        return factory

    return deco


def make_method(method, **hyperparameters) -> Method:
    """A :class:`Method` from a registry name, a Method instance, or an
    ``optax.GradientTransformation`` (run as a full-batch gradient method)."""
    import optax

    from ._gradient import OptaxMethod

    if isinstance(method, Method):
        if hyperparameters:
            raise ValueError("pass hyperparameters to the method's constructor, not with a Method instance")
        return method
    if isinstance(method, optax.GradientTransformation):
        return OptaxMethod.from_transformation(method, **hyperparameters)
    if not isinstance(method, str):
        raise TypeError(f"method must be a name, a jaxcal Method or an optax.GradientTransformation, got {type(method)}")
    key = method.lower()
    if key not in METHODS:
        raise ValueError(f"unknown method {method!r}; available: {', '.join(sorted(METHODS))}")
    try:
        cache_key = (key, tuple(sorted(hyperparameters.items())))
        hash(cache_key)
    except TypeError:  # unhashable settings (e.g. arrays): build afresh
        cache_key = None
    if cache_key is not None and cache_key in _METHOD_CACHE:
        return _METHOD_CACHE[cache_key]
    try:
        built = METHODS[key](**hyperparameters)
    except TypeError as e:
        raise TypeError(f"bad hyperparameters for method {method!r}: {e}") from None
    if cache_key is not None:
        # the same name and settings give the same object, so jit caches hit (an optax
        # transformation is a static field, compared by identity)
        _METHOD_CACHE[cache_key] = built
    return built


_METHOD_CACHE: dict = {}


