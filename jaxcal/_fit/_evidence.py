"""The prior's scale chosen by the evidence (type-II maximum likelihood, MacKay's evidence framework).

A Gaussian prior toward the nominal robot, ``Δ ~ N(m, S)``, states how far the robot is from its
drawing; its scale (0.5°, 2 mm by default) is a guess. The data can say how far it is: choose the
scale ``k_f`` of each parameter family ``f`` (the prior's σ on angles, its σ on lengths; for a
learned prior with a full covariance, one factor on that covariance) and the noise σ that
maximise the **marginal likelihood** of the data (the evidence; MacKay 1992, *Neural Comput.*
4:415 and 4:448; Bishop, *Pattern Recognition and Machine Learning*, §3.5),

    p(y | k, σ) = ∫ p(y | x, σ) p(x | k) dx,

with the model linearised at the MAP estimate ``x̂`` (Laplace's approximation; exact for a
linear model). In the column-scaled coordinates ``t = D(x − m)`` (``D = diag(d)``, ``d`` the
data Jacobian's column norms) the data term around ``t̂`` is the quadratic

    Φ(t) = RSS + 2 gᵀ(t − t̂) + (t − t̂)ᵀ A (t − t̂),

``A = JₛᵀWJₛ`` the solve's Gram matrix (robust weights ``W``), ``RSS = Σ w r²`` and ``g = Jₛᵀ W r``
at ``x̂``; ``g`` need not be computed: the solve stopped where its gradient vanishes,
``g = −σ_u² Q_u t̂`` (``σ_u``, ``Q_u`` the noise σ and scaled prior information it used). With
``Q(k) = Σ_f Q_f / k_f²`` (``Q_f`` the family's block of the requested prior's information),
``H = A/σ² + Q`` and ``t* = H⁻¹(A t̂ − g)/σ²`` the MAP under ``(k, σ)``,

    ln p(y | k, σ) = −½ [Φ(t*)/σ² + t*ᵀ Q t*] − ½ ln det H + ½ ln det₊ Q − (N/2) ln σ² + const

(``det₊`` over the parameters with a prior; those without one, the sensor extras, have a flat
prior: their integral does not depend on ``k`` or σ). Its stationary points are MacKay's fixed
point: ``γ_f = n_f − tr(Q_f H⁻¹)`` (how many of the family's ``n_f`` parameters the data
determine; ``Σ_i λ_i/(λ_i + α)`` for one family with ``Q = α·I`` and the data's eigenvalues
``λ_i``), ``t*ᵀ Q_f t* = γ_f`` and ``σ² = Φ(t*)/(N − γ)`` with ``γ = p − tr(Q H⁻¹)``.
:func:`evidence_scales` iterates it on the host (``p × p`` matrices: the ``[N, p]`` Jacobian
stays in the solve's program), and the uncertainty of each ``ln k_f`` comes from the curvature of
the log evidence there (Laplace's approximation in the hyperparameters; MacKay 1999, *Neural
Comput.* 11:1035). :func:`jaxcal.calibrate` alternates this with the MAP solve (each
round's prior σ is run-time data of the same compiled program) until the scales settle.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

__all__ = ["EvidenceScales", "FAMILY_LABELS", "FACTOR_RANGE", "evidence_scales", "log_evidence", "choose_prior"]

#: family names and how :meth:`EvidenceScales.describe` names them
FAMILY_LABELS = {"angles": "angles", "lengths": "lengths", "covariance": "the learned covariance"}
#: the factors on the requested prior's σ searched (a family pushed to an end says so: ``at_bound``)
FACTOR_RANGE = (1e-3, 1e2)


@dataclasses.dataclass(frozen=True)
class EvidenceScales:
    """The prior's scale chosen by the evidence (:func:`evidence_scales`).

    Attributes:
        families: the parameter families scaled: ``"angles"`` (σ of the angle deviations),
            ``"lengths"`` (σ of the length deviations), or ``"covariance"`` (one factor on a
            learned prior's covariance: :meth:`jaxcal.Prior.from_fleet`, a previous result).
        factors: ``k_f``, the chosen σ over the requested prior's σ, per family.
        std: the chosen σ per family in display units: degrees for angles, mm for lengths, the
            factor itself for a covariance.
        log_std: σ of ``ln k_f`` from the curvature of the log evidence at its maximum (``inf``
            where the data do not constrain the family's scale): ``k_f`` is known to within a
            factor ``exp(log_std)`` (one σ).
        effective: ``γ_f``, how many of the family's parameters the data determine (of ``counts``).
        counts: ``n_f``, the family's free parameters under the prior.
        noise_std: σ at the maximum, in the residuals' unit (:attr:`noise_unit`):
            ``sqrt(Φ/(N − γ))``, or the given one (:attr:`jaxcal.Prior.noise_std`).
        log_evidence: the log evidence there (up to a constant of the data: compare only fits
            of the same data and free parameters).
        at_bound: per family, whether the factor ended at an end of :data:`FACTOR_RANGE` (the
            evidence wants a prior still tighter or wider).
        rounds: MAP solves of the fit (each followed by a choice of the scales).
        noise_unit: the residuals' unit: ``"mm"``, ``"px"`` (a camera), ``"σ"`` (the whitened
            blocks of a combined fit).
    """

    families: tuple[str, ...]
    factors: tuple[float, ...]
    std: tuple[float, ...]
    log_std: tuple[float, ...]
    effective: tuple[float, ...]
    counts: tuple[int, ...]
    noise_std: float
    log_evidence: float
    at_bound: tuple[bool, ...] = ()
    rounds: int = 0
    noise_unit: str = "mm"

    def family_text(self, i: int) -> str:
        """``"angles σ = 0.21° (×/÷ 1.3)"``: one family's chosen σ and its uncertainty."""
        f, v, s = self.families[i], self.std[i], self.log_std[i]
        value = (f"σ = {v:.3g}°" if f == "angles" else f"σ = {v:.3g} mm" if f == "lengths"
                 else f"× {v:.3g} on its σ")
        spread = f"×/÷ {math.exp(s):.2g}" if math.isfinite(s) and s < 20 else "not constrained by the data"
        bound = "; at the end of the range searched" if self.at_bound and self.at_bound[i] else ""
        return (f"{FAMILY_LABELS.get(f, f)} {value} ({spread}; the data determine {self.effective[i]:.1f} of "
                f"{self.counts[i]}{bound})")

    def describe(self) -> str:
        """One line: the chosen scales, their uncertainty and the noise σ they go with."""
        return ("prior scale chosen by the evidence (type-II maximum likelihood): "
                + ", ".join(self.family_text(i) for i in range(len(self.families)))
                + f"; noise σ {self.noise_std:.3g} {self.noise_unit}")

    def to_dict(self) -> dict:
        out = {"families": list(self.families), "factors": [float(v) for v in self.factors],
               "log_std": [float(v) if math.isfinite(v) else None for v in self.log_std],
               "effective_parameters": [float(v) for v in self.effective], "counts": [int(v) for v in self.counts],
               "noise_std": float(self.noise_std), "noise_unit": self.noise_unit,
               "log_evidence": float(self.log_evidence),
               "at_bound": [bool(b) for b in self.at_bound], "rounds": int(self.rounds),
               "method": "type-II maximum likelihood (MacKay's evidence), linearised at the MAP estimate"}
        for f, v in zip(self.families, self.std):  # the chosen σ in the families' display units
            out[{"angles": "angle_deg", "lengths": "length_mm"}.get(f, "covariance_factor")] = float(v)
        return out

    @classmethod
    def from_dict(cls, d: dict | None) -> EvidenceScales | None:
        if not d or "families" not in d:
            return None
        fam = tuple(d["families"])
        std = tuple(float(d.get({"angles": "angle_deg", "lengths": "length_mm"}.get(f, "covariance_factor"), k))
                    for f, k in zip(fam, d["factors"]))
        return cls(fam, tuple(map(float, d["factors"])), std,
                   tuple(math.inf if v is None else float(v) for v in d["log_std"]),
                   tuple(map(float, d["effective_parameters"])), tuple(map(int, d["counts"])),
                   float(d["noise_std"]), float(d["log_evidence"]), tuple(map(bool, d.get("at_bound", ()))),
                   int(d.get("rounds", 0)), str(d.get("noise_unit", "mm")))


class _Linearised:
    """The linearised evidence of one solve in column-scaled coordinates (see the module text)."""

    def __init__(self, A, d, rss, n, delta, info, family, names, factors_used, noise_used):
        A, d = np.asarray(A, np.float64), np.asarray(d, np.float64)
        delta, info = np.asarray(delta, np.float64), np.asarray(info, np.float64)
        family = np.asarray(family)
        p = A.shape[0]
        # a column the data do not see (round-off size) is taken as zero and left unscaled, as
        # parameter_uncertainty does
        tiny = d <= 1e-10 * (d.max() if d.size else 0.0)
        A = A * np.outer(~tiny, ~tiny)
        d = np.where(tiny | (d <= 0), 1.0, d)
        scale = np.ones(p)
        for f, k in zip(names, factors_used):
            scale[family == f] = k
        Q0 = info / np.outer(d, d)  # the requested prior's information, scaled
        Qu = Q0 / np.outer(scale, scale)  # the one the solve used
        self.t_hat = d * delta
        self.g = -float(noise_used) ** 2 * (Qu @ self.t_hat)  # the solve's stationarity
        self.A, self.rss, self.n, self.p = A, float(rss), float(n), p
        self.names = tuple(names)
        self.masks = [family == f for f in names]
        self.Q_f = [Q0 * np.outer(m, m) for m in self.masks]
        fixed = ~np.any(self.masks, axis=0) if names else np.ones(p, bool)
        self.Q_fixed = Q0 * np.outer(fixed, fixed)
        self.n_f = np.asarray([int(m.sum()) for m in self.masks])
        prior_rows = np.flatnonzero(np.abs(Q0).sum(axis=1) > 0)
        self.prior_rows = prior_rows

    def prior(self, k):
        return self.Q_fixed + sum(Qf / (kf * kf) for Qf, kf in zip(self.Q_f, k))

    def map(self, k, s2):
        """``(t*, H⁻¹, Q, Φ(t*))`` under the factors ``k`` and the noise variance ``s2``."""
        Q = self.prior(k)
        H = self.A / s2 + Q
        C = _inverse(H)
        t = C @ ((self.A @ self.t_hat - self.g) / s2)
        u = t - self.t_hat
        phi = self.rss + 2.0 * float(self.g @ u) + float(u @ self.A @ u)
        return t, C, Q, max(phi, 0.0)

    def log_evidence(self, k, s2) -> float:
        Q = self.prior(k)
        H = self.A / s2 + Q
        t, _, _, phi = self.map(k, s2)
        _, logdet_h = np.linalg.slogdet(H)
        sub = self.prior_rows
        _, logdet_q = np.linalg.slogdet(Q[np.ix_(sub, sub)]) if sub.size else (1.0, 0.0)
        return float(-0.5 * (phi / s2 + t @ Q @ t) - 0.5 * logdet_h + 0.5 * logdet_q - 0.5 * self.n * math.log(s2))


def _inverse(H):
    try:
        return np.linalg.inv(H)
    except np.linalg.LinAlgError:  # pragma: no cover - a flat direction no data determine
        return np.linalg.pinv(H)


def evidence_scales(A, d, rss: float, n_residuals: float, delta, info, family, *, names=None, factors=None,
                    noise_used: float, noise_std: float | None = None, noise_start: float | None = None,
                    max_iterations: int = 500, tol: float = 1e-9, rounds: int = 0) -> tuple[EvidenceScales, float]:
    """The factors on a prior's σ per family, and the noise σ, that maximise the linearised evidence.

    Args:
        A: ``[p, p]`` the column-scaled ``JᵀWJ`` of the solve at its solution ``x̂``
            (:func:`~jaxcal._fit._diagnostics.gram_at`'s second entry).
        d: ``[p]`` the data Jacobian's column norms (its first entry).
        rss: ``Σ w r²`` at ``x̂`` (mm², the residuals' unit squared).
        n_residuals: ``N``, the observed residual entries.
        delta: ``[p]`` ``x̂ − m`` (rad, mm), the solution less the prior mean.
        info: ``[p, p]`` the requested prior's information (1/rad², 1/mm²; zero rows for the
            parameters without a prior): ``diag(1/s²)`` or :meth:`jaxcal.Prior.information`.
        family: ``[p]`` each parameter's family name (``""``: not scaled; its prior σ stays).
        names: the families to scale, in order (default: those in ``family``, sorted).
        factors: the factors the solve used (default 1): with ``noise_used`` they give the
            solve's gradient (it stopped where the gradient of its objective vanishes).
        noise_used: the noise σ (mm) the solve weighed its prior against.
        noise_std: a given noise σ (mm; :attr:`jaxcal.Prior.noise_std`): held, not estimated.
        noise_start: where σ's search starts (default ``noise_used``).
        max_iterations, tol: the fixed point's budget and its tolerance on ``ln k`` and ``ln σ²``.
        rounds: stored in the result (:attr:`EvidenceScales.rounds`).

    Returns:
        ``(EvidenceScales, σ)``: the choice (its ``std`` in the requested prior's units is filled
        in by the caller, here the factors) and the noise σ (mm) to weigh the prior against.
    """
    family = np.asarray(family)
    names = tuple(sorted({f for f in family.tolist() if f})) if names is None else tuple(names)
    factors = np.ones(len(names)) if factors is None else np.asarray(factors, np.float64)
    lin = _Linearised(A, d, rss, n_residuals, delta, info, family, names, factors, noise_used)
    lo, hi = FACTOR_RANGE
    k = np.clip(factors.copy(), lo, hi)
    fixed_noise = noise_std is not None
    s2 = float(noise_std if fixed_noise else (noise_start or noise_used)) ** 2
    active = lin.n_f > 0
    gamma = np.zeros(len(names))
    for _ in range(max_iterations):
        t, C, Q, phi = lin.map(k, s2)
        gamma = np.asarray([lin.n_f[i] - float(np.sum(C * lin.Q_f[i].T)) / k[i] ** 2 for i in range(len(names))])
        new_k = k.copy()
        for i in range(len(names)):
            e = float(t @ lin.Q_f[i] @ t)  # t*ᵀ Q_f t*: the squared deviation in units of the requested prior
            if not active[i] or gamma[i] <= 1e-9 * lin.n_f[i]:
                continue  # the data do not see the family: the evidence is flat in its scale
            new_k[i] = math.sqrt(e / gamma[i]) if e > 0 else lo  # MacKay: α_f = γ_f / ‖Δ_f‖²
        new_k = np.clip(new_k, lo, hi)
        new_s2 = s2
        if not fixed_noise:
            dof = lin.n - (lin.p - float(np.sum(C * Q.T)))
            new_s2 = phi / dof if dof > 0 and phi > 0 else s2
        step = max(np.max(np.abs(np.log(new_k / k)), initial=0.0), abs(math.log(new_s2 / s2)))
        k, s2 = new_k, new_s2
        if step < tol:
            break
    # the curvature of the log evidence in (ln k, ln σ²): central differences
    theta = np.concatenate([np.log(k), [] if fixed_noise else [math.log(s2)]])

    def f(th):
        kk = np.exp(th[: len(names)])
        return lin.log_evidence(kk, s2 if fixed_noise else math.exp(th[-1]))

    L0 = f(theta)
    log_std = _log_std(f, theta, L0, len(names))
    at = tuple(bool(v <= lo * (1 + 1e-6) or v >= hi * (1 - 1e-6)) for v in k)
    ev = EvidenceScales(names, tuple(float(v) for v in k), tuple(float(v) for v in k), log_std,
                        tuple(float(v) for v in gamma), tuple(int(v) for v in lin.n_f), math.sqrt(s2), L0, at, rounds)
    return ev, math.sqrt(s2)


def _log_std(f, theta, f0: float, n_families: int, h: float = 1e-3) -> tuple[float, ...]:
    """σ of the first ``n_families`` coordinates of ``theta`` from the curvature of ``f`` (a log
    density) there: the square root of the diagonal of ``(−∇²f)⁻¹`` (``inf`` where it is flat)."""
    m = theta.size
    H = np.zeros((m, m))
    for i in range(m):
        for j in range(i, m):
            if i == j:
                e = np.zeros(m)
                e[i] = h
                H[i, i] = (f(theta + e) - 2 * f0 + f(theta - e)) / (h * h)
            else:
                ei, ej = np.zeros(m), np.zeros(m)
                ei[i], ej[j] = h, h
                H[i, j] = H[j, i] = (f(theta + ei + ej) - f(theta + ei - ej) - f(theta - ei + ej)
                                     + f(theta - ei - ej)) / (4 * h * h)
    neg = -0.5 * (H + H.T)
    ev, V = np.linalg.eigh(neg)
    big = ev > 1e-8 * max(abs(ev).max(initial=0.0), 1e-300)
    cov = (V[:, big] / ev[big]) @ V[:, big].T
    flat = np.abs(V[:, ~big]).max(axis=1) > 1e-6 if (~big).any() else np.zeros(m, bool)
    return tuple(math.inf if flat[i] else float(math.sqrt(max(cov[i, i], 0.0))) for i in range(n_families))


def log_evidence(A, d, rss: float, n_residuals: float, delta, info, family, factors, noise_std: float, *,
                 names=None, factors_used=None, noise_used: float) -> float:
    """The linearised log evidence (up to a constant of the data) at the factors ``factors`` and
    the noise σ ``noise_std`` (mm), for the solve described as in :func:`evidence_scales`."""
    family = np.asarray(family)
    names = tuple(sorted({f for f in family.tolist() if f})) if names is None else tuple(names)
    used = np.ones(len(names)) if factors_used is None else factors_used
    lin = _Linearised(A, d, rss, n_residuals, delta, info, family, names, used, noise_used)
    return lin.log_evidence(np.asarray(factors, np.float64), float(noise_std) ** 2)


def choose_prior(prior, space, gram, x, n_residuals: float, *, noise_used: float, rounds: int = 0,
                 unit: str = "mm"):
    """The prior ``prior`` (``scale_by="evidence"``) with its families' σ chosen by the evidence at
    one MAP solve: ``(chosen prior, noise σ to weigh it against)``; the chosen prior carries the
    choice (:attr:`jaxcal.Prior.evidence`, its ``std`` in degrees / mm / the covariance's factor).

    Args:
        prior: the requested :class:`~jaxcal.Prior`, or the chosen one of an earlier round (its
            :attr:`~jaxcal.Prior.evidence` factors are then the ones the solve used, and the new
            factors apply to the requested σ, the chosen ones divided by them).
        space: the free parameters of the solve.
        gram: :func:`~jaxcal._fit._diagnostics.gram_at` of the solve at its solution ``x`` ``[p]``
            (over ``space``'s free parameters).
        n_residuals: the observed residual entries.
        noise_used: the noise σ (mm) the solve weighed the prior against.
        rounds: MAP solves so far (recorded).
        unit: the residuals' unit (recorded: :attr:`EvidenceScales.noise_unit`).
    """
    ev0 = prior.evidence
    fams = prior.families(space)
    names = tuple(sorted({f for f in fams.tolist() if f}))
    used = np.asarray([1.0 if ev0 is None or f not in ev0.families else ev0.factors[ev0.families.index(f)]
                       for f in names])
    requested = prior.rescaled({f: 1.0 / k for f, k in zip(names, used)})
    d, A, _, rss, *_ = gram
    std = requested.std(space)
    info = requested.information(space)
    if info is None:
        info = np.diag(np.where(np.isfinite(std), 1.0 / np.where(np.isfinite(std), std, 1.0) ** 2, 0.0))
    delta = np.asarray(x, np.float64) - requested.mean_vector(space)
    ev, sigma = evidence_scales(A, d, float(rss), n_residuals, delta, info, fams, names=names, factors=used,
                                noise_used=noise_used, noise_std=prior.noise_std, rounds=rounds)
    factors = dict(zip(names, ev.factors))
    chosen = requested.rescaled(factors)
    shown = tuple(float(chosen.angle_deg if f == "angles" else chosen.length_mm if f == "lengths" else factors[f])
                  for f in names)
    return dataclasses.replace(chosen, evidence=dataclasses.replace(ev, std=shown, noise_unit=unit)), sigma
