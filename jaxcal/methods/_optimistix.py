"""The optimistix side of the least-squares methods (:mod:`jaxcal.methods._least_squares`): the
linear solvers, LM's round-off-aware trust region and the step loop. Imported when a solve is
traced, not when a method is made: a process that loads its compiled solve from the cache (a warm
``jaxcal calibrate``) does not import optimistix and lineax (~0.15 s on 2 CPU cores)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from optimistix._misc import cauchy_termination as optx_cauchy_termination

from .._core._xla import computed_once
from .._fit._problem import value_and_jacfwd
from .._fit._result import Status
from .._sensors._measurement import Pose
from ._base import DIVERGENCE_FACTOR, RawRun, ScaledProblem, finish_history

__all__ = ["RoundoffAwareTrustRegion", "make_linear_solver", "optimistix_run"]


def make_linear_solver(name: str) -> lx.AbstractLinearSolver:
    """``"cholesky"`` → ``lx.Normal(lx.Cholesky())`` (p×p normal equations), ``"qr"`` → ``lx.QR()``."""
    if name == "cholesky":
        return lx.Normal(lx.Cholesky())
    if name == "qr":
        return lx.QR()
    raise ValueError(f"linear_solver must be 'cholesky' or 'qr', got {name!r}")


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
    rows (shape buckets), so the threshold is the unpadded one; ``None``: its length.
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
    # data residuals (robust-scaled) and prior residuals, per real data residual: n·m entries (padding
    # rows are 0; a model that names its own entries leaves out only zeros)
    return jnp.sqrt(measurement.size * jnp.sum(r * r) / problem.problem.n_real_residuals)


def _start_jacobians(problem: ScaledProblem):
    """``(∂r/∂z, ∂r_data/∂z)`` at ``z = 0``: the objective's Jacobian and the data residuals'
    (the same array for plain least squares), or ``(None, None)`` when the scales are pending (the
    loop's first step computes them). The data Jacobian is ``J_x·diag(scale)`` with ``J_x`` the
    one :meth:`ScaledProblem.build` computed for the column scales or was given
    (``start_jacobian``); the objective's follows from it
    (:meth:`ScaledProblem.objective_from_data`), so the start costs no second ``jacfwd``."""
    if problem.scale_pending:
        return None, None
    z0 = jnp.zeros(problem.n_free, problem.dtype)
    Jx = problem.start_jacobian if problem.start_jacobian is not None else problem.problem.jacobian(problem.x_start)
    Jd = Jx * problem.scale
    if problem.plain:
        return Jd, Jd
    return problem.objective_from_data(z0, problem.problem.residual(problem.x_start), Jd)[1], Jd


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

    With ``problem.keep_jacobian`` the final point's Jacobian is computed in the loop too and
    returned as :attr:`RawRun.data_jacobian` (the data residuals' ``∂r/∂z``): a caller that needs
    it (the posterior covariance) then holds the kinematics' derivative once in its program,
    not twice. With pending scales and a start Jacobian given at run time
    (:attr:`ScaledProblem.start_jacobian_given`), the first step takes that Jacobian where the flag
    is set and computes its own where it is not (one program for both). Each Jacobian the loop
    computes passes through :func:`~jaxcal._core._xla.computed_once`, and the first step's column
    norms run in a conditional: XLA:CPU otherwise fused the kinematics into each use of the
    Jacobian and computed it twice per step.
    """
    pr = problem.problem
    if (pr.weight is not None or problem.mask is not None) and isinstance(solver.search, RoundoffAwareTrustRegion):
        # the round-off threshold counts the real residuals (data + the free parameters' prior),
        # not the padding nor the prior rows of masked parameters (zeros)
        solver = eqx.tree_at(lambda s: s.search.n_residuals, solver, pr.n_real_residuals + problem.n_prior_residuals,
                             is_leaf=lambda v: v is None)
    search, descent = solver.search, solver.descent
    z0 = jnp.zeros(problem.n_free, problem.dtype)
    J0, Jd0 = _start_jacobians(problem)
    keep, pending, plain = problem.keep_jacobian, problem.scale_pending, problem.plain
    # a start Jacobian given at run time (pending scales only): where it is, the first step takes it
    given = problem.start_jacobian_given if pending and problem.start_jacobian is not None else None
    # the data residual and Jacobian of the accepted point are carried apart from the objective's
    # only where the two differ (a prior or a robust loss) and the caller asked for them
    carry_data = keep and not plain
    n_data = problem.problem.n_entries
    r_struct = jax.ShapeDtypeStruct((problem.n_objective_residuals,), problem.dtype)
    jac_struct = jax.ShapeDtypeStruct((problem.n_objective_residuals, problem.n_free), problem.dtype)
    info_struct = optx.FunctionInfo.ResidualJac(r_struct, lx.MatrixLinearOperator(jac_struct))
    f_info0 = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), info_struct)
    search_state0 = search.init(z0, info_struct)
    # a trust region's step size from the caller (a later round of calibrate: the last solve's)
    radius = problem.trust_radius if isinstance(search, optx.ClassicalTrustRegion) else None
    if radius is not None:
        search_state0 = eqx.tree_at(lambda s: s.step_size, search_state0,
                                    jnp.asarray(radius, search_state0.step_size.dtype))
    descent_state0 = descent.init(z0, info_struct)
    hist0 = jnp.full(max_steps + 1, jnp.nan, problem.dtype)

    def scaled_by(scale):
        return eqx.tree_at(lambda p: p.scale, problem, scale) if pending else problem

    def jacobians_from(z, scale, first, r, Jx):
        """``(objective Jacobian, data Jacobian or (), scale)`` at ``z`` from the data residual
        ``r`` and Jacobian ``Jx = ∂r/∂x`` there (the scales from ``Jx`` at the start when they are
        pending)."""
        pb = scaled_by(scale)
        if pending:
            # the scales from the column norms at the first step only, and Jx's one consumer this
            # conditional: with two (the norms, Jx·scale) XLA:CPU fused the whole kinematic
            # Jacobian into each, computing it twice per step (the N×p norms ran at every step too)
            def rescaled(J):
                s = ScaledProblem.scale_from_jacobian(pb.problem, J, pb.mask)
                return J * s, s

            Jd, scale = jax.lax.cond(first, rescaled, lambda J: (J * scale, scale), Jx)
            pb = scaled_by(scale)
        else:
            Jd = Jx * scale
        Jo = Jd if plain else pb.objective_from_data(z, r, Jd)[1]
        return Jo, (Jd if carry_data else ()), scale

    def jacobians_at(args):
        """:func:`jacobians_from` at ``z``: the one place of the program that differentiates the
        kinematics (at the start too when the scales are pending: they come from this Jacobian)."""
        z, scale, first, _ = args
        pb = scaled_by(scale)
        # computed once, not once per use (the linear solve needs it written out anyway)
        r, Jx = computed_once(value_and_jacfwd(pb.problem.residual, pb.x(z), pb.problem.q), jnp.sum(z))
        return jacobians_from(z, scale, first, r, Jx)

    def jacobians_given(args):
        """:func:`jacobians_from` at the start from the given start Jacobian
        (:attr:`ScaledProblem.start_jacobian_given`): no kinematics differentiated."""
        z, scale, first, r = args
        return jacobians_from(z, scale, first, r, problem.start_jacobian)

    def cond(c):
        k, done, result = c[3], c[-6], c[-5]
        return (~done) & (result == optx.RESULTS.successful) & (k < max_steps)

    def body(c):
        z, z_eval, first, k, f_info, s_state, d_state, _, _, hist, data, data_start, scale = c
        pb = scaled_by(scale)
        # the candidate's residual (the start's at the first step: z_eval = 0)
        rd_eval = pb.problem.residual(pb.x(z_eval))
        r_eval = rd_eval if plain else pb.objective_from_residual(z_eval, rd_eval)
        # the search reads only the loss at the candidate (and the accepted point's Jacobian)
        probe = optx.FunctionInfo.ResidualJac(r_eval, f_info.jac)
        step_size, accept, search_result, s_state = search.step(first, z, z_eval, f_info, probe, s_state)
        terminate = accept & optx_cauchy_termination(
            solver.rtol, solver.atol, solver.norm, z_eval, z_eval - z, r_eval, r_eval - f_info.residual
        )
        # the final point's Jacobian only when the caller keeps it
        need_jac = accept & ~first if keep else accept & ~terminate & ~first
        if pending:  # the start's Jacobian (for the scales) even where the start is already final
            need_jac = need_jac | first

        def previous(a):
            return (f_info.jac.matrix if pending else jnp.where(first, J0, f_info.jac.matrix),
                    data[1] if pending or not carry_data else jnp.where(first, Jd0, data[1]), a[1])

        args = (z_eval, scale, first, rd_eval)
        if given is None:
            J_eval, jd_eval, scale = jax.lax.cond(need_jac, jacobians_at, previous, args)
        else:  # a start Jacobian passed at run time: taken at the first step where it is given
            branch = jnp.where(first & given, 2, jnp.where(need_jac, 0, 1))
            J_eval, jd_eval, scale = jax.lax.switch(branch, (jacobians_at, previous, jacobians_given), args)
        eval_info = optx.FunctionInfo.ResidualJac(r_eval, lx.MatrixLinearOperator(J_eval))
        d_state = jax.lax.cond(accept, lambda d: descent.query(z_eval, eval_info, d), lambda d: d, d_state)
        z_acc = jnp.where(accept, z_eval, z)
        f_info = jax.tree.map(lambda a, b: jnp.where(accept, a, b), eval_info, f_info)
        if carry_data:
            data = jax.tree.map(lambda a, b: jnp.where(accept, a, b), (rd_eval, jd_eval), data)
        if keep:  # the start's data residual, returned where a non-finite point is dropped
            data_start = jnp.where(first, rd_eval, data_start)
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
        rmse = _rmse_from_residual(scaled_by(scale), z_acc, f_info.residual)
        hist = hist.at[k + 1].set(rmse)
        hist = jnp.where(first, hist.at[0].set(rmse), hist)  # the first step accepts the start (z = 0)
        return (z_acc, z_next, jnp.asarray(False), k + 1, f_info, s_state, d_state, terminate, result,
                hist, data, data_start, scale)

    data0 = (jnp.zeros(n_data, problem.dtype), jnp.zeros((n_data, problem.n_free), problem.dtype)) if carry_data \
        else ((), ())
    carry0 = (z0, z0, jnp.asarray(True), jnp.asarray(0), f_info0, search_state0, descent_state0,
              jnp.asarray(False), optx.RESULTS.successful, hist0, data0,
              jnp.zeros(n_data, problem.dtype) if keep else (), problem.scale)
    z, _, _, k, f_info, s_state, _, done, result, hist, data, data_start, scale = jax.lax.while_loop(cond, body,
                                                                                                     carry0)
    rmse0 = hist[0]
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
    z_finite = jnp.all(jnp.isfinite(z))
    z = jnp.where(z_finite, z, z0)
    data_residual = data_jacobian = None
    if keep:
        # at the returned z; a dropped non-finite point returns the start (a diverged solve's
        # covariance is not reported, but it must be a matrix of numbers)
        r, J = data if carry_data else (f_info.residual, f_info.jac.matrix)
        data_residual = jnp.where(z_finite, r, data_start)
        data_jacobian = jnp.where(z_finite, J, 0.0 if Jd0 is None else Jd0)
    return RawRun(z, hist, k, status, data_residual=data_residual, data_jacobian=data_jacobian,
                  scale=scale if pending else None, trust_radius=None if radius is None else s_state.step_size)
