"""What a calibration minimises beyond plain least squares: Gaussian priors (MAP) and robust losses.

Plain calibration minimises ``Σ r²`` over the residuals ``r`` (mm). On real data two additions
matter:

* **Priors toward the nominal robot** (maximum a posteriori). With measurement noise σ (mm) and
  independent Gaussian priors ``Δ_j ~ N(m_j, s_j²)`` the negative log posterior is, up to a
  constant, ``(1/σ²)·[Σ r² + Σ_j (σ·(Δ_j − m_j)/s_j)²]``: the prior is ``p`` extra residuals
  ``σ·(Δ_j − m_j)/s_j`` (mm). Least-squares methods append them to the residual vector, gradient
  methods add their square to the loss, population methods to the fitness, the EKF starts from
  the prior covariance. Narrow joint coverage leaves some combinations of DH parameters weakly
  determined; unregularised fits then "explain" the data with absurd parameters (|Δa| > 100 mm)
  that extrapolate badly. Priors of the size of real manufacturing errors (0.5°, 2 mm) keep them
  plausible at a small cost in training fit.
* **Robust losses** against gross outliers: each sample's residual block ``r_i`` is scaled by
  ``f(u_i)``, ``u_i = ‖r_i‖/c``, so that ``‖f r_i‖² = c²·2ρ(u_i)``: Huber ``ρ(u) = u²/2`` for
  ``u ≤ 1``, ``u − ½`` beyond (Huber, 1964); Cauchy ``ρ(u) = ½·log(1 + u²)``. Minimising the sum
  of the transformed squares minimises ``Σ ρ``, so every method (LM included) handles it
  unchanged. The scale ``c`` is ``k·√m_e·σ̂`` with ``σ̂ = 1.4826·MAD`` of the residual entries,
  the usual 95 %-efficiency constants ``k`` = 1.345 (Huber), 2.385 (Cauchy), and ``m_e`` the mean
  square of a clean sample's error in units of σ² (:func:`~jaxcal._fit._diagnostics.error_dims`:
  1 for a length, 3 for a position's norm or an RMS over markers, 2 for image corners), so that
  ``k`` means what it means for one reading; :func:`jaxcal.calibrate` re-estimates it from the fit
  (a few rounds, each warm-started). (``c = k·σ̂`` without ``√m_e`` would cap 61 % of clean
  tracker rows on a position's norm instead of 13 %.)

:data:`MEASURED_DEFAULTS` is the objective for measured data: the default prior toward the
nominal robot plus the Huber loss (``calibrate(..., objective="measured")``, the CLI,
:func:`jaxcal.holdout_session`, :func:`jaxcal.leave_one_session_out`). Measured on messy
simulated data (``benchmarks/bench_measured_defaults.py``, ``benchmarks/results/
measured_defaults_cpu.md``, 3 seeds, draw-wire and tracker data): without a gross outlier the
four objectives reach the same held-out RMSE (within 1.5 %); with one gross row, least squares
with the prior ended 2.77× (draw-wire; up to 5.4×) and 1.28× (tracker) above its fit without
that row, the prior + Huber fit within 0.34 % of it (mean 0.05 %); without the prior the
Huber fit also shrugged the row off, but its error over the unmeasured workspace was 9–12 mm
against 1.6–1.8 mm with the prior, and its parameters implausible. ``calibrate()``'s bare
default stays plain least squares: it is the paper's experiment.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core._metrics import robust_scale
from .._core._params import Deviations, ParameterSpace, group_of
from .._core._precision import to_device
from .._models import _chain, _nongeometric  # noqa: F401 — they register their group names (Prior.parse)

__all__ = ["Prior", "Objective", "LOSSES", "robust_factor", "robust_scale", "resolve_prior", "MEASURED_DEFAULTS",
           "OBJECTIVES", "resolve_objective", "describe_objective"]

#: how a :class:`Prior`'s scale is set (:attr:`Prior.scale_by`): as given, or by the evidence
SCALE_BY = ("fixed", "evidence")

#: robust losses and their 95 %-efficiency tuning constants ``k`` (scale ``c = k·σ̂``).
LOSSES: dict[str, float] = {"linear": math.inf, "huber": 1.345, "cauchy": 2.385}


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
            from ._learned_prior import prior_from_file

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
        from ._learned_prior import fleet_prior

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
        from ._learned_prior import result_prior

        return result_prior(result, cls() if base is None else base, source=source)

    def save(self, path) -> None:
        """Write the prior as a JSON file (``jaxcal-prior/1``; :meth:`load` reads it back)."""
        from ._learned_prior import save_prior

        save_prior(self, path)

    @classmethod
    def load(cls, path) -> Prior:
        """Read a prior file written by :meth:`save` (or ``jaxcal fleet-prior --out``)."""
        from ._learned_prior import load_prior

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


class Objective(eqx.Module):
    """The pure, jittable description of the objective in physical units (a pytree).

    Attributes:
        prior_mean: ``[p]`` prior means of the free parameters (rad/mm).
        prior_precision: ``[p]`` ``σ_noise / s_j`` (mm per unit of the parameter), 0 = no prior:
            the prior residual is ``prior_precision·(x − prior_mean)`` (mm).
        loss_scale: robust-loss scale ``c`` (mm).
        loss: ``"linear"``, ``"huber"`` or ``"cauchy"`` (static).
        has_prior: whether any prior is active (static; without one the objective is exactly
            plain least squares, bit for bit).
        prior_whitening: ``[p, p]`` ``σ_noise·W`` of a prior with a full covariance
            (:meth:`Prior.whitening`): the prior residuals are then ``prior_whitening·(x −
            prior_mean)`` (mm), and ``prior_precision`` is its diagonal counterpart ``σ_noise/s_j``
            (the marginal σ) for the methods that take a diagonal prior (the EKF). ``None``: diagonal.
    """

    prior_mean: Float[Array, " p"]
    prior_precision: Float[Array, " p"]
    loss_scale: Float[Array, ""]
    loss: str = eqx.field(static=True, default="linear")
    has_prior: bool = eqx.field(static=True, default=False)
    prior_whitening: Float[Array, "p p"] | None = None

    @classmethod
    def plain(cls, p: int, dtype=None) -> Objective:
        z = jnp.zeros(p, dtype)
        return cls(z, z, jnp.asarray(1.0, dtype), "linear", False)

    @classmethod
    def build(cls, space: ParameterSpace, prior: Prior | None, noise_std: float | None, loss: str = "linear",
              loss_scale: float | None = None, dtype=None, free: ParameterSpace | None = None) -> Objective:
        """From a :class:`Prior` (or ``None``), the noise σ it is weighed against (mm) and a loss.
        ``free``: the parameters that move when ``space`` is a masked solve's program space (a full
        prior covariance is whitened over them alone: :meth:`Prior.whitening`)."""
        if loss not in LOSSES:
            raise ValueError(f"unknown loss {loss!r}; choose one of {list(LOSSES)}")
        p = space.n_free
        whitening = None
        if prior is None:
            mean = np.zeros(p)
            precision = np.zeros(p)
        else:
            sigma = prior.noise_std if prior.noise_std is not None else noise_std
            if sigma is None:
                raise ValueError("the prior needs a noise σ (mm): set Prior(noise_std=...) or let calibrate estimate it")
            std = prior.std(space)
            precision = np.where(np.isfinite(std), float(sigma) / std, 0.0)
            mean = prior.mean_vector(space)
            W = prior.whitening(space, free)
            whitening = None if W is None else float(sigma) * W
        scale = 1.0 if loss_scale is None else float(loss_scale)
        if loss != "linear" and not (scale > 0 and math.isfinite(scale)):
            raise ValueError(f"robust loss scale must be a finite number > 0 (mm), got {loss_scale!r}")
        has_prior = bool(np.any(precision > 0))
        dt = jnp.result_type(float) if dtype is None else dtype
        return cls(to_device(mean, dt), to_device(precision, dt), to_device(scale, dt), loss, has_prior,
                   None if whitening is None else to_device(whitening, dt))

    @property
    def plain_least_squares(self) -> bool:
        return self.loss == "linear" and not self.has_prior


def robust_factor(loss: str, sq_error: Array, scale: Array, xp=jnp) -> Array:
    """Per-sample factor ``f`` with ``(f·e)² = c²·2ρ(e/c)`` for squared errors ``e²`` ``[n]``.

    Smooth and differentiable at ``e = 0`` (series below ``u² = 1e-8``), so ``jax.jacfwd``
    through it is exact. ``xp``: the array module (``jax.numpy``, or ``numpy`` for host-side
    statistics that should not compile a program).
    """
    if loss == "linear":
        return xp.ones_like(sq_error)
    u2 = sq_error / (scale * scale)
    if loss == "huber":
        big = u2 > 1.0
        u = xp.sqrt(xp.where(big, u2, 1.0))
        return xp.where(big, xp.sqrt(2.0 * u - 1.0) / u, 1.0)
    if loss == "cauchy":
        small = u2 < 1e-8
        u2s = xp.where(small, 1.0, u2)
        return xp.where(small, 1.0 - 0.25 * u2, xp.sqrt(xp.log1p(u2s) / u2s))
    raise ValueError(f"unknown loss {loss!r}; choose one of {list(LOSSES)}")


# -- named objectives ------------------------------------------------------------------------

#: The objective for measured data (issue 24; evidence in ``benchmarks/results/measured_defaults_cpu.md``):
#: the default Gaussian prior toward the nominal robot (0.5° on angles, 2 mm on DH lengths, none
#: on the sensor extras) and the Huber loss (scale 1.345 robust σ, re-estimated from the fit).
MEASURED_DEFAULTS = {"prior": "default", "loss": "huber"}
#: Named objectives of :func:`jaxcal.calibrate` (``objective=``): ``"measured"`` the defaults for
#: measured data, ``"least_squares"`` plain least squares (the paper's experiment; the bare default).
OBJECTIVES = {"measured": MEASURED_DEFAULTS, "least_squares": {"prior": None, "loss": "linear"}}


def resolve_objective(objective, prior, loss):
    """``(prior, loss)`` of a :func:`jaxcal.calibrate` call: ``objective`` (``None``, ``"measured"``,
    ``"least_squares"``) fills in what is not given (``prior=None``, ``loss=None``); explicit values win
    (``prior="none"`` for no prior). Without an objective: ``prior`` as given, ``loss`` ``"linear"``."""
    if objective is None:
        return prior, "linear" if loss is None else loss
    if objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {objective!r}; choose one of {list(OBJECTIVES)} (or None)")
    preset = OBJECTIVES[objective]
    return (preset["prior"] if prior is None else prior), (preset["loss"] if loss is None else loss)


def describe_objective(prior, loss: str) -> str:
    """One line naming the objective, and whether it is :data:`MEASURED_DEFAULTS`."""
    p = resolve_prior(prior)
    what = "least squares" if loss == "linear" else f"{loss} loss"
    text = f"{what}; " + (p.describe() if p is not None else "no prior")
    if p == Prior() and loss == MEASURED_DEFAULTS["loss"]:
        return "measured-data defaults (default prior + Huber loss, jaxcal.MEASURED_DEFAULTS): " + text
    return "objective: " + text + " (not the measured-data defaults: default prior + Huber loss)"
