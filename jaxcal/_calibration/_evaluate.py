"""Checking a calibration on new measurements, the honest "before", and the defaults for measured data.

A calibration is believed once it predicts readings it has not seen. A new day's readings are
usually taken with the sensor set up again: the draw-wire anchor, the tracker's frame, the marker
plate are not where they were, so the robot is judged with those *extras* registered again on
the new rows, the robot itself fixed (closed form, :func:`jaxcal.initial_extras`, then a fit of
only the extras) — for the nominal robot ("before") and the calibrated one ("after") alike.
:func:`evaluate_result` (``jaxcal evaluate``) does that and
says which extras were registered or taken from the result.

"Before" everywhere (``jaxcal calibrate``, ``jaxcal evaluate``, :func:`jaxcal.holdout_session`) is
the nominal robot with the extras estimated from the data; the raw nominal model (the guessed
anchor / frame, as written in the measurement model) is only shown as its own line.

:data:`MEASURED_DEFAULTS` (the objective for measured data) and the named objectives live in
:mod:`jaxcal._fit._objective`; they are re-exported here.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._core._buckets import LeanJit, signature
from .._core._metrics import Metrics, format_table, metrics_numpy
from .._core._params import Deviations, ParameterSpace, group_kind, layout_for
from .._core._precision import to_device, uncommitted
from .._core._xla import ahead_enabled, compile_ahead, filter_jit, take_ahead
from .._fit._diagnostics import OutlierScan
from .._fit._objective import MEASURED_DEFAULTS, OBJECTIVES, describe_objective, resolve_objective
from .._sensors._initialise import _residual, _sample_error, has_plain_row_error, plain_row_errors, residual_rows

__all__ = ["MEASURED_DEFAULTS", "OBJECTIVES", "resolve_objective", "describe_objective", "Evaluation",
    "evaluate_result", "register_extras", "registrable_extras", "nominal_with_extras", "sample_errors",
    "evaluate_sessions", "relabelled_result", "match_labels", "residual_outliers"]

#: extra group families that a new set-up changes, and the :func:`jaxcal.initial_extras` name of each
_REGISTRABLE = {"anchor": "anchor", "cable_offset": "cable_offset", "base_rotation": "base",
                "base_translation": "base", "marker": "markers",
                "plane": "plane", "point": "point", "radius": "point",  # contact set-ups (jaxcal._sensors._contact)
                "handeye_rotation": "handeye", "handeye_translation": "handeye",  # a camera mounted again
                "target_rotation": "target", "target_translation": "target"}


# -- extras --------------------------------------------------------------------------------------------
def _family(group: str) -> str:
    g = group.partition("@")[0]
    return "marker" if g.startswith("marker_") else g


def registrable_extras(result) -> tuple[str, ...]:
    """The groups of ``result``'s free extras a new sensor set-up changes (anchor, cable offset,
    sensor frame, marker positions, contact planes / points, a camera's hand-eye transform and
    target pose); a tool point and a camera's intrinsics count as part of the robot / the sensor
    itself and are kept."""
    layout = result.space.layout
    groups = dict.fromkeys(layout.group_of(n) for n in result.space.free_names if group_kind(n) == "extra")
    return tuple(g for g in groups if _family(g) in _REGISTRABLE)


def relabelled_result(result, labels):
    """A contact result (plane / point) for data whose labels are ``labels``: the same robot and
    tool, the model's labels those of the data — the planes / points the result has keep their
    nominal geometry and deviations, new ones start at a zero nominal, free, so that
    :func:`evaluate_result` registers them on the new rows (a new placement of a plate, another
    table). The posterior covariance is kept for
    the parameters the result had, zero for the new labels (registered on the new data instead).
    ``result`` itself when it has every label."""
    from .._fit._diagnostics import Uncertainty
    from .._sensors._contact import FixedPoint, PlaneContact

    m = result.measurement
    labels = tuple(labels)
    if not isinstance(m, (PlaneContact, FixedPoint)) or set(labels) <= set(m.labels):
        return result
    new_labels = labels  # the file's labels: the ones the result has keep its nominal geometry
    at = [m.labels.index(s) if s in m.labels else -1 for s in new_labels]

    def take(a, fill):
        a = np.asarray(a, np.float64)
        return np.stack([a[i] if i >= 0 else np.asarray(fill, np.float64) for i in at])

    if isinstance(m, PlaneContact):
        new = PlaneContact(new_labels, take(m.normals, [0.0, 0.0, 1.0]), take(m.offsets, 0.0), tip=m.tip)
    else:
        r = np.asarray(m.radii, np.float64)
        new = FixedPoint(new_labels, take(m.centres, np.zeros(3)), take(r, r[0]) if m.sphere else None,
                         m.estimate_radius, tip=m.tip)
    layout = layout_for(result.robot, new)
    old = result.deviations.values
    dev = Deviations({g: old[g] for g in layout.group_names if g in old}, layout,
                     dtype=np.asarray(result.deviations._ravel_numpy()).dtype)
    added = [n for g in new.extra_groups() if g.name not in old for n in g.names]
    space = ParameterSpace.from_names(layout, [n for n in layout.names
                                               if n in set(result.space.free_names) or n in set(added)])
    out = dataclasses.replace(result, measurement=new, deviations=dev, space=space, x=space.to_vector_numpy(dev),
                              start=None)
    unc = result.uncertainty
    if unc is not None:
        idx = {n: i for i, n in enumerate(unc.names)}
        p = space.n_free
        cov = np.zeros((p, p))
        keep = [(j, idx[n]) for j, n in enumerate(space.free_names) if n in idx]
        if keep:
            a, b = (np.asarray(v) for v in zip(*keep))
            cov[np.ix_(a, a)] = np.asarray(unc.covariance)[np.ix_(b, b)]
        unc = Uncertainty(space.free_names, space.free_units, np.sqrt(np.diag(cov)), cov, unc.noise_std,
                          unc.effective_parameters, unc.n_residuals)
    object.__setattr__(out, "uncertainty", unc)
    return out


def has_guessed_extras(measurement) -> bool:
    """Whether the measurement model's own extras are a guess worth a "raw nominal" line: not for a
    camera whose hand-eye and target are the identity (no guess given: the target passes through
    the camera's centre and the reprojection errors are meaningless, ~1e8 px)."""
    if getattr(measurement, "kind", None) != "camera":
        return True
    frames = (measurement.handeye_rotation, measurement.handeye_translation, measurement.target_rotation,
              measurement.target_translation)
    eye = (np.eye(3), np.zeros(3), np.eye(3), np.zeros(3))
    return not all(np.allclose(np.asarray(a, np.float64), b) for a, b in zip(frames, eye))


def _extras_of(groups, source: Deviations, into: Deviations) -> Deviations:
    return into.replace(**{g: source.values[g] for g in groups}) if groups else into


def nominal_with_extras(result) -> Deviations:
    """The nominal robot (zero robot deviations) with ``result``'s starting extras (the
    closed-form estimate on the training data; zero where none ran) — the "before" of a random
    split of the training session."""
    layout = result.space.layout
    start = result.start if result.start is not None else result.deviations
    groups = [g for g in layout.group_names if all(group_kind(n) == "extra" for n in layout.group(g).names)]
    zero = Deviations.zeros(layout, np.asarray(start._ravel_numpy()).dtype)
    return _extras_of(groups, start, zero) if result.start is not None else zero


def register_extras(robot, measurement, data, deviations: Deviations, groups, *, loss: str = "huber", like=None):
    """``deviations`` with the extra ``groups`` registered on ``data`` (robot and every other entry
    fixed): closed form (:func:`jaxcal.initial_extras`), then LM on those groups only with the
    ``loss`` (Huber by default: a gross row on the new day must not move the frame). Returns
    ``(deviations, message)``.

    ``like``: the :class:`~jaxcal.CalibrationResult` whose set-up this is. The fit then runs the
    calibration's compiled solve (same program space and objective kind, the free set a run-time
    mask) instead of compiling one of its own: its estimated extras stay candidates (held fixed),
    and a calibration with a diagonal prior gives the fit the default :class:`Prior` — which puts
    none on sensor extras and whose robot rows the mask zeroes, so the registration's minimiser
    is the prior-free one (to round-off)."""
    from .._fit._objective import Prior
    from .._sensors._initial_extras import initial_extras
    from ._calibrate import calibrate
    from ._selection import extras_among

    if not groups:
        return deviations, ""
    est = sorted({_REGISTRABLE[_family(g)] for g in groups})
    start = initial_extras(robot, measurement, data, estimate=est, start=deviations)
    layout = layout_for(robot, measurement)
    names = [n for g in groups for n in layout.group(g).names]
    space = ParameterSpace.from_names(layout, names)
    extras, prior = (), None
    if like is not None:
        extras = [e for e, held in extras_among(like.space.free_names).items() if held]
        # the default prior leaves the sensor extras free (σ = inf); used only where it does so for
        # every registered parameter, so that the minimiser is the prior-free one
        diagonal = isinstance(like.prior, Prior) and not like.prior.covariance
        prior = Prior() if diagonal and np.all(np.isinf(Prior().std(space))) else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate(robot, measurement, data, "lm", space=space, start=start.deviations, init="none", loss=loss,
                        extras=extras, prior=prior)
    return res.deviations, start.message


def _host_sample_errors(robot, measurement, deviations: Deviations, data) -> np.ndarray:
    """:func:`sample_errors` of a plain-error model (:func:`~jaxcal._sensors._initialise.has_plain_row_error`) from the residual
    program of the calibration's host-side checks (one per models and row bucket, loaded where a
    calibration of the set-up compiled it): no program of its own."""
    return plain_row_errors(measurement, residual_rows(measurement, robot, deviations, data.q, data.y))


def sample_errors(robot, measurement, deviations: Deviations, data) -> np.ndarray:
    """Per-row errors (mm) of ``robot + deviations`` on ``data`` (compiled once per shape; a
    length, position or pose from the residual program the calibration's checks use)."""
    from .._fit._problem import Problem, sample_errors_at

    if has_plain_row_error(measurement):
        return _host_sample_errors(robot, measurement, deviations, data)
    q = to_device(data.q)  # not jnp.asarray: a copy program per shape
    space = ParameterSpace.from_names(layout_for(robot, measurement), [])
    # uncommitted: a fit's deviations and zeros run one program, not one per placement
    pr = Problem(robot, measurement, q, data.y, space, uncommitted(deviations.astype(q.dtype)))
    return np.asarray(sample_errors_at(pr, pr.x0()), np.float64)


def sample_errors_many(robot, measurement, deviations, datasets) -> list[np.ndarray]:
    """Per-row errors (mm) of ``robot + d`` for every ``d`` in ``deviations`` on every dataset of
    ``datasets`` (one ``measurement`` model for all): a list with one ``[len(deviations), n_i]``
    array per dataset, the values of :func:`sample_errors` (the same operations on the same
    shapes), from one compiled program where :func:`sample_errors` per deviations and dataset
    runs one per shape (the command line's before/after table: four programs, each loaded from
    the compilation cache at every start); a length, position or pose from the residual program
    of the calibration's checks, as :func:`sample_errors`. The datasets are not concatenated:
    XLA:CPU's code for another row count can differ in the last bits."""
    if has_plain_row_error(measurement):  # no program of its own (see sample_errors)
        return [np.stack([_host_sample_errors(robot, measurement, d, ds) for d in deviations]) for ds in datasets]
    # to_device, not jnp.asarray: that compiles a copy program per shape
    qs, ys = tuple(to_device(ds.q) for ds in datasets), tuple(to_device(ds.y) for ds in datasets)
    devs = tuple(d.astype(qs[0].dtype) for d in deviations)
    return [np.asarray(e, np.float64) for e in _sample_errors_many(robot, measurement, devs, qs, ys)]


def _sample_errors_many_fn(robot, measurement, deviations, qs, ys):
    from .._fit._problem import Problem

    space = ParameterSpace.from_names(layout_for(robot, measurement), [])
    out = []
    for q, y in zip(qs, ys):
        errors = []
        for d in deviations:  # the kinematics once per deviations: the ops of sample_errors_at
            pr = Problem(robot, measurement, q, y, space, d)
            errors.append(pr.sample_errors(pr.x0()))
        out.append(jnp.stack(errors))
    return out


#: compiled once per (models, number of deviations, shapes) and kept in a bounded cache
_sample_errors_many = LeanJit(_sample_errors_many_fn, maxsize=8)


def before_after_errors(result, robot, measurement, sets) -> tuple[bool, dict]:
    """The per-row errors of a calibration's accuracy table (``jaxcal calibrate``'s before/after
    table and result file): ``(show_raw, {name: (before, after, raw)})`` for every ``name: (data,
    model)`` of ``sets`` (e.g. ``{"train": (train, measurement), "test": (test, model)}``), arrays
    ``[n]`` in the model's unit.

    *before* is the nominal robot with the sensor extras estimated from the data
    (:func:`nominal_with_extras`), *after* the calibrated robot (with its learned correction, an
    RBF network, on data of ``measurement``: the model ``result`` was fitted with), *raw* the
    nominal robot with the model's guessed extras (nothing estimated) — only where extras were
    estimated and the model has a guess (``show_raw``; else ``None``). One compiled program per
    model (:func:`sample_errors_many`), not one per deviations and part."""
    dev_before = nominal_with_extras(result)
    first = next(iter(sets.values()))[0]
    zero = Deviations.zeros(result.space.layout, np.asarray(first.q).dtype)
    show_raw = (any(group_kind(n) == "extra" for n in result.space.free_names)
                and has_guessed_extras(measurement))
    devs = (dev_before, result.deviations, zero) if show_raw else (dev_before, result.deviations)
    errors = {}
    for m in {id(m): m for _, m in sets.values()}.values():
        names = [n for n, (_, m_n) in sets.items() if m_n is m]
        errors.update(zip(names, sample_errors_many(robot, m, devs, [sets[n][0] for n in names])))
    out = {}
    for name, (ds, m) in sets.items():
        eb, ea = errors[name][0], errors[name][1]
        if m is measurement and result.predictor is not None:  # a learned correction (RBF) of the model
            ea = np.asarray(result.sample_errors(ds), np.float64)
        out[name] = (eb, ea, errors[name][2] if show_raw else None)
    return show_raw, out


def joints_to_file_units(robot, q) -> np.ndarray:
    """Joint readings ``[n, dof]`` (rad, mm at prismatic joints) in the files' units: degrees, mm."""
    rad = np.asarray([u == "rad" for u in robot.joint_units()])
    q = np.asarray(q, np.float64)
    return np.where(rad[None, :], np.rad2deg(q), q)


def joints_from_file_units(robot, q) -> np.ndarray:
    """Inverse of :func:`joints_to_file_units`."""
    rad = np.asarray([u == "rad" for u in robot.joint_units()])
    q = np.asarray(q, np.float64)
    return np.where(rad[None, :], np.deg2rad(q), q)


# -- evaluation ----------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, eq=False)
class Evaluation:
    """A calibration checked on new data (:func:`evaluate_result`).

    Attributes:
        before: RMSE/MEAN/MAX (mm) of the nominal robot with the extras estimated from the new
            data (closed form + a fit of the extras only, robot fixed) — or, where the extras are
            taken from the result, still estimated from the new data (the best case for nominal).
        after: of the calibrated robot, its extras registered the same way or taken from the result.
        raw_nominal: of the nominal robot with the measurement model's guessed extras (nothing
            estimated): shown for reference only; ``None`` where the model has no guess (a
            camera's identity hand-eye and target: the target through the camera's centre).
        before_errors, after_errors: ``[n]`` per-row errors (:attr:`unit`: mm; px for a camera).
        q: ``[n, dof]`` the rows' joint angles (rad).
        extras: ``"registered"`` (re-estimated on the new rows: a new day's frame/anchor),
            ``"result"`` (taken from the calibration) or ``"none"`` (no extras were estimated).
        registered: the groups re-registered (empty unless ``extras == "registered"``).
        kept: extras the calibration estimated that are not a sensor set-up (a tool point, a
            camera's intrinsics): taken from the result for the calibrated robot (and for the
            nominal one where no set-up extras are registered: nothing else to compare).
        unit: the unit of the errors and metrics (the model's ``unit``: ``"mm"``, ``"px"``).
        message: one line saying where the extras came from.
        outlier_rows: rows (positions in the data, from 0) whose after-residual is an outlier in
            the rows' own robust σ̂ (:func:`residual_outliers`, a 1 % false-alarm rate over the
            file's clean rows by default); ``outlier_scale_mm`` that σ̂ (:attr:`unit`);
            ``outlier_scan`` the whole scan (threshold, rate), ``None`` on an old evaluation.
        deviations_before, deviations_after: the deviations evaluated.
        q_file: ``[n, dof]`` the joint readings in the files' units (degrees; mm at prismatic joints).
        objective: the calibration's objective (one line), if known.
        expected_rmse: the RMSE (mm) the calibration itself predicts on these rows
            (:func:`expected_rmse`: its σ̂ and its parameter uncertainty at these poses), or
            ``None`` where the result has no uncertainty; ``worse_than_expected`` says whether
            the calibrated robot did clearly worse (more than :data:`EXPECTED_FACTOR` times).

    ``rmse``/``mean``/``max`` are the ``after`` numbers; ``worse`` says whether the calibrated robot
    predicts the data worse than the nominal one.
    """

    before: Metrics
    after: Metrics
    raw_nominal: Metrics | None
    before_errors: np.ndarray
    after_errors: np.ndarray
    q: np.ndarray
    extras: str
    registered: tuple[str, ...]
    message: str
    outlier_rows: tuple[int, ...]
    outlier_scale_mm: float
    deviations_before: Deviations
    deviations_after: Deviations
    objective: str | None = None
    q_file: np.ndarray | None = None
    expected_rmse: float | None = None
    kept: tuple[str, ...] = ()
    unit: str = "mm"
    outlier_scan: OutlierScan | None = None

    @property
    def worse_than_expected(self) -> bool:
        """The calibrated robot's RMSE on these rows is more than :data:`EXPECTED_FACTOR` times
        what the calibration predicts (:attr:`expected_rmse`): the set-up changed since (tool,
        sensor, robot), the rows lie where the calibration did not look, or the noise is larger."""
        return self.expected_rmse is not None and self.after.rmse > EXPECTED_FACTOR * self.expected_rmse

    def expectation(self) -> tuple[str | None, str | None]:
        """``(line, warning)``: the expected and the measured RMSE in one line, and when the rows fit
        worse than expected (:attr:`worse_than_expected`) a sentence saying so; ``None`` for
        what does not apply. Printed by ``str()``, ``jaxcal evaluate`` and ``jaxcal calibrate --test``."""
        if self.expected_rmse is None:
            return None, None
        u = self.unit
        line = (f"expected from the calibration (its σ̂ and parameter uncertainty at these poses): RMSE "
                f"{self.expected_rmse:.3g} {u}; measured {self.after.rmse:.3g} {u}")
        warning = (f"{self.after.rmse / self.expected_rmse:.1f}× worse than the calibration predicts (RMSE "
                   f"{self.after.rmse:.4g} vs {self.expected_rmse:.4g} {u}): has the set-up changed since (tool, "
                   "sensor, a collision), do these poses lie outside the calibrated workspace, or is the noise "
                   "larger today?") if self.worse_than_expected else None
        return line, warning

    @property
    def rmse(self) -> float:
        return self.after.rmse

    @property
    def mean(self) -> float:
        return self.after.mean

    @property
    def max(self) -> float:
        return self.after.max

    @property
    def n(self) -> int:
        return int(self.after_errors.shape[0])

    @property
    def worse(self) -> bool:
        """The calibrated robot predicts these data worse (higher RMSE) than the nominal one."""
        return not (self.after.rmse <= self.before.rmse)

    def rows(self) -> list[tuple[str, Metrics]]:
        """``[(label, Metrics)]``: raw nominal (when extras were estimated and the model has a
        guess), before, after."""
        out = []
        if self.extras != "none" and self.raw_nominal is not None:
            out.append(("raw nominal (guessed extras, nothing estimated)", self.raw_nominal))
        kept = f"{', '.join(self.kept)} from the result" if self.kept else ""
        lab = "extras from the data" if self.extras != "none" else kept or "nothing estimated"
        out.append((f"before: nominal robot, {lab}", self.before))
        lab = {"registered": "extras re-registered", "result": "extras from the result",
               "none": kept or "no extras"}[self.extras] + (f", {kept}" if kept and self.extras != "none" else "")
        out.append((f"after: calibrated robot, {lab}", self.after))
        return out

    def table(self) -> str:
        rows = [[name, m.rmse, m.mean, m.max] for name, m in self.rows()]
        u = self.unit
        return format_table(rows, ["data", f"RMSE/{u}", f"MEAN/{u}", f"MAX/{u}"],
                            title=f"Accuracy on {self.n} new rows before/after calibration")

    def __str__(self) -> str:
        return self.describe()

    def describe(self, outliers: bool = True) -> str:
        """What ``str()`` prints: where the extras came from, the before/after table, the outlier
        rows (``outliers``; ``jaxcal evaluate`` warns about them naming the file instead), the
        verdict and the expected RMSE."""
        lines = [self.message, self.table()]
        if outliers and self.outlier_rows and self.outlier_scan is not None:
            lines.append(self.outlier_message("these rows"))
        verdict = ("WORSE than the nominal robot" if self.worse else
                   f"{100 * (1 - self.after.rmse / self.before.rmse):.1f} % lower RMSE than the nominal robot"
                   if self.before.rmse > 0 else "")
        lines.append(f"calibrated robot on these data: {verdict}")
        line, warning = self.expectation()
        lines += [] if line is None else [line]
        lines += [] if warning is None else [f"WARNING: {warning}"]
        return "\n".join(lines)

    def outlier_message(self, where: str) -> str | None:
        """The outlier rows as one sentence (:meth:`OutlierScan.message`), named as 1-based data rows
        of the new data (``where``: its file), or ``None`` when none was flagged."""
        if not self.outlier_rows or self.outlier_scan is None:
            return None
        return self.outlier_scan.message(where, [r + 1 for r in self.outlier_rows],
                                         "they are in the 'after' RMSE/MAX above; check those rows")

    def to_dict(self) -> dict:
        """JSON-friendly: ``metrics_mm`` (``before``, ``after``, ``raw_nominal``), extras, outliers,
        per-row errors and joint angles (degrees)."""
        return {
            "metrics_mm": {"before": self.before._asdict(), "after": self.after._asdict(),
                           **({} if self.raw_nominal is None else {"raw_nominal": self.raw_nominal._asdict()})},
            "unit": self.unit,
            "worse": self.worse,
            "extras": {"source": self.extras, "registered": list(self.registered), "kept": list(self.kept),
                       "message": self.message},
            "objective": self.objective,
            "expected_rmse_mm": self.expected_rmse,
            "worse_than_expected": self.worse_than_expected,
            "outlier_rows": [r + 1 for r in self.outlier_rows],
            "outlier_scale_mm": self.outlier_scale_mm,
            "outlier_threshold": None if self.outlier_scan is None else self.outlier_scan.threshold,
            "outlier_rate": None if self.outlier_scan is None else self.outlier_scan.rate,
            "n_samples": self.n,
            "rows": {"row": list(range(1, self.n + 1)), "q_deg": (np.rad2deg(self.q) if self.q_file is None else self.q_file).tolist(),
                     "before_mm": self.before_errors.tolist(), "after_mm": self.after_errors.tolist()},
            "deviations_before": self.deviations_before.named(),
            "deviations_after": self.deviations_after.named(),
        }


def residual_outliers(robot, measurement, deviations, data, k: float | None = None, *, rate: float = 0.01,
                      n_file: int | None = None) -> OutlierScan:
    """Rows of ``data`` with a gross error under a given model, e.g. the held-out rows of a fit
    (``jaxcal calibrate`` names them; they enter the test RMSE/MAX, not the fit), or a new day's
    rows (``jaxcal evaluate``).

    The rows are judged in their own robust σ̂ (1.4826·MAD of their residual entries; a pose's
    position part) with the threshold for a false-alarm probability ``rate`` over ``n_file`` clean
    Gaussian rows (:func:`~jaxcal._fit._diagnostics.outlier_threshold`; about 4.4 σ̂ for 800
    one-entry rows), or a fixed ``k``.

    Args:
        robot, measurement: the models (``measurement`` of these rows).
        deviations: the robot's and the sensor's deviations (a result's ``.deviations``).
        data: the rows (a :class:`~jaxcal.Dataset`).
        k: a fixed threshold in robust σ̂ on a row's residual norm instead of ``rate``.
        rate: the chance that any of ``n_file`` clean rows is flagged (default 1 %).
        n_file: the rows of the file these rows are part of (default: ``data``'s; a file's test
            rows scanned with the file's count and :func:`~jaxcal._fit._diagnostics.file_rate` of
            the rate keep the file's rate over its training and test scans together).

    Returns:
        :class:`~jaxcal._fit._diagnostics.OutlierScan`: ``.rows`` (positions in ``data``, from 0),
        ``.scale`` (σ̂ in mm; px for camera data), ``.k``, ``.rate``, ``.message(...)``. It unpacks
        as ``rows, scale = residual_outliers(...)``, as before issue 53.
    """
    from .._fit._diagnostics import Checks, scan_outliers
    from .._fit._problem import Problem

    q = to_device(data.q)  # not jnp.asarray: a copy program per shape
    space = ParameterSpace.from_names(layout_for(robot, measurement), [])
    pr = Problem(robot, measurement, q, data.y, space, deviations.astype(q.dtype))
    (scan,) = scan_outliers(pr, pr.x0(), Checks(outlier_rate=rate, outlier_k=k), n_file=n_file)
    return scan


#: :attr:`Evaluation.worse_than_expected` when the measured RMSE exceeds this many times the expected
#: one (the RMSE of 20 draw-wire rows scatters by ~16 % (1 sd) around its expectation)
EXPECTED_FACTOR = 1.5


@functools.lru_cache(maxsize=1)
def _jacobian_program():

    return filter_jit(lambda problem: problem.to_blocks(problem.jacobian(problem.x0())).reshape(problem.n_residuals, -1))


def _registered_problem(result, data, registered, deviations):
    """``(problem, registered names, robot names)`` of :func:`_registered_terms`: the Jacobian's
    problem at ``deviations`` (uncommitted: the compile-ahead's zeros and a fit's deviations run
    one program) over the robot's free parameters with an uncertainty and the ``registered``
    extras."""
    from .._fit._problem import Problem

    layout = result.space.layout
    e_names = [n for g in registered for n in layout.group(g).names]
    theta = [n for n in result.space.free_names if n not in set(e_names) and n in result.uncertainty.names]
    space = ParameterSpace.from_names(layout, [n for n in layout.names if n in set(theta) | set(e_names)])
    q = to_device(np.asarray(data.q, np.float64))
    pr = Problem(result.robot, result.measurement, q, to_device(np.asarray(data.y, np.float64)), space,
                 uncommitted(deviations.astype(q.dtype)))
    return pr, e_names, theta


def _registered_key(pr) -> tuple | None:
    """What decides the Jacobian program of :func:`_registered_terms` (its static part, shapes and
    dtypes), or ``None`` where it is not hashable."""
    dyn, stat = eqx.partition(pr, eqx.is_array)
    try:
        key = (stat, signature(dyn))
        hash(key)
    except TypeError:
        return None
    return key


#: Jacobian programs of :func:`_registered_terms` being compiled on the background thread, by key
_JACOBIAN_AHEAD: dict = {}


def _compile_registered_ahead(result, data, registered) -> None:
    """Start compiling (and running once, at zero deviations) the Jacobian program of
    :func:`_registered_terms` on the background compile thread while :func:`evaluate_result`
    registers the extras: its largest program (0.4-0.6 s on 2 CPU cores), independent of the
    registration's result. Nothing happens on a single core or with ``JAXCAL_COMPILE_AHEAD=off``."""
    if not ahead_enabled():
        return
    pr, _, _ = _registered_problem(result, data, registered, Deviations.zeros(result.space.layout, np.float64))
    key = _registered_key(pr)
    if key is not None:
        compile_ahead(_JACOBIAN_AHEAD, key, lambda: jax.block_until_ready(_jacobian_program()(pr)))


def _registered_terms(result, data, registered, deviations):
    """``(mean prediction variance per sample, registered parameters p_E, residual entries N)`` when
    the extras ``registered`` are fitted again on ``data`` with the robot fixed: the robot's
    uncertainty seen through ``M = I − J_E J_E⁺`` (what the registration does not absorb: a base
    rotation the prior alone held is absorbed by new point centres), at ``data``'s own readings
    (labels pick the plane/point of each row)."""
    m = result.measurement
    unc = result.uncertainty
    pr, e_names, theta = _registered_problem(result, data, registered, deviations)
    q = pr.q
    take_ahead(_JACOBIAN_AHEAD, _registered_key(pr))  # compiled on the background thread (evaluate_result)
    J = np.asarray(_jacobian_program()(pr), np.float64)
    obs = m.observed(np.asarray(data.y))
    size = m.size
    keep = np.ones(J.shape[0], bool) if obs is None else np.asarray(obs, bool).reshape(-1)
    if m.error_entries is not None:  # a pose's position part, as the sample error
        keep &= np.tile(np.arange(size) < m.error_entries, q.shape[0])
    J = np.where(keep[:, None], J, 0.0)
    idx = {n: i for i, n in enumerate(pr.space.free_names)}
    JE, Jt = J[:, [idx[n] for n in e_names]], J[:, [idx[n] for n in theta]]
    U, s, _ = np.linalg.svd(JE, full_matrices=False)
    U = U[:, s > 1e-10 * (s[0] if s.size else 1.0)]
    MJ = Jt - U @ (U.T @ Jt)
    ui = [unc.names.index(n) for n in theta]
    cov = np.asarray(unc.covariance, np.float64)[np.ix_(ui, ui)]
    v = np.einsum("ip,pq,iq->i", MJ, cov, MJ).reshape(q.shape[0], size).sum(axis=1)
    return float(np.mean(v)), U.shape[1], int(keep.sum())


def _has_expectation(result) -> bool:
    """Whether ``result`` predicts its own error (:func:`expected_rmse`): an uncertainty with a
    finite noise estimate, and no learned predictor of its own (the RBF network)."""
    unc = result.uncertainty
    return unc is not None and result.predictor is None and unc.noise_std > 0 and math.isfinite(unc.noise_std)


def expected_rmse(result, data, registered=(), deviations=None) -> float | None:
    """The RMSE (mm) that ``result`` predicts for itself on ``data``'s poses: ``sqrt(c·σ̂² + v̄/w)``
    with σ̂ the calibration's noise estimate, ``c = E[e²]`` of a sample error on unit noise (1 for a
    length, 3 for a position's norm or an RMS over markers: the model's own
    :meth:`~jaxcal.MeasurementModel.sample_error`, by the Monte Carlo of
    :func:`~jaxcal._fit._diagnostics.robust_consistency`), ``v̄`` the mean prediction variance
    at the poses (:meth:`~jaxcal.CalibrationResult.prediction_std`, summed over coordinates) and
    ``w`` the coordinates one sample error averages over. On poses like the training poses this is
    the statistical floor of a new pose (:func:`jaxcal.statistical_floor`), with σ̂ for σ; away
    from them the parameter term grows. Approximate where the extras are registered again on the
    new rows (their own fit then takes the place of the result's extras' uncertainty). ``None``
    where the result has no uncertainty (a loaded result from an old file; a method with its own
    predictor, the RBF network). ``registered``: extra groups fitted again on ``data`` (robot fixed) at
    ``deviations``: the parameter term then counts only what the registration cannot absorb, and the
    noise term the ``p_E`` parameters the registration fits, ``σ̂²(1 − p_E/N)`` per entry."""
    from .._fit._diagnostics import robust_consistency

    if not _has_expectation(result):
        return None
    unc = result.uncertainty
    m = result.measurement
    c = robust_consistency(m, "linear", m.observed(data.y)).mean_sq_error
    coords = m.size if m.error_entries is None else m.error_entries
    if registered:
        mean_var, p_e, n_entries = _registered_terms(result, data, registered, deviations)
        noise = unc.noise_std ** 2 * max(0.0, 1.0 - p_e / max(n_entries, 1))
        value = math.sqrt(c * noise + mean_var * c / coords)
        return value if math.isfinite(value) else None
    var = result.prediction_std(data.q, data.y) ** 2  # the readings pick a contact row's plane / point
    value = math.sqrt(c * unc.noise_std ** 2 + float(np.mean(var)) * c / coords)
    return value if math.isfinite(value) else None


def match_labels(result, data):
    """``(result, data, new)`` for a contact result (plane / point) and a contact
    :class:`~jaxcal.Dataset` whose ``plane_labels``/``point_labels`` metadata name its labels: the
    result relabelled to the data's labels (:func:`relabelled_result`: labels it has not seen,
    ``new``, get zero values, to be registered on the data) and the data's label indices
    renumbered to the result's label order. Anything else comes back unchanged (``new`` empty)."""
    from .._datasets._dataset import Dataset, relabel
    from .._sensors._contact import dataset_labels, label_metadata_key
    from .._sensors._kind import sensor_kind

    m = result.measurement
    if not (isinstance(data, Dataset) and data.kind == m.kind and sensor_kind(m.kind).labelled
            and data.meta.get(label_metadata_key(data.kind))):
        return result, data, ()
    labels = dataset_labels(data)
    new = tuple(s for s in labels if s not in m.labels)
    result = relabelled_result(result, labels)
    return result, relabel(data, result.measurement.labels), new


def evaluate_result(result, data, *, extras: str = "auto", objective: str | None = None,
                    outlier_rate: float = 0.01) -> Evaluation:
    """Check ``result`` (a :class:`~jaxcal.CalibrationResult`, e.g. from :func:`jaxcal.load_result`)
    on new ``data`` (a :class:`~jaxcal.Dataset` of the same kind).

    Example:
        A calibration saved on Monday, checked on Tuesday's readings of a sensor set up again
        (``jaxcal evaluate monday.json tuesday.csv`` does the same):

        ```python
        res = jaxcal.load_result("monday.json")
        ev = jaxcal.evaluate_result(res, jaxcal.load_csv("tuesday.csv"))  # extras registered again
        print(ev)                    # before/after RMSE/MEAN/MAX (mm), what was registered
        line, warning = ev.expectation()   # the RMSE the calibration expects vs the measured one
        ```

    Args:
        extras: ``"register"``: the result's sensor extras (anchor, cable offset, sensor frame,
            marker positions) are registered again on ``data`` with the robot fixed, for the
            nominal and the calibrated robot alike — a new day's set-up; ``"result"``: the
            calibrated robot keeps the result's extras (the same set-up as the training data; the
            nominal robot still gets extras estimated from ``data``); ``"auto"`` (default):
            ``"register"`` when the result estimated such extras and ``data`` has enough rows
            (more residuals than twice the extras' parameters), else ``"result"``.
        objective: a line naming the calibration's objective, kept on the evaluation.
        outlier_rate: the outlier scan's false-alarm probability over the new rows (their own
            robust σ̂; :func:`residual_outliers`): the chance that any clean row is named.

    Returns:
        :class:`Evaluation`.
    """
    from .._datasets._dataset import Dataset
    from ._calibrate import _as_arrays

    robot, m = result.robot, result.measurement
    if m.row_sessions:  # SessionMarkers: the new data's sessions get their own model

        return evaluate_sessions(result, data, extras=extras, objective=objective, outlier_rate=outlier_rate)
    if not isinstance(data, Dataset):
        q, y = _as_arrays(data, m, robot)
        data = Dataset(q, y, m.kind)
    result, data, _ = match_labels(result, data)  # the data's plane / point labels, new ones included
    m = result.measurement
    _as_arrays(data, m, robot)  # kind, shapes, joint limits
    if extras not in ("auto", "register", "result"):
        raise ValueError(f"extras must be 'auto', 'register' or 'result', got {extras!r}")
    groups = registrable_extras(result)
    layout = result.space.layout
    n_par = sum(len(layout.group(g).names) for g in groups)
    enough = data.n * m.size > 2 * n_par and data.n >= 6
    why = ""
    if extras == "register" and groups and not enough:
        raise ValueError(f"{data.n} rows are too few to register {', '.join(groups)} ({n_par} parameters) again; "
                         "keep the calibration's extras instead (--keep-extras on the command line, "
                         "extras \"result\" in Python)")
    mode = extras if extras != "auto" else ("register" if groups and enough else "result")
    if extras == "auto" and groups and not enough:
        why = f" ({data.n} rows are too few to register them again)"
    dtype = np.asarray(data.q).dtype
    zero = Deviations.zeros(layout, dtype)
    raw = metrics_numpy(sample_errors(robot, m, zero, data)) if has_guessed_extras(m) else None
    # estimated extras that are no sensor set-up (a tool point, a camera's intrinsics): part of the
    # robot / the sensor here, taken from the result before and after
    kept = tuple(g for g in dict.fromkeys(layout.group_of(n) for n in result.space.free_names)
                 if g not in groups and all(group_kind(n) == "extra" for n in layout.group(g).names))
    what = f"; {', '.join(kept)} (estimated with the robot, not a new set-up) taken from the calibration for "
    held = f"{what}the nominal and the calibrated robot alike" if kept else ""
    if not groups:
        dev_b, dev_a = _extras_of(kept, result.deviations, zero), result.deviations
        source, registered = "none", ()
        msg = ("no sensor set-up extras to register (none estimated in the calibration); the saved sensor model is "
               f"used before and after{held}" if not kept else
               f"no sensor set-up extras to register{held}")
    else:
        if mode == "register" and _has_expectation(result):  # expected_rmse's program, while the extras are registered
            _compile_registered_ahead(result, data, groups)
        dev_b, msg_b = register_extras(robot, m, data, zero, groups, like=result)  # the nominal robot, its nominal tool
        held = f"{what}the calibrated robot (the nominal robot keeps its nominal one)" if kept else ""
        if mode == "register":
            keep = _extras_of(groups, zero, result.deviations)  # extras back to the guess, robot calibrated
            dev_a, _ = register_extras(robot, m, data, keep, groups, like=result)
            source, registered = "registered", groups
            msg = (f"extras re-registered on the new data (a new set-up: {', '.join(groups)}), robot fixed, for the "
                   f"nominal and the calibrated robot alike (closed form, then a fit of the extras only){held}")
        else:
            dev_a = result.deviations
            source, registered = "result", ()
            msg = (f"extras taken from the calibration result ({', '.join(groups)}: the same set-up as the training "
                   f"data{why}); the nominal robot's extras estimated from the new data{held}")
    eb = sample_errors(robot, m, dev_b, data)
    ea = sample_errors(robot, m, dev_a, data)
    scan = residual_outliers(robot, m, dev_a, data, rate=outlier_rate)
    rows, scale = scan.rows, scan.scale
    return Evaluation(
        before=metrics_numpy(eb), after=metrics_numpy(ea), raw_nominal=raw, before_errors=eb, after_errors=ea,
        q=np.asarray(data.q, np.float64), extras=source, registered=tuple(registered), message=msg,
        outlier_rows=rows, outlier_scale_mm=scale if math.isfinite(scale) else float("nan"),
        deviations_before=dev_b, deviations_after=dev_a, objective=objective,
        q_file=joints_to_file_units(robot, data.q),
        expected_rmse=expected_rmse(result, data, registered, dev_a if registered else None),
        kept=kept, unit=getattr(m, "unit", "mm"), outlier_scan=scan,
    )


def _errors(robot, m, dev, q, y) -> np.ndarray:
    """Per-row marker errors (mm), compiled (the same jitted residual as the extras start)."""
    return np.asarray(_sample_error(m, _residual(m, robot, dev, jnp.asarray(q), jnp.asarray(y))), np.float64)


def _register(robot, m, q, y, dev, groups, frames, placements, loss: str = "linear"):
    """Closed form, then LM on ``groups`` only (robot and other extras fixed at ``dev``)."""
    from .._sensors._sessions import initial_sessions
    from ._calibrate import calibrate

    if not groups:
        return dev
    dev = initial_sessions(robot, m, (q, y), start=dev, frames=frames, placements=placements).deviations
    layout = layout_for(robot, m)
    names = [n for g in groups for n in layout.group(g).names]
    space = ParameterSpace.from_names(layout, names)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate(robot, m, (jnp.asarray(q), jnp.asarray(y)), "lm", space=space, start=dev, init="none",
                        loss=loss)
    return res.deviations


def evaluate_sessions(result, data, *, extras: str = "auto", objective: str | None = None,
                      outlier_rate: float = 0.01):
    """:func:`jaxcal.evaluate_result` for a :class:`SessionMarkers` calibration: the calibrated
    robot on new marker ``data`` (a :class:`~jaxcal.Dataset`; with session labels, or without:
    then one new session labelled ``"new"``), whose sessions may have other frames, placements
    and marker counts (a one-point session: NaN in the other markers' columns).

    The new data get their own :class:`SessionMarkers` (:meth:`SessionMarkers.from_dataset`); the
    robot's deviations are the result's. Every frame and placement of the new data is
    **registered** on its rows with the robot fixed (closed form, then a Huber fit of those
    groups only), for the nominal and the calibrated robot alike — ``extras="register"``, and
    ``"auto"`` when there are more residuals than twice the extras' parameters; with
    ``"result"`` the calibrated robot keeps the result's values of the labels it was trained on
    (same label, same marker) and only labels the result has not seen are registered.

    Returns:
        :class:`jaxcal.Evaluation` (``registered`` names every group fitted on the new rows).
    """
    from .._datasets._dataset import Dataset
    from .._sensors._sessions import SessionMarkers, masked_markers

    robot = result.robot
    if extras not in ("auto", "register", "result"):
        raise ValueError(f"extras must be 'auto', 'register' or 'result', got {extras!r}")
    if not isinstance(data, Dataset) or data.kind != SessionMarkers.kind:
        raise ValueError("a session-marker result is evaluated on marker data: give a jaxcal.Dataset of kind "
                         "'markers' (load_csv of a marker file)")
    if not data.labels:
        data = Dataset(data.q, data.y, "markers", data.metadata, labels=[("new", "new", "new")] * data.n)
    m = SessionMarkers.from_dataset(data)
    m.check_measurements(data.y, data.n)
    q, y = np.asarray(data.q), np.asarray(data.y)
    layout = layout_for(robot, m)
    dtype = q.dtype
    zero = Deviations.zeros(layout, dtype)
    # the robot's groups (every group without a session label) from the result
    robot_groups = [g for g in layout.group_names if "@" not in g and g in result.deviations.values]
    calibrated = zero.replace(**{g: jnp.asarray(result.deviations.values[g]).astype(dtype) for g in robot_groups})
    every = tuple(g for f in m.frames for g in m.groups_of(frame=f)) + tuple(
        g for p in m.placements for g in m.groups_of(placement=p))
    n_par = sum(len(layout.group(g).names) for g in every)
    obs = m.observed(y)
    enough = int(y.size if obs is None else obs.sum()) > 2 * n_par
    mode = extras if extras != "auto" else ("register" if enough else "result")
    known = set(result.deviations.values) if mode == "result" else set()
    kept = tuple(g for g in every if g in known)
    if kept:
        calibrated = calibrated.replace(**{g: jnp.asarray(result.deviations.values[g]).astype(dtype) for g in kept})
    new = tuple(g for g in every if g not in kept)
    if not enough and new:
        raise ValueError(f"{data.n} rows are too few to register {', '.join(new)} ({n_par} parameters) on the new "
                         "data; give more rows")
    new_f = [f for f in m.frames if any(g in new for g in m.groups_of(frame=f))]
    new_p = [p for p in m.placements if any(g in new for g in m.groups_of(placement=p))]
    dev_b = _register(robot, m, q, y, zero, every, list(m.frames), list(m.placements), loss="huber")
    dev_a = _register(robot, m, q, y, calibrated, new, new_f, new_p, loss="huber")
    eb, ea = _errors(robot, m, dev_b, q, y), _errors(robot, m, dev_a, q, y)
    raw = _errors(robot, m, zero, q, y)
    scan = residual_outliers(robot, m, dev_a, data, rate=outlier_rate)
    rows, scale = scan.rows, scan.scale
    n_miss, n_all, n_rows = masked_markers(y)
    gaps = (f"; {n_miss} of {n_all} marker readings missing (NaN) in {n_rows} row(s): masked (zero weight)"
            if n_miss else "")
    source = "registered" if new else "result"
    how = ("re-registered on the new rows" if not kept else
           f"{len(new)} group(s) registered on the new rows, {len(kept)} taken from the result")
    msg = (f"session frames ({', '.join(m.frames)}) and marker placements ({', '.join(m.placements)}) of the new "
           f"data: {how}, robot fixed (for the nominal robot every one is registered); closed form, then a Huber fit of "
           f"the extras only{gaps}")
    return Evaluation(
        before=metrics_numpy(eb), after=metrics_numpy(ea), raw_nominal=metrics_numpy(raw), before_errors=eb,
        after_errors=ea, q=np.asarray(q, np.float64), extras=source, registered=new, message=msg, outlier_rows=rows,
        outlier_scale_mm=scale if np.isfinite(scale) else float("nan"), deviations_before=dev_b,
        deviations_after=dev_a, objective=objective, q_file=joints_to_file_units(robot, q), outlier_scan=scan)
