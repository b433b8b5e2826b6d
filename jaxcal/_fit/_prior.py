"""The prior of a calibration (maximum a posteriori): :class:`Prior` — Gaussian toward the nominal
robot, from its specification text, a fleet of calibrated units, a unit's previous result or a
file — and the priors learned from calibrations: a robot model's fleet (empirical Bayes) and a
unit's previous result. One module, so that :class:`Prior`'s constructors and the learning they call
live together (the prior's parts as the objective uses them: :mod:`jaxcal._fit._objective`).

**The fleet prior.** Units of one robot model share systematic deviations (the drawing's nominal
is off the same way for all) and scatter around them. Model unit ``k``'s robot deviations as
``x_k ~ N(μ, Σ)`` (the population) and its calibration as a Gaussian measurement of ``x_k``: its
posterior ``N(m_k, C_k)`` under the prior it was calibrated with, ``N(μ₀, P₀⁻¹)``, carries the
data information ``J_k = C_k⁻¹ − P₀`` and ``h_k = C_k⁻¹m_k − P₀μ₀`` (the data alone, the prior
divided out; Gaussian, to first order in the deviations). :func:`fleet_prior` maximises the
marginal likelihood of ``(μ, Σ)`` by expectation–maximisation (the normal hierarchical model;
Gelman et al., *Bayesian Data Analysis*, 3rd ed., ch. 5; Dempster, Laird & Rubin 1977):

* E: each unit's posterior under the population, ``C'_k = (J_k + Σ⁻¹)⁻¹``,
  ``m'_k = C'_k(h_k + Σ⁻¹μ)``;
* M: ``μ = mean m'_k``, ``Σ = mean[(m'_k − μ)(m'_k − μ)ᵀ + C'_k]``.

The spread of the estimates is the true spread plus each unit's estimation noise; the ``C'_k``
term is what takes the noise out (the moment form: sample covariance of the estimates minus
their mean posterior covariance, here never negative). Directions that the units' data together
determine less than the generic prior does (``d₂ − d₃`` of parallel axes) keep the generic
prior (``base``): mean, spread and no correlation with the others. With few units the correlations are noisy: they are shrunk toward zero by the
Schäfer–Strimmer estimate of the optimal weight (Schäfer & Strimmer 2005, *Stat. Appl. Genet.
Mol. Biol.* 4:32, target D; a Ledoit–Wolf-type rule). The mean's own uncertainty is
``M = (Σ_k (Σ + J_k⁻¹)⁻¹ + P₀)⁻¹`` (the generic prior as the hyper-prior of ``μ``), and a new
unit's prior is ``N(μ, Σ + M)``.

Only the robot's own parameters enter (geometric and non-geometric groups): sensor extras
(anchor, tool point, sensor frame, markers) belong to one unit's set-up.

**A previous result as the prior** (:func:`result_prior`): a unit recalibrated months later
starts from what it was: mean = the previous estimate, covariance = its posterior. Which
parameters moved between two calibrations: :func:`jaxcal.drift`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
from typing import Any

import numpy as np

from .._core._json import to_jsonable
from .._core._metrics import format_table
from .._core._params import Deviations, ParameterSpace, group_kind, group_of
from .._models import _chain, _nongeometric  # noqa: F401 — they register their group names (Prior.parse)
from ._evidence import EvidenceScales

__all__ = ["Prior", "resolve_prior", "SCALE_BY", "FleetPopulation", "fleet_prior", "result_prior", "save_prior",
           "load_prior", "prior_from_file", "PRIOR_FORMAT", "robot_part"]

#: ``"format"`` entry of prior files.
PRIOR_FORMAT = "jaxcal-prior/1"


def _display(value: float, unit: str) -> tuple[float, str]:
    """A value in its display unit: degrees for radians (at the edge), as it is otherwise."""
    return (math.degrees(value), "°") if unit == "rad" else (float(value), f" {unit}")


@dataclasses.dataclass(frozen=True)
class FleetPopulation:
    """The population of a robot model's units, as learned by :meth:`jaxcal.Prior.from_fleet` (rad, mm).

    Attributes:
        robot: the robot model's name.
        n_units: calibrated units it was learned from.
        names, units: the robot parameters (``"theta_3"``, ``"rad"``...).
        mean: ``[k]`` population mean deviation from nominal (the shared systematic error).
        mean_std: ``[k]`` σ of ``mean`` (from the number of units and their estimation noise).
        spread: ``[k]`` population σ of a unit around ``mean`` (estimation noise taken out).
        spread_std: ``[k]`` approximate σ of ``spread`` (delta method on the variance estimate).
        data_share: ``[k]`` how much the units' data determined each parameter's spread, 0–1
            (``1 − mean posterior variance / spread²``); near 0: no unit's data see it, the spread
            is the generic prior's.
        shrinkage: the weight (0–1) that pulled the correlations toward zero.
    """

    robot: str
    n_units: int
    names: tuple
    units: tuple
    mean: tuple
    mean_std: tuple
    spread: tuple
    spread_std: tuple
    data_share: tuple
    shrinkage: float

    def table(self, markdown: bool = False) -> str:
        """One row per parameter: mean ± its σ, spread ± its σ, data share (degrees for angles)."""
        rows = []
        for i, (n, u) in enumerate(zip(self.names, self.units)):
            m, du = _display(self.mean[i], u)
            ms = _display(self.mean_std[i], u)[0]
            s = _display(self.spread[i], u)[0]
            ss = _display(self.spread_std[i], u)[0]
            rows.append((n, f"{m:+.4g} ± {ms:.2g}{du}", f"{s:.4g} ± {ss:.2g}{du}", f"{self.data_share[i]:.2f}"))
        return format_table(rows, ("parameter", "population mean", "unit spread σ", "data share"), markdown=markdown,
                            title=f"{self.robot}: population learned from {self.n_units} units "
                                  f"(correlations shrunk by {self.shrinkage:.2f})")

    def __str__(self) -> str:
        return self.table()

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls, d: dict) -> FleetPopulation:
        return cls(**{f.name: tuple(d[f.name]) if isinstance(d[f.name], list) else d[f.name]
                      for f in dataclasses.fields(cls)})


def robot_part(names) -> np.ndarray:
    """Indices of the robot's own parameters (not sensor extras) among ``names``."""
    return np.asarray([i for i, n in enumerate(names) if group_kind(n) != "extra"], int)


def _unit_information(result, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """``(J [k, k], h [k])``: the data information of one calibration about the parameters
    ``names`` (zero for those it did not fit), its prior divided out (module docstring)."""
    unc = result.uncertainty
    if unc is None:
        raise ValueError("a fleet prior needs each unit's posterior covariance (result.uncertainty, "
                         "from jaxcal.calibrate or a result file that has it)")
    free = list(result.space.free_names)
    rob = robot_part(free)
    std = np.asarray(unc.std, np.float64)[rob]
    if not np.all(np.isfinite(std)):
        bad = [free[i] for i, s in zip(rob, std) if not np.isfinite(s)]
        raise ValueError(f"unit's posterior leaves {bad} undetermined; calibrate the units under a prior "
                         "(the command line's default, or objective \"measured\" / prior \"default\" in Python)")
    C = np.asarray(unc.covariance, np.float64)[np.ix_(rob, rob)]
    x = np.asarray(result.x, np.float64)[rob]
    P = np.linalg.inv(0.5 * (C + C.T))  # posterior information of the robot part (extras marginalised)
    P = 0.5 * (P + P.T)
    prior = result.prior
    if prior is not None:
        sub = ParameterSpace.from_names(result.space.layout, [free[i] for i in rob])
        info = prior.information(sub)
        if info is None:
            s = prior.std(sub)
            info = np.diag(np.where(np.isfinite(s), 1.0 / np.where(np.isfinite(s), s, 1.0) ** 2, 0.0))
        J = P - info
        h = P @ x - info @ prior.mean_vector(sub)
    else:
        J, h = P, P @ x
    ev, V = np.linalg.eigh(0.5 * (J + J.T))  # the data information is positive semi-definite: clip round-off
    J = (V * np.maximum(ev, 0.0)) @ V.T
    at = {free[i]: j for j, i in enumerate(rob)}
    idx = np.asarray([at.get(n, -1) for n in names])
    ok = idx >= 0
    Jf, hf = np.zeros((len(names), len(names))), np.zeros(len(names))
    Jf[np.ix_(ok, ok)] = J[np.ix_(idx[ok], idx[ok])]
    hf[ok] = h[idx[ok]]
    return Jf, hf


def _same_model(results) -> None:
    import jax

    first = results[0].robot
    for i, r in enumerate(results[1:], 2):
        same = type(r.robot) is type(first) and r.robot.name == first.name and r.space.layout == results[0].space.layout
        if same:
            a, b = jax.tree.leaves(first), jax.tree.leaves(r.robot)
            same = len(a) == len(b) and all(np.shape(u) == np.shape(v) and np.allclose(u, v, atol=1e-9)
                                            for u, v in zip(a, b))
        if not same:
            raise ValueError(f"unit {i} is not the same robot model as unit 1 ({r.robot.name!r} vs {first.name!r}, "
                             "or another nominal table): a fleet prior is learned from units of one model")


def _correlation_shrinkage(samples: np.ndarray) -> float:
    """Schäfer & Strimmer's (2005) estimate of the optimal shrinkage weight of a correlation
    matrix toward the identity, from ``samples`` ``[K, k]``."""
    K = samples.shape[0]
    sd = samples.std(axis=0, ddof=1)
    sd = np.where(sd > 0, sd, 1.0)
    z = (samples - samples.mean(axis=0)) / sd
    w = z[:, :, None] * z[:, None, :]  # [K, k, k]
    r = w.mean(axis=0) * K / (K - 1)
    var_r = K / (K - 1) ** 3 * ((w - w.mean(axis=0)) ** 2).sum(axis=0)
    off = ~np.eye(samples.shape[1], dtype=bool)
    denom = float((r[off] ** 2).sum())
    return 1.0 if denom <= 0 else float(np.clip(var_r[off].sum() / denom, 0.0, 1.0))


def fleet_prior(results, base: Prior, *, noise_std: float | None = None, iterations: int = 1000,
                tol: float = 1e-7, members: bool = False) -> Prior:
    """The robot model's prior learned from calibrated units of it (empirical Bayes): a
    :class:`~jaxcal.Prior` with the population mean as its ``mean`` and the population covariance
    plus the mean's uncertainty as its ``covariance``; its ``population`` holds the
    :class:`FleetPopulation` (mean, spread and their uncertainties).

    Unit ``k``'s robot deviations are modelled as ``x_k ~ N(μ, Σ)``; its calibration, posterior
    ``N(m_k, C_k)`` under its own prior ``N(μ₀, P₀⁻¹)``, carries the data information
    ``J_k = C_k⁻¹ − P₀``, ``h_k = C_k⁻¹m_k − P₀μ₀``. Expectation–maximisation of the marginal
    likelihood: E, ``C'_k = (J_k + Σ⁻¹)⁻¹``, ``m'_k = C'_k(h_k + Σ⁻¹μ)``; M, ``μ = mean m'_k``,
    ``Σ = mean[(m'_k − μ)(m'_k − μ)ᵀ + C'_k]`` (the ``C'_k`` term takes each unit's estimation noise
    out of the spread). Directions the units' data determine less than ``base`` does keep
    ``base``; with few units the correlations are shrunk toward zero (Schäfer & Strimmer 2005).
    The mean's uncertainty is ``M = (Σ_k (Σ + J_k⁻¹)⁻¹ + P₀)⁻¹`` and a new unit's prior
    ``N(μ, Σ + M)``. Only the robot's own parameters enter, not sensor extras.

    Args:
        results: ≥ 3 :class:`~jaxcal.CalibrationResult` of units of one robot model (same nominal
            table and parameter layout; e.g. ``[jaxcal.load_result(f) for f in files]``), each with
            its ``uncertainty`` (from :func:`jaxcal.calibrate`; under a prior, so that every robot
            parameter it freed is determined). Each unit's own prior is divided out (a loaded
            result file keeps it from this version on; a result without one counts as a fit
            without a prior).
        base: the generic prior: where the spread starts, what the directions no unit's data see
            keep, the hyper-prior of the mean, and the σ of parameters no unit fitted
            (:meth:`jaxcal.Prior.from_fleet`: :class:`~jaxcal.Prior` ``()``, 0.5°, 2 mm).
        noise_std: the sensor noise σ (mm) the prior is weighed against (default: estimated from
            each new fit, see ``Prior.noise_std``).
        iterations, tol: expectation–maximisation's budget and relative tolerance on ``Σ``.
        members: the prior of the units it was learned from, ``N(μ, Σ)`` (the E step's: what
            :func:`jaxcal.calibrate_fleet_jointly` refits them under), not a new unit's
            ``N(μ, Σ + M)``; ``population`` is the same either way.
    """
    results = [r for r in results]
    if any(r is None for r in results):
        raise ValueError("fleet prior: a unit has no result (None: its calibration failed); leave it out")
    if len(results) < 3:
        raise ValueError(f"a fleet prior needs at least 3 calibrated units, got {len(results)}")
    _same_model(results)
    layout = results[0].space.layout
    fitted = set().union(*(set(np.asarray(r.space.free_names)[robot_part(r.space.free_names)]) for r in results))
    names = [n for n in layout.names if n in fitted]
    space = ParameterSpace.from_names(layout, names)
    units = list(space.free_units)
    base_std = base.std(space)
    if not np.all(np.isfinite(base_std)):
        raise ValueError("the base prior must give every robot parameter a finite σ")
    info = [_unit_information(r, names) for r in results]
    K, k = len(results), len(names)
    Js, hs = np.stack([J for J, _ in info]), np.stack([h for _, h in info])
    # the start: each unit's posterior under the generic prior, and the moment estimate from it
    # (spread of the estimates + their mean posterior covariance: the generic prior's variance in
    # the directions no data see, the data's in the others); EM creeps where information is small
    S0 = np.diag(1.0 / base_std**2)
    C0 = np.linalg.inv(Js + S0)
    m0 = np.einsum("kij,kj->ki", C0, hs + (S0 @ base.mean_vector(space))[None])
    # directions the fleet's data do not determine (all units together know less there than the
    # generic prior: d₂ − d₃ of parallel axes) keep the generic prior: the likelihood is flat
    # there, and EM would wander along it through the cross-covariances
    mu0, B = base.mean_vector(space), base_std
    ev, V = np.linalg.eigh(B[:, None] * Js.sum(axis=0) * B[None, :])
    U = V[:, ev < 1.0]
    Pu = U @ U.T
    Ps = np.eye(k) - Pu

    def keep_unseen(Sigma, mu):
        Sw = Sigma / np.outer(B, B)
        Sw = Ps @ Sw @ Ps + Pu
        return np.outer(B, B) * 0.5 * (Sw + Sw.T), B * (Ps @ (mu / B) + Pu @ (mu0 / B))

    Sigma, mu = keep_unseen(np.cov(m0.T, ddof=0).reshape(k, k) + C0.mean(axis=0), m0.mean(axis=0))
    for _ in range(iterations):
        Si = np.linalg.inv(Sigma)
        Cp = np.linalg.inv(Js + Si)
        mp = np.einsum("kij,kj->ki", Cp, hs + (Si @ mu)[None])
        dev = mp - mp.mean(axis=0)
        new, mu = keep_unseen((dev.T @ dev) / K + Cp.mean(axis=0), mp.mean(axis=0))
        done = np.max(np.abs(new - Sigma) / np.outer(B, B)) <= tol * np.max(np.abs(Sigma) / np.outer(B, B))
        Sigma = new
        if done:
            break
    lam = _correlation_shrinkage(mp)
    sd = np.sqrt(np.diag(Sigma))
    R = Sigma / np.outer(sd, sd)
    Sigma = keep_unseen(np.outer(sd, sd) * ((1.0 - lam) * R + lam * np.eye(k)), mu)[0]
    Si = np.linalg.inv(Sigma)
    Cp = np.linalg.inv(Js + Si)
    # (Σ + J⁻¹)⁻¹ = Σ⁻¹ − Σ⁻¹C'Σ⁻¹ (Woodbury: also where J is singular), plus the hyper-prior
    info_mu = K * Si - Si @ Cp.sum(axis=0) @ Si + np.diag(1.0 / base_std**2)
    M = np.linalg.inv(0.5 * (info_mu + info_mu.T))
    est_var = np.diag(Cp.mean(axis=0))
    var = np.diag(Sigma)
    spread = np.sqrt(var)
    spread_std = np.sqrt(2.0 / (K - 1)) * (var + est_var) / (2.0 * spread)
    share = np.clip(1.0 - est_var / var, 0.0, 1.0)
    cov = Sigma if members else Sigma + M
    cov = 0.5 * (cov + cov.T)
    robot = results[0].robot.name
    population = FleetPopulation(robot, K, tuple(names), tuple(units), tuple(map(float, mu)),
                                 tuple(map(float, np.sqrt(np.diag(M)))), tuple(map(float, spread)),
                                 tuple(map(float, spread_std)), tuple(map(float, share)), lam)
    return dataclasses.replace(
        base, mean=tuple(zip(names, map(float, mu))), covariance=(tuple(names), tuple(map(tuple, cov.tolist()))),
        noise_std=noise_std if noise_std is not None else base.noise_std,
        source=f"fleet of {K} units of {robot}" + (" (the members' prior)" if members else ""), population=population)


def _result_prior(free, units, x, cov, deviations: dict, base: Prior, source: str, noise_std=None) -> Prior:
    rob = robot_part(free)
    C = np.asarray(cov, np.float64)[np.ix_(rob, rob)]
    std = np.sqrt(np.maximum(np.diag(C), 0.0))
    keep = np.isfinite(std) & (std > 0)
    names = [free[i] for i, ok in zip(rob, keep) if ok]
    C = C[np.ix_(keep, keep)]
    mean = {n: float(v) for n, v in deviations.items() if group_kind(n) != "extra"}
    mean.update({free[i]: float(x[i]) for i in rob})
    return dataclasses.replace(base, mean=tuple(mean.items()),
                               covariance=(tuple(names), tuple(map(tuple, (0.5 * (C + C.T)).tolist()))),
                               source=source, population=None,
                               noise_std=base.noise_std if base.noise_std is not None else noise_std)


def result_prior(result, base: Prior, *, source: str | None = None) -> Prior:
    """A unit's previous calibration as the prior of its next one (rad, mm): mean = the previous
    estimate of every robot parameter, covariance = the previous posterior covariance of those it
    fitted (parameters it did not fit keep ``base``'s σ: the default 0.5°, 2 mm); the sensor extras
    stay out (a new set-up). ``result``: a :class:`~jaxcal.CalibrationResult` with its
    ``uncertainty``.

    The noise σ the prior is weighed against is the previous fit's σ̂ (the unit's sensor), unless
    ``base.noise_std`` says: estimated from the new fit instead, a prior this tight can hold the
    fit where it was, leave large residuals, and so read a large σ̂ that keeps it there (a 0.1°
    change went unseen that way)."""
    if result.uncertainty is None:
        raise ValueError("the previous result has no posterior covariance (result.uncertainty)")
    return _result_prior(list(result.space.free_names), list(result.space.free_units), np.asarray(result.x),
                         result.uncertainty.covariance, result.deviations.named(), base,
                         source or f"previous calibration of {result.robot.name}", result.uncertainty.noise_std)


# -- files ----------------------------------------------------------------------------------------------


def prior_to_dict(prior: Prior) -> dict:
    """JSON-friendly prior (rad, mm as the names' units; ``inf`` σ written as ``null``)."""
    fin = lambda v: None if not math.isfinite(v) else float(v)  # noqa: E731
    mean = prior.mean
    if mean is not None and not isinstance(mean, tuple):  # Deviations
        mean = tuple(mean.named().items())
    out = {"format": PRIOR_FORMAT, "source": prior.source,
           "angle_deg": fin(prior.angle_deg), "length_mm": fin(prior.length_mm),
           "extras_mm": fin(prior.extras_mm), "extras_deg": fin(prior.extras_deg), "noise_std_mm": prior.noise_std,
           "strength": prior.strength, "overrides": [list(o) for o in prior.overrides],
           "mean": None if mean is None else dict(mean)}
    if prior.covariance:
        out["covariance"] = {"names": list(prior.covariance[0]), "matrix": [list(r) for r in prior.covariance[1]]}
    if prior.population is not None:
        out["population"] = prior.population.to_dict()
    if prior.scale_by != "fixed":
        out["scale_by"] = prior.scale_by
    if prior.evidence is not None:  # the scales the evidence chose (the σ above are the chosen ones)
        out["evidence"] = prior.evidence.to_dict()
    return to_jsonable(out)


def prior_from_dict(d: dict, cls: type[Prior], where: str = "prior") -> Prior:
    """Inverse of :func:`prior_to_dict` (``cls``: :class:`~jaxcal.Prior`)."""
    if not str(d.get("format", "")).startswith("jaxcal-prior/"):
        raise ValueError(f"{where} is not a jaxcal prior file (no 'format': {PRIOR_FORMAT!r} entry)")
    inf = lambda v: math.inf if v is None else float(v)  # noqa: E731
    cov = d.get("covariance")
    try:
        return cls(angle_deg=inf(d.get("angle_deg", 0.5)), length_mm=inf(d.get("length_mm", 2.0)),
                     extras_mm=inf(d.get("extras_mm")), extras_deg=inf(d.get("extras_deg")),
                     noise_std=d.get("noise_std_mm"), strength=float(d.get("strength", 1.0)),
                     overrides=tuple((str(n), float(s)) for n, s in d.get("overrides", ())),
                     mean=None if d.get("mean") is None else tuple((str(n), float(v)) for n, v in d["mean"].items()),
                     covariance=() if cov is None else (tuple(cov["names"]), tuple(map(tuple, cov["matrix"]))),
                     source=str(d.get("source", "")),
                     population=None if d.get("population") is None else FleetPopulation.from_dict(d["population"]),
                     scale_by=str(d.get("scale_by", "fixed")), evidence=EvidenceScales.from_dict(d.get("evidence")))
    except (KeyError, TypeError) as e:
        raise ValueError(f"{where}: malformed prior file ({type(e).__name__}: {e})") from None


def save_prior(prior: Prior, path) -> None:
    """Write ``prior`` as JSON (:data:`PRIOR_FORMAT`)."""
    pathlib.Path(path).write_text(json.dumps(prior_to_dict(prior), indent=1, allow_nan=False) + "\n", encoding="utf-8")


def _read_json(path) -> dict:
    p = pathlib.Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"prior file {str(path)!r} not found")
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise ValueError(f"{path} is not a JSON file: {e}") from None
    if not isinstance(d, dict):
        raise ValueError(f"{path} is not a jaxcal prior or result file")
    return d


def load_prior(path, cls: type[Prior]) -> Prior:
    """Read a prior file written by :func:`save_prior`."""
    return prior_from_dict(_read_json(path), cls, str(path))


def prior_from_file(path, cls: type[Prior]) -> Prior:
    """A prior file (:func:`save_prior`), or a calibration result file as the prior of the unit's
    next calibration (:func:`result_prior`)."""
    d = _read_json(path)
    if str(d.get("format", "")).startswith("jaxcal-calibration-result/"):
        unc = d.get("uncertainty")
        if not unc or "covariance" not in unc:
            raise ValueError(f"{path}: the result has no posterior covariance to use as a prior")
        free = list(d["free_names"])
        units = [d["units"][n] for n in free]
        x = np.asarray([d["free_parameters"][n] for n in free], np.float64)
        spec = d.get("prior_spec")
        base = prior_from_dict(spec, cls, str(path)) if spec else cls()
        if base.covariance:  # the previous fit's own learned prior: keep its generic σ for the rest
            base = dataclasses.replace(base, covariance=(), mean=None, population=None)
        # σ chosen by the evidence stay as the generic σ of the rest; the new prior's scale is fixed
        base = dataclasses.replace(base, scale_by="fixed", evidence=None)
        name = (d.get("robot") or {}).get("name", "robot")
        return _result_prior(free, units, x, unc["covariance"], d["deviations"], base,
                             f"previous calibration of {name} ({pathlib.Path(path).name})", unc.get("noise_std_mm"))
    return prior_from_dict(d, cls, str(path))


#: how a :class:`Prior`'s scale is set (:attr:`Prior.scale_by`): as given, or by the evidence
SCALE_BY = ("fixed", "evidence")

@dataclasses.dataclass(frozen=True)
class Prior:
    """Independent Gaussian priors on the deviations Δ from nominal (maximum a posteriori).

    Per-group standard deviations; ``math.inf`` (the default for the sensor extras) means no
    prior on that group. The defaults are the size of real manufacturing errors of industrial
    arms (tenths of a degree, a few mm), wide enough not to bias a well-determined parameter.
    Robot groups in other units (a compliance in rad/(N·m)...) take their group's own default
    σ (the group's default prior σ, divided by ``strength``), or no prior if the
    group has none.

    Attributes:
        angle_deg: σ of the DH angles α, θ and Hayati β (degrees).
        length_mm: σ of the DH lengths a, d (mm).
        extras_mm: σ of the anchor, tool point, cable offset and base translation (mm).
        extras_deg: σ of the base-frame rotation (degrees).
        noise_std: the measurement noise σ (mm) the prior is weighed against; ``None``: estimated
            from the fit by :func:`jaxcal.calibrate` (a sweep uses its simulated σ).
        mean: prior means (default: the nominal robot, zero deviations): :class:`Deviations`, or
            ``((name, value), ...)`` by parameter name (rad/mm; names not listed: 0).
        overrides: ``((name, σ), ...)`` per-parameter σ by name (rad/mm as the name's unit says:
            ``("d_1", 10.0)``, ``("theta_2", 0.01)``), taking precedence over the groups.
        strength: divides the groups' own default σ (:meth:`scaled` multiplies it).
        covariance: ``(names, rows)``: a full prior covariance ``[k, k]`` (rad/mm, as the names'
            units) of the parameters ``names`` (a learned prior: :meth:`from_fleet`,
            :meth:`from_result`); it replaces the groups' σ of those parameters (an override still
            wins) and correlates them: the MAP objective's prior residuals are then
            ``σ·L⁻¹(x − m)`` with ``L Lᵀ`` the covariance of the free parameters (:meth:`whitening`).
        source: where a learned prior comes from (printed by :meth:`describe`).
        population: a prior learned from a fleet: the :class:`~jaxcal.FleetPopulation` estimate
            (population mean and spread with their uncertainties), else ``None``.
        scale_by: ``"fixed"`` (the σ as given) or ``"evidence"``: :func:`jaxcal.calibrate` chooses
            the scale from the data (type-II maximum likelihood: :mod:`jaxcal._fit._evidence`), one
            factor per family — the σ of the angle deviations (:attr:`angle_deg`), the σ of the
            length deviations (:attr:`length_mm`), or, for a prior with a :attr:`covariance`, one
            factor on that covariance — starting from the σ given here. Per-parameter
            :attr:`overrides`, the sensor extras' σ and groups with their own default σ keep theirs.
            ``prior="evidence"`` (CLI ``--prior evidence``) is the default prior's σ chosen so.
        evidence: the choice (:class:`~jaxcal._fit._evidence.EvidenceScales`: factors, their
            uncertainty, how many parameters the data determine) on the prior of a result
            calibrated with ``scale_by="evidence"``, whose σ are then the chosen ones; else ``None``.
    """

    angle_deg: float = 0.5
    length_mm: float = 2.0
    extras_mm: float = math.inf
    extras_deg: float = math.inf
    noise_std: float | None = None
    mean: Deviations | None = None
    overrides: tuple = ()
    strength: float = 1.0
    covariance: tuple = ()
    source: str = ""
    population: Any = None
    scale_by: str = "fixed"
    evidence: Any = None

    def __post_init__(self):
        if self.scale_by not in SCALE_BY:
            raise ValueError(f"Prior.scale_by must be one of {list(SCALE_BY)}, got {self.scale_by!r}")
        for name in ("angle_deg", "length_mm", "extras_mm", "extras_deg"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0):
                raise ValueError(f"Prior.{name} must be > 0 (use math.inf for no prior), got {v!r}")
        if self.noise_std is not None and not (self.noise_std > 0 and math.isfinite(self.noise_std)):
            raise ValueError(f"Prior.noise_std must be a finite number > 0 (mm) or None, got {self.noise_std!r}")
        for item in self.overrides:
            if len(item) != 2 or not (item[1] > 0):
                raise ValueError(f"Prior.overrides entries must be (name, σ > 0), got {item!r}")
        if self.covariance:
            names, rows = self.covariance
            C = np.asarray(rows, np.float64)
            if C.shape != (len(names), len(names)) or not np.all(np.isfinite(C)) or not np.allclose(C, C.T):
                raise ValueError(f"Prior.covariance must be (names, a symmetric finite [k, k] matrix) with k = "
                                 f"{len(names)} names, got a matrix of shape {C.shape}")
            if np.linalg.eigvalsh(C)[0] <= 0:
                raise ValueError("Prior.covariance must be positive definite")
            for n in names:
                group_of(n)  # raises naming an unknown parameter
        if self.mean is not None and not isinstance(self.mean, Deviations):
            for item in self.mean:
                if len(item) != 2 or not math.isfinite(item[1]):
                    raise ValueError(f"Prior.mean entries must be (name, finite value), got {item!r}")
                group_of(item[0])

    @classmethod
    def parse(cls, text: str) -> Prior | None:
        """From a command-line string: ``none``, ``default``, ``key=value`` pairs separated by
        commas (keys: the attribute names, e.g. ``angle_deg=0.5,length_mm=2,extras_mm=500``;
        a parameter name sets that parameter's σ, e.g. ``d_1=10``), or a ``.json`` file: a prior
        file (:meth:`save`, ``jaxcal fleet-prior``) or a previous calibration result of the unit
        (:meth:`from_result`). ``evidence`` is the default prior with its scale chosen by the data
        (:attr:`scale_by`); ``evidence:SPEC`` any of the above so (``evidence:MODEL.prior.json``:
        one factor on a learned prior's covariance)."""
        text = text.strip()
        head, sep, rest = text.partition(":")
        if head.strip().lower() == "evidence":
            base = cls() if not sep else cls.parse(rest)
            if base is None:
                raise ValueError("prior: 'evidence' chooses the scale of a prior; 'none' has none")
            return dataclasses.replace(base, scale_by="evidence")
        if text.lower().endswith(".json"):  # a prior file (jaxcal fleet-prior) or a previous result

            return prior_from_file(text, cls)
        if text.lower() in ("none", "off", ""):
            return None
        if text.lower() == "default":
            return cls()
        fields, overrides = {}, []
        for part in text.split(","):
            if "=" not in part:
                raise ValueError(f"prior: expected NAME=VALUE pairs or 'none'/'default', got {part!r}")
            k, v = (s.strip() for s in part.split("=", 1))
            try:
                val = float(v)
            except ValueError:
                raise ValueError(f"prior: {k} must be a number, got {v!r}") from None
            if k in ("angle_deg", "length_mm", "extras_mm", "extras_deg", "noise_std"):
                fields[k] = val
            else:
                group_of(k)  # raises naming an unknown parameter
                overrides.append((k, val))
        return cls(**fields, overrides=tuple(overrides))

    def scaled(self, strength: float) -> Prior:
        """The same prior ``strength`` times stronger (every finite σ divided by ``strength``, a
        learned covariance by ``strength²``)."""
        if not strength > 0:
            raise ValueError(f"prior strength must be > 0, got {strength}")
        cov = self.covariance
        if cov:
            cov = (cov[0], tuple(tuple(v / strength**2 for v in row) for row in cov[1]))
        return dataclasses.replace(
            self, angle_deg=self.angle_deg / strength, length_mm=self.length_mm / strength,
            extras_mm=self.extras_mm / strength, extras_deg=self.extras_deg / strength,
            overrides=tuple((n, s / strength) for n, s in self.overrides), strength=self.strength * strength,
            covariance=cov,
        )

    def std(self, space: ParameterSpace) -> np.ndarray:
        """σ ``[p]`` of the free parameters in their units (rad, mm); ``inf`` = no prior (with a
        ``covariance``: its marginal σ for the parameters it names)."""
        return self._std_families(space)[0]

    def families(self, space: ParameterSpace) -> np.ndarray:
        """``[p]`` the family of each free parameter whose σ a ``scale_by="evidence"`` choice
        scales: ``"angles"`` (σ from :attr:`angle_deg`), ``"lengths"`` (from :attr:`length_mm`),
        ``"covariance"`` (named by a learned :attr:`covariance`; the others then keep their σ),
        ``""`` for the rest (an override, a sensor extra, a group's own σ, no prior)."""
        return self._std_families(space)[1]

    def _std_families(self, space: ParameterSpace) -> tuple[np.ndarray, np.ndarray]:
        over = dict(self.overrides)
        unknown = set(over) - set(space.names)
        if unknown:
            raise ValueError(f"prior overrides name unknown parameter(s) {sorted(unknown)}")
        learned = {}
        if self.covariance:
            names, rows = self.covariance
            learned = dict(zip(names, np.sqrt(np.diag(np.asarray(rows, np.float64)))))
        out, fam = [], []
        for name, unit in zip(space.free_names, space.free_units):
            family = ""
            if name in over:
                s = float(over[name])
            elif name in learned:
                s, family = float(learned[name]), "covariance"
            else:
                group = space.layout.group(space.layout.group_of(name))
                if group.kind == "extra":
                    own = math.radians(self.extras_deg) if unit == "rad" else self.extras_mm
                    s = own if unit in ("rad", "mm") else math.inf
                elif group.prior_std is not None:
                    s = group.prior_std / self.strength
                elif unit in ("rad", "mm"):
                    s = math.radians(self.angle_deg) if unit == "rad" else self.length_mm
                    family = "" if learned else "angles" if unit == "rad" else "lengths"
                else:
                    s = math.inf
            out.append(s)
            fam.append(family if math.isfinite(s) else "")
        return np.asarray(out, dtype=np.float64), np.asarray(fam, dtype=object)

    def rescaled(self, factors: dict) -> Prior:
        """The prior with its families' σ multiplied by ``factors`` ``{family: k}`` (see
        :meth:`families`: ``angle_deg``, ``length_mm`` times ``k``, a learned covariance times ``k²``)."""
        cov = self.covariance
        k = factors.get("covariance", 1.0)
        if cov and k != 1.0:
            cov = (cov[0], tuple(tuple(v * k * k for v in row) for row in cov[1]))
        return dataclasses.replace(self, angle_deg=self.angle_deg * factors.get("angles", 1.0),
                                   length_mm=self.length_mm * factors.get("lengths", 1.0), covariance=cov)

    def mean_vector(self, space: ParameterSpace) -> np.ndarray:
        """Prior means ``[p]`` of the free parameters (rad, mm)."""
        if self.mean is None:
            return np.zeros(space.n_free)
        if isinstance(self.mean, Deviations):
            return np.asarray(space.to_vector_numpy(self.mean), np.float64)
        named = dict(self.mean)
        return np.asarray([float(named.get(n, 0.0)) for n in space.free_names], np.float64)

    def whitening(self, space: ParameterSpace, free: ParameterSpace | None = None) -> np.ndarray | None:
        """``W`` ``[p, p]`` (1/rad, 1/mm) with ``WᵀW`` the prior information of the parameters of
        ``free`` (default: all of ``space``'s) that have a prior: the prior residuals are
        ``W(x − m)``, ``W = L⁻¹`` for the Cholesky factor ``L`` of their prior covariance (the
        marginal of :attr:`covariance` and the groups' independent σ), zero rows and columns
        elsewhere. ``None`` without a :attr:`covariance` (the prior is diagonal: ``1/σ``)."""
        if not self.covariance:
            return None
        std = self.std(space)
        keep = np.isfinite(std)
        if free is not None:
            chosen = set(free.free_names)
            keep &= np.asarray([n in chosen for n in space.free_names])
        C = np.diag(np.where(keep, std, 1.0) ** 2)
        names, rows = self.covariance
        rows = np.asarray(rows, np.float64)
        at = {n: i for i, n in enumerate(names)}
        over = dict(self.overrides)
        idx = [(j, at[n]) for j, n in enumerate(space.free_names) if n in at and n not in over]
        for j, a in idx:
            for k, b in idx:
                C[j, k] = rows[a, b]
        W = np.zeros((space.n_free, space.n_free))
        act = np.flatnonzero(keep)
        if act.size:
            L = np.linalg.cholesky(C[np.ix_(act, act)])
            W[np.ix_(act, act)] = np.linalg.solve(L, np.eye(act.size))
        return W

    def information(self, space: ParameterSpace) -> np.ndarray | None:
        """The prior information ``WᵀW`` ``[p, p]`` of the free parameters (see :meth:`whitening`);
        ``None`` for a diagonal prior (``diag(1/σ²)``)."""
        W = self.whitening(space)
        return None if W is None else W.T @ W

    @classmethod
    def from_fleet(cls, results, *, base: Prior | None = None, noise_std: float | None = None, iterations: int = 1000,
                   tol: float = 1e-7) -> Prior:
        """The robot model's own prior, learned from calibrated units of it (empirical Bayes).

        Unit ``k``'s robot deviations are modelled as drawn from ``N(μ, Σ)``, its calibration as a
        Gaussian measurement of them (its own prior divided out); ``μ`` and ``Σ`` maximise the
        marginal likelihood (expectation–maximisation; Gelman et al., *Bayesian Data Analysis*,
        ch. 5), so the spread of the estimates is split into the true unit spread and each unit's
        estimation noise; the correlations are shrunk toward zero (Schäfer & Strimmer 2005) when
        the units are few; directions no unit's data determine keep ``base``. The result's
        ``mean`` is ``μ``, its ``covariance`` ``Σ`` plus the uncertainty of ``μ`` (from the number
        of units), its ``population`` the :class:`~jaxcal.FleetPopulation` (mean, spread and their
        σ). Sensor extras (anchor, tool point, sensor frame) stay out: they are per unit.

        Args:
            results: ≥ 3 :class:`~jaxcal.CalibrationResult` of units of one robot model, each with
                its ``uncertainty``, calibrated under a prior (``objective="measured"``, the CLI's
                default), e.g. ``[jaxcal.load_result(f) for f in files]``.
            base: the generic prior (default ``Prior()``: 0.5°, 2 mm): the spread's start, the
                hyper-prior of the mean, and the σ of parameters no unit fitted.
            noise_std: the sensor noise σ (mm) the prior is weighed against (default: estimated
                from each new fit).
            iterations, tol: the EM budget and its relative tolerance on ``Σ``.
        """

        return fleet_prior(results, cls() if base is None else base, noise_std=noise_std, iterations=iterations,
                           tol=tol)

    @classmethod
    def from_result(cls, result, *, base: Prior | None = None, source: str | None = None) -> Prior:
        """A unit's previous calibration as the prior of its next one: mean = its estimate of
        every robot parameter, covariance = its posterior covariance of those it fitted (the
        others keep ``base``'s σ, default ``Prior()``); sensor extras stay out; weighed against
        the previous fit's σ̂ (the unit's sensor) unless ``base.noise_std`` says otherwise.
        ``result``: a :class:`~jaxcal.CalibrationResult` with its ``uncertainty``. For which
        parameters moved since, compare two independent calibrations: :func:`jaxcal.drift`."""

        return result_prior(result, cls() if base is None else base, source=source)

    def save(self, path) -> None:
        """Write the prior as a JSON file (``jaxcal-prior/1``; :meth:`load` reads it back)."""

        save_prior(self, path)

    @classmethod
    def load(cls, path) -> Prior:
        """Read a prior file written by :meth:`save` (or ``jaxcal fleet-prior --out``)."""

        return load_prior(path, cls)

    def describe(self) -> str:
        """One line: the prior's σ (or its learned covariance), and the evidence's choice of scale."""
        fmt = (lambda v: f"{v:.3g}") if self.evidence is not None else (lambda v: f"{v:g}")  # noqa: E731
        if self.covariance:
            k = len(self.covariance[0])
            text = f"learned Gaussian prior ({self.source or 'a learned prior'}): mean and covariance of {k} parameters"
            text += (f", the others σ = {fmt(self.angle_deg)}°, {fmt(self.length_mm)} mm toward nominal"
                     if math.isfinite(self.angle_deg) or math.isfinite(self.length_mm) else "")
        else:
            parts = [f"{fmt(self.angle_deg)}°", f"{fmt(self.length_mm)} mm on the robot's geometric deviations"]
            if math.isfinite(self.extras_mm) or math.isfinite(self.extras_deg):
                parts.append(f"extras {self.extras_mm:g} mm / {self.extras_deg:g}°")
            if self.overrides:
                parts.append("overrides " + ", ".join(f"{n}={s:g}" for n, s in self.overrides))
            text = "Gaussian prior toward nominal: σ = " + ", ".join(parts)
        if self.evidence is not None:
            return f"{text} — {self.evidence.describe()}"
        return text + ("; its scale to be chosen by the evidence (type-II maximum likelihood)"
                       if self.scale_by == "evidence" else "")


def resolve_prior(prior) -> Prior | None:
    """``None``/``"none"`` → ``None``; ``"default"`` → :class:`Prior` (); ``"evidence"`` → the
    default prior with its scale chosen by the evidence (:attr:`Prior.scale_by`); a :class:`Prior`
    as given; a string of ``key=value`` pairs (or ``evidence:SPEC``) → :meth:`Prior.parse`."""
    if prior is None or isinstance(prior, Prior):
        return prior
    if isinstance(prior, str):
        return Prior.parse(prior)
    raise TypeError(f"prior must be None, 'default', 'evidence', a jaxcal.Prior or a 'key=value,...' string, got "
                    f"{type(prior)}")
