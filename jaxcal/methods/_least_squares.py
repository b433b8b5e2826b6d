"""Least-squares methods from optimistix: Levenberg–Marquardt (the paper's M4) and Gauss–Newton.

The Jacobian comes from ``jax.jacfwd``: the residual function handed to optimistix is a
``jax.custom_jvp`` whose JVP rule materialises the ``[N, p]`` Jacobian with ``jax.jacfwd`` once
per linearisation point and returns ``J·t`` (:func:`residual_with_jacfwd`). optimistix's
``jac="fwd"`` linearisation then holds a plain matrix, so its trust-region test (``J·δ``), the
lineax materialisation and the transposes in the normal equations are matrix products instead
of passes through the linearised kinematics — which XLA:CPU evaluated ~3x slower than the
Jacobian itself (the LM solve of the default experiment: 11.3 ms → 4.6 ms, 2-core CPU; the
iterates are the same to round-off). The damped system is solved through its small ``p×p`` normal
equations, ``lineax.Normal(lineax.Cholesky())``, in the column-scaled coordinates
of :class:`ScaledProblem` (which keep them well conditioned on an identifiable parameter set).
``linear_solver="qr"`` selects optimistix's default QR instead. LM's trust region is
optimistix's ``ClassicalTrustRegion`` plus one rule (:class:`RoundoffAwareTrustRegion`): a step
whose predicted and actual changes of the loss are both below its rounding error is accepted, so
a converged solve stops instead of shrinking the trust region through ~20 rejected round-off
steps.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from optimistix._misc import cauchy_termination as optx_cauchy_termination

from .._fit._result import Status
from .._sensors._measurement import Pose
from ._base import DIVERGENCE_FACTOR, Method, RawRun, ScaledProblem, finish_history, register_method

__all__ = [
    "LevenbergMarquardt",
    "GaussNewton",
    "RoundoffAwareTrustRegion",
    "make_linear_solver",
    "optimistix_run",
    "residual_with_jacfwd",
]


def make_linear_solver(name: str) -> lx.AbstractLinearSolver:
    """``"cholesky"`` → ``lx.Normal(lx.Cholesky())`` (p×p normal equations), ``"qr"`` → ``lx.QR()``."""
    if name == "cholesky":
        return lx.Normal(lx.Cholesky())
    if name == "qr":
        return lx.QR()
    raise ValueError(f"linear_solver must be 'cholesky' or 'qr', got {name!r}")


def residual_with_jacfwd(problem: ScaledProblem):
    """``z ↦ problem.objective_residual(z)`` (the data residuals, plus prior residuals and the
    robust scaling when the problem has them) whose JVP is ``J·t`` with ``J = jax.jacfwd(residual)(z)``.

    Same values and derivatives as ``problem.residual`` (the JVP is exact, not approximate);
    what changes is how a linearisation is represented: one materialised Jacobian per point
    instead of a linear function through the kinematic chain. Differentiable in ``z`` only
    (``problem`` is closed over, as optimistix closes over ``args``).
    """

    @jax.custom_jvp
    def residual(z):
        return problem.objective_residual(z)

    @residual.defjvp
    def _jvp(primals, tangents):
        (z,), (t,) = primals, tangents
        r, J = problem.objective_residual_and_jacobian(z)
        return r, J @ t

    return residual


class RoundoffAwareTrustRegion(optx.ClassicalTrustRegion):
    """``optimistix.ClassicalTrustRegion`` that also accepts a step whose predicted decrease of the
    loss ``½‖r‖²`` is below the loss's rounding error (``N·eps·loss``, ``N`` residuals) and whose
    actual change is too (the step size is then left as it is).

    Near the optimum both the predicted and the actual decrease are round-off, so the classical
    ratio test accepts or rejects at random; after a rejection the trust region shrinks by 4 and
    the next, smaller step is again round-off — optimistix's LM then spent up to ~20 extra
    steps (each with a Jacobian) until a step happened to pass, and a ``vmap``-ed batch of LM
    trials waits for its slowest member. Accepting such a step changes the loss by at most its
    rounding error, and lets the Cauchy termination (step below ``atol + rtol·|z|``) end the
    solve.

    ``n_residuals``: the count ``N`` of real residuals when the residual vector carries padding
    rows (:mod:`jaxcal._core._buckets`), so the threshold is the unpadded one; ``None``: its length.
    """

    n_residuals: object = None

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        step_size, accept, result, new_state = super().step(first_step, y, y_eval, f_info, f_eval_info, state)
        r = f_info.residual
        loss = f_info.as_min()
        size = r.size if self.n_residuals is None else self.n_residuals
        noise = size * jnp.finfo(r.dtype).eps * loss
        predicted = self.predict_reduction(y_eval - y, f_info)
        roundoff = (~first_step) & (jnp.abs(predicted) <= noise) & (f_eval_info.as_min() - loss <= noise)
        step_size = jnp.where(roundoff & ~accept, state.step_size, step_size)
        new_state = eqx.tree_at(lambda s: s.step_size, new_state, step_size)
        return step_size, accept | roundoff, result, new_state


def _rmse_from_residual(problem: ScaledProblem, z, r):
    """Training RMSE at the accepted point ``z`` from its objective residual ``r``, which the
    solver already holds (saves one FK evaluation per step); pose data need the position-only
    sample errors."""
    measurement = problem.problem.measurement
    if isinstance(measurement, Pose):
        return problem.rmse(z)
    if problem.plain and problem.problem.weight is None:
        return jnp.sqrt(measurement.size * jnp.mean(r * r))
    # data residuals (robust-scaled) and prior residuals, per real data residual (padding rows are 0)
    return jnp.sqrt(measurement.size * jnp.sum(r * r) / problem.problem.n_real_residuals)


def _start_residual_and_jacobian(problem: ScaledProblem):
    """``(r, ∂r/∂z)`` at ``z = 0``. For plain least squares the Jacobian is ``J_x·diag(scale)``
    with ``J_x = problem.problem.jacobian(x_start)``, the very computation
    :meth:`ScaledProblem.build` made for the column scales (XLA merges the two; or the one it was
    given, ``start_jacobian``), so the start costs no second ``jacfwd``; equal to ``jacfwd`` in
    ``z`` up to round-off."""
    z0 = jnp.zeros(problem.n_free, problem.dtype)
    if problem.plain:
        r0 = problem.problem.residual(problem.x_start)
        Jx = problem.start_jacobian if problem.start_jacobian is not None else problem.problem.jacobian(problem.x_start)
        return r0, Jx * problem.scale
    return problem.objective_residual_and_jacobian(z0)


def optimistix_run(solver, problem: ScaledProblem, max_steps: int) -> RawRun:
    """Run an optimistix Gauss–Newton-type least-squares solver (LM, GN) step by step,
    recording the training RMSE.

    The loop is optimistix's own step (``AbstractGaussNewton.step``: its search — the trust
    region —, its descent — the damped Newton step through ``linear_solver`` — and its Cauchy
    termination), with the evaluations arranged so that no Jacobian is computed that is not
    used: each step evaluates the residual at the candidate point, lets the search accept or
    reject it from the residual alone (the trust-region ratio needs the loss there and the
    Jacobian of the last *accepted* point), tests termination, and computes the Jacobian
    (``jax.jacfwd``) only for an accepted, non-final point; the start's Jacobian is the one
    :meth:`ScaledProblem.build` computed for the scales. ``optimistix.least_squares`` would
    linearise at every candidate, rejected and final ones included (default experiment: 6
    Jacobians where 4 are needed). Same iterates up to round-off. Keeps a per-iteration
    history ``[max_steps + 1]``. Pure and vmappable (under ``vmap`` the loop runs until the
    slowest member terminates; finished members do not move, and the conditional Jacobian is
    computed for every member).
    """
    pr = problem.problem
    if (pr.weight is not None or problem.mask is not None) and isinstance(solver.search, RoundoffAwareTrustRegion):
        # the round-off threshold counts the real residuals (data + the free parameters' prior),
        # not the padding nor the prior rows of masked parameters (zeros)
        solver = eqx.tree_at(lambda s: s.search.n_residuals, solver, pr.n_real_residuals + problem.n_prior_residuals,
                             is_leaf=lambda v: v is None)
    search, descent = solver.search, solver.descent
    z0 = jnp.zeros(problem.n_free, problem.dtype)
    r0, J0 = _start_residual_and_jacobian(problem)
    info_struct = jax.eval_shape(lambda: optx.FunctionInfo.ResidualJac(r0, lx.MatrixLinearOperator(J0)))
    f_info0 = optx.FunctionInfo.ResidualJac(jnp.zeros_like(r0), lx.MatrixLinearOperator(jnp.zeros_like(J0)))
    search_state0 = search.init(z0, info_struct)
    descent_state0 = descent.init(z0, info_struct)
    rmse0 = _rmse_from_residual(problem, z0, r0)  # from the start residual: no extra FK pass
    hist0 = jnp.full(max_steps + 1, jnp.nan, problem.dtype).at[0].set(rmse0)

    def jacobian_at(z):
        return problem.objective_residual_and_jacobian(z)[1]

    def cond(c):
        k, done, result = c[3], c[-3], c[-2]
        return (~done) & (result == optx.RESULTS.successful) & (k < max_steps)

    def body(c):
        z, z_eval, first, k, f_info, s_state, d_state, _, _, hist = c
        r_eval = jax.lax.cond(first, lambda _: r0, lambda z: problem.objective_residual(z), z_eval)
        # the search reads only the loss at the candidate (and the accepted point's Jacobian)
        probe = optx.FunctionInfo.ResidualJac(r_eval, f_info.jac)
        step_size, accept, search_result, s_state = search.step(first, z, z_eval, f_info, probe, s_state)
        terminate = accept & optx_cauchy_termination(
            solver.rtol, solver.atol, solver.norm, z_eval, z_eval - z, r_eval, r_eval - f_info.residual
        )
        need_jac = accept & ~terminate & ~first
        J_eval = jax.lax.cond(need_jac, jacobian_at, lambda _: jnp.where(first, J0, f_info.jac.matrix), z_eval)
        eval_info = optx.FunctionInfo.ResidualJac(r_eval, lx.MatrixLinearOperator(J_eval))
        d_state = jax.lax.cond(accept, lambda d: descent.query(z_eval, eval_info, d), lambda d: d, d_state)
        z_acc = jnp.where(accept, z_eval, z)
        f_info = jax.tree.map(lambda a, b: jnp.where(accept, a, b), eval_info, f_info)
        # the step from a point where the solve terminates is never taken: skip its linear solve
        y_descent, descent_result = jax.lax.cond(
            terminate,
            lambda _: (jnp.zeros_like(z_acc), optx.RESULTS.successful),
            lambda d: descent.step(step_size, d),
            d_state,
        )
        result = optx.RESULTS.where(search_result == optx.RESULTS.successful, descent_result, search_result)
        z_next = z_acc + y_descent
        finite = jnp.all(jnp.isfinite(z_acc))  # as optimistix: the accepted point, not the candidate
        result = optx.RESULTS.where(finite, result, optx.RESULTS.nonfinite)
        rmse = _rmse_from_residual(problem, z_acc, f_info.residual)
        return (z_acc, z_next, jnp.asarray(False), k + 1, f_info, s_state, d_state, terminate, result,
                hist.at[k + 1].set(rmse))

    carry0 = (z0, z0, jnp.asarray(True), jnp.asarray(0), f_info0, search_state0, descent_state0,
              jnp.asarray(False), optx.RESULTS.successful, hist0)
    z, _, _, k, _, _, _, done, result, hist = jax.lax.while_loop(cond, body, carry0)
    hist = finish_history(hist, k)
    finite = jnp.all(jnp.isfinite(hist[: max_steps + 1])) & jnp.all(jnp.isfinite(z))
    exploded = hist[k] > DIVERGENCE_FACTOR * rmse0
    status = jnp.where(
        (~finite) | exploded | (result == optx.RESULTS.nonfinite),
        int(Status.DIVERGED),
        jnp.where(
            result != optx.RESULTS.successful,
            int(Status.FAILED),
            jnp.where(done, int(Status.CONVERGED), int(Status.MAX_STEPS)),
        ),
    )
    z = jnp.where(jnp.all(jnp.isfinite(z)), z, z0)
    return RawRun(z, hist, k, status)


#: Least-squares termination tolerances are at least this in float32 (see ``_OptimistixMethod``).
FLOAT32_TOL = 1e-3


class _OptimistixMethod(Method):
    """Shared fields and run loop of the optimistix least-squares methods.

    Args:
        rtol, atol: optimistix's Cauchy termination tolerances: an accepted step must change
            every scaled parameter (a unit moves the RMS residual ~1 mm) and every residual
            (mm) by less than ``atol + rtol·|value|``. At 1e-5 the training RMSE is within
            ~1e-8 mm of the optimum; tighter values make LM spend steps being rejected at
            round-off level (optimistix counts rejected steps). In float32 both are raised to at
            least ``FLOAT32_TOL`` = 1e-3: the float32 residuals carry ~1e-4 relative round-off,
            so 1e-5 is never met and LM/GN would end at their step budget (MAX_STEPS) at the
            optimum.
        max_steps: step budget (accepted and rejected steps both count).
        linear_solver: ``"cholesky"`` (default, p×p normal equations) or ``"qr"``.
    """

    rtol: float = 1e-5
    atol: float = 1e-5
    max_steps: int = 100
    linear_solver: str = "cholesky"
    #: the optimistix solver class (``optx.LevenbergMarquardt`` or ``optx.GaussNewton``).
    solver_cls: ClassVar[type] = optx.LevenbergMarquardt

    def __check_init__(self):
        make_linear_solver(self.linear_solver)
        if self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps}")
        if not (self.rtol >= 0 and self.atol >= 0 and self.rtol + self.atol > 0):
            raise ValueError(f"rtol and atol must be >= 0 and not both 0, got {self.rtol}, {self.atol}")

    @property
    def max_iterations(self) -> int:
        return self.max_steps

    def solver(self, dtype=None) -> optx.AbstractLeastSquaresSolver:
        """The optimistix solver (tolerances raised to ``FLOAT32_TOL`` for a float32 ``dtype``)."""
        rtol, atol = self.rtol, self.atol
        if dtype is not None and jnp.finfo(dtype).bits < 64:
            rtol, atol = max(rtol, FLOAT32_TOL), max(atol, FLOAT32_TOL)
        solver = type(self).solver_cls(rtol, atol, linear_solver=make_linear_solver(self.linear_solver))
        if isinstance(solver.search, optx.ClassicalTrustRegion):  # LM
            solver = eqx.tree_at(lambda s: s.search, solver, RoundoffAwareTrustRegion())
        return solver

    def run(self, problem: ScaledProblem, key) -> RawRun:
        del key  # deterministic
        return optimistix_run(self.solver(problem.dtype), problem, self.max_steps)


@register_method("lm")
class LevenbergMarquardt(_OptimistixMethod):
    """Levenberg–Marquardt (``optimistix.LevenbergMarquardt``), the paper's M4 (Marquardt, 1963).

    Defaults: ``rtol = atol = 1e-5``, ``max_steps = 100``, ``linear_solver = "cholesky"``
    (see :class:`_OptimistixMethod`).
    """

    name: ClassVar[str] = "lm"
    solver_cls: ClassVar[type] = optx.LevenbergMarquardt
    maskable: ClassVar[bool] = True


@register_method("gn")
class GaussNewton(_OptimistixMethod):
    """Gauss–Newton (``optimistix.GaussNewton``): LM without damping; fast when the start is
    close and the parameter set identifiable, no safeguard otherwise. Same settings as LM."""

    name: ClassVar[str] = "gn"
    solver_cls: ClassVar[type] = optx.GaussNewton
