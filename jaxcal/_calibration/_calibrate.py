"""One entry point for every method: :func:`calibrate`, and the generator of its solves
(:func:`_calibration_steps`) that :func:`calibrate` and :func:`jaxcal.calibrate_many` drive.

The parts live in modules of their own: the pure core :class:`Calibrator`
(:mod:`._calibrator`), which parameters are freed (:mod:`._selection`), the rounds of
re-estimated scales (:mod:`._rounds`), the compiled solves (:mod:`._programs`) and what the
result reports (:mod:`._diagnose`)."""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from collections.abc import Generator

import numpy as np
from jaxtyping import Array

from .._core._cache import ensure_compilation_cache
from .._core._metrics import Metrics
from .._core._params import Deviations, ParameterSpace, layout_for
from .._core._precision import to_device, warn_if_float32
from .._datasets._dataset import Dataset, mm_joints_metadata
from .._datasets._split import key_numpy
from .._fit._diagnostics import Checks, error_dims
from .._fit._objective import LOSSES, Prior, resolve_objective, resolve_prior
from .._fit._problem import Problem, residual_blocks_numpy, signed_residuals
from .._fit._result import CalibrationResult, Status, iterations_to_converge_numpy
from .._models._abstract import AbstractRobot
from .._sensors._initial_extras import initial_extras
from .._sensors._measurement import MeasurementModel
from ..methods import make_method
from ._calibrator import CalibrationOutput, Calibrator
from ._diagnose import _given_noise, diagnose, outlier_warnings
from ._programs import _compile_ahead, _launch, _Launched, _masked, _program_columns, _program_space, _solve_space
from ._rounds import Rounds, Solves, _with_rounds
from ._selection import (
    MAX_RESELECTIONS,
    _check_enough_residuals,
    _default_selection,
    _resolve_candidates,
    candidate_space,
    extras_flags,
    extras_to_start,
    reselect,
    resolve_space,
)

__all__ = ["calibrate", "Calibrator", "CalibrationOutput", "CalibrationWarning", "OutlierWarning", "CalibrationError",
           "resolve_space", "extras_flags", "outlier_warnings"]


class CalibrationWarning(RuntimeWarning):
    """A calibration diverged or failed (the result's ``status`` says how)."""


class StatedNoiseWarning(CalibrationWarning):
    """A block of a combined fit whose residual σ̂ is at least :attr:`~jaxcal.Checks.noise_warn_factor`
    times the noise its data file states (:meth:`~jaxcal.BlockStats.noise_warning`); the command
    line prints it naming the file instead."""


class OutlierWarning(CalibrationWarning):
    """Rows of the training data (of a block of a combined fit) whose residual is an outlier in
    their own robust σ̂ (:attr:`jaxcal.Diagnostics.outlier_scans`, at the false-alarm rate
    :attr:`~jaxcal.Checks.outlier_rate`); the command line prints them naming the file and its data
    rows instead."""



class CalibrationError(RuntimeError):
    """Raised instead of :class:`CalibrationWarning` with ``calibrate(..., throw=True)``."""



def _as_arrays(data, measurement: MeasurementModel, robot: AbstractRobot, stacklevel: int = 3):
    if measurement.stacked_data and isinstance(data, (tuple, list)) and len(data) == 2:
        # stacked blocks (jaxcal._sensors._blocks.combine validated each block's data): checked below
        q = to_device(data[0])
        y = to_device(data[1], q.dtype)
    elif isinstance(data, Dataset):
        if data.kind != measurement.kind:
            raise ValueError(f"data are {data.kind!r} measurements but the measurement model is {measurement.kind!r}")
        q, y = data.q, data.y
    elif isinstance(data, (tuple, list)) and len(data) == 2:
        q, y = data
        # host arrays by jax.device_put (jnp.asarray compiles a small program per shape)
        q = to_device(q)
        y = to_device(y, q.dtype)
        Dataset(q, y, measurement.kind, mm_joints_metadata(robot))  # validates shapes, NaN/inf, degrees
    else:
        raise TypeError("data must be a jaxcal.Dataset or a (q, y) pair of arrays")
    if q.shape[1] != robot.dof:
        raise ValueError(f"data have {q.shape[1]} joint angles per sample but robot {robot.name!r} has {robot.dof} joints")
    measurement.check_measurements(y, q.shape[0])
    qn = np.asarray(q)
    lo, hi = np.asarray(robot.q_min), np.asarray(robot.q_max)
    outside = (qn < lo - 1e-6) | (qn > hi + 1e-6)
    if outside.any():
        joints = sorted({int(j) + 1 for j in np.nonzero(outside)[1]})
        warnings.warn(
            f"{int(outside.any(axis=1).sum())} sample(s) have joint angles outside robot {robot.name!r}'s limits "
            f"(joints {joints}); check the units (radians expected) and the robot model",
            UserWarning,
            stacklevel=stacklevel,
        )
    return q, y



def calibrate(
    robot: AbstractRobot,
    measurement: MeasurementModel,
    data,
    method="lm",
    *,
    key: Array | None = None,
    space: ParameterSpace | str | None = None,
    start: Deviations | None = None,
    extras=(),
    free=None,
    fix=(),
    init: str = "auto",
    prior: Prior | str | None = None,
    loss: str | None = None,
    objective: str | None = None,
    loss_scale: float | None = None,
    checks: Checks | None = None,
    throw: bool = False,
    **hyperparameters,
) -> CalibrationResult:
    """Calibrate ``robot`` from measured ``data`` with one of the registered methods.

    Example:
        A tracker's data file to a calibrated robot (what ``jaxcal calibrate tracker.csv --robot
        hsr_jr680 --measurement position --estimate base,tool`` does, less its test split):

        ```python
        import jaxcal

        jaxcal.enable_x64()                                   # float64 (see the concepts page)
        robot = jaxcal.robots.hsr_jr680()                     # or jaxcal.load_urdf(...)
        data = jaxcal.load_csv("tracker.csv")                 # joint angles + x_mm, y_mm, z_mm
        setup = jaxcal.measurement_for(data, robot, estimate="base,tool")
        res = jaxcal.calibrate(robot, setup.measurement, data, "lm", extras=setup.extras,
                               objective="measured")          # the defaults for measured data
        print(res, res.dh_table())                            # status, RMSE (mm), calibrated DH table
        ```

    Args:
        robot: nominal robot model: a DH table (:class:`DHRobot`, e.g. a preset of
            ``jaxcal.robots``), a URDF chain (:class:`SerialChain`, :func:`jaxcal.load_urdf`) or a
            kinematic tree (:class:`KinematicTree`).
        measurement: the measurement model the data come from (e.g. :class:`CableLength`); its
            anchor / sensor frame is the nominal guess the extras correct.
        data: training data, a :class:`Dataset` or a ``(q [n, dof] rad, y)`` pair; ``y`` in the
            measurement's units: wire lengths ``[n]`` mm (cable), tool positions ``[n, 3]`` mm,
            poses ``[n, 4, 4]`` (mm, rotation), marker positions ``[n, N, 3]`` mm, image points
            ``[n, N, 2]`` px (:class:`Dataset` lists every kind).
        method: a registry name (``"lm"``, ``"gn"``, ``"adam"``, ``"adamw"``, ``"adamod"``,
            ``"adamodw"``, and the baselines), a :class:`~jaxcal.methods.Method`, or any
            ``optax.GradientTransformation`` (run full batch; pass ``steps=``).
        key: ``jax.random`` key for the method's randomness (default ``jax.random.key(0)``).
        space: free parameters; default (see :func:`resolve_space`): without a prior the
            identifiable subset of the DH deviations and the ``extras``; with a ``prior`` every
            candidate it covers and the data-identifiable extras (maximum a posteriori); after
            the fit, identifiability is judged again with the extras where it put them, and
            parameters that became identifiable are freed and refit (``diagnostics.reselection``).
        start: starting deviations (default: nominal, with the extras initialised from the
            data, see ``init``); entries that are not free keep these.
        extras: sensor/setup unknowns to estimate with the robot: ``"anchor"``,
            ``"cable_offset"`` (draw-wire), ``"tool"`` (tool point), ``"base"`` (position/pose
            sensor frame, 6 parameters), as a list or a comma-separated string.
        free: the candidate parameters, by group (``"dh"``, ``"alpha"``, ``"a"``, ``"d"``,
            ``"theta"``, ``"beta"``, ``"anchor"``, ``"cable_offset"``, ``"tool"``, ``"base"``,
            ``"extras"``; a generic chain's ``"tip"`` = ``tip_translation`` + ``tip_rotation``, or
            any group of its layout) or by name (``"d_6"``, ``"tip_dx"``), as a list or a
            comma-separated string. They replace the default DH candidates (all DH deviations);
            the ``extras`` stay, and extras named here are estimated too
            (``free="anchor,cable_offset"`` fits the sensor with the DH table fixed). ``None``
            (default): the default candidates. The identifiable subset of the candidates is then
            freed (``space`` default).
        fix: groups or names, as for ``free``, removed from the candidates. Default: none.
        init: ``"auto"`` (default): when anchor, cable offset, tool point or base frame are
            estimated, start them from the data in closed form (:func:`jaxcal.initial_extras`:
            multilateration, Kabsch, the tool point jointly with the frame or anchor, on the
            nominal robot) — a guess far off is fine;
            ``"none"``: start from ``start`` as given.
        prior: Gaussian priors toward nominal (maximum a posteriori): ``None`` (default: none,
            unless ``objective`` gives one), ``"none"``, ``"default"`` (0.5°, 2 mm on the DH deviations, none on extras), a
            :class:`jaxcal.Prior`, or a ``"key=value,..."`` string. The prior's noise σ is
            estimated from the fit unless given (see ``Prior.noise_std``). ``"evidence"``: the
            default prior with its scale — one σ on the angles, one on the lengths — chosen by the
            data (type-II maximum likelihood: :mod:`jaxcal._fit._evidence`), alternating with the
            MAP solve in the rounds (the same compiled program); a :class:`jaxcal.Prior` with
            ``scale_by="evidence"`` (a learned prior: one factor on its covariance) likewise. The
            result's ``prior`` then has the chosen σ and the choice (``prior.evidence``).
        loss: ``"linear"`` (least squares; the default unless ``objective`` gives another),
            ``"huber"`` or ``"cauchy"`` (robust against gross outliers: a residual's weight falls
            beyond the scale ``loss_scale``).
        objective: a named preset of ``prior`` and ``loss`` filling in those not given:
            ``"measured"`` = :data:`jaxcal.MEASURED_DEFAULTS` (the default prior + the Huber
            loss: the defaults for measured data, used by the CLI, :func:`jaxcal.holdout_session`
            and :func:`jaxcal.leave_one_session_out`; evidence in
            ``benchmarks/results/measured_defaults_cpu.md``), ``"least_squares"``. Without it
            (``None``, the default) ``calibrate`` is plain least squares with no prior — the
            paper's experiment, on purpose; pass ``objective="measured"`` for real data.
        loss_scale: robust-loss scale ``c`` (mm); default ``k·√m_e·σ̂`` re-estimated from the fit (``k`` the
            loss's constant: 1.345 for Huber, 2.385 for Cauchy; ``m_e`` 1 for a length, 3 for a position
            or markers, 2 for image corners).
        checks: thresholds of the plausibility / conditioning / coverage / outlier checks
            (:class:`jaxcal.Checks`).
        throw: raise :class:`CalibrationError` on divergence/failure instead of warning.
        **hyperparameters: the method's settings (e.g. ``learning_rate=``, ``steps=``,
            ``batch_size=``, ``max_steps=``).

    Returns:
        :class:`CalibrationResult` with calibrated deviations, the per-iteration training
        objective history, iterations (and iterations to converge), status, run time excluding
        compilation, ``uncertainty`` (posterior σ of each free parameter) and ``diagnostics``
        (plausibility, conditioning, coverage, outliers; its warnings are also issued as
        :class:`CalibrationWarning`).
    """
    steps = _calibration_steps(robot, measurement, data, method, key=key, space=space, start=start, extras=extras,
                               free=free, fix=fix, init=init, prior=prior, loss=loss, objective=objective,
                               loss_scale=loss_scale, checks=checks, throw=throw, ahead=_compile_ahead,
                               share_start_jacobian=True,
                               **hyperparameters)
    launched = None
    while True:  # each request is one compiled solve (calibrate_many batches the requests of many units)
        try:
            cal, q, y, k = steps.send(launched)
        except StopIteration as done:
            return done.value
        launched = _Launched(*_launch(cal, q, y, k))



def _calibration_steps(
    robot: AbstractRobot,
    measurement: MeasurementModel,
    data,
    method="lm",
    *,
    key: Array | None = None,
    space: ParameterSpace | str | None = None,
    start: Deviations | None = None,
    extras=(),
    free=None,
    fix=(),
    init: str = "auto",
    prior: Prior | str | None = None,
    loss: str | None = None,
    objective: str | None = None,
    loss_scale: float | None = None,
    checks: Checks | None = None,
    throw: bool = False,
    sensor_noise_std: float | None = None,
    ahead=None,
    share_start_jacobian: bool = False,
    **hyperparameters,
) -> Generator[tuple, _Launched, CalibrationResult]:
    """:func:`calibrate` as a generator: it yields each solve it needs as ``(Calibrator, q, y, key)``
    and is sent back a :class:`_Launched` (the solve started; ``wait()`` gives its output), so that
    one driver runs one unit's solves one by one (:func:`calibrate`) and another runs the solves of
    many units as one vmapped program (:func:`jaxcal.calibrate_many`). Its warnings name the frame
    two levels above it (the caller of the driver). ``sensor_noise_std``: the sensor's noise σ (mm)
    that σ̂ is checked against when neither the prior nor the data's metadata give one
    (:func:`~jaxcal._fit._diagnostics.given_noise_std`; :func:`jaxcal.calibrate_many`'s ``noise_std``).
    ``ahead``: called with a summary of the set-up and a function giving ``(Calibrator, q, y,
    key)`` of the first solve as soon as its program is known (before the closed-form extras and
    the identifiability): :func:`calibrate` starts compiling it on a background thread
    (:func:`_compile_ahead`). ``share_start_jacobian``: the masked solves of a measurement whose
    Jacobian does not depend on the readings carry a start Jacobian with a run-time flag
    (``Calibrator.start_jacobian``/``start_jacobian_given``): the identifiability program's at the
    first round of a selection (a re-selection refit's from the same program; one Jacobian fewer in
    the solve), zeros standing in elsewhere — one compiled solve either way. :func:`calibrate`
    sets it; a batched driver does not (it would stack an ``[N, p]`` array per unit)."""
    ensure_compilation_cache()  # before the first of this call's programs compiles
    meth = make_method(method, **hyperparameters)
    prior, loss = resolve_objective(objective, prior, loss)  # named presets (issue 24)
    q, y = _as_arrays(data, measurement, robot, stacklevel=4)
    warn_if_float32(q.dtype, "calibrate")
    checks = Checks() if checks is None else checks
    prior = resolve_prior(prior)
    _check_settings(robot, prior, loss, init)
    cand = candidate_space(robot, measurement, extras, free, fix)
    start = Deviations.zeros(layout_for(robot, measurement), q.dtype) if start is None else start.astype(q.dtype)
    key = _default_key() if key is None else key
    plain = prior is None and loss == "linear"  # plain least squares: no scale to estimate, no Objective
    # a masked method's program space, the same for every round: every free set this call meets
    # (identifiability and its re-selection pick from the candidates; "all" is the candidates; a
    # given space is its own) lies in the program space of the candidates and a given space
    given = space if isinstance(space, ParameterSpace) else cand
    prog_space = _program_space(robot, measurement, cand, given) if _masked(meth) else None
    # masked solves carry a start Jacobian (the program space's columns) with a run-time flag
    # (share_start_jacobian): the identifiability program's at the start of a selection's first
    # round, zeros standing in elsewhere — one compiled program either way
    carry_jac = share_start_jacobian and prog_space is not None and measurement.jacobian_free_of_data
    solves = Solves(robot, meth, q, y, key, loss, plain, carry_jac)
    if ahead is not None and prog_space is not None and (_default_selection(space) or given is space):
        _start_ahead(ahead, solves, measurement, prior, start, prog_space, given)
    extras_msg = None
    initialisable = extras_to_start(cand, measurement)
    if init == "auto" and initialisable:
        est = initial_extras(robot, measurement, (q, y), estimate=initialisable, start=start)
        start, extras_msg = est.deviations, est.message
    rounds, report = _first_selection(solves, measurement, cand, space, start, prior, loss_scale, checks, prog_space)
    reselection = []
    while True:  # re-selection: identifiability judged again at the solution (below)
        yield from rounds.selection()
        if (not _default_selection(space) or int(rounds.out.status) in (Status.DIVERGED, Status.FAILED)
                or len(reselection) >= MAX_RESELECTIONS):
            break
        got = reselect(cand, robot, rounds.measurement, q, y, prior, start, rounds.cur, rounds.space, report)
        if got is None:
            break
        new_space, report, message = got
        reselection.append(message)
        _check_enough_residuals(q.shape[0], rounds.n_res, new_space, report, prior)
        rounds.restart(new_space, cand)
    result = _result(rounds, report, start)
    _finish(result, rounds, data, prior, checks, extras_msg, reselection, sensor_noise_std, throw)
    return result


def _check_settings(robot, prior, loss: str, init: str) -> None:
    """Raise ``ValueError`` for a prior learned from another robot model, an unknown loss or
    ``init``."""
    learned_from = getattr(getattr(prior, "population", None), "robot", None)
    if learned_from is not None and learned_from != robot.name:
        raise ValueError(f"the prior was learned from units of {learned_from!r}, not of robot {robot.name!r}")
    if loss not in LOSSES:
        raise ValueError(f"unknown loss {loss!r}; choose one of {list(LOSSES)}")
    if init not in ("auto", "none"):
        raise ValueError(f"init must be 'auto' or 'none', got {init!r}")


def _start_ahead(ahead, solves: Solves, measurement, prior, start, prog_space, given) -> None:
    """Hand ``ahead`` the first solve's program, known before its free set: the candidates'
    program space with the free set as a run-time mask (the σ and scale values are run-time data)."""
    q = solves.q
    seen = (solves.robot.name, type(measurement).__name__, type(solves.meth).__name__, tuple(q.shape), str(q.dtype),
            prog_space.free_names, None if solves.plain else (solves.loss, prior is not None), solves.carry_jac)
    ahead(seen, lambda: solves.request(measurement, prior, start, prog_space,
                                       _solve_space(prog_space, given, q.dtype)[2], 1.0, 1.0, given, None))


def _first_selection(solves: Solves, measurement, cand, space, start, prior, loss_scale, checks, prog_space):
    """The free parameters at the start and the :class:`Rounds` that fit them: ``(rounds, report)``
    (``report``: the identifiability report, or ``None`` for a space given or ``"all"``)."""
    robot, q, y, loss = solves.robot, solves.q, solves.y, solves.loss
    # rounds: a robust scale or the prior's noise σ not given are re-estimated from the fit
    adaptive = (loss != "linear" and loss_scale is None) or (prior is not None and prior.noise_std is None)
    # the prior's scale chosen by the evidence between the rounds (run-time data of the same program)
    evidence = prior is not None and prior.scale_by == "evidence"
    adaptive = adaptive or evidence
    # the identifiability program's Jacobian starts a one-round fit (several rounds share one
    # compiled program, which then computes it), or the first round of a carried one (the later
    # rounds' solves compute theirs); else a masked solve computes its own
    first_round_jac = solves.carry_jac or not (adaptive or prog_space is not None)
    space, report, resid_start, start_jac = _resolve_candidates(cand, robot, measurement, q, space, start, y, prior,
                                                                jacobian=first_round_jac, all_columns=solves.carry_jac)
    if solves.carry_jac and start_jac is not None:
        start_jac = _program_columns(start_jac, cand, prog_space)
    problem = Problem(robot, measurement, q, y, space, start)
    n_res = problem.n_observed_residuals  # real readings (a missing marker is masked)
    _check_enough_residuals(q.shape[0], n_res, space, report, prior)
    x = space.to_vector_numpy(start)  # problem.x0() on the host (no device round trip)
    if resid_start is None:  # else from the identifiability program
        resid_start = signed_residuals(problem, x)
    else:
        resid_start = residual_blocks_numpy(problem, resid_start)
    # a robust loss's threshold in units of a clean sample's RMS error (√3 σ for a position's norm)
    dims = math.sqrt(error_dims(measurement, problem.observed())) if loss != "linear" and loss_scale is None else 1.0
    # a σ per residual component estimated from the fit, the model reweighted between the rounds
    reweight = measurement.estimates_weights()
    rounds = Rounds(solves, prior, loss_scale, checks, adaptive or reweight, evidence, reweight, first_round_jac,
                    prog_space, dims, n_res, x, measurement, problem, space, start, resid_start, start_jac,
                    round_prior=prior)
    return rounds, report


def _result(rounds: Rounds, report, start: Deviations) -> CalibrationResult:
    """The :class:`CalibrationResult` of the last solve of ``rounds`` (before its diagnostics)."""
    out, meth = rounds.out, rounds.solves.meth
    label = meth.label() if hasattr(meth, "label") else type(meth).name
    history, n_it = rounds.history()
    return CalibrationResult(
        method=label,
        deviations=rounds.cur,
        x=np.asarray(out.x),
        space=rounds.space,
        robot=rounds.solves.robot,
        measurement=rounds.measurement,
        history=history,
        n_iterations=n_it,
        iterations_to_converge=int(out.iterations_to_converge) if rounds.rounds == 1 else
        iterations_to_converge_numpy(history, n_it),
        status=Status(int(out.status)),
        train_metrics=Metrics(*(float(v) for v in out.train_metrics)),
        wall_time_s=rounds.run_s,
        compile_time_s=rounds.compile_s,
        hyperparameters=meth.hyperparameters(),
        extra=out.extra,
        predictor=getattr(meth, "predictor", lambda: None)(),
        identifiability=report,
        prior=_with_rounds(rounds.round_prior, rounds.rounds),
        loss=rounds.solves.loss,
        loss_scale_mm=rounds.scale,
        start=start,
    )


def _finish(result: CalibrationResult, rounds: Rounds, data, prior, checks: Checks, extras_msg, reselection,
            sensor_noise_std, throw: bool) -> None:
    """Warn (or raise, ``throw``) where the fit failed; attach the diagnostics and uncertainty
    and issue their warnings. Warnings name the frame three levels above this one (the caller of
    the driver of :func:`_calibration_steps`)."""
    if result.status in (Status.DIVERGED, Status.FAILED):
        if throw:
            raise CalibrationError(result.message)
        warnings.warn(result.message, CalibrationWarning, stacklevel=4)
    diag, unc = diagnose(result, rounds.problem, rounds.before_rows, checks, extras_msg, rounds.rounds, rounds.out.gram,
                         rounds.cov, tuple(reselection),
                         _given_noise(data, prior, rounds.measurement, sensor_noise_std), rounds.resid_start)
    object.__setattr__(result, "diagnostics", diag)
    object.__setattr__(result, "uncertainty", unc)
    if result.identifiability is not None and diag.verdicts is not None:  # its lines in the verdicts' words
        object.__setattr__(result, "identifiability", dataclasses.replace(result.identifiability, verdicts=diag.verdicts))
    flagged = set(outlier_warnings(result))
    for w in diag.warnings:
        warnings.warn(w, OutlierWarning if w in flagged else CalibrationWarning, stacklevel=4)


@functools.lru_cache(maxsize=1)
def _default_key():
    """``jax.random.key(0)``, made once and on the host (:func:`~jaxcal._datasets._split.key_numpy`:
    ``jax.random.key`` runs two small programs, which a fresh process compiles or loads)."""
    return key_numpy(0)
