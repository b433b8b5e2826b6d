"""The rounds of one selection's solves: the robust loss scale and the prior's noise σ
re-estimated from each fit, the prior's scale chosen by the evidence, a σ per residual
component (reweighting), until they settle (:class:`Rounds`); and what one solve asks for
(:class:`Solves`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Generator

import equinox as eqx
import numpy as np

from .._core._params import Deviations, ParameterSpace
from .._fit._diagnostics import Checks, coverage, flagged_rows, parameter_uncertainty, scan_outliers
from .._fit._evidence import choose_prior
from .._fit._identifiability import start_jacobian
from .._fit._objective import LOSSES, Objective, robust_scale
from .._fit._problem import Problem, observed_entries, residual_blocks_numpy, signed_residuals
from .._fit._result import Status
from ._calibrator import CalibrationOutput, Calibrator
from ._diagnose import _prior_terms
from ._programs import _Launched, _mask_output, _program_columns, _solve_space
from ._variance import block_sigmas

__all__ = ["Solves", "Rounds", "MAX_EVIDENCE_ROUNDS"]


def _close(a, b, rtol: float = 0.05) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return bool(np.all(np.abs(np.subtract(a, b)) <= rtol * np.abs(b)))


#: at most this many solves per selection while the evidence chooses the prior's scale (each
#: warm-started; the scales settle within 5 % in 2–4 on the benchmarks' data)
MAX_EVIDENCE_ROUNDS = 8


def _settled(chosen, used, rtol: float = 0.05) -> bool:
    """Whether the evidence's new choice ``chosen`` is the prior ``used`` by the last solve, its
    factors within ``rtol`` (both ``None``: no evidence, nothing to settle)."""
    a, b = (None if p is None or p.evidence is None else dict(zip(p.evidence.families, p.evidence.factors))
            for p in (chosen, used))
    if a is None or b is None:
        return a is None and b is None
    return a.keys() == b.keys() and all(abs(a[f] - b[f]) <= rtol * b[f] for f in a)


def _with_rounds(prior, rounds: int):
    """``prior`` with the fit's solve count on its evidence record (as it is without one)."""
    if prior is None or prior.evidence is None:
        return prior
    return dataclasses.replace(prior, evidence=dataclasses.replace(prior.evidence, rounds=rounds))


def _reweighted(problem: Problem, out: CalibrationOutput, prior, loss: str, scale, cur: Deviations):
    """``problem``'s measurement reweighted by the σ̂ of its residual components at the solve
    ``out`` (at the deviations ``cur``; variance components:
    :attr:`~jaxcal._fit._diagnostics.Uncertainty.component_std`), or as it is where they cannot be
    estimated. Several blocks' data stacked (:class:`~jaxcal.Combined`): a σ per block
    (:func:`~jaxcal._calibration._variance.block_sigmas`)."""
    m = problem.measurement
    if m.stacked_data:
        return m.with_sigma(block_sigmas(problem.robot, m, problem.space, cur, prior, problem.q, problem.y))
    inv, info = _prior_terms(prior, problem.space)
    unc, _ = parameter_uncertainty(problem, np.asarray(out.x, np.float64), prior_inv_std=inv, prior_information=info,
                                   loss=loss, loss_scale=scale or 1.0, gram=out.gram)
    if unc.component_std is None:
        return m
    return m.reweighted([unc.component_std[c[0]] for c in m.components])



@dataclasses.dataclass(frozen=True, eq=False)
class Solves:
    """What every solve of one calibration shares: the robot, method, data, key, loss and whether
    the masked solves carry a start Jacobian with a run-time flag (``carry_jac``)."""

    robot: object
    meth: object
    q: object
    y: object
    key: object
    loss: str
    plain: bool  # plain least squares: no scale to estimate, no Objective
    carry_jac: bool

    def request(self, measurement, prior, cur, prog, mask, noise, scale, free, start_jacobian, radius=None):
        """The solve of one round: ``(Calibrator, q, y, key)``. ``radius``: the trust region's step
        size to start from (a trust-region method: the last round's; ``None``: optimistix's 1)."""
        objective = None if self.plain else Objective.build(prog, prior, noise, self.loss, scale, self.q.dtype,
                                                            free=free)
        flag = np.bool_(start_jacobian is not None) if self.carry_jac else None
        # a trust-region method always gets its step size as run-time data: one program for every round
        radius = (np.asarray(1.0 if radius is None else radius, self.q.dtype) if self.meth.trust_region else None)
        return Calibrator(self.robot, measurement, self.meth, cur, prog,
                          None if objective is None or objective.plain_least_squares else objective, report=True,
                          start_jacobian=start_jacobian, free=mask, start_jacobian_given=flag,
                          trust_radius=radius), self.q, self.y, self.key


@dataclasses.dataclass(eq=False)
class Rounds:
    """The solves of one calibration, round after round (:meth:`selection`), and what they carry
    from one to the next: the deviations reached (``cur``), the noise σ and loss scale of the last
    solve, the prior (the evidence's choice), the measurement model (reweighted), the histories.

    ``adaptive``: the scales (or the prior's, or the weights) are re-estimated from each fit;
    ``first_round_jac``: a selection's first solve takes ``start_jac`` (the identifiability
    program's Jacobian); ``dims``: a robust loss's threshold in units of a clean sample's RMS
    error; ``n_res``: the data's observed residuals; ``x0``: the start (outliers before the fit)."""

    solves: Solves
    prior: object  # the prior as given (resolved)
    loss_scale: float | None
    checks: Checks
    adaptive: bool
    evidence: bool
    reweight: bool
    first_round_jac: bool
    prog_space: ParameterSpace | None
    dims: float
    n_res: int
    x0: np.ndarray
    measurement: object
    problem: Problem
    space: ParameterSpace
    cur: Deviations
    resid_start: object
    start_jac: object
    round_prior: object  # the prior of the next solve
    ev_prior: object = None  # the evidence's choice and the σ of its maximum
    ev_noise: object = None
    noise: object = None
    scale: object = None
    moved: bool = False  # the last reweighting moved the component weights
    rounds: int = 0
    compile_s: float = 0.0
    run_s: float = 0.0
    histories: list = dataclasses.field(default_factory=list)
    before_rows: object = None
    cov: object = None
    out: CalibrationOutput | None = None

    def selection(self) -> Generator[tuple, _Launched, None]:
        """The rounds of the current free set ``space``: yields each solve (``(Calibrator, q, y,
        key)``), is sent it started, until the scales settle, a solve fails or the round budget ends."""
        first = self.rounds
        prog, columns, mask = _solve_space(self.prog_space, self.space, self.solves.q.dtype)
        while True:  # rounds of re-estimated scales
            new_noise, new_scale = self._scales(first)
            if self.rounds > first and self._done(first, new_noise, new_scale):
                break
            self.noise, self.scale = new_noise, new_scale
            self.round_prior = self.round_prior if self.ev_prior is None else self.ev_prior
            jac = self.start_jac if self.first_round_jac and self.rounds == first else None
            # a later round starts near its solution: the trust region as the last solve left it
            radius = None if self.out is None else self.out.trust_radius
            launched = yield self.solves.request(self.measurement, self.round_prior, self.cur, prog, mask, self.noise,
                                                 self.scale, self.space, jac, radius)
            out = self._take(launched, columns)
            if int(out.status) in (Status.DIVERGED, Status.FAILED) or not self.adaptive:
                break
            self._update(out)

    def _scales(self, first: int):
        """``(noise σ, loss scale)`` of the next solve, re-estimated from the residual of the last."""
        if self.solves.plain:
            return None, None
        prior, loss, loss_scale = self.prior, self.solves.loss, self.loss_scale
        resid = self.resid_start if self.rounds == first else signed_residuals(self.problem, self.space.to_vector(self.cur))
        s_hat = robust_scale(observed_entries(self.problem, resid))  # masked readings left out
        s_hat = s_hat if (s_hat > 0 and np.isfinite(s_hat)) else 1.0
        new_noise = prior.noise_std if prior is not None and prior.noise_std is not None else s_hat
        if self.ev_prior is not None and prior.noise_std is None:  # the σ of the evidence's maximum
            new_noise = self.ev_noise
        new_scale = (loss_scale if loss_scale is not None else LOSSES[loss] * self.dims * s_hat
                     if loss != "linear" else None)
        return new_noise, new_scale

    def _done(self, first: int, new_noise, new_scale) -> bool:
        """Whether a selection's rounds end before the next solve: nothing adapts, or everything
        settled, or the round budget is spent."""
        return (not self.adaptive or (_close(new_noise, self.noise) and _close(new_scale, self.scale) and not self.moved
                                      and _settled(self.ev_prior, self.round_prior))
                or self.rounds - first >= (self.measurement.weight_rounds if self.reweight else
                                           MAX_EVIDENCE_ROUNDS if self.evidence else 4))

    def _take(self, launched: _Launched, columns) -> CalibrationOutput:
        """Wait for a started solve (doing the host work that does not need it meanwhile) and
        record its output."""
        out, c_s = launched.out, launched.compile_s
        if self.before_rows is None:  # host work that does not need the fit, while the device runs it
            self.before_rows = flagged_rows(scan_outliers(self.problem, self.x0, self.checks,
                                                          residuals=self.resid_start))
            self.cov = coverage(self.solves.robot, self.solves.q)
        out, r_s = launched.wait()
        if columns is not None:
            out = _mask_output(out, columns)
        self.compile_s, self.run_s, self.rounds = self.compile_s + c_s, self.run_s + r_s, self.rounds + 1
        self.cur = out.deviations  # space.from_vector(out.x, cur), made in the compiled program
        self.histories.append(np.asarray(out.history)[: int(out.n_iterations) + 1])
        self.out = out
        return out

    def _update(self, out: CalibrationOutput) -> None:
        """Between two rounds: the evidence's prior and the reweighted model at the solution ``out``."""
        if self.evidence:  # the scales the evidence chooses at this solution (host, p×p matrices)
            self.ev_prior, self.ev_noise = choose_prior(self.round_prior, self.space, out.gram, out.x, self.n_res,
                                                        rounds=self.rounds, noise_used=self.prior.noise_std or self.noise,
                                                        unit=getattr(self.measurement, "unit", "mm"))
        if self.reweight:  # a σ per residual component (a pose's position, orientation): refit whitened
            new_m = _reweighted(self.problem, out, self.round_prior, self.solves.loss, self.scale, self.cur)
            self.moved = not _close(new_m.component_scales(), self.measurement.component_scales(),
                                    self.measurement.weights_rtol)
            self.measurement = new_m
            self.problem = eqx.tree_at(lambda pr: pr.measurement, self.problem, new_m)

    def restart(self, space: ParameterSpace, cand: ParameterSpace) -> None:
        """The next selection: the free set ``space`` (re-selected), from the deviations reached,
        with its start residual (and Jacobian, where the solves carry one: the identifiability
        program's, compiled already; ``cand``: the candidates it is computed for)."""
        s, robot, q, y = self.solves, self.solves.robot, self.solves.q, self.solves.y
        self.space = space
        self.problem = Problem(robot, self.measurement, q, y, space, self.cur)
        if s.carry_jac:  # the refit's start Jacobian from the identifiability program (compiled already)
            resid_start, start_jac = start_jacobian(robot, self.measurement, q, cand, self.cur, y)
            self.resid_start = residual_blocks_numpy(self.problem, resid_start)
            self.start_jac = _program_columns(start_jac, cand, self.prog_space)
        else:
            self.start_jac = None
            self.resid_start = signed_residuals(self.problem, space.to_vector_numpy(self.cur))

    def history(self) -> tuple[np.ndarray, int]:
        """``(history, iterations)``: one history across the rounds (each round restarts where the
        last ended; the objective's scales change between rounds, so the curve may step at the
        boundaries), padded to the budget of every round."""
        h = self.histories
        history = np.concatenate([h[0]] + [x[1:] for x in h[1:]])
        n_it = history.shape[0] - 1
        budget = self.solves.meth.max_iterations * self.rounds
        return np.concatenate([history, np.full(budget - n_it, history[-1])]), n_it
