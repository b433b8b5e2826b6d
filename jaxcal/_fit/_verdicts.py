"""What the data determine: one verdict per parameter, for every output of a calibration.

A calibrated parameter is **determined by the data**, **held by the prior** or **not calibrated**
(held at its start value). The identifiability lines, the marks of the DH and chain tables (``†``,
``*``), the block report of a combined fit, the HTML report and the warnings all read the verdict
of :func:`parameter_verdicts`, so they cannot disagree (issue 53: a rank test on the data Jacobian
called ``d_5`` identifiable while the table marked it † from the posterior σ; a block's share of
the diagonal information said "planes alone determines d_1" while the prior held it).

The verdict comes from the posterior covariance ``C = (G + Λ)⁻¹`` (``G`` the data's information
``JᵀWJ/σ̂²``, ``Λ`` the prior's precision), split into the data's and the prior's parts,
``C = C G C + C Λ C``. The **prior's share** of a parameter's posterior variance is
``π_j = (C Λ C)_jj / C_jj`` (for one parameter alone ``λ/(g + λ)``: the prior's precision over
the total). A parameter is held by the prior when ``π_j`` exceeds :data:`PRIOR_SHARE` (½: the
prior tells more about it than the data). This covers parameters without a prior of their own
too: a draw wire's ``anchor_y`` trades against ``θ_1``, which the prior holds, so the prior gives
nearly all of ``anchor_y``'s ±15 mm.

Of the parameters the prior holds, those whose posterior variance lies mostly (more than
:data:`PRIOR_SHARE`) in directions the measurements do not see at all (the exact dependencies of
the identification Jacobian at the nominal robot, :class:`~jaxcal.IdentifiabilityReport`: what the
sensor cannot see by construction, such as a draw wire's ``α_6`` or the difference ``d_2 − d_3``
of parallel axes), or that the prior would still hold with :data:`MORE_DATA` times the data's
information (a tracker's SMR 0.5 mm from the flange sees the wrist's α_5, a_5 through that lever
arm only), are **expected**: more poses would not change it, nothing to do. The others are held
because these poses see them weakly: more poses, or poses over wider joint ranges, would determine
them (``jaxcal plan``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["DATA", "PRIOR", "HELD", "UNDETERMINED", "PRIOR_SHARE", "MORE_DATA", "PRIOR_MARK", "HELD_MARK",
           "MARKS_LEGEND", "Verdicts", "parameter_verdicts", "fit_verdicts", "fixable_text", "prior_lines"]

#: determined by the data
DATA = "data"
#: held by the prior: the prior gives more than :data:`PRIOR_SHARE` of its posterior variance
PRIOR = "prior"
#: not calibrated: held at its start value (fixed, or not identifiable without a prior)
HELD = "held"
#: free, but neither the data nor a prior determine it (posterior σ infinite)
UNDETERMINED = "undetermined"

#: the prior's share of a parameter's posterior variance above which the prior, not the data, holds it
PRIOR_SHARE = 0.5

#: a parameter the prior would still hold with this many times the data's information (ten times as
#: many poses like these) is not the poses' fault: what the sensor and its set-up see too weakly
MORE_DATA = 10.0

#: the legend of the tables' † and * marks (``jaxcal calibrate``'s tables, the HTML report)
PRIOR_MARK = "† held by the prior: the prior, not the data, gives most of its posterior variance"
HELD_MARK = "* not calibrated: held at its start value (not identifiable without a prior, or fixed)"
MARKS_LEGEND = f"{PRIOR_MARK}; {HELD_MARK}"


@dataclasses.dataclass(frozen=True)
class Verdicts:
    """The verdict of each parameter of a calibration (:func:`parameter_verdicts`).

    Attributes:
        verdict: ``{name: DATA | PRIOR | HELD | UNDETERMINED}`` for every parameter of the
            result's space, in its order.
        prior_share: ``{free name: π}``, the prior's share of its posterior variance (0 without
            a prior).
        expected: the names held by the prior because the data do not see them at all (more than
            :data:`PRIOR_SHARE` of their posterior variance lies in directions the data cannot
            see): what the sensor and set-up cannot see by construction. The other names held by
            the prior (:attr:`fixable`) the data see, but less than the prior.
    """

    verdict: dict
    prior_share: dict = dataclasses.field(default_factory=dict)
    expected: tuple[str, ...] = ()

    def names(self, verdict: str) -> tuple[str, ...]:
        """The names with this verdict, in the space's order."""
        return tuple(n for n, v in self.verdict.items() if v == verdict)

    @property
    def determined(self) -> tuple[str, ...]:
        """Determined by the data."""
        return self.names(DATA)

    @property
    def by_prior(self) -> tuple[str, ...]:
        """Held by the prior (marked † in the tables)."""
        return self.names(PRIOR)

    @property
    def fixable(self) -> tuple[str, ...]:
        """Held by the prior although the data see them: weakly determined by these poses."""
        expected = set(self.expected)
        return tuple(n for n in self.by_prior if n not in expected)

    def mark(self, name: str) -> str:
        """``"†"`` held by the prior, ``"*"`` not calibrated, else ``""``."""
        v = self.verdict.get(name, HELD)
        return "†" if v == PRIOR else "*" if v == HELD else ""

    def renamed(self, mapping: dict) -> Verdicts:
        """The verdicts under other names: ``mapping`` ``{new name: name here}`` (a block's own
        names of a combined fit's parameters); names not in ``mapping``'s values are left out."""
        back = {old: new for new, old in mapping.items()}
        return Verdicts({back[n]: v for n, v in self.verdict.items() if n in back},
                        {back[n]: s for n, s in self.prior_share.items() if n in back},
                        tuple(back[n] for n in self.expected if n in back))

    def to_dict(self) -> dict:
        return {"verdict": dict(self.verdict), "prior_share": {n: float(s) for n, s in self.prior_share.items()},
                "expected": list(self.expected)}

    @classmethod
    def from_dict(cls, d: dict | None) -> Verdicts | None:
        """The inverse of :meth:`to_dict`; ``None`` for a file written before verdicts existed."""
        if not d or "verdict" not in d:
            return None
        return cls(dict(d["verdict"]), {n: float(s) for n, s in d.get("prior_share", {}).items()},
                   tuple(d.get("expected", ())))


def parameter_verdicts(names, free_names, covariance, unseen=None, prior_precision=None, std=None, *,
                       share: float = PRIOR_SHARE, more_data: float = MORE_DATA) -> Verdicts:
    """One verdict per parameter: determined by the data, held by the prior, not calibrated.

    Args:
        names: every parameter of the space (the free ones and those held at their start).
        free_names: the ``p`` free parameters (the order of the matrices).
        covariance: ``[p, p]`` the posterior covariance ``(G + Λ)⁻¹`` (rad, mm).
        unseen: ``[p, k]`` the directions the measurements cannot see
            (:meth:`~jaxcal.IdentifiabilityReport.unseen_directions`: the exact dependencies at
            the nominal robot; at the solution real-size deviations leave some of them seen at
            1e-7 of the largest eigenvalue, which only the prior holds all the same), or ``None``
            (not known: ``expected`` stays empty).
        prior_precision: ``[p, p]`` the prior's precision ``Λ`` (``diag(1/s²)``, zero for a
            parameter without a prior; a full-covariance prior's information), ``None`` without
            a prior.
        std: ``[p]`` posterior σ (``inf`` where undetermined); default from ``covariance``.
        share: the prior's share of the posterior variance above which the prior holds a
            parameter (:data:`PRIOR_SHARE`).
        more_data: a parameter the prior would still hold with this many times the data's
            information ``G = C⁻¹ − Λ`` is expected (:data:`MORE_DATA`).

    Returns:
        :class:`Verdicts`: ``PRIOR`` where the prior's share ``π_j = (CΛC)_jj / C_jj`` exceeds
        ``share``; ``DATA`` for the other free parameters (``UNDETERMINED`` where σ is infinite);
        ``HELD`` for the parameters that are not free. ``expected`` names the ``PRIOR`` ones with
        more than ``share`` of their posterior variance in the prior's covariance along the unseen
        directions ``N (NᵀΛN)⁺ Nᵀ`` (what would remain with data of any precision), or a prior's
        share above ``share`` with ``more_data`` times the data (``(more_data·C⁻¹ − (more_data −
        1)·Λ)⁻¹``).
    """
    free_names = list(free_names)
    p = len(free_names)
    C = np.asarray(covariance, np.float64).reshape(p, p)
    sd = np.sqrt(np.clip(np.diag(C), 0.0, None)) if std is None else np.asarray(std, np.float64)
    var = np.diag(C)
    pi = np.zeros(p)
    expected = np.zeros(p, bool)
    if prior_precision is not None and p:
        P = np.asarray(prior_precision, np.float64)
        pos = var > 0
        pi = np.where(pos, np.diag(C @ P @ C) / np.where(pos, var, 1.0), 0.0)
        N = np.zeros((p, 0)) if unseen is None else np.asarray(unseen, np.float64).reshape(p, -1)
        if N.shape[1]:
            expected = np.diag(N @ np.linalg.pinv(N.T @ P @ N, hermitian=True) @ N.T) > share * var
        C_more = np.linalg.pinv(more_data * np.linalg.pinv(C, hermitian=True) - (more_data - 1.0) * P, hermitian=True)
        v_more = np.diag(C_more)
        expected |= np.diag(C_more @ P @ C_more) > share * np.where(v_more > 0, v_more, np.inf)
    free = dict(zip(free_names, range(p)))
    verdict, shares, exp = {}, {}, []
    for n in names:
        j = free.get(n)
        if j is None:
            verdict[n] = HELD
            continue
        shares[n] = float(pi[j])
        if not np.isfinite(sd[j]):
            verdict[n] = UNDETERMINED
        elif pi[j] > share:
            verdict[n] = PRIOR
            if expected[j]:
                exp.append(n)
        else:
            verdict[n] = DATA
    return Verdicts(verdict, shares, tuple(exp))


def fit_verdicts(space, uncertainty, prior, report=None, share: float = PRIOR_SHARE) -> Verdicts:
    """:func:`parameter_verdicts` of a fit: ``space`` its :class:`~jaxcal.ParameterSpace`,
    ``uncertainty`` its :class:`~jaxcal._fit._diagnostics.Uncertainty` (covariance and σ),
    ``prior`` its :class:`~jaxcal.Prior` or ``None``, ``report`` the
    :class:`~jaxcal.IdentifiabilityReport` that chose the free set (what the data cannot see), or
    ``None``."""
    precision = None
    if prior is not None:
        precision = prior.information(space)  # a full prior covariance; else diag(1/s²)
        if precision is None:
            s = np.asarray(prior.std(space), np.float64)
            precision = np.diag(np.where(np.isfinite(s), 1.0 / np.where(np.isfinite(s), s, 1.0) ** 2, 0.0))
    unseen = None if report is None else report.unseen_directions(space.free_names)
    return parameter_verdicts(space.names, space.free_names, uncertainty.covariance, unseen, precision,
                              uncertainty.std, share=share)


def fixable_text(verdicts: Verdicts | None) -> str:
    """The warning for what the prior holds although the data see it (:attr:`Verdicts.fixable`):
    the poses determine it only weakly, and what to do; ``""`` when there is none (what the sensor
    cannot see by construction is information, not a warning: :func:`prior_lines`)."""
    names = () if verdicts is None else verdicts.fixable
    if not names:
        return ""
    them = "them" if len(names) > 1 else "it"
    return (f"these poses determine {', '.join(names)} less than the prior does: the prior holds {them} (marked † "
            f"in the tables), although the data see {them} — more poses, or poses over wider joint ranges, would let "
            f"the data determine {them} (jaxcal plan, or jaxcal.select_poses in Python, chooses such poses)")


def prior_lines(verdicts: Verdicts, names, describe=None) -> list[str]:
    """The lines of the normal output on what the prior holds among ``names`` (the space's order):
    what these measurements cannot see at all (:attr:`Verdicts.expected`: information, said once,
    nothing to do), then what the data see but weakly (:attr:`Verdicts.fixable`: the warning says
    what to do). ``describe(name)``: a line explaining a name (what it acts like), or ``None``."""
    expected = set(verdicts.expected)
    groups = ([n for n in names if n in expected],
              [n for n in names if verdicts.verdict.get(n) == PRIOR and n not in expected])
    heads = ("held by the prior (†): {} — what these measurements cannot see, or see too weakly for more poses to "
             "help (how the sensor and its set-up measure); the prior keeps them near their nominal or guessed value, "
             "nothing to do",
             "held by the prior (†) although the data see them, weakly (see the warning): {}")
    lines = []
    for group, head in zip(groups, heads):
        if group:
            more = [] if describe is None else [t for t in map(describe, group) if t]
            lines += [head.format(", ".join(group)) + (":" if more else "")] + more
    return lines
