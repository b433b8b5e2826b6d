"""What a calibration's result reports besides its parameters: the uncertainty and the
plausibility / conditioning / coverage / outlier findings (:class:`~jaxcal.Diagnostics`), and
the warnings that name outlier rows."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from .._fit._diagnostics import (
    Checks,
    Diagnostics,
    coverage,
    flagged_rows,
    given_noise_std,
    implausible_deviations,
    narrow_joints,
    parameter_uncertainty,
    prior_directions,
    result_findings,
    scan_outliers,
    weak_parameters,
)
from .._fit._identifiability import STILL_JOINT_DEG
from .._fit._objective import robust_scale
from .._fit._problem import Problem, observed_entries
from .._fit._result import CalibrationResult, Status
from .._fit._verdicts import fit_verdicts, fixable_text

__all__ = ["outlier_warnings", "diagnose"]

def outlier_warnings(result) -> tuple[str, ...]:
    """The warnings of ``result`` (its ``diagnostics.warnings``) that name outlier rows: one per
    scan that flagged any (:class:`OutlierWarning`), rows as positions in the training data (a
    block's own rows in a combined fit)."""
    diag = getattr(result, "diagnostics", None)
    if diag is None:
        return ()
    hint = ("" if result.loss != "linear" else
            "; a robust loss (--loss huber; loss \"huber\" in Python) guards against them")
    return tuple(sc.message("training data" if sc.block is None else f"block {sc.block!r}",
                            action="check those rows, or leave them out and fit again" + hint)
                 for sc in diag.outlier_scans if sc.rows)



def _prior_terms(prior, space):
    """``(1/s [p], information [p, p] or None)`` of ``prior`` over ``space`` (``(None, None)``
    without one): what :func:`~jaxcal._fit._diagnostics.parameter_uncertainty` weighs it by."""
    if prior is None:
        return None, None
    s = prior.std(space)
    return np.where(np.isfinite(s), 1.0 / s, 0.0), prior.information(space)



def _given_noise(data, prior, measurement, sensor_noise_std):
    """The sensor's given noise σ for the result's checks: the prior's or the data's
    (:func:`given_noise_std`), else ``sensor_noise_std``."""
    given = given_noise_std(data, prior, measurement)
    return given if given is not None else sensor_noise_std


def _still_message(result: CalibrationResult) -> str:
    """What the report says about near-still joints (:func:`~jaxcal._fit._identifiability.still_joints`):
    the parameters only their motion would show, held at their start values."""
    report = result.identifiability
    if report is None or not report.still_unseen:
        return ""
    joints = ", ".join(f"q{j}" for j in report.still_joints)
    n = len(report.still_unseen)
    return (f"joint(s) {joints} barely move in the data (span < {STILL_JOINT_DEG:g}°): {', '.join(report.still_unseen)} "
            f"would be seen only through that motion and {'are' if n > 1 else 'is'} held at {'their' if n > 1 else 'its'} "
            f"start value{'s' if n > 1 else ''}, with or without a prior — move the joint(s) to calibrate "
            f"{'them' if n > 1 else 'it'}")


def diagnose(result: CalibrationResult, problem: Problem, before_rows, checks: Checks, extras_msg, rounds,
             gram=None, cov=None, reselection=(), noise_std=None, resid_start=None):
    """Uncertainty and the plausibility / conditioning / coverage / outlier findings (``gram``,
    ``cov``: :func:`gram_at` and :func:`coverage` when the caller has them; ``noise_std``: the
    sensor's given noise, :func:`given_noise_std`; ``resid_start``: the residual blocks at the
    last round's start), and the checks of the result as a whole (:func:`result_findings`):
    ``(Diagnostics, Uncertainty or None)``."""
    x = np.asarray(result.x, np.float64)
    msgs = []
    unc, cond, resid = _uncertainty(result, problem, x, gram, msgs)
    bad = _fit_messages(result, cond, checks, msgs)
    cov = coverage(result.robot, problem.q) if cov is None else cov
    narrow, weak, verdicts, directions = _coverage_messages(result, unc, cov, checks, msgs)
    scans = scan_outliers(problem, x, checks, residuals=resid)  # each file's (block's) rows in their own σ̂
    after_rows = flagged_rows(scans)
    msgs += outlier_warnings(SimpleNamespace(loss=result.loss, diagnostics=SimpleNamespace(outlier_scans=scans)))
    s_after = scans[0].scale if len(scans) == 1 else robust_scale(observed_entries(problem, resid)) \
        if resid is not None else math.nan
    suspect, cause = result_findings(result, problem, unc, resid, resid_start, checks,
                                     extras_started=extras_msg is not None, noise_std=noise_std)
    if suspect:
        msgs.append("the result fails its checks: " + "; ".join(suspect) + (f" — likely cause: {cause}" if cause else ""))
    diag = Diagnostics(tuple(msgs), bad, cond, cov, narrow, weak, tuple(int(r) for r in before_rows),
                       tuple(int(r) for r in after_rows), s_after, extras_msg, rounds, tuple(reselection), directions,
                       suspect, cause, verdicts=verdicts, outlier_scans=scans)
    return diag, unc


def _uncertainty(result: CalibrationResult, problem: Problem, x, gram, msgs: list):
    """``(Uncertainty or None, condition number, residual)`` at the solution ``x`` (a message in
    ``msgs`` where it cannot be computed)."""
    try:
        inv, info = _prior_terms(result.prior, result.space)  # info: a full prior covariance
        return parameter_uncertainty(problem, x, prior_inv_std=inv, prior_information=info, loss=result.loss,
                                     loss_scale=result.loss_scale_mm or 1.0, return_residuals=True, gram=gram)
    except (np.linalg.LinAlgError, ValueError) as e:  # pragma: no cover - defensive
        msgs.append(f"uncertainty could not be computed: {e}")
        return None, float("inf"), None


def _fit_messages(result: CalibrationResult, cond: float, checks: Checks, msgs: list):
    """The solve's status, implausible parameters and conditioning, as messages in ``msgs``: the
    implausible deviations (:func:`implausible_deviations`)."""
    space = result.space
    if result.status == Status.MAX_STEPS:
        msgs.append(f"{result.method}: step budget exhausted before the stopping tolerance was met — the fit may "
                    "not be finished (raise max_steps, or check the start and the data)")
    if result.status == Status.STILL_IMPROVING:
        msgs.append(result.message)
    flat = np.asarray(result.deviations._ravel_numpy(), np.float64)
    bad = implausible_deviations(space.names, space.units, flat, checks)
    if bad:
        listed = ", ".join(f"Δ{n} = {v:+.4g} {'°' if u == 'deg' else 'mm'}" for n, v, u in bad[:8])
        hint = "" if result.prior is not None else "; a prior toward nominal (--prior default; prior \"default\" in Python) usually fixes this"
        msgs.append(f"implausible parameters (beyond ±{checks.angle_deg:g}° / ±{checks.length_mm:g} mm): {listed}"
                    f"{' …' if len(bad) > 8 else ''} — the model may fit the measured region and be wrong "
                    f"elsewhere{hint}")
    # under a prior the data Jacobian of the free set is rank deficient by design (the prior sets the
    # directions the data cannot see); those directions are reported by name below instead
    if cond > checks.condition_number and result.prior is None:
        msgs.append(f"condition number {cond:.3g} of the identification Jacobian exceeds {checks.condition_number:.3g}: "
                    "some parameter combinations are weakly determined by these poses")
    return bad


def _coverage_messages(result: CalibrationResult, unc, cov, checks: Checks, msgs: list):
    """Joint coverage, weakly determined parameters and still joints, as messages in ``msgs``:
    ``(narrow joints, weak parameters, verdicts, prior directions)``."""
    space = result.space
    prior_std = result.prior.std(space) if result.prior is not None else None
    narrow = narrow_joints(result.robot, cov, checks)
    unit = dict(zip(range(1, result.robot.dof + 1), ("°" if u == "rad" else " mm" for u in result.robot.joint_units())))
    # one verdict per parameter (data / prior / not calibrated) for every output of the result
    verdicts = None if unc is None else fit_verdicts(space, unc, result.prior, result.identifiability,
                                                     checks.prior_share)
    n_dir, directions = (0, ()) if unc is None or prior_std is None else prior_directions(unc, prior_std, checks)
    if prior_std is not None:
        # a warning only for what the user can change (poses): what the sensor cannot see by
        # construction is said once in the normal output (the identifiability lines)
        weak = () if verdicts is None else verdicts.by_prior
        weak_text = fixable_text(verdicts)
    else:
        weak = weak_parameters(unc, checks) if unc is not None else ()
        weak_text = f"weakly determined by the data: {', '.join(weak)}" if weak else ""
    if narrow:
        moved = ", ".join(f"q{j} {cov[j - 1, 0]:.1f}{unit[j]}" for j in narrow)
        prismatic = any(unit[j] == " mm" for j in narrow)
        msgs.append(f"narrow joint coverage: {moved} of motion (< {checks.narrow_joint_deg:g}°"
                    + (f", or {checks.narrow_joint_deg / 360:.3g} of a prismatic joint's range)" if prismatic else ")")
                    + (f"; {weak_text}" if weak_text else ""))
    elif weak_text:
        msgs.append(weak_text)
    still = _still_message(result)
    if still:
        msgs.append(still)
    return narrow, weak, verdicts, directions
