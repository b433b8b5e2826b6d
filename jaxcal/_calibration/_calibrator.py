"""The pure core of a calibration: :class:`Calibrator`, a calibration as a pure function
``(q, y, key) -> CalibrationOutput`` that ``jax.jit`` and ``jax.vmap`` take as it is."""

from __future__ import annotations

import functools
from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from .._core._metrics import Metrics, compute_metrics
from .._core._params import Deviations, ParameterSpace
from .._core._xla import jit
from .._fit._diagnostics import gram_at, gram_from_jacobian
from .._fit._objective import Objective
from .._fit._problem import Problem
from .._fit._result import budget_status, iterations_to_converge
from .._models._abstract import AbstractRobot
from .._models._kinematics import shared_joint_trig
from .._sensors._measurement import MeasurementModel
from ..methods import Method, ScaledProblem

__all__ = ["Calibrator", "CalibrationOutput"]


class CalibrationOutput(NamedTuple):
    """Pure output of :class:`Calibrator` (a pytree; batched under ``vmap``)."""

    x: Float[Array, " p"]
    history: Float[Array, " T"]
    n_iterations: Int[Array, ""]
    iterations_to_converge: Int[Array, ""]
    status: Int[Array, ""]
    train_metrics: Metrics
    extra: object = None
    #: with ``Calibrator(report=True)``: :func:`~jaxcal._fit._diagnostics.gram_at` at ``x``, and the
    #: full :class:`Deviations` at ``x`` (``start`` in the entries that are not free).
    gram: object = None
    deviations: object = None
    #: a trust-region method's (LM) step size at its end (:attr:`Calibrator.trust_radius` of a
    #: solve that continues from ``x``), else ``None``.
    trust_radius: object = None


class Calibrator(eqx.Module):
    """A calibration as a pure function ``(q, y, key) -> CalibrationOutput``.

    ``jax.jit`` it, or ``jax.vmap`` it over keys and datasets for seed sweeps.

    Attributes:
        robot, measurement: nominal models.
        method: a :class:`~jaxcal.methods.Method`.
        start: deviations the run starts from (zeros = nominal); non-free entries stay fixed.
        space: free parameters (static).
        objective: prior and robust loss (:class:`~jaxcal._fit._objective.Objective`); ``None`` =
            plain least squares.
        report: also return what :func:`calibrate` reports besides ``x``, from the same compiled
            program: the Jacobian products at the solution that
            :func:`~jaxcal._fit._diagnostics.parameter_uncertainty` needs (``gram``) and the full
            ``deviations`` (static; sweeps leave it off).
        start_jacobian: ``∂residual/∂x`` ``[N, p]`` of the data at ``start`` for the free
            parameters when the caller has it (``calibrate``: from the identifiability program,
            for measurements whose Jacobian does not depend on the readings); computed in the
            program otherwise. See :meth:`ScaledProblem.build`.
        start_jacobian_given: with ``start_jacobian`` and a method that computes its own scales
            (:attr:`~jaxcal.methods.Method.scales_itself`: LM, GN), a run-time boolean: whether
            ``start_jacobian`` holds the start's Jacobian or zeros standing in (the program
            computes it then), so the fits with and without one run one compiled program
            (:func:`calibrate`'s masked solves of measurements whose Jacobian does not depend on
            the readings).
        free: ``[p]`` 0/1 mask over ``space``'s parameters, run-time data: only those with 1 move
            (the others stay at ``start``, without prior terms), so one compiled program serves
            every free set of ``space`` (:attr:`~jaxcal.methods.Method.maskable` methods only;
            ``None``: all of ``space`` moves). :func:`calibrate` runs LM this way.
        trust_radius: a run-time scalar: the trust region's step size at the start (LM; ``1``,
            optimistix's own, at a calibration's first solve): :func:`calibrate`'s later rounds
            pass the last solve's (:attr:`CalibrationOutput.trust_radius`), so a round that starts
            near its solution takes Gauss–Newton-like steps at once. ``None``: the solver's own.
    """

    robot: AbstractRobot
    measurement: MeasurementModel
    method: Method
    start: Deviations
    space: ParameterSpace = eqx.field(static=True)
    objective: Objective | None = None
    report: bool = eqx.field(static=True, default=False)
    start_jacobian: Array | None = None
    free: Array | None = None
    start_jacobian_given: Array | None = None
    trust_radius: Array | None = None

    def __check_init__(self):
        if self.free is not None and not self.method.maskable:
            raise ValueError(f"method {type(self.method).__name__} cannot run with a free-parameter mask (free=)")

    def problem(self, q, y, weight=None) -> Problem:
        return Problem(self.robot, self.measurement, q, y, self.space, self.start, weight)

    def __call__(self, q: Float[Array, "n dof"], y: Array, key: Array, weight: Array | None = None
                 ) -> CalibrationOutput:
        """``weight``: ``[n]`` 1 for a real sample, 0 for a padding row (shape buckets);
        the output then equals the unpadded run's to round-off."""
        problem = self.problem(q, y, weight)
        with shared_joint_trig(problem.q):  # cos/sin of the data once per solve, not per evaluation
            scaled = ScaledProblem.build(problem, objective=self.objective, jacobian=self.start_jacobian,
                                         mask=self.free, keep_jacobian=self.report,
                                         defer_scale=self.method.scales_itself,
                                         jacobian_given=self.start_jacobian_given,
                                         trust_radius=self.trust_radius)
            raw = self.method.run(scaled, key)
            if raw.scale is not None:  # computed by the method from the start's Jacobian
                scaled = eqx.tree_at(lambda s: s.scale, scaled, raw.scale)
            x = scaled.x(raw.z)
            if raw.data_residual is None:
                errors = self.method.sample_errors(problem, x, raw.extra)
            else:  # the solve's own residual at x: no further kinematics in the program
                errors = problem.sample_errors_from_residual(raw.data_residual)
            metrics = compute_metrics(errors, problem.weight)
            gram = deviations = None
            if self.report:
                ob = self.objective
                loss, scale = ("linear", 1.0) if ob is None else (ob.loss, ob.loss_scale)
                scale = jnp.asarray(scale, problem.dtype)
                if raw.data_jacobian is None:
                    gram = gram_at(problem, x, loss, scale)
                else:  # the solve's own final Jacobian, ∂r/∂z = ∂r/∂x·diag(scale); held columns are 0
                    s = scaled.scale
                    J = raw.data_jacobian / jnp.where(s != 0, s, 1.0)
                    gram = gram_from_jacobian(problem, raw.data_residual, J, loss, scale)
                deviations = problem.deviations(x)
        its = iterations_to_converge(raw.history, raw.n_iterations)
        status = budget_status(raw.status, raw.history, raw.n_iterations)  # COMPLETED → STILL_IMPROVING
        return CalibrationOutput(x, raw.history, raw.n_iterations, its, status, metrics, raw.extra, gram, deviations,
                                 raw.trust_radius)


@functools.partial(jit, static_argnums=1)
def _run_calibrator(dynamic, static, q, y, key, weight=None) -> CalibrationOutput:
    """The jitted core of :func:`calibrate` (module level, so compilations are cached)."""
    return eqx.combine(dynamic, static)(q, y, key, weight)

