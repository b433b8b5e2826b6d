"""Priors learned from calibrations: a robot model's fleet (empirical Bayes) and a unit's previous result.

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
from typing import TYPE_CHECKING

import numpy as np

from .._core._json import to_jsonable
from .._core._metrics import format_table
from .._core._params import ParameterSpace, group_kind
from ._evidence import EvidenceScales

if TYPE_CHECKING:  # the Prior class is passed in (Prior's own methods call these): no import circle
    from ._objective import Prior

__all__ = ["FleetPopulation", "fleet_prior", "result_prior", "save_prior", "load_prior", "prior_from_file",
           "PRIOR_FORMAT", "robot_part"]

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
