"""Which parameters a calibration frees: the candidates (``extras=``, ``free=``, ``fix=``), the
identifiable subset of them (or those a prior covers), the check that the data have enough
residuals for them, and the re-selection with the extras where a fit put them."""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from .._core._buckets import LeanJit
from .._core._params import EXTRA_GROUPS, Deviations, ParameterSpace, group_kind, group_of
from .._fit._identifiability import identify_with_residuals
from .._fit._objective import resolve_prior
from .._sensors._measurement import MeasurementModel

__all__ = ["EXTRAS", "SELECT_GROUPS", "extras_flags", "extras_among", "candidate_space", "resolve_space",
           "TooFewSamples", "MAX_RESELECTIONS"]


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
        if measurement.takes_extra(flag, e):  # raises where the sensor does not see it
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
    wrong = sorted(n for n in chosen if not measurement.sees_group(group_of(n)))
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



#: ``J[:, columns]`` as one compiled call (eager indexing costs ~0.5 ms of Python per call)
_take_columns = LeanJit(lambda J, columns: jnp.take(J, columns, axis=1), maxsize=16)


def reselect(cand, robot, measurement, q, y, prior, start: Deviations, cur: Deviations, space: ParameterSpace,
             report):
    """Identifiability judged again with the extras where a fit put them (:func:`_extras_moved`):
    ``(space, report, message)`` with the parameters that became identifiable freed, or ``None``
    where none did (or nothing can change: no report, no free extras)."""
    # judge identifiability again where the fit put the extras: a start far from the truth
    # (a tool point started on the flange axis) can hide parameters that the solution shows
    if not report.held:
        return None
    free_extras = any(group_kind(n) == "extra" for n in space.free_names)
    if not free_extras:  # the robot's groups are judged at their start: nothing else moved
        return None
    # with the readings, as at the start: the report does not depend on them (the sample is the
    # prediction, or the readings where the Jacobian is free of them), and the start's compiled
    # program serves (without them, a second program of the same size compiled: ~11 s for a camera)
    new = _resolve_candidates(cand, robot, measurement, q, None, _extras_moved(start, cur), y, prior,
                              jacobian=False)[1]
    added = [n for n in new.space.free_names if n not in set(space.free_names)]
    if not added:
        return None
    space = ParameterSpace.from_names(space.layout, [*space.free_names, *added])
    message = (f"identifiability judged again with the extras where the fit put them: "
               f"{', '.join(added)} {'becomes' if len(added) == 1 else 'become'} identifiable "
               f"(not at the start) — freed and refit from the solution")
    # the start's report with the freed names moved over (the solution's own rank counts the
    # near-dependencies of real-size deviations, which stay held)
    report = dataclasses.replace(
        report, space=space, rank=report.rank + len(added), identifiable=(*report.identifiable, *added),
        unidentifiable=tuple(n for n in report.unidentifiable if n not in added),
        dependencies={k: v for k, v in report.dependencies.items() if k not in added})
    return space, report, message


def extras_to_start(cand: ParameterSpace, measurement: MeasurementModel) -> list[str]:
    """The extras of ``measurement`` (:attr:`~jaxcal.MeasurementModel.initialisable`) that the
    candidates ``cand`` free: those :func:`~jaxcal.initial_extras` starts from the data."""
    flags = extras_among(cand.free_names)
    groups = {group_of(n) for n in cand.free_names}
    flags["markers"] = any(g.startswith("marker_") for g in groups)
    for e in ("handeye", "target"):  # camera extras (jaxcal._sensors._camera)
        flags[e] = any(g.startswith(e + "_") for g in groups)
    families = {_family(g) for g in groups}
    flags.update({e: e in families for e in ("plane", "point")})
    return [e for e in measurement.initialisable if flags.get(e)]
