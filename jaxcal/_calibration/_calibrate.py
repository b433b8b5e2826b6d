"""One entry point for every method: :func:`calibrate`, and its pure core :class:`Calibrator`."""

from __future__ import annotations

import dataclasses
import functools
import math
import time
import warnings
from collections.abc import Generator
from types import SimpleNamespace
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._core import _exported
from .._core._buckets import (
    BoundedCache,
    LeanJit,
    cache_size,
    pad_model_rows,
    release_memory,
    signature,
)
from .._core._cache import ensure_compilation_cache, switched_off
from .._core._metrics import Metrics, compute_metrics
from .._core._params import EXTRA_GROUPS, Deviations, ParameterSpace, group_kind, group_of, layout_for
from .._core._precision import cast_floating, dtype_scope, to_device, warn_if_float32
from .._core._xla import ahead_enabled, compile_ahead, compile_lowered, jit, take_ahead, target_platform
from .._datasets._dataset import Dataset, mm_joints_metadata
from .._datasets._split import key_numpy
from .._fit._diagnostics import (
    Checks,
    Diagnostics,
    coverage,
    error_dims,
    flagged_rows,
    given_noise_std,
    gram_at,
    gram_from_jacobian,
    implausible_deviations,
    narrow_joints,
    parameter_uncertainty,
    prior_directions,
    result_findings,
    scan_outliers,
    weak_parameters,
)
from .._fit._evidence import choose_prior
from .._fit._identifiability import STILL_JOINT_DEG, identify_with_residuals, start_jacobian
from .._fit._objective import LOSSES, Objective, Prior, resolve_objective, resolve_prior, robust_scale
from .._fit._problem import Problem, entry_count, observed_entries, residual_blocks_numpy, signed_residuals
from .._fit._result import (
    CalibrationResult,
    Status,
    budget_status,
    iterations_to_converge,
    iterations_to_converge_numpy,
)
from .._fit._verdicts import fit_verdicts, fixable_text
from .._models._abstract import AbstractRobot
from .._models._kinematics import shared_joint_trig
from .._sensors._initial_extras import initial_extras
from .._sensors._measurement import MeasurementModel
from ..methods import Method, ScaledProblem, make_method

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


class CalibrationError(RuntimeError):
    """Raised instead of :class:`CalibrationWarning` with ``calibrate(..., throw=True)``."""


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
                                         jacobian_given=self.start_jacobian_given)
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
        return CalibrationOutput(x, raw.history, raw.n_iterations, its, status, metrics, raw.extra, gram, deviations)


@functools.partial(jit, static_argnums=1)
def _run_calibrator(dynamic, static, q, y, key, weight=None) -> CalibrationOutput:
    """The jitted core of :func:`calibrate` (module level, so compilations are cached)."""
    return eqx.combine(dynamic, static)(q, y, key, weight)


def _as_arrays(data, measurement: MeasurementModel, robot: AbstractRobot, stacklevel: int = 3):
    if measurement.kind == "blocks" and isinstance(data, (tuple, list)) and len(data) == 2:
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


#: ``extras=`` names accepted by :func:`calibrate` → :meth:`ParameterSpace.for_robot` flags.
EXTRAS = {"anchor": "anchor", "tool": "tool", "cable_offset": "cable_offset", "offset": "cable_offset",
          "base": "base"}


def extras_flags(extras, measurement: MeasurementModel) -> dict[str, bool]:
    """``extras`` (names such as ``"anchor"``, ``"cable_offset"``, ``"tool"``, ``"base"``) as
    keyword flags of :meth:`ParameterSpace.for_robot`, checked against the measurement kind."""
    if isinstance(extras, str):
        extras = [e for e in extras.split(",") if e.strip()]
    flags = {}
    for e in extras or ():
        key = e.strip().lower()
        if key not in EXTRAS:
            raise ValueError(f"unknown extra {e!r}; choose from anchor, cable_offset (offset), tool, base")
        flag = EXTRAS[key]
        if measurement.kind == "blocks":  # several sensors: each block checked its own (jaxcal.Block)
            flags[flag] = True
            continue
        if flag == "base" and hasattr(measurement, "frame_index"):
            continue  # SessionMarkers: every session frame is already free (base_rotation@F, ...)
        if flag in ("anchor", "cable_offset") and measurement.kind != "cable":
            raise ValueError(f"extra {e!r} applies to draw-wire (cable) data only, not {measurement.kind!r}")
        if flag == "base" and measurement.kind == "cable":
            raise ValueError("extra 'base' (sensor frame) applies to position/pose data; a draw-wire has an anchor")
        if flag == "tool" and measurement.kind == "markers":
            raise ValueError("extra 'tool' does not apply to marker data: the marker positions (marker_k groups) "
                             "are the tool; Markers(known=False) calibrates them")
        flags[flag] = True
    return flags


#: group names accepted by ``free=`` / ``fix=`` (besides single parameter names such as ``d_6``).
SELECT_GROUPS = {
    "dh": ("alpha", "a", "d", "theta"), "alpha": ("alpha",), "a": ("a",), "d": ("d",), "theta": ("theta",),
    "beta": ("beta",), "anchor": ("anchor",), "tool": ("tool",), "cable_offset": ("cable_offset",),
    "offset": ("cable_offset",), "base": ("base_rotation", "base_translation"),
    "base_rotation": ("base_rotation",), "base_translation": ("base_translation",), "extras": EXTRA_GROUPS,
    "tip": ("tip_translation", "tip_rotation"),  # a generic chain's tip transform errors
}


def _family(group: str) -> str:
    """A group's family: its name before ``@`` (``base_rotation@F`` → ``base_rotation``)."""
    return group.partition("@")[0]


def extras_among(names) -> dict[str, bool]:
    """Which of the extras ``calibrate(extras=...)`` names (anchor, cable offset, base, tool) the
    parameter ``names`` hold: ``{extra: bool}``."""
    families = {_family(group_of(n)) for n in names}
    return {e: any(f in SELECT_GROUPS[e] for f in families) for e in ("anchor", "cable_offset", "base", "tool")}


def _selection(items, layout) -> set[str]:
    """Parameter names selected by ``items``: aliases of :data:`SELECT_GROUPS`, a kind
    (``geometric``, ``nongeometric``, ``extras``), any group name of ``layout`` or parameter names."""
    if isinstance(items, str):
        items = [i for i in items.split(",") if i.strip()]
    names, groups_of = layout.names, layout.entry_groups
    out = set()
    for it in items or ():
        key = it.strip()
        if key.lower() in SELECT_GROUPS:
            # per-session groups (SessionMarkers: base_rotation@F, marker_k@K) count as their family:
            # "base" selects every session frame; "extras" also every session group
            groups = SELECT_GROUPS[key.lower()]
            out |= {n for n, g in zip(names, groups_of)
                    if _family(g) in groups or ("@" in g and key.lower() == "extras")}
        elif key.lower() == "markers":
            out |= {n for n, g in zip(names, groups_of) if g.startswith("marker_")}
        elif key.lower() in ("geometric", "nongeometric"):
            out |= {n for n, k in zip(names, layout.kinds) if k == key.lower()}
        elif key in layout.group_names:
            out |= {n for n, g in zip(names, groups_of) if g == key}
        elif key in names:
            out.add(key)
        else:
            raise ValueError(f"unknown parameter or group {key!r}; groups: "
                             f"{', '.join(dict.fromkeys([*SELECT_GROUPS, 'geometric', 'nongeometric', *layout.group_names]))}; "
                             f"or a parameter name such as {', '.join(names[:2])}, anchor_x, base_rz")
    return out


def candidate_space(robot, measurement, extras=(), free=None, fix=()) -> ParameterSpace:
    """The parameters a calibration may free, before the identifiability reduction: all DH (+β at
    Hayati joints) — or instead the groups/names in ``free`` — plus the ``extras``, minus ``fix``."""
    flags = extras_flags(extras, measurement)
    base = ParameterSpace.for_robot(robot, measurement=measurement, **flags)
    if free is None and not fix:
        return base
    layout = base.layout
    names = layout.names
    chosen = set(base.free_names)
    if free is not None:  # free replaces the robot part; the requested extras stay
        chosen = _selection(free, layout) | {n for n in chosen if group_kind(n) == "extra"}
    chosen -= _selection(fix, layout)
    blocks = measurement.kind == "blocks"  # several sensors: each block checked its own extras
    wrong = sorted(n for n in chosen if group_of(n) in ("anchor", "cable_offset") and measurement.kind != "cable"
                   and not blocks)
    wrong += sorted(n for n in chosen if group_of(n).startswith("base") and measurement.kind == "cable")
    if wrong:
        raise ValueError(f"{', '.join(wrong)} do not apply to {measurement.kind} data")
    if not chosen:
        raise ValueError("no free parameters left after the free and fix choices (--free/--fix on the command line)")
    return ParameterSpace.from_names(layout, [n for n in names if n in chosen])


def resolve_space(robot, measurement, q, space, start=None, extras=(), free=None, fix=(), prior=None, n_to=None
                  ) -> tuple[ParameterSpace, object]:
    """The free parameters of a calibration: ``(space, report_or_None)``.

    ``space=None`` or ``"identifiable"`` (the default of :func:`calibrate`, :func:`jaxcal.sweep`):
    chosen from the candidates (:func:`candidate_space`: all DH (+β) deviations and the requested
    ``extras``, or ``free`` minus ``fix``) by the identification Jacobian at ``start``
    (:func:`jaxcal.identifiability`: QR with column pivoting, then :data:`KEEP_PREFERENCE`):

    * without a ``prior``: the identifiable subset (plain least squares has no answer along the
      directions the data cannot see; the other candidates are held at ``start``);
    * with a ``prior`` (maximum a posteriori): every candidate the prior covers, plus the
      data-identifiable subset of the others (:func:`~jaxcal._fit._identifiability.select_free`):
      nothing the prior determines is frozen at a start value.

    ``"all"``: every candidate; or a :class:`ParameterSpace` as given. ``n_to``: the row count the
    identifiability program pads to (default: the shape bucket of ``q``'s rows)."""
    cand = candidate_space(robot, measurement, extras, free, fix)
    return _resolve_candidates(cand, robot, measurement, q, space, start, prior=resolve_prior(prior), n_to=n_to)[:2]


def _default_selection(space) -> bool:
    return space is None or (isinstance(space, str) and space == "identifiable")


def _resolve_candidates(cand, robot, measurement, q, space, start, y=None, prior=None, jacobian: bool = True,
                        n_to=None, all_columns: bool = False):
    """:func:`resolve_space` from the candidates ``cand``: ``(space, report_or_None, residuals,
    jacobian)``, the last two the residual blocks (NumPy) and the identification Jacobian of the
    chosen free parameters (device) at ``start`` when ``y`` is given and the identifiability
    program computed them (see :func:`~jaxcal._fit._identifiability.identify_with_residuals`), else
    ``None``; the Jacobian also ``None`` with ``jacobian=False`` (the caller does not use it: its
    columns are not taken, a compiled program fewer). ``all_columns``: the Jacobian of every
    candidate (a masked solve's start), not of the chosen ones."""
    if _default_selection(space):
        prior_std = None if prior is None else prior.std(cand)
        report, resid, J = identify_with_residuals(robot, measurement, q, cand, start, y, prior_std=prior_std,
                                                   n_to=n_to)
        if not jacobian:
            J = None
        if J is not None and not all_columns:
            kept = set(report.space.free_names)
            J = _take_columns(J, np.asarray([i for i, n in enumerate(cand.free_names) if n in kept]))
        return report.space, report, resid, J
    if isinstance(space, str):
        if space == "all":
            return cand, None, None, None
        raise ValueError(f"space must be None, 'identifiable', 'all' or a ParameterSpace, got {space!r}")
    if not isinstance(space, ParameterSpace):
        raise TypeError(f"space must be a ParameterSpace, got {type(space)}")
    if space.layout != cand.layout:
        raise ValueError(f"parameter space has groups {list(space.layout.group_names)} for {space.dof} joints, but "
                         f"robot {robot.name!r} with this measurement has {list(cand.layout.group_names)} for "
                         f"{robot.dof} joints")
    return space, None, None, None


#: how often :func:`calibrate` judges identifiability again with the extras where a fit put them
#: and refits with the parameters that become identifiable (:func:`_extras_moved`)
MAX_RESELECTIONS = 2


def _extras_moved(start: Deviations, cur: Deviations) -> Deviations:
    """``start`` with the extras (sensor/set-up groups) taken from ``cur``: where identifiability is
    judged after a fit. The robot's own groups stay at the start (nominal): exact dependencies of
    the nominal geometry (parallel axes) stay exact instead of turning into near-dependencies of
    the deviations' size that no data determine, while extras that moved far (a tool point found
    58 mm off the flange axis) reveal what they reveal (α5, a5 of a 6R arm)."""
    extras = {g.name: cur.values[g.name] for g in start.layout.groups if g.kind == "extra"}
    return start.replace(**extras) if extras else start


class TooFewSamples(ValueError):
    """The data have no more residuals than the parameters they must determine. A ``ValueError``
    with the counts as attributes: ``n_samples`` given, ``n_residuals`` they give, ``n_needed``
    the residuals to exceed, ``n_free`` the free parameters, ``samples_needed`` the fewest
    samples of this kind that exceed ``n_needed`` and ``samples_for_all`` those that exceed
    ``n_free`` (at these samples' residuals per sample). Under a prior ``n_needed`` is what these
    few poses determine, which grows with more poses up to ``n_free``: ``samples_needed`` is a
    lower bound, ``samples_for_all`` enough for any pose set that sees every free parameter."""

    def __init__(self, n_samples: int, n_residuals: int, n_needed: int, n_free: int, what: str):
        self.n_samples, self.n_residuals, self.n_needed, self.n_free = n_samples, n_residuals, n_needed, n_free
        per = n_residuals / n_samples if n_samples and n_residuals else 1.0
        self.samples_needed = int(math.floor(n_needed / per)) + 1
        self.samples_for_all = int(math.floor(n_free / per)) + 1
        more = "" if self.samples_for_all == self.samples_needed else (
            f" ({self.samples_for_all} for the data to determine all {n_free} free parameters)")
        super().__init__(f"too few samples: {n_samples} sample(s) give {n_residuals} residuals for {what}; need "
                         f"more residuals than that: at least {self.samples_needed} sample(s){more}")


def _check_enough_residuals(n: int, n_res: int, space: ParameterSpace, report=None, prior=None) -> None:
    """Raise :class:`TooFewSamples` unless the data have more residuals than the parameters they
    must determine: every free one, or under a prior (MAP) the data-identifiable ones
    (``report.rank``) — the prior determines the rest, but the noise σ the prior is weighed
    against needs ``N > rank``."""
    need = space.n_free if prior is None or report is None else report.rank
    if n_res <= need:
        what = (f"{need} data-identifiable parameters (of {space.n_free} free under the prior)" if need != space.n_free
                else f"{space.n_free} free parameters")
        raise TooFewSamples(n, n_res, need, space.n_free, what)


def _program_space(robot, measurement, cand: ParameterSpace, space: ParameterSpace) -> ParameterSpace:
    """The parameter space of the compiled solve of a :attr:`~jaxcal.methods.Method.maskable`
    method: the robot's default candidates (every DH deviation, β at Hayati joints), the
    candidates ``cand`` (requested extras, ``free=``) and the free ``space``, in layout order. The
    free set is a run-time mask inside it (:class:`Calibrator` ``free=``), so every selection of
    one set-up — identifiability, its re-selection at the solution, ``free=``/``fix=``, the
    robust/MAP rounds, an evaluation registering the extras with the robot fixed — runs the same
    compiled program."""
    keep = set(ParameterSpace.for_robot(robot, measurement=measurement).free_names)
    keep |= set(cand.free_names) | set(space.free_names)
    return ParameterSpace.from_names(space.layout, [n for n in space.layout.names if n in keep])


def _solve_space(prog: ParameterSpace | None, space: ParameterSpace, dtype):
    """``(program space, columns, mask)`` of a solve of the free ``space``: with a program space
    ``prog`` (:func:`_program_space`; a masked solve), ``prog``, the free parameters' columns in it
    and the run-time 0/1 mask; else (``prog=None``) ``(space, None, None)``."""
    if prog is None:
        return space, None, None
    key = (prog.free_names, space.free_names, np.dtype(dtype))
    got = _MASKS.get(key)
    if got is None:
        free = set(space.free_names)
        columns = np.asarray([i for i, n in enumerate(prog.free_names) if n in free])
        mask = np.zeros(prog.n_free)
        mask[columns] = 1.0
        got = (columns, to_device(mask, dtype))
        _MASKS.put(key, got)
    return (prog, *got)


#: the masks of the last free sets :func:`_solve_space` met (device arrays; a warm call reuses its own)
_MASKS = BoundedCache(8)


def _program_columns(J, cand: ParameterSpace, prog: ParameterSpace):
    """A Jacobian ``J`` ``[N, p]`` of the candidates ``cand`` as the program space ``prog``'s
    ``[N, P]`` (zero columns for the parameters outside ``cand``: a mask holds them). Where the
    two are the same (the default candidates), ``J`` itself."""
    if prog.free_names == cand.free_names:
        return J
    index = {n: i for i, n in enumerate(prog.free_names)}
    out = np.zeros((J.shape[0], prog.n_free), J.dtype)
    out[:, [index[n] for n in cand.free_names]] = np.asarray(J)
    return jax.device_put(out)


def _mask_output(out: CalibrationOutput, columns: np.ndarray) -> CalibrationOutput:
    """A masked solve's output on its free parameters alone (``columns`` of the program space):
    ``x`` and the Jacobian products of ``gram`` restricted to them, as an unmasked solve gives."""
    x = np.asarray(out.x)[columns]
    gram = out.gram
    if gram is not None:
        d, A, G, rss, r, e, comp = gram
        sub = np.ix_(columns, columns)
        comp = None if comp is None else np.asarray(comp)[:, columns][:, :, columns]
        gram = (np.asarray(d)[columns], np.asarray(A)[sub], np.asarray(G)[sub], rss, r, e, comp)
    return out._replace(x=x, gram=gram)


def _masked(meth) -> bool:
    """Whether :func:`calibrate` runs ``meth`` with the free set as a run-time mask
    (``$JAXCAL_FREE_MASK=off`` turns it off: one program per free set, as before)."""
    return meth.maskable and not switched_off("JAXCAL_FREE_MASK")


#: ``J[:, columns]`` as one compiled call (eager indexing costs ~0.5 ms of Python per call)
_take_columns = LeanJit(lambda J, columns: jnp.take(J, columns, axis=1), maxsize=16)


#: compiled calibrators by (static part, dynamic shapes/dtypes): a warm ``calibrate`` call skips
#: tracing and lowering (``jit.lower`` re-traces on every call; ~10–30 ms on 2 CPU cores). A
#: least-recently-used cache of at most 16 programs (``$JAXCAL_CALIBRATE_CACHE``): with shape
#: buckets one model and method need one program per bucket, and memory
#: stays flat however many sample counts a session calibrates.
_COMPILED = BoundedCache(cache_size("calibrate", 16))


def _pad_to_bucket(cal: Calibrator, q, y, n_to: int | None = None, host: bool = False):
    """``(cal, q, y, weight)``: the data padded with zero-weight rows to their bucket size
    (:func:`~jaxcal._core._buckets.bucket_size`) when the method allows it (:attr:`Method.paddable`;
    weights all 1 at a bucket size exactly), the measurement model's per-row arrays
    (:meth:`MeasurementModel.pad_rows`) and the start Jacobian (if any) padded to match;
    unchanged with ``weight=None`` otherwise. ``n_to``: pad to this row count instead (a paddable
    method; :func:`jaxcal.calibrate_many` pads every unit to one size). ``host``: ``q``, ``y``,
    ``weight`` and a padded start Jacobian as NumPy arrays (a caller that stacks units on the
    host first)."""
    n, measurement = int(q.shape[0]), cal.measurement
    w = None
    new = {}  # fields replaced (one dataclasses.replace: ~3x cheaper than eqx.tree_at per field)
    if cal.method.paddable:
        padded, q, y, w = pad_model_rows(measurement, q, y, n_to, host=host)
        if padded is not measurement:
            new["measurement"] = padded
    n_to = int(q.shape[0])
    J = cal.start_jacobian
    rows, rows_to = entry_count(measurement, n), entry_count(new.get("measurement", measurement), n_to)
    if J is None and cal.start_jacobian_given is not None:  # zeros stand in (Calibrator.start_jacobian_given)
        new["start_jacobian"] = _zero_jacobian((rows_to, cal.space.n_free), q.dtype, host)
    elif J is not None and J.shape[0] != rows_to:
        # computed on the real rows, or on another padding (the identifiability program pads
        # whatever the method): the real rows on the host (padding rows' entries come last), zero
        # rows for this padding
        Jn = np.asarray(J)[:rows]
        if rows_to != rows:
            Jn = np.concatenate([Jn, np.zeros((rows_to - rows, Jn.shape[1]), Jn.dtype)])
        new["start_jacobian"] = Jn if host else jax.device_put(Jn)
    if new:
        cal = dataclasses.replace(cal, **new)
    return cal, q, y, w


#: the last zero start Jacobians :func:`_pad_to_bucket` made, by (shape, dtype, host)
_ZERO_JACOBIAN = BoundedCache(4)


def _zero_jacobian(shape: tuple, dtype, host: bool):
    """Zeros ``shape`` standing in for a start Jacobian not given (NumPy with ``host``, else on
    the device); the last few are kept (every masked solve of one set-up has the same shape)."""
    key = (shape, np.dtype(dtype), host)
    z = _ZERO_JACOBIAN.get(key)
    if z is None:
        z = np.zeros(shape, dtype)
        z = z if host else jax.device_put(z)
        _ZERO_JACOBIAN.put(key, z)
    return z


def _launch(cal: Calibrator, q, y, key):
    """Compile (cached) and start ``cal`` without waiting for it (JAX dispatches asynchronously):
    ``(output, compile_s, t_started)``; the caller may do host work, then blocks on ``output``.
    The data are padded to their shape bucket (:func:`_pad_to_bucket`); the output is the
    unpadded run's, except ``gram``'s residual vector, which carries the padding rows (zeros) at
    its end. A compilation :func:`_compile_ahead` started for the same program is waited for;
    ``compile_s`` is then its own duration on the background thread (the call may have waited
    for none of it), not the wait."""
    with dtype_scope(q.dtype):
        cal, q, y, w, dyn, stat, ck = _solve_inputs(cal, q, y, key)
        t0 = time.perf_counter()
        ahead = take_ahead(_AHEAD, ck)  # a compilation _compile_ahead started: waited for
        compiled = None if ahead is None else ahead[0]
        if compiled is None and ck is not None:
            compiled = _COMPILED.get(ck)
        if compiled is None:
            compiled = _build_solve(cal, dyn, stat, q, y, key, w, ck)
        t1 = time.perf_counter()
        out = compiled(dyn, q, y, key, w)
    return out, (t1 - t0 if ahead is None else ahead[1]), t1


def _solve_inputs(cal: Calibrator, q, y, key, host: bool = False):
    """``(cal, q, y, weight, dynamic part, static part, cache key or None)`` of a solve: the data
    padded to their bucket, the calibrator split for ``jit``. ``host``: the padded data as NumPy
    arrays (enough to know the program and to compile it; no transfer to the device)."""
    cal, q, y, w = _pad_to_bucket(cal, q, y, host=host)
    dyn, stat = eqx.partition(cal, eqx.is_array)
    dyn = cast_floating(dyn, q.dtype)
    try:
        ck = (stat, signature((dyn, q, y, key, w)), target_platform(), jax.config.jax_enable_x64)
        hash(ck)
    except TypeError:  # unhashable static part: no cache
        ck = None
    return cal, q, y, w, dyn, stat, ck


def _build_solve(cal: Calibrator, dyn, stat, q, y, key, w, ck):
    """The compiled solve: kept on disk (a fresh process skips tracing), else traced and lowered
    here; remembered under ``ck``."""
    compiled = (_stored_calibrator(cal, dyn, stat, q, y, key, w) if ck is not None else None) or \
        compile_lowered(_run_calibrator.lower(dyn, stat, q, y, key, w))
    if ck is not None:
        _COMPILED.put(ck, compiled)
        # the executable is all a later call needs: drop the trace (jaxpr, lowering) that
        # jax.jit keeps per shape, tens of MB for a solve, never freed otherwise
        _run_calibrator.clear_cache()
    release_memory()
    return compiled


#: solves being compiled on a background thread (:func:`_compile_ahead`), by cache key
_AHEAD: dict = {}
#: summaries of the set-ups :func:`_compile_ahead` has met in this process
_AHEAD_SEEN: set = set()


def _compile_ahead(seen, make) -> None:
    """Start compiling the solve ``make()`` gives (``(Calibrator, q, y, key)``) on a background
    thread while :func:`calibrate` does its other work (closed-form extras, the identifiability
    program): XLA compiles without holding Python's lock, so on a machine with a second core the
    two programs compile at once. :func:`_launch` waits for it. Nothing happens when the program
    is compiled already, where ``JAXCAL_COMPILE_AHEAD=off`` or on a single core.

    ``seen``: a hashable summary of the set-up; one this process met before has its program
    already (a warm call), and nothing is made, padded or hashed (~0.3 ms of a ~6 ms warm
    calibrate). A set-up that shares its summary but not its program just compiles in the
    calling thread, as without this function."""
    if not ahead_enabled() or seen in _AHEAD_SEEN:
        return
    _AHEAD_SEEN.add(seen)
    cal, q, y, key = make()
    with dtype_scope(q.dtype):
        cal, q, y, w, dyn, stat, ck = _solve_inputs(cal, q, y, key, host=True)
    if ck is None or _COMPILED.get(ck) is not None:
        return

    def build():  # (program, seconds it took)
        t = time.perf_counter()
        with dtype_scope(q.dtype):
            return _build_solve(cal, dyn, stat, q, y, key, w, ck), time.perf_counter() - t

    compile_ahead(_AHEAD, ck, build)


def _output_structure(cal: Calibrator):
    """The pytree structure of ``cal``'s :class:`CalibrationOutput`, known without tracing for a
    method whose run carries no extra state (``extra=None``; LM): checked against the traced one
    when a program is stored (:func:`~jaxcal._core._exported.compile_stored`)."""
    z = 0
    robust = cal.objective is not None and cal.objective.loss != "linear"  # gram_at's per-sample errors
    comp = z if len(cal.measurement.components) > 1 else None  # gram_at's per-component grams
    gram = (z, z, z, z, z, z if robust else None, comp) if cal.report else None
    dev = cal.start if cal.report else None
    template = CalibrationOutput(z, z, z, z, z, Metrics(*(z for _ in Metrics._fields)), None, gram, dev)
    return jax.tree_util.tree_structure(template)


def _stored_calibrator(cal: Calibrator, dyn, stat, q, y, key, w):
    """``cal``'s solve as a program kept on disk by :mod:`jaxcal._core._exported` (a fresh process
    skips tracing and lowering it), or ``None``: a method with extra state or a configuration
    without a plain description (a user's callable), or the layer turned off."""
    if not (cal.method.maskable and _exported.enabled()):
        return None
    description = _exported.plain_description((stat, cal.space))  # the space with its layout
    if description is None:
        return None

    def solve(dyn, q, y, key, w):
        return eqx.combine(dyn, stat)(q, y, key, w)

    return _exported.compile_stored("calibrate", solve, (dyn, q, y, key, w), description, compile_lowered,
                                    _output_structure(cal))


class _Launched:
    """A solve started by a driver of :func:`_calibration_steps`: ``out`` (possibly still
    computing), ``compile_s``; :meth:`wait` gives ``(output, run seconds)``. ``run_s`` given: the
    output is ready (a share of a batched solve, :func:`jaxcal.calibrate_many`)."""

    def __init__(self, out, compile_s: float, t_started: float, run_s: float | None = None):
        self.out, self.compile_s, self.t_started, self.run_s = out, compile_s, t_started, run_s

    def wait(self):
        if self.run_s is not None:
            return self.out, self.run_s
        out = jax.block_until_ready(self.out)
        return out, time.perf_counter() - self.t_started


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
    learned_from = getattr(getattr(prior, "population", None), "robot", None)
    if learned_from is not None and learned_from != robot.name:
        raise ValueError(f"the prior was learned from units of {learned_from!r}, not of robot {robot.name!r}")
    if loss not in LOSSES:
        raise ValueError(f"unknown loss {loss!r}; choose one of {list(LOSSES)}")
    if init not in ("auto", "none"):
        raise ValueError(f"init must be 'auto' or 'none', got {init!r}")
    cand = candidate_space(robot, measurement, extras, free, fix)
    flags = extras_among(cand.free_names)
    groups = {group_of(n) for n in cand.free_names}
    flags["markers"] = any(g.startswith("marker_") for g in groups)
    for e in ("handeye", "target"):  # camera extras (jaxcal._sensors._camera)
        flags[e] = any(g.startswith(e + "_") for g in groups)
    families = {_family(g) for g in groups}
    flags.update({e: e in families for e in ("plane", "point")})
    start = Deviations.zeros(layout_for(robot, measurement), q.dtype) if start is None else start.astype(q.dtype)
    masked = _masked(meth)
    key = _default_key() if key is None else key
    plain = prior is None and loss == "linear"  # plain least squares: no scale to estimate, no Objective
    # rounds: a robust scale or the prior's noise σ not given are re-estimated from the fit
    adaptive = (loss != "linear" and loss_scale is None) or (prior is not None and prior.noise_std is None)
    # the prior's scale chosen by the evidence between the rounds (run-time data of the same program)
    evidence = prior is not None and prior.scale_by == "evidence"
    adaptive = adaptive or evidence
    round_prior, ev_prior, ev_noise = prior, None, None  # the prior of the next solve; the evidence's choice
    selecting = _default_selection(space)

    # a masked method's program space, the same for every round: every free set this call meets
    # (identifiability and its re-selection pick from the candidates; "all" is the candidates; a
    # given space is its own) lies in the program space of the candidates and a given space
    given = space if isinstance(space, ParameterSpace) else cand
    prog_space = _program_space(robot, measurement, cand, given) if masked else None
    # masked solves carry a start Jacobian (the program space's columns) with a run-time flag
    # (share_start_jacobian): the identifiability program's at the start of a selection's first
    # round, zeros standing in elsewhere — one compiled program either way
    carry_jac = share_start_jacobian and prog_space is not None and measurement.jacobian_free_of_data
    # the identifiability program's Jacobian starts a one-round fit (several rounds share one
    # compiled program, which then computes it), or the first round of a carried one (the later
    # rounds' solves compute theirs); else a masked solve computes its own
    first_round_jac = carry_jac or not (adaptive or masked)

    def solve(cur, prog, mask, noise, scale, free, start_jacobian):
        """The solve of one round: ``(Calibrator, q, y, key)``."""
        objective = None if plain else Objective.build(prog, round_prior, noise, loss, scale, q.dtype, free=free)
        flag = np.bool_(start_jacobian is not None) if carry_jac else None
        return Calibrator(robot, measurement, meth, cur, prog,
                          None if objective is None or objective.plain_least_squares else objective, report=True,
                          start_jacobian=start_jacobian, free=mask, start_jacobian_given=flag), q, y, key

    if ahead is not None and prog_space is not None and (selecting or given is space):
        # the program of the first solve is known before its free set: the candidates' program
        # space with the free set as a run-time mask (the σ and scale values are run-time data)
        seen = (robot.name, type(measurement).__name__, type(meth).__name__, tuple(q.shape), str(q.dtype),
                prog_space.free_names, None if plain else (loss, prior is not None), carry_jac)
        ahead(seen, lambda: solve(start, prog_space, _solve_space(prog_space, given, q.dtype)[2], 1.0, 1.0, given,
                                  None))
    extras_msg = None
    initialisable = [e for e in measurement.initialisable if flags.get(e)]
    if init == "auto" and initialisable:
        est = initial_extras(robot, measurement, (q, y), estimate=initialisable, start=start)
        start, extras_msg = est.deviations, est.message
    # the start Jacobian serves a one-round fit only (below), or a carried one's first round
    space, report, resid_start, start_jac = _resolve_candidates(cand, robot, measurement, q, space, start, y, prior,
                                                                jacobian=first_round_jac, all_columns=carry_jac)
    if carry_jac and start_jac is not None:
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
    rounds, compile_s, run_s, cur = 0, 0.0, 0.0, start
    noise = scale = None
    # a σ per residual component estimated from the fit, the model reweighted between the rounds
    reweight, moved = measurement.estimates_weights(), False
    adaptive = adaptive or reweight
    histories = []
    reselection = []
    before_rows = cov = None
    while True:  # re-selection: identifiability judged again at the solution (below)
        first = rounds
        prog, columns, mask = _solve_space(prog_space, space, q.dtype)
        while True:  # rounds of re-estimated scales
            if plain:
                new_noise = new_scale = None
            else:
                resid = resid_start if rounds == first else signed_residuals(problem, space.to_vector(cur))
                s_hat = robust_scale(observed_entries(problem, resid))  # masked readings left out
                s_hat = s_hat if (s_hat > 0 and np.isfinite(s_hat)) else 1.0
                new_noise = prior.noise_std if prior is not None and prior.noise_std is not None else s_hat
                if ev_prior is not None and prior.noise_std is None:  # the σ of the evidence's maximum
                    new_noise = ev_noise
                new_scale = (loss_scale if loss_scale is not None else LOSSES[loss] * dims * s_hat
                             if loss != "linear" else None)
            if rounds > first and (not adaptive or (_close(new_noise, noise) and _close(new_scale, scale) and not moved
                                                    and _settled(ev_prior, round_prior))
                                   or rounds - first >= (MAX_REWEIGHT_ROUNDS if reweight else
                                                         MAX_EVIDENCE_ROUNDS if evidence else 4)):
                break
            noise, scale = new_noise, new_scale
            round_prior = round_prior if ev_prior is None else ev_prior
            jac = start_jac if first_round_jac and rounds == first else None
            launched = yield solve(cur, prog, mask, noise, scale, space, jac)
            out, c_s = launched.out, launched.compile_s
            if before_rows is None:  # host work that does not need the fit, while the device runs it
                before_rows = flagged_rows(scan_outliers(problem, x, checks, residuals=resid_start))
                cov = coverage(robot, q)
            out, r_s = launched.wait()
            if columns is not None:
                out = _mask_output(out, columns)
            compile_s, run_s, rounds = compile_s + c_s, run_s + r_s, rounds + 1
            cur = out.deviations  # space.from_vector(out.x, cur), made in the compiled program
            histories.append(np.asarray(out.history)[: int(out.n_iterations) + 1])
            if int(out.status) in (Status.DIVERGED, Status.FAILED) or not adaptive:
                break
            if evidence:  # the scales the evidence chooses at this solution (host, p×p matrices)
                ev_prior, ev_noise = choose_prior(round_prior, space, out.gram, out.x, n_res, rounds=rounds,
                                                  noise_used=prior.noise_std or noise,
                                                  unit=getattr(measurement, "unit", "mm"))
            if reweight:  # a σ per residual component (a pose's position, orientation): refit whitened
                new_m = _reweighted(problem, out, round_prior, loss, scale)
                moved = not _close(new_m.component_scales(), measurement.component_scales(), 0.02)
                measurement = new_m
                problem = eqx.tree_at(lambda pr: pr.measurement, problem, measurement)
        if not selecting or int(out.status) in (Status.DIVERGED, Status.FAILED) or len(reselection) >= MAX_RESELECTIONS:
            break
        # judge identifiability again where the fit put the extras: a start far from the truth
        # (a tool point started on the flange axis) can hide parameters that the solution shows
        if not report.held:
            break
        free_extras = any(group_kind(n) == "extra" for n in space.free_names)
        if not free_extras:  # the robot's groups are judged at their start: nothing else moved
            break
        # with the readings, as at the start: the report does not depend on them (the sample is the
        # prediction, or the readings where the Jacobian is free of them), and the start's compiled
        # program serves (without them, a second program of the same size compiled: ~11 s for a camera)
        new = _resolve_candidates(cand, robot, measurement, q, None, _extras_moved(start, cur), y, prior,
                                  jacobian=False)[1]
        added = [n for n in new.space.free_names if n not in set(space.free_names)]
        if not added:
            break
        space = ParameterSpace.from_names(space.layout, [*space.free_names, *added])
        reselection.append(f"identifiability judged again with the extras where the fit put them: "
                           f"{', '.join(added)} {'becomes' if len(added) == 1 else 'become'} identifiable "
                           f"(not at the start) — freed and refit from the solution")
        # the start's report with the freed names moved over (the solution's own rank counts the
        # near-dependencies of real-size deviations, which stay held)
        report = dataclasses.replace(
            report, space=space, rank=report.rank + len(added), identifiable=(*report.identifiable, *added),
            unidentifiable=tuple(n for n in report.unidentifiable if n not in added),
            dependencies={k: v for k, v in report.dependencies.items() if k not in added})
        _check_enough_residuals(q.shape[0], n_res, space, report, prior)
        problem = Problem(robot, measurement, q, y, space, cur)
        if carry_jac:  # the refit's start Jacobian from the identifiability program (compiled already)
            resid_start, start_jac = start_jacobian(robot, measurement, q, cand, cur, y)
            resid_start = residual_blocks_numpy(problem, resid_start)
            start_jac = _program_columns(start_jac, cand, prog_space)
        else:
            start_jac = None
            resid_start = signed_residuals(problem, space.to_vector_numpy(cur))
    status = Status(int(out.status))
    label = meth.label() if hasattr(meth, "label") else type(meth).name
    # one history across the rounds (each round restarts where the last ended; the objective's
    # scales change between rounds, so the curve may step at the boundaries)
    history = np.concatenate([histories[0]] + [h[1:] for h in histories[1:]])
    n_it = history.shape[0] - 1
    history = np.concatenate([history, np.full(meth.max_iterations * rounds - n_it, history[-1])])
    result = CalibrationResult(
        method=label,
        deviations=cur,
        x=np.asarray(out.x),
        space=space,
        robot=robot,
        measurement=measurement,
        history=history,
        n_iterations=n_it,
        iterations_to_converge=int(out.iterations_to_converge) if rounds == 1 else
        iterations_to_converge_numpy(history, n_it),
        status=status,
        train_metrics=Metrics(*(float(v) for v in out.train_metrics)),
        wall_time_s=run_s,
        compile_time_s=compile_s,
        hyperparameters=meth.hyperparameters(),
        extra=out.extra,
        predictor=getattr(meth, "predictor", lambda: None)(),
        identifiability=report,
        prior=_with_rounds(round_prior, rounds),
        loss=loss,
        loss_scale_mm=scale,
        start=start,
    )
    if status in (Status.DIVERGED, Status.FAILED):
        if throw:
            raise CalibrationError(result.message)
        warnings.warn(result.message, CalibrationWarning, stacklevel=3)
    diag, unc = _diagnose(result, problem, before_rows, checks, extras_msg, rounds, out.gram, cov, tuple(reselection),
                          _given_noise(data, prior, measurement, sensor_noise_std), resid_start)
    object.__setattr__(result, "diagnostics", diag)
    object.__setattr__(result, "uncertainty", unc)
    if result.identifiability is not None and diag.verdicts is not None:  # its lines in the verdicts' words
        object.__setattr__(result, "identifiability", dataclasses.replace(result.identifiability, verdicts=diag.verdicts))
    flagged = set(outlier_warnings(result))
    for w in diag.warnings:
        warnings.warn(w, OutlierWarning if w in flagged else CalibrationWarning, stacklevel=3)
    return result


@functools.lru_cache(maxsize=1)
def _default_key():
    """``jax.random.key(0)``, made once and on the host (:func:`~jaxcal._datasets._split.key_numpy`:
    ``jax.random.key`` runs two small programs, which a fresh process compiles or loads)."""
    return key_numpy(0)


def _close(a, b, rtol: float = 0.05) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return bool(np.all(np.abs(np.subtract(a, b)) <= rtol * np.abs(b)))


#: at most this many solves per selection while a model's component weights settle
#: (:meth:`~jaxcal.MeasurementModel.estimates_weights`; exact orientation readings push a pose's
#: weight to the end of its range, a factor of a few per round)
MAX_REWEIGHT_ROUNDS = 10


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


def _prior_terms(prior, space):
    """``(1/s [p], information [p, p] or None)`` of ``prior`` over ``space`` (``(None, None)``
    without one): what :func:`~jaxcal._fit._diagnostics.parameter_uncertainty` weighs it by."""
    if prior is None:
        return None, None
    s = prior.std(space)
    return np.where(np.isfinite(s), 1.0 / s, 0.0), prior.information(space)


def _reweighted(problem: Problem, out: CalibrationOutput, prior, loss: str, scale):
    """``problem``'s measurement reweighted by the σ̂ of its residual components at the solve
    ``out`` (variance components: :attr:`~jaxcal._fit._diagnostics.Uncertainty.component_std`),
    or as it is where they cannot be estimated."""
    inv, info = _prior_terms(prior, problem.space)
    unc, _ = parameter_uncertainty(problem, np.asarray(out.x, np.float64), prior_inv_std=inv, prior_information=info,
                                   loss=loss, loss_scale=scale or 1.0, gram=out.gram)
    m = problem.measurement
    if unc.component_std is None:
        return m
    return m.reweighted([unc.component_std[c[0]] for c in m.components])


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


def _diagnose(result: CalibrationResult, problem: Problem, before_rows, checks: Checks, extras_msg, rounds,
              gram=None, cov=None, reselection=(), noise_std=None, resid_start=None):
    """Uncertainty and the plausibility / conditioning / coverage / outlier findings (``gram``,
    ``cov``: :func:`gram_at` and :func:`coverage` when the caller has them; ``noise_std``: the
    sensor's given noise, :func:`given_noise_std`; ``resid_start``: the residual blocks at the
    last round's start), and the checks of the result as a whole (:func:`result_findings`)."""
    space = result.space
    x = np.asarray(result.x, np.float64)
    prior_std = result.prior.std(space) if result.prior is not None else None
    msgs = []
    try:
        inv, info = _prior_terms(result.prior, space)  # info: a full prior covariance
        unc, cond, resid = parameter_uncertainty(problem, x, prior_inv_std=inv, prior_information=info,
                                                 loss=result.loss,
                                                 loss_scale=result.loss_scale_mm or 1.0, return_residuals=True,
                                                 gram=gram)
    except (np.linalg.LinAlgError, ValueError) as e:  # pragma: no cover - defensive
        unc, cond, resid = None, float("inf"), None
        msgs.append(f"uncertainty could not be computed: {e}")
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
    if cond > checks.condition_number and prior_std is None:
        msgs.append(f"condition number {cond:.3g} of the identification Jacobian exceeds {checks.condition_number:.3g}: "
                    "some parameter combinations are weakly determined by these poses")
    cov = coverage(result.robot, problem.q) if cov is None else cov
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
