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

from .._core._host_method import host_method
from .._fit._objective import Objective, robust_factor
from .._fit._problem import Problem, value_and_jacfwd
from .._models._kinematics import shared_joint_trig

__all__ = [
    "ScaledProblem",
    "RawRun",
    "Method",
    "register_method",
    "METHODS",
    "method_settings",
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

    The **objective** (:class:`~jaxcal._fit._objective.Objective`) adds Gaussian priors (extra
    residuals ``P·(x − m)``, mm) and a robust loss (each sample's residual block scaled by
    :func:`~jaxcal._fit._objective.robust_factor`) to plain least squares. ``residual`` and
    ``residual_and_jacobian`` are always the plain data residuals; ``objective_residual``,
    ``objective_residual_and_jacobian``, ``loss``, ``loss_and_grad``, ``rmse`` and ``rmse_batch``
    are what the methods minimise and record: ``rmse`` is the objective as an RMS per sample,
    ``sqrt((Σ‖f·r_i‖² + Σ prior²)/n)`` (mm), equal to the training RMSE without prior and
    robust loss (then every computation is exactly the plain one).
    """

    problem: Problem
    x_start: Float[Array, " p"]
    scale: Float[Array, " p"]
    objective: Objective | None = None
    start_jacobian: Float[Array, "N p"] | None = None
    #: ``[p]`` 1 for a parameter that moves, 0 for one held at ``x_start`` (``None``: all move).
    mask: Float[Array, " p"] | None = None
    #: the least-squares methods return the data Jacobian at their solution
    #: (:attr:`RawRun.data_jacobian`), so a caller that needs it (``Calibrator(report=True)``)
    #: does not differentiate the kinematics once more in its program (static).
    keep_jacobian: bool = eqx.field(static=True, default=False)
    #: ``scale`` is a placeholder that the method's ``run`` computes from the start's Jacobian
    #: itself and returns (:attr:`RawRun.scale`; :attr:`Method.scales_itself` methods only): the
    #: least-squares loop then differentiates the kinematics at one place in its program (static).
    scale_pending: bool = eqx.field(static=True, default=False)
    #: with :attr:`scale_pending` and a ``start_jacobian``: a run-time boolean, whether
    #: ``start_jacobian`` holds the start's data Jacobian (the run takes the scales and its first
    #: step from it) or zeros standing in (the run computes it), so one compiled program serves
    #: both (``None``: no start Jacobian is passed).
    start_jacobian_given: Array | None = None
    #: a run-time scalar: a trust-region method's step size at the start (``None``: the solver's
    #: own); :attr:`RawRun.trust_radius` its step size at the end.
    trust_radius: Array | None = None

    @classmethod
    def build(cls, problem: Problem, x_start: Float[Array, " p"] | None = None,
              objective: Objective | None = None, jacobian: Float[Array, "N p"] | None = None,
              mask: Float[Array, " p"] | None = None, keep_jacobian: bool = False,
              defer_scale: bool = False, jacobian_given: Array | None = None,
              trust_radius: Array | None = None) -> ScaledProblem:
        """Scales from the Jacobian ``problem.jacobian(x_start)`` (``x_start`` default
        ``problem.x0()``), or from ``jacobian`` when the caller has computed it (it is then kept
        as ``start_jacobian`` for the least-squares methods' first step).

        ``mask`` ``[p]`` (0/1, run-time data): the free set inside ``problem.space``. A masked
        parameter gets scale 0 (its column of ``∂r/∂z`` is zero, so no step moves it and ``x`` keeps
        its start value) and no prior term, so one compiled program serves every free set of a
        parameter space (:attr:`Method.maskable` methods; the others see ``mask=None``).

        ``defer_scale`` (and no ``jacobian``): the scales are left to the method's ``run``
        (:attr:`scale_pending`), which computes the start's Jacobian in its own loop.
        ``jacobian_given`` (a run-time boolean, with ``defer_scale`` and ``jacobian``): the scales
        are left to ``run`` too, which takes the start's Jacobian from ``jacobian`` where
        ``jacobian_given`` is true and computes it otherwise (:attr:`start_jacobian_given`).
        ``trust_radius``: :attr:`trust_radius`."""
        if objective is not None and objective.plain_least_squares:
            objective = None
        x_start = problem.x0() if x_start is None else jnp.asarray(x_start, problem.dtype)
        if jacobian is not None and jacobian.shape != (problem.n_entries, problem.space.n_free):
            raise ValueError(f"start Jacobian has shape {jacobian.shape}, expected "
                             f"{(problem.n_entries, problem.space.n_free)} (residuals × free parameters)")
        if jacobian_given is not None and (jacobian is None or not defer_scale):
            raise ValueError("jacobian_given needs a start jacobian and defer_scale=True")
        pending = defer_scale and (jacobian is None or jacobian_given is not None)
        if mask is not None:
            mask = jnp.asarray(mask, problem.dtype)
        J = None if jacobian is None else jnp.asarray(jacobian, problem.dtype)
        if pending:
            scale = jnp.ones_like(x_start)
        else:
            J = problem.jacobian(x_start) if J is None else J
            scale = cls.scale_from_jacobian(problem, J, mask)
        if objective is not None:
            objective = jax.tree.map(lambda a: jnp.asarray(a, problem.dtype), objective)
        if mask is not None:
            if objective is not None:
                objective = eqx.tree_at(lambda o: o.prior_precision, objective, objective.prior_precision * mask)
                if objective.prior_whitening is not None:  # no prior rows/columns for a held parameter
                    objective = eqx.tree_at(lambda o: o.prior_whitening, objective,
                                            objective.prior_whitening * mask[:, None] * mask[None, :])
        given = None if jacobian_given is None else jnp.asarray(jacobian_given, bool)
        radius = None if trust_radius is None else jnp.asarray(trust_radius, problem.dtype)
        return cls(problem, x_start, scale, objective, None if jacobian is None else J, mask, keep_jacobian, pending,
                   given, radius)

    @staticmethod
    def scale_from_jacobian(problem: Problem, J: Float[Array, "N p"], mask: Float[Array, " p"] | None = None
                            ) -> Float[Array, " p"]:
        """``scale_j = sqrt(N)/‖J_j‖`` (1 for a zero column; 0 where ``mask`` holds a parameter)."""
        # sqrt(sum(J²)) rather than jnp.linalg.norm: the latter's column reduction is ~10x
        # slower on XLA:CPU for a [N, p] Jacobian (measured, JAX 0.10)
        norms = jnp.sqrt(jnp.sum(J * J, axis=0))
        # sqrt(N) of the real residuals (padding rows of a bucketed problem have zero Jacobian rows;
        # N counts all n·m entries also where J holds the model's own entries only: the same scales)
        root_n = math.sqrt(problem.n_residuals) if problem.weight is None else jnp.sqrt(problem.n_real_residuals)
        scale = jnp.where(norms > 0, root_n / jnp.where(norms > 0, norms, 1.0), 1.0)
        return scale if mask is None else scale * mask

    @property
    def n_prior_residuals(self):
        """Prior residuals that count (:meth:`prior_residual`): the free parameters with a prior
        active, 0 without one (a traced count with a ``mask``)."""
        if self.objective is None or not self.objective.has_prior:
            return 0
        return self.n_free if self.mask is None else jnp.sum(self.mask)

    @property
    def plain(self) -> bool:
        """Plain least squares (no prior, linear loss)."""
        return self.objective is None

    @property
    def n_objective_residuals(self) -> int:
        """Entries of :meth:`objective_residual`: data residuals, plus ``p`` with a prior."""
        extra = self.n_free if (self.objective is not None and self.objective.has_prior) else 0
        return self.problem.n_entries + extra

    def prior_residual(self, z: Float[Array, " p"]) -> Float[Array, " p"]:
        """``P·(x − m)`` (mm), ``σ·W(x − m)`` with a full prior covariance; zeros without a prior."""
        ob = self.objective
        if ob is None or not ob.has_prior:
            return jnp.zeros(self.n_free, self.dtype)
        if ob.prior_whitening is not None:
            return ob.prior_whitening @ (self.x(z) - ob.prior_mean)
        return ob.prior_precision * (self.x(z) - ob.prior_mean)

    @property
    def robust(self) -> bool:
        """Whether the objective has a robust (non-linear) loss."""
        return self.objective is not None and self.objective.loss != "linear"

    def _robust_factor(self, e: Float[Array, " n"]) -> Float[Array, " n"]:
        """The robust loss's factor of each sample with error ``e`` (:attr:`robust` only)."""
        ob = self.objective
        return robust_factor(ob.loss, e * e, ob.loss_scale)

    def _robust_errors(self, problem: Problem, x) -> Array:
        """The per-sample errors ``[n]`` (what the metrics measure, e.g. the position part of a
        pose) scaled by the robust factor."""
        pr = problem
        e = pr.measurement.sample_error(pr.measurement.residual(pr.robot, pr.deviations(x), pr.q, pr.y))
        return pr.weighted_blocks(e * self._robust_factor(e) if self.robust else e)

    def objective_residual(self, z: Float[Array, " p"], problem: Problem | None = None) -> Float[Array, " M"]:
        """What least squares minimises: robust-scaled data residuals ``[N]`` followed, with a
        prior, by the ``p`` prior residuals (mm)."""
        pr = self.problem if problem is None else problem
        return self.objective_from_residual(z, pr.residual(self.x(z)), pr)

    def objective_from_residual(self, z: Float[Array, " p"], r: Float[Array, " N"],
                                problem: Problem | None = None) -> Float[Array, " M"]:
        """:meth:`objective_residual` at ``z`` from the data residual ``r`` there."""
        pr = self.problem if problem is None else problem
        r = self._robust_data(pr, r)
        if self.objective is not None and self.objective.has_prior:
            r = jnp.concatenate([r, self.prior_residual(z)])
        return r

    def objective_residual_and_jacobian(self, z: Float[Array, " p"], problem: Problem | None = None):
        """``(objective_residual [M], ∂/∂z [M, p])`` from one ``jax.jacfwd`` pass through the
        kinematics (:meth:`residual_and_jacobian`) and :meth:`objective_from_data`."""
        r, J = self.residual_and_jacobian(z, problem)
        if self.objective is None:
            return r, J
        return self.objective_from_data(z, r, J, problem)

    def objective_from_data(self, z: Float[Array, " p"], r: Float[Array, " N"], J: Float[Array, "N p"],
                            problem: Problem | None = None):
        """``(objective_residual [M], ∂/∂z [M, p])`` at ``z`` from the data residual ``r`` and its
        Jacobian ``J = ∂r/∂z`` there: the chain rule through the robust scaling (a JVP per column
        of ``J`` through a per-sample function, no kinematics) and the prior rows (linear in
        ``z``). The same values as ``jax.jacfwd`` of :meth:`objective_residual`, with the kinematic
        chain differentiated once, so a program that already holds ``J`` (the start's, from the
        identifiability check) compiles no second derivative of it."""
        pr = self.problem if problem is None else problem
        if self.objective is None:
            return r, J
        if self.robust:
            r, scaled = jax.linearize(lambda r: self._robust_data(pr, r), r)
            J = jax.vmap(scaled, in_axes=1, out_axes=1)(J)
        if self.objective.has_prior:
            r = jnp.concatenate([r, self.prior_residual(z)])
            J = jnp.concatenate([J, jax.jacfwd(self.prior_residual)(z)])
        return r, J

    def _robust_data(self, problem: Problem, r: Float[Array, " N"]) -> Float[Array, " N"]:
        """The flat data residuals ``r`` (padding rows zero) with each sample's block scaled by
        the robust factor of its error (``r`` itself for plain least squares / the linear loss)."""
        if not self.robust:
            return r
        blocks = problem.to_blocks(r)
        f = self._robust_factor(problem.measurement.sample_error(blocks))
        rows = problem.entry_rows()
        return (blocks * f[:, None]).reshape(-1) if rows is None else r * f[rows]

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
        """Training RMSE over the per-sample errors (mm); with a prior or robust loss the
        objective as an RMS per sample (see the class docstring)."""
        pr = self.problem
        if self.objective is None:
            e = pr.sample_errors(self.x(z))
            return jnp.sqrt(jnp.mean(e * e) if pr.weight is None else jnp.sum(e * e) / pr.n_real)
        e = self._robust_errors(pr, self.x(z))
        pz = self.prior_residual(z)
        if pr.weight is None:
            return jnp.sqrt(jnp.mean(e * e) + jnp.sum(pz * pz) / e.shape[0])
        return jnp.sqrt((jnp.sum(e * e) + jnp.sum(pz * pz)) / pr.n_real)

    def loss(self, z: Float[Array, " p"]) -> Float[Array, ""]:
        """``½·(Σ r̃² + Σ prior²)/N`` (mm², ``N`` data residuals), the objective of the gradient
        methods (``½·mean(r²)`` for plain least squares)."""
        r = self.objective_residual(z)
        return 0.5 * jnp.sum(r * r) / self.problem.n_real_residuals

    def jacobian(self, z: Float[Array, " p"]) -> Float[Array, "N p"]:
        """``∂residual/∂z`` by ``jax.jacfwd``."""
        return self.residual_and_jacobian(z)[1]

    def residual_and_jacobian(self, z: Float[Array, " p"], problem: Problem | None = None):
        """``(r [N], ∂r/∂z [N, p])`` from one ``jax.jacfwd`` pass (the residual is its primal).

        ``problem`` (default: the training problem) lets mini-batches reuse the scaling.
        """
        pr = self.problem if problem is None else problem
        return value_and_jacfwd(lambda z: pr.residual(self.x(z)), z, pr.q)

    def loss_and_grad(self, z: Float[Array, " p"], problem: Problem | None = None):
        """``(½·mean(r²), ∇_z)`` in forward mode: ``Jᵀr/N`` from one ``jacfwd`` pass.

        With p ≪ N this is ~3x faster on CPU than reverse mode (``jax.value_and_grad``).
        ``problem`` (default: the training problem) lets mini-batches reuse it.
        """
        r, J = self.objective_residual_and_jacobian(z, problem)
        pr = self.problem if problem is None else problem
        n = pr.n_real_residuals
        return 0.5 * jnp.sum(r * r) / n, jnp.sum(J * r[:, None], axis=0) / n

    def rmse_batch(self, Z: Float[Array, "P p"]) -> Float[Array, " P"]:
        """Training RMSE of ``P`` candidates in one batched (``jax.vmap``-ed) FK call
        (non-finite → ``inf``).

        The mean over samples is a matrix–vector product on purpose: on XLA:CPU (JAX 0.10) a
        row reduction (``jnp.mean(e², axis=-1)``, ``jnp.sum``, ``einsum``) of the vmapped
        errors is lowered to a reduction fusion that recomputes the kinematic chain per output
        and ran ~14x slower (1600 samples, P = 64: 127 ms vs 9 ms).
        """
        with shared_joint_trig(self.problem.q):  # cos/sin of the data once, not per candidate
            mw = self.problem.mean_weights()  # 1/n, or weight/n_real for a padded problem
            if self.objective is None:
                e = jax.vmap(lambda z: self.problem.sample_errors(self.x(z)))(Z)  # [P, n]
                r = jnp.sqrt((e * e) @ mw.astype(e.dtype))
            else:
                e = jax.vmap(lambda z: self._robust_errors(self.problem, self.x(z)))(Z)  # [P, n]
                n = e.shape[-1] if self.problem.weight is None else self.problem.n_real
                pz = jax.vmap(self.prior_residual)(Z)
                r = jnp.sqrt((e * e) @ mw.astype(e.dtype) + jnp.sum(pz * pz, axis=-1) / n)
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
        data_residual: ``[N]`` the data residuals at ``z`` when the method has them (as
            ``data_jacobian``), else ``None``.
        data_jacobian: ``∂residual/∂z`` ``[N, p]`` of the data at ``z`` when the method has it
            (the least-squares methods under :attr:`ScaledProblem.keep_jacobian`), else ``None``.
        scale: ``[p]`` the scales ``z`` is in when the method computed them
            (:attr:`ScaledProblem.scale_pending`), else ``None`` (the problem's own).
        trust_radius: a trust-region method's step size at the end (LM) when the problem gave
            one to start from (:attr:`ScaledProblem.trust_radius`), else ``None``.
    """

    z: Float[Array, " p"]
    history: Float[Array, " T"]
    n_iterations: Int[Array, ""]
    status: Int[Array, ""]
    extra: Any = None
    data_residual: Float[Array, " N"] | None = None
    data_jacobian: Float[Array, "N p"] | None = None
    scale: Float[Array, " p"] | None = None
    trust_radius: Float[Array, ""] | None = None


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

    @host_method
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

    @host_method
    def label(self) -> str:
        return type(self).name

    #: whether :func:`jaxcal.calibrate` may run the method on its parameter space with the free
    #: set as a run-time mask (:meth:`ScaledProblem.build`): one compiled program for every free
    #: set. True where a masked parameter provably never moves and the run equals the run on the
    #: free parameters alone to round-off (LM: a zero column of the damped normal equations gives
    #: a zero step); random search and decoupled weight decay would act on the masked coordinates.
    maskable: ClassVar[bool] = False

    #: whether ``run`` accepts a :attr:`ScaledProblem.scale_pending` problem: it computes the
    #: start's Jacobian and the scales itself and returns them (:attr:`RawRun.scale`).
    scales_itself: ClassVar[bool] = False

    #: whether ``run`` is a trust-region method that starts from :attr:`ScaledProblem.trust_radius`
    #: and returns its step size at the end (:attr:`RawRun.trust_radius`): :func:`jaxcal.calibrate`'s
    #: later rounds continue with the last solve's.
    trust_region: ClassVar[bool] = False

    @property
    def paddable(self) -> bool:
        """Whether a run on data padded with zero-weight rows (shape buckets) equals the
        unpadded run to round-off. Methods whose result depends on the rows themselves (random
        mini-batches, RBF centres) say ``False``; :func:`jaxcal.calibrate` then does not pad."""
        return True

    def sample_errors(self, problem: Problem, x: Float[Array, " p"], extra: Any) -> Float[Array, " n"]:
        """Per-sample errors (mm) of the calibrated model on ``problem``'s data (pure, vmappable).

        Default: the calibrated kinematic model at free parameters ``x``. Methods whose model
        is more than the kinematics (the RBF network) override this, using ``extra``.
        """
        del extra
        return problem.sample_errors(x)


class _Builtin:
    """A registry entry whose module is imported on first use (it registers the real factory)."""

    def __init__(self, name: str, module: str):
        self.name, self.module = name, module

    def resolve(self):
        import importlib

        importlib.import_module(self.module)
        factory = METHODS[self.name]
        if isinstance(factory, _Builtin):  # pragma: no cover - a module that does not register
            raise RuntimeError(f"{self.module} did not register method {self.name!r}")
        return factory

    def __call__(self, *args, **kwargs):
        return self.resolve()(*args, **kwargs)


class _Registry(dict):
    """``name → factory``; built-in entries are imported when first looked up."""

    def __getitem__(self, name):
        v = dict.__getitem__(self, name)
        return v.resolve() if isinstance(v, _Builtin) else v

    def get(self, name, default=None):
        return self[name] if name in self else default

    def values(self):
        return [self[k] for k in self]

    def items(self):
        return [(k, self[k]) for k in self]


#: name → factory(**hyperparameters) → Method
METHODS: dict[str, Callable[..., Method]] = _Registry()


def register_builtin(name: str, module: str) -> None:
    """Register built-in method ``name`` whose module (absolute name) is imported on first use."""
    if name not in METHODS:
        METHODS[name] = _Builtin(name, module)


def register_method(name: str):
    """Decorator registering a :class:`Method` factory (usually the class) under ``name``."""

    def deco(factory):
        METHODS[name] = factory
        return factory

    return deco


def method_settings(name: str) -> list[str] | None:
    """The settings (hyperparameter names) a registered method accepts, or ``None`` if unknown
    (a staged name such as ``"ga>lm"`` checks its ``stage.setting`` names itself)."""
    factory = METHODS.get(name.lower())
    if factory is None:
        return None
    names = getattr(factory, "settings", None)
    if names is None and isinstance(factory, type) and dataclasses.is_dataclass(factory):
        names = [f.name for f in dataclasses.fields(factory) if f.init]
    return None if names is None else sorted(names)


