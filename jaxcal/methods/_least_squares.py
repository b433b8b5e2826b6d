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

from ._base import Method, RawRun, ScaledProblem, register_method

__all__ = ["LevenbergMarquardt", "GaussNewton", "residual_with_jacfwd"]

#: the linear solvers of the damped step (:func:`~jaxcal.methods._optimistix.make_linear_solver`)
LINEAR_SOLVERS = ("cholesky", "qr")


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
    #: the optimistix solver class by name (``"LevenbergMarquardt"`` or ``"GaussNewton"``; looked up
    #: in optimistix when a solve is traced)
    solver_name: ClassVar[str] = "LevenbergMarquardt"

    def __check_init__(self):
        if self.linear_solver not in LINEAR_SOLVERS:
            raise ValueError(f"linear_solver must be 'cholesky' or 'qr', got {self.linear_solver!r}")
        if self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps}")
        if not (self.rtol >= 0 and self.atol >= 0 and self.rtol + self.atol > 0):
            raise ValueError(f"rtol and atol must be >= 0 and not both 0, got {self.rtol}, {self.atol}")

    @property
    def max_iterations(self) -> int:
        return self.max_steps

    def solver(self, dtype=None):
        """The optimistix solver (tolerances raised to ``FLOAT32_TOL`` for a float32 ``dtype``)."""
        import optimistix as optx

        from ._optimistix import RoundoffAwareTrustRegion, make_linear_solver

        rtol, atol = self.rtol, self.atol
        if dtype is not None and jnp.finfo(dtype).bits < 64:
            rtol, atol = max(rtol, FLOAT32_TOL), max(atol, FLOAT32_TOL)
        cls = getattr(optx, type(self).solver_name)
        solver = cls(rtol, atol, linear_solver=make_linear_solver(self.linear_solver))
        if isinstance(solver.search, optx.ClassicalTrustRegion):  # LM
            solver = eqx.tree_at(lambda s: s.search, solver, RoundoffAwareTrustRegion())
        return solver

    scales_itself: ClassVar[bool] = True

    def run(self, problem: ScaledProblem, key) -> RawRun:
        from ._optimistix import optimistix_run

        del key  # deterministic
        return optimistix_run(self.solver(problem.dtype), problem, self.max_steps)


@register_method("lm")
class LevenbergMarquardt(_OptimistixMethod):
    """Levenberg–Marquardt (``optimistix.LevenbergMarquardt``), the paper's M4 (Marquardt, 1963).

    Defaults: ``rtol = atol = 1e-5``, ``max_steps = 100``, ``linear_solver = "cholesky"``
    (see :class:`_OptimistixMethod`).
    """

    name: ClassVar[str] = "lm"
    solver_name: ClassVar[str] = "LevenbergMarquardt"
    maskable: ClassVar[bool] = True
    trust_region: ClassVar[bool] = True


@register_method("gn")
class GaussNewton(_OptimistixMethod):
    """Gauss–Newton (``optimistix.GaussNewton``): LM without damping; fast when the start is
    close and the parameter set identifiable, no safeguard otherwise. Same settings as LM."""

    name: ClassVar[str] = "gn"
    solver_name: ClassVar[str] = "GaussNewton"
