"""Drift over time: which robot parameters moved between two calibrations of one unit, beyond their uncertainty."""

from __future__ import annotations

import math
import statistics
from typing import NamedTuple

import numpy as np

from .._core._metrics import format_table
from .._core._params import group_of
from ._prior import robot_part

__all__ = ["drift", "DriftReport", "DriftRow", "parameter_label"]

#: what a DH group's entry is, for the report's sentences
_WHAT = {"alpha": "twist α", "a": "link length a", "d": "link offset d", "theta": "offset θ", "beta": "tilt β"}


def parameter_label(name: str) -> str:
    """``"theta_3"`` → ``"joint 3's offset θ"``; other names as they are."""
    g = group_of(name)
    head, _, tail = name.rpartition("_")
    return f"joint {tail}'s {_WHAT[g]}" if g in _WHAT and head == g and tail.isdigit() else name


class DriftRow(NamedTuple):
    """One robot parameter of a :class:`DriftReport` (display units: degrees for angles, mm).

    Attributes:
        name: parameter name (``"theta_3"``).
        label: ``"joint 3's offset θ"``.
        unit: ``"°"`` or ``"mm"`` (the display unit).
        change: current − previous estimate.
        std: σ of the change (both calibrations' posterior σ in quadrature).
        z: ``change / std``.
        moved: ``|z|`` above the report's threshold.
    """

    name: str
    label: str
    unit: str
    change: float
    std: float
    z: float
    moved: bool


class DriftReport(NamedTuple):
    """What :func:`drift` returns; ``str(report)`` is a sentence per moved parameter and the table.

    Attributes:
        rows: one :class:`DriftRow` per robot parameter both calibrations fitted.
        since: a label of the previous calibration (a date, a file name) or ``""``.
        threshold: the ``|z|`` beyond which a parameter counts as moved.
        alpha: the family-wise false-alarm probability the threshold is set for.
    """

    rows: tuple
    since: str
    threshold: float
    alpha: float

    @property
    def moved(self) -> tuple:
        """Names of the parameters that moved beyond their uncertainty."""
        return tuple(r.name for r in self.rows if r.moved)

    def sentences(self) -> list[str]:
        since = f" since {self.since}" if self.since else ""
        return [f"{r.label} ({r.name}) moved {r.change:+.3g}{_sp(r.unit)} ± {r.std:.2g}{_sp(r.unit)}{since} "
                f"(z = {r.z:+.1f})" for r in self.rows if r.moved]

    def table(self, markdown: bool = False) -> str:
        rows = [(r.name, r.label, f"{r.change:+.4g}{_sp(r.unit)}", f"{r.std:.3g}{_sp(r.unit)}", f"{r.z:+.2f}",
                 "MOVED" if r.moved else "") for r in self.rows]
        return format_table(rows, ("parameter", "what", "change", "σ", "z", ""), markdown=markdown,
                            title=f"change of the robot's parameters{' since ' + self.since if self.since else ''} "
                                  f"(moved: |z| > {self.threshold:.2f}, family-wise false-alarm rate {self.alpha:g})")

    def __str__(self) -> str:
        head = self.sentences() or [f"no robot parameter moved beyond its uncertainty"
                                    f"{' since ' + self.since if self.since else ''}"]
        return "\n".join(head) + "\n\n" + self.table()

    def to_dict(self) -> dict:
        return {"since": self.since, "threshold": self.threshold, "alpha": self.alpha, "moved": list(self.moved),
                "rows": [r._asdict() for r in self.rows]}


def _sp(unit: str) -> str:
    return unit if unit == "°" else f" {unit}"


def _robot_posterior(result):
    unc = result.uncertainty
    if unc is None:
        raise ValueError("drift needs both results' posterior covariance (result.uncertainty)")
    names = list(result.space.free_names)
    rob = robot_part(names)
    C = np.asarray(unc.covariance, np.float64)[np.ix_(rob, rob)]
    ok = np.isfinite(np.asarray(unc.std, np.float64)[rob])
    return ({names[i]: j for j, i in enumerate(rob) if ok[j]}, np.asarray(result.x, np.float64)[rob], C,
            [result.space.free_units[i] for i in rob])


def _was_prior_of(previous, current) -> bool:
    """Whether ``current`` was calibrated under ``previous`` as its prior (:meth:`jaxcal.Prior.from_result`)."""
    p = current.prior
    if p is None or not p.covariance or not isinstance(p.mean, tuple):
        return False
    mean = dict(p.mean)
    names = list(previous.space.free_names)
    return all(n in mean and abs(mean[n] - float(v)) <= 1e-12 * max(1.0, abs(float(v)))
               for n, v in zip(names, np.asarray(previous.x)) if n in p.covariance[0])


def drift(previous, current, *, since: str = "", alpha: float = 0.01) -> DriftReport:
    """Which robot parameters of one unit moved between two calibrations, beyond their uncertainty.

    The two calibrations must be independent: each from its own data under a generic prior (as
    ``jaxcal calibrate`` does by default). For each robot parameter both fitted (sensor extras
    left out: a new set-up), the change ``Δ = x_current − x_previous`` has ``Var Δ = C_prev +
    C_cur`` (their posterior variances); in directions a prior rather than the data set, both
    estimates sit near the prior and the σ is conservative. A parameter counts as moved when
    ``|Δ/σ| > Φ⁻¹(1 − α/(2m))`` over the ``m`` parameters compared (Bonferroni: a unit that did not
    change reports any move with probability at most ``alpha``).

    A calibration with the previous result as its prior (:meth:`jaxcal.Prior.from_result`) is
    refused: it pulls toward the previous estimate, and a change it cannot give back to the
    parameter that moved (held by the tight prior) spreads over the correlated others.

    Args:
        previous, current: :class:`~jaxcal.CalibrationResult` of one unit (same robot model), with
            their ``uncertainty`` (from :func:`jaxcal.calibrate` or result files).
        since: a label of the previous calibration for the report (``"2026-05-01"``).
        alpha: family-wise false-alarm probability (default 0.01).

    Returns:
        :class:`DriftReport` (``str()``: ``"joint 3's offset θ (theta_3) moved +0.1° ± 0.0021° since
        2026-05-01"`` lines and a table; ``.moved`` the names).
    """
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    if previous.space.layout != current.space.layout or previous.robot.name != current.robot.name:
        raise ValueError(f"the two results are not of one robot model ({previous.robot.name!r}, "
                         f"{current.robot.name!r}, or different parameter layouts)")
    if _was_prior_of(previous, current):
        raise ValueError("the current calibration used the previous one as its prior: for a drift report, "
                         "calibrate the new data under the generic prior (the default) and compare the two")
    ia, xa, Ca, units = _robot_posterior(previous)
    ib, xb, Cb, _ = _robot_posterior(current)
    names = [n for n in ia if n in ib]
    if not names:
        raise ValueError("the two calibrations have no robot parameter in common")
    a = np.asarray([ia[n] for n in names])
    b = np.asarray([ib[n] for n in names])
    change = xb[b] - xa[a]
    std = np.sqrt(np.diag(Ca)[a] + np.diag(Cb)[b])
    threshold = statistics.NormalDist().inv_cdf(1.0 - alpha / (2 * len(names)))
    rows = []
    for j, n in enumerate(names):
        deg = units[a[j]] == "rad"
        f = math.degrees(1.0) if deg else 1.0
        z = float(change[j] / std[j]) if std[j] > 0 else math.copysign(math.inf, change[j])
        rows.append(DriftRow(n, parameter_label(n), "°" if deg else units[a[j]], float(change[j] * f),
                             float(std[j] * f), z, bool(abs(z) > threshold)))
    return DriftReport(tuple(rows), since, float(threshold), float(alpha))
