"""Honest numbers about a calibration: uncertainties, plausibility, conditioning, coverage, outliers.

A calibration that fits the data with absurd parameters is a failure, not a result. After every
:func:`jaxcal.calibrate` these checks run on the host (one ``jax.jacfwd`` Jacobian at the
solution, a few small dense factorisations) and their findings land in
``CalibrationResult.diagnostics`` (warnings as plain sentences) and ``.uncertainty``.

Uncertainty (Gauss–Markov / Laplace approximation of the posterior at the solution ``x̂``):
``Cov = (JᵀWJ/σ̂² + Λ)⁻¹`` with ``J`` the identification Jacobian of the data residuals, ``W``
the robust-loss weights (IRLS weights ``f_i²``; identity for least squares), ``Λ = diag(1/s_j²)``
the prior precision (0 without prior) and ``σ̂² = Σ w r² / (N − p_eff)`` the residual variance,
``p_eff = tr(JᵀWJ/σ̂²·Cov)`` the effective number of parameters (= ``p`` without prior).
Without prior this is ``σ̂²(JᵀJ)⁻¹``, the Cramér–Rao bound with σ estimated from the residuals.
Under a robust loss ``Σ w r²`` is replaced by its bounded-influence counterpart
(:class:`RobustNoise`), so that gross outliers inflate neither σ̂ nor the covariance.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._core._buckets import LeanJit
from .._core._json import from_json_number
from .._core._params import group_kind
from .._core._precision import to_device
from ._objective import robust_factor, robust_scale
from ._problem import observed_entries, residual_blocks_numpy, signed_residuals, value_and_jacfwd

__all__ = ["Checks", "Uncertainty", "Diagnostics", "parameter_uncertainty", "outlier_rows", "wrap_angle_deg",
           "prior_directions"]


@dataclasses.dataclass(frozen=True)
class Checks:
    """Thresholds of the post-calibration checks (all configurable).

    Attributes:
        angle_deg, length_mm: a DH deviation beyond these (wrapped angles, degrees; mm) is
            implausible for a real arm (default 5°, 20 mm).
        condition_number: warn above this condition number of the column-scaled Jacobian of the
            free parameters at the solution (default 1e4).
        narrow_joint_deg: warn when a joint moved less than this in the data (default 30°).
        outlier_k: a sample is an outlier when its residual exceeds ``k`` robust standard
            deviations (1.4826·MAD) from the median residual (default 5).
        weak_fraction: with a prior, a parameter whose posterior σ exceeds this fraction of its
            prior σ is "weakly determined" by the data (default 0.5).
    """

    angle_deg: float = 5.0
    length_mm: float = 20.0
    condition_number: float = 1e4
    narrow_joint_deg: float = 30.0
    outlier_k: float = 5.0
    weak_fraction: float = 0.5


def wrap_angle_deg(v):
    """Angles in degrees wrapped to (−180°, 180°]."""
    v = np.asarray(v, dtype=np.float64)
    w = np.mod(v + 180.0, 360.0) - 180.0
    return np.where(w == -180.0, 180.0, w)


@dataclasses.dataclass(frozen=True)
class Uncertainty:
    """Posterior standard deviations of the free parameters (see the module docstring).

    Attributes:
        names, units: of the free parameters (``"rad"``/``"mm"``).
        std: ``[p]`` standard deviations (rad, mm); ``inf`` where the data and prior leave a
            direction undetermined.
        covariance: ``[p, p]``.
        noise_std: σ̂, the sensor noise estimated from the residuals (mm): their RMS over
            ``N − p_eff`` degrees of freedom; under a robust loss a bounded-influence scale,
            consistent for Gaussian noise (:class:`RobustNoise`).
        effective_parameters: ``p_eff``.
        n_residuals: ``N``.
    """

    names: tuple[str, ...]
    units: tuple[str, ...]
    std: np.ndarray
    covariance: np.ndarray
    noise_std: float
    effective_parameters: float
    n_residuals: int

    def std_display(self) -> dict[str, tuple[float, str]]:
        """``{name: (σ, unit)}`` with angles in degrees (other units as they are: mm, rad/(N*m)...)."""
        return {n: ((math.degrees(s), "deg") if u == "rad" else (float(s), u))
                for n, s, u in zip(self.names, self.std, self.units)}

    def to_dict(self) -> dict:
        return {
            "std": {n: float(s) for n, s in zip(self.names, self.std)},
            "units": dict(zip(self.names, self.units)),
            "noise_std_mm": self.noise_std,
            "effective_parameters": self.effective_parameters,
            "n_residuals": self.n_residuals,
            "covariance": np.asarray(self.covariance).tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict | None, names, units) -> Uncertainty | None:
        """The inverse of :meth:`to_dict` for the free parameters ``names`` (``units``): ``None``
        where ``d`` is absent or was written for another set of free parameters. ``"inf"`` and
        ``null`` (NaN) entries as JSON writes them."""
        if not d or "covariance" not in d:
            return None
        num = from_json_number
        cov = np.asarray([[num(v) for v in row] for row in d["covariance"]], np.float64)
        if cov.shape != (len(names), len(names)) or set(d.get("std", {})) != set(names):
            return None
        return cls(tuple(names), tuple(units), np.asarray([num(d["std"][n]) for n in names], np.float64), cov,
                   num(d.get("noise_std_mm")), num(d.get("effective_parameters")), int(d.get("n_residuals", 0)))


def gram_at(problem, x, loss: str, loss_scale):
    """One ``jacfwd`` pass at ``x``: column norms ``d`` of the Jacobian, the column-scaled ``JᵀWJ``
    and ``JᵀJ`` (p×p; ``W`` the per-residual robust weights ``f²``; the same matrix for the
    linear loss), ``Σ w r²``, the residual ``r`` ``[N]`` itself (for the outlier scan) and, under a
    robust loss, the per-sample errors ``e`` ``[n]`` the loss acts on (for the bounded-influence
    σ̂ of :class:`RobustNoise`; ``None`` for least squares). Pure and jittable:
    :class:`~jaxcal.Calibrator` evaluates it in the solve's own program (``report=True``),
    :func:`parameter_uncertainty` otherwise compiles it alone. The N×p Jacobian stays inside XLA;
    the host only factorises p×p matrices."""
    r, J = value_and_jacfwd(problem.residual, x, problem.q)
    d = jnp.sqrt(jnp.sum(J * J, axis=0))
    Js = J / jnp.where(d > 0, d, 1.0)
    G = Js.T @ Js
    if loss == "linear":
        return d, G, G, jnp.sum(r * r), r, None
    n, m = problem.n_samples, problem.measurement.size
    e = problem.measurement.sample_error(r.reshape(n, m))
    f = robust_factor(loss, e * e, loss_scale)
    w = jnp.repeat(f * f, m)
    return d, (Js * w[:, None]).T @ Js, G, jnp.sum(w * r * r), r, e


_gram = jax.jit(gram_at, static_argnames="loss")


def _sample_errors(measurement, z):
    return measurement.sample_error(z)


#: the model's per-sample errors of the consistency draws: one program per model and draw shape
_sample_errors = LeanJit(_sample_errors, maxsize=4)


class Consistency:
    """Gaussian consistency factors of a robust loss on clean residual blocks of one measurement
    model, as functions of the loss scale in units of the noise σ (``c = k·σ``); from
    :func:`robust_consistency`.

    * ``self(k)`` — ``κ(k) = E[Σ (f·r)²] / E[Σ r²]``: the factor by which the robust objective's
      residual sum undershoots the plain one (Huber, 1981, §7.8).
    * :meth:`capped` — ``β(k) = E[min(1, k²/e²)·Σ r²] / E[Σ r²]``: the same for the residual sum
      with every block scaled down so that its error ``e`` is at most ``k`` (Huber's Proposal 2
      for the scale, 1981, §6.4, with the model's own sample error); what :class:`RobustNoise`
      solves for σ̂ with.
    """

    def __init__(self, loss: str, e2: np.ndarray, sq: np.ndarray):
        self.loss, self._e2, self._sq, self._total = loss, e2, sq, float(np.sum(sq))
        #: ``E[e²]`` of a clean block with unit noise: 1 for one reading, 3 for a position's norm
        self.mean_sq_error = float(np.mean(e2))

    def __call__(self, k: float) -> float:
        f = robust_factor(self.loss, self._e2, np.float64(k), xp=np)  # NumPy: no program per call
        return float(np.sum(f * f * self._sq) / self._total)

    def capped(self, k: float) -> float:
        return float(np.sum(_capped_weight(self._e2, k * k) * self._sq) / self._total)


def _capped_weight(e2: np.ndarray, cap2: float) -> np.ndarray:
    """``min(1, cap²/e²)`` per block (1 where ``e = 0``)."""
    return np.minimum(1.0, cap2 / np.where(e2 > 0, e2, np.inf))


def robust_consistency(measurement, loss: str, observed=None, n_draws: int = 40_000) -> Consistency:
    """The Gaussian consistency factors (:class:`Consistency`) of ``loss`` for ``measurement``;
    calling the result at ``k`` gives ``κ(k) = E[Σ (f·r)²] / E[Σ r²]``.

    Computed with the model's own :meth:`~jaxcal.MeasurementModel.sample_error` (what the robust
    factor :func:`~jaxcal._fit._objective.robust_factor` acts on: a residual norm, an RMS over
    markers or corners, a pose's position part) on ``n_draws`` blocks of ``N(0, 1)`` entries
    (fixed seed; at most ~2M entries), with the data's pattern of masked readings (``observed``
    ``[n, m]``, rows drawn in turn); the factors are then exact in expectation for any model
    (sampling error ~0.3 %). Examples (Huber, k = 1.345): κ = 0.933 for a draw-wire length, 0.858
    for a tracker position (the norm of 3 entries exceeds ``c`` in 61 % of clean samples)."""
    m = int(measurement.size)
    n = int(min(n_draws, max(2_000, 2_000_000 // m)))
    if observed is None:
        real = np.ones((n, m), bool)
    else:
        obs = np.asarray(observed, bool).reshape(-1, m)
        real = obs[np.arange(n) % obs.shape[0]]
    # draws only for the real entries, in order: masked readings (a marker column that is empty
    # in every row, say) change neither the draws nor the factors
    z = np.zeros((n, m))
    z[real] = np.random.default_rng(0).standard_normal(int(real.sum()))
    e2 = np.asarray(_sample_errors(measurement, to_device(z)), np.float64) ** 2
    return Consistency(loss, e2, np.sum(z * z, axis=1))


class RobustNoise:
    """σ̂ under a robust loss: a bounded-influence scale (Huber's Proposal 2, 1981, §6.4, on the
    model's sample errors), consistent for Gaussian noise.

    The residuals' own scale ``σ_r`` solves ``σ_r² = Σ_i min(1, (kσ_r)²/e_i²)·‖r_i‖² / (N·β(k))``:
    every residual block ``r_i`` (sample error ``e_i``) is scaled down to error at most ``k·σ_r``
    before it is summed, ``k`` the loss's constant times a clean block's RMS sample error in units
    of σ (√3 for a position's norm), and ``β`` (:meth:`Consistency.capped`) makes the sum
    consistent on clean data; then ``σ̂² = σ_r²·N/(N − p_eff)``, as ``Σ r²/(N − p)`` for least squares. (Capping at
    ``k·σ̂`` and dividing by ``(N − p_eff)·β`` instead — Huber's own degrees-of-freedom correction
    — caps fitted residuals, whose scale is ``σ√(1 − p/N)``, too little: σ̂ came out 2.6 % high on
    240 tracker rows, Monte Carlo over 30 data sets.) The loss's constant is ``c/s``, the loss
    scale ``c`` over the robust scale ``s`` (1.4826·MAD) of the real residual entries at the fit
    (1.345 for Huber, unless ``c`` was given).

    Why not the objective's own ``Σ (f·r)²``: a gross outlier enters it linearly (``2c|e|``), so
    two 145 mm outliers among 800 draw-wire rows made σ̂ 0.667 mm against a held-out RMSE of
    0.449 mm (the messy example report); capped, each adds at most ``k²σ̂²``. The posterior
    covariance weighs ``JᵀWJ`` with the objective's robust weights, so it takes
    ``κ(k)·σ̂²`` (:func:`robust_consistency`) for the objective's residual variance: the same value
    on clean data (Monte Carlo, 40 tracker data sets under the measured-data defaults:
    reported/empirical σ 0.97), without the outliers' inflation on messy data.

    ``None`` from :meth:`build` where the loss is linear or the robust scale is 0 or not finite
    (σ̂ is then the plain RMS).

    Attributes:
        resid_var: ``σ_r²`` (mm²).
        kappa: ``κ(k)`` of the loss at its own constant.
        n_residuals: ``N``, the real residual entries.
    """

    def __init__(self, resid_var: float, kappa: float, n_residuals: int):
        self.resid_var, self.kappa, self.n_residuals = resid_var, kappa, n_residuals

    @classmethod
    def build(cls, loss: str, loss_scale, problem, blocks, r, e) -> RobustNoise | None:
        """From the fit's real residual blocks ``blocks`` (:func:`residual_blocks_numpy`), its
        full residual ``r`` ``[n·m]`` and sample errors ``e`` ``[n]`` (:func:`gram_at`)."""
        if loss == "linear" or e is None:
            return None
        s = robust_scale(observed_entries(problem, blocks))
        if not (s > 0 and math.isfinite(s)):
            return None
        n, m = problem.n_samples, problem.measurement.size
        rr = np.asarray(r, np.float64)[: n * m].reshape(n, m)
        e2, sq = np.asarray(e, np.float64)[:n] ** 2, np.sum(rr * rr, axis=1)
        cons = robust_consistency(problem.measurement, loss, problem.observed())
        k = float(np.asarray(loss_scale)) / s
        # the cap in units of σ on the sample error: k times a clean block's RMS error, so that it
        # caps the same share of clean blocks for every model (18 % at k = 1.345 for one reading,
        # 13 % for a position's norm; at k itself, 61 % of positions and σ̂ ~1.4× as variable)
        cap = k * math.sqrt(cons.mean_sq_error)
        N = problem.n_observed_residuals
        return cls(_capped_fixed_point(e2, sq, cap, N * cons.capped(cap)), cons(k), N)

    def noise_var(self, dof: float) -> float:
        """σ̂² (mm²) over ``dof = N − p_eff`` degrees of freedom."""
        return self.resid_var * self.n_residuals / dof

    def objective_var(self, dof: float) -> float:
        """``κ(k)·σ̂²``: the objective's residual variance ``Σ (f·r)² / dof`` that clean data with
        noise σ̂ would give (what the posterior covariance weighs ``JᵀWJ`` by)."""
        return self.kappa * self.noise_var(dof)


def _capped_fixed_point(e2: np.ndarray, sq: np.ndarray, cap: float, den: float) -> float:
    """``s²`` with ``s² = Σ_i min(1, (cap·s)²/e_i²)·sq_i / den``, by iteration (a concave increasing
    map; geometric convergence from the uncapped value, above the root)."""
    s2 = float(np.sum(sq)) / den
    for _ in range(500):
        new = float(np.sum(_capped_weight(e2, cap * cap * s2) * sq)) / den
        done = abs(new - s2) <= 1e-12 * s2
        s2 = new
        if done or not s2 > 0:
            break
    return s2


def parameter_uncertainty(problem, x, *, prior_inv_std=None, loss: str = "linear", loss_scale: float = 1.0,
                          return_residuals: bool = False, gram=None):
    """Posterior covariance of the free parameters at ``x`` ``[p]`` for ``problem`` (training data).

    Args:
        prior_inv_std: ``[p]`` ``1/s_j`` of the prior (0 = none).
        loss, loss_scale: the robust loss of the fit.

        return_residuals: also return the residual at ``x`` as NumPy ``[n, m]`` (mm), from the
            same compiled pass (what :func:`outlier_rows` scans).
        gram: :func:`gram_at` of ``(problem, x, loss, loss_scale)`` when the caller has it already
            (``calibrate`` gets it from the solve's program); computed here otherwise.

    Returns:
        ``(Uncertainty, condition_number)`` — the latter of the column-scaled data Jacobian, or
        with a prior of the posterior information (the column-scaled data Jacobian over σ̂ stacked
        on the prior's rows: what the MAP fit inverts; the data alone are singular by design) —
        and with ``return_residuals`` the residual blocks as a third element.
    """
    if gram is None:
        gram = _gram(problem, to_device(x, problem.dtype), loss, to_device(loss_scale, problem.dtype))
    d, A, G, rss, r, e = gram
    d, A, G = (np.asarray(v, np.float64) for v in (d, A, G))
    N, p = problem.n_observed_residuals, A.shape[0]  # real readings (masked ones left out)
    rss = float(rss)
    # a padded solve's residual carries its zero padding rows at the end (jaxcal._core._buckets)
    r = np.asarray(r)[: problem.n_residuals]
    blocks = residual_blocks_numpy(problem, r.reshape(problem.n_samples, problem.measurement.size))
    robust = RobustNoise.build(loss, loss_scale, problem, blocks, r, e)

    def objective_var(dof: float) -> float:  # Σ (f·r)² / dof, bounded-influence under a robust loss
        return rss / dof if robust is None else robust.objective_var(dof)
    lam = np.zeros(p) if prior_inv_std is None else np.asarray(prior_inv_std, np.float64) ** 2
    # a column the data cannot see can come out at round-off size (1e-12 where a difference of two
    # tool points cancels: distance data and θ_1) instead of 0: scaled by its own norm it became a
    # unit column of noise, and its prior term λ/d² ~ 1e28 wrecked the eigenvalue threshold (every σ
    # came out infinite). Such columns are taken as zero, unscaled, like an exactly zero one.
    tiny = d <= 1e-10 * (d.max() if d.size else 0.0)
    if tiny.any():
        keep = np.where(tiny, 0.0, 1.0)
        A, G = A * np.outer(keep, keep), G * np.outer(keep, keep)
    d = np.where(tiny | (d <= 0), 1.0, d)
    ev_g = np.linalg.eigvalsh(G)  # squared singular values of the column-scaled Jacobian
    cond = float(np.sqrt(ev_g[-1] / ev_g[0])) if ev_g[0] > 0 else math.inf
    p_eff = float(p)
    sigma2 = objective_var(max(N - p, 1))
    for _ in range(3):
        H = A / sigma2 + np.diag(lam / (d * d))
        try:
            ev, V = np.linalg.eigh(H)
        except np.linalg.LinAlgError:
            ev, V = np.full(p, 0.0), np.eye(p)
        tol = ev.max() * p * np.finfo(np.float64).eps if ev.size else 0.0
        inv = np.where(ev > tol, 1.0 / np.where(ev > tol, ev, 1.0), np.inf)
        Cs = (V * np.where(np.isfinite(inv), inv, 0.0)) @ V.T
        p_eff = float(np.trace(A / sigma2 @ Cs))
        new = objective_var(max(N - p_eff, 1.0))
        if abs(new - sigma2) <= 1e-6 * sigma2:
            sigma2 = new
            break
        sigma2 = new
    if prior_inv_std is not None and np.any(lam > 0) and ev.size:
        # under a prior the MAP solve inverts the data information plus the prior's: the data
        # Jacobian alone is rank deficient by design (cond = inf), so report the posterior's
        cond = float(np.sqrt(ev[-1] / ev[0])) if ev[0] > 0 else math.inf
    C = Cs / np.outer(d, d)
    std = np.sqrt(np.maximum(np.diag(C), 0.0))
    undetermined = np.abs(V[:, ~np.isfinite(inv)]).max(axis=1) > 1e-6 if (~np.isfinite(inv)).any() else np.zeros(p, bool)
    std = np.where(undetermined, np.inf, std)
    space = problem.space
    noise = math.sqrt(max(sigma2, 0.0) if robust is None else sigma2 / robust.kappa)
    unc = Uncertainty(space.free_names, space.free_units, std, C, noise, p_eff, N)
    if not return_residuals:
        return unc, cond
    return unc, cond, blocks


def outlier_rows(problem, x, k: float = 5.0, *, residuals=None) -> tuple[np.ndarray, np.ndarray, float]:
    """Samples whose residual is more than ``k`` robust standard deviations from the median.

    ``residuals``: the signed residuals at ``x`` (NumPy ``[n, m]``, :func:`signed_residuals`) when
    the caller has them already (``x`` is then not evaluated).

    Returns:
        ``(rows [k_out], errors [k_out] mm, scale mm)``: row indices into ``problem``'s data (0-based),
        each row's largest residual entry, and the robust scale σ̂ = 1.4826·MAD of the residual
        entries (position part for poses).
    """
    r = signed_residuals(problem, x) if residuals is None else residuals
    obs = problem.observed()
    if obs is None:
        med = np.median(r)
        s = robust_scale(r)
        dev = np.abs(r - med)
    else:  # masked readings (a missing marker) are left out of the scale and the scan
        real = np.asarray(r)[obs[:, : np.shape(r)[1]]]
        med = np.median(real)
        s = robust_scale(real)
        dev = np.where(obs[:, : np.shape(r)[1]], np.abs(r - med), 0.0)
    worst = dev.max(axis=1)
    rows = np.flatnonzero(~(worst <= k * s))  # NaN/inf count as outliers
    errors = (r - med)[rows, np.argmax(dev[rows], axis=1)] if rows.size else np.zeros(0)
    return rows, errors, s


@dataclasses.dataclass(frozen=True)
class Diagnostics:
    """Findings of the post-calibration checks (:class:`Checks`).

    Attributes:
        warnings: plain sentences, one per finding (also issued as ``CalibrationWarning``).
        implausible: ``((name, deviation, unit), ...)`` DH deviations beyond the bounds (angles in
            degrees, wrapped).
        condition_number: of the column-scaled Jacobian of the free parameters at the solution;
            with a prior, of that Jacobian (over σ̂) stacked on the prior's rows (the posterior
            information, which is what a MAP fit inverts; the data Jacobian alone may be singular).
        coverage_deg: ``[dof, 2]`` per joint: range moved in the data and range of the limits (°;
            mm for prismatic joints).
        narrow_joints: 1-based joints that moved less than ``Checks.narrow_joint_deg``.
        weak_parameters: free parameters the data barely determine (see :class:`Checks`).
        outliers_before, outliers_after: training rows (0-based) flagged as outliers at the start
            and after the fit; ``outlier_scale_mm``: the robust residual scale after the fit.
        extras: the message of the extras initialisation, if one ran.
        rounds: fits run (more than 1 when a robust-loss scale or the prior's noise σ was
            re-estimated, or the free set grew at the solution).
        reselection: one line per refit after identifiability was judged again at the solution
            (parameters the start could not see and the solution can).
        prior_directions: with a prior, the few combinations of parameters that the prior
            rather than the data determines (posterior variance above ``weak_fraction²`` of the
            prior variance), each named by its largest members in units of the prior σ, e.g.
            ``"0.71·d_2 + 0.71·d_3"``; the weakest first.
    """

    warnings: tuple[str, ...]
    implausible: tuple
    condition_number: float
    coverage_deg: np.ndarray
    narrow_joints: tuple[int, ...]
    weak_parameters: tuple[str, ...]
    outliers_before: tuple[int, ...]
    outliers_after: tuple[int, ...]
    outlier_scale_mm: float
    extras: str | None = None
    rounds: int = 1
    reselection: tuple[str, ...] = ()
    prior_directions: tuple[str, ...] = ()

    @property
    def plausible(self) -> bool:
        return not self.implausible

    def to_dict(self) -> dict:
        return {
            "warnings": list(self.warnings),
            "plausible": self.plausible,
            "implausible": [[n, float(v), u] for n, v, u in self.implausible],
            "condition_number": self.condition_number,
            "coverage_deg": np.asarray(self.coverage_deg).tolist(),
            "narrow_joints": list(self.narrow_joints),
            "weak_parameters": list(self.weak_parameters),
            "outliers_before": list(self.outliers_before),
            "outliers_after": list(self.outliers_after),
            "outlier_scale_mm": self.outlier_scale_mm,
            "extras": self.extras,
            "rounds": self.rounds,
            "reselection": list(self.reselection),
            "prior_directions": list(self.prior_directions),
        }


def robot_deviations(names, units, values):
    """The robot's own angle and length deviations (not the sensor/set-up extras, not entries in
    other units such as compliances) as ``(name, value, unit)`` with angles in wrapped degrees
    (``"deg"``) and lengths in ``"mm"``; non-finite values pass through."""
    for n, u, v in zip(names, units, values):
        if u not in ("rad", "mm") or group_kind(n) == "extra":
            continue
        v = float(v)
        if u == "rad":
            yield n, (float(wrap_angle_deg(math.degrees(v))) if math.isfinite(v) else v), "deg"
        else:
            yield n, v, "mm"


def implausible_deviations(names, units, values, checks: Checks) -> tuple:
    """Robot deviations beyond the plausibility bounds (:func:`robot_deviations`):
    ``((name, value, unit), ...)``; non-finite values always count."""
    return tuple((n, v, u) for n, v, u in robot_deviations(names, units, values)
                 if not math.isfinite(v) or abs(v) > (checks.angle_deg if u == "deg" else checks.length_mm))


def joint_units(robot) -> tuple[str, ...]:
    """``"rad"`` per revolute and ``"mm"`` per prismatic joint (DH robots: all revolute)."""
    return tuple(robot.joint_units()) if hasattr(robot, "joint_units") else ("rad",) * robot.dof


def coverage(robot, q) -> np.ndarray:
    """``[dof, 2]``: how far each joint moved in ``q`` and the width of its limits, in degrees
    (revolute joints) or mm (prismatic joints, :func:`joint_units`)."""
    qn = np.asarray(q, np.float64)
    used = qn.max(axis=0) - qn.min(axis=0) if qn.shape[0] else np.zeros(robot.dof)
    limits = np.asarray(robot.q_max, np.float64) - np.asarray(robot.q_min, np.float64)
    deg = np.asarray([u == "rad" for u in joint_units(robot)])
    return np.stack([np.where(deg, np.rad2deg(used), used), np.where(deg, np.rad2deg(limits), limits)], axis=1)


def narrow_joints(robot, cov: np.ndarray, checks: Checks) -> tuple[int, ...]:
    """1-based joints that moved less than ``checks.narrow_joint_deg`` (revolute) or, prismatic,
    less than the same fraction of a turn of their limit range (the default 30° ↔ 1/12 of it)."""
    out = []
    for j, u in enumerate(joint_units(robot)):
        bound = checks.narrow_joint_deg if u == "rad" else checks.narrow_joint_deg / 360.0 * cov[j, 1]
        if cov[j, 0] < bound:
            out.append(j + 1)
    return tuple(out)


def prior_directions(unc: Uncertainty, prior_std, checks: Checks, *, max_listed: int = 5,
                     max_members: int = 4) -> tuple[int, tuple[str, ...]]:
    """The combinations of parameters that the prior rather than the data determines.

    The data's information about the parameters with a prior is the posterior precision
    ``C⁻¹`` minus the prior precision ``diag(1/s²)``, with the parameters without a prior
    marginalised out (Schur complement). In units of the prior σ (``M = S·D·S``), a direction
    with eigenvalue ``λ`` has posterior variance ``1/(1 + λ)`` of its prior variance, so it is
    prior-determined when ``1/(1 + λ) > weak_fraction²``.

    Returns:
        ``(count, listed)``: how many such directions, and up to ``max_listed`` of them (the
        weakest first) as text naming the ``max_members`` largest members in prior-σ units,
        e.g. ``"0.71·d_2 − 0.71·d_3"``.
    """
    s = np.asarray(prior_std, np.float64)
    cov = np.asarray(unc.covariance, np.float64)
    if not np.all(np.isfinite(unc.std)) or not np.isfinite(s).any():
        return 0, ()
    c = np.flatnonzero(np.isfinite(s))
    n = np.flatnonzero(~np.isfinite(s))
    try:
        P = np.linalg.inv(cov)
    except np.linalg.LinAlgError:  # pragma: no cover - defensive
        return 0, ()
    D = P[np.ix_(c, c)] - np.diag(1.0 / s[c] ** 2)
    if n.size:
        D = D - P[np.ix_(c, n)] @ np.linalg.solve(P[np.ix_(n, n)], P[np.ix_(n, c)])
    M = D * np.outer(s[c], s[c])
    lam, V = np.linalg.eigh((M + M.T) / 2)
    weak = lam < 1.0 / checks.weak_fraction**2 - 1.0
    names = [unc.names[i] for i in c]
    listed = []
    for k in np.flatnonzero(weak)[:max_listed]:
        v = V[:, k] * (1.0 if V[np.argmax(np.abs(V[:, k])), k] > 0 else -1.0)
        top = [i for i in np.argsort(-np.abs(v))[:max_members] if abs(v[i]) >= 0.25 * np.abs(v).max()]
        text = " ".join(f"{'−' if v[i] < 0 else '+'} {abs(v[i]):.2f}·{names[i]}" for i in top)
        listed.append(text[2:] if text.startswith("+ ") else "−" + text[2:])
    return int(weak.sum()), tuple(listed)


def weak_parameters(unc: Uncertainty, prior_std, checks: Checks) -> tuple[str, ...]:
    """Free parameters the data barely determine: posterior σ above ``weak_fraction`` of the prior
    σ, or (no prior) above a third of the plausibility bound; undetermined ones always."""
    out = []
    prior_std = np.full(len(unc.names), np.inf) if prior_std is None else np.asarray(prior_std, np.float64)
    for n, u, s, s0 in zip(unc.names, unc.units, unc.std, prior_std):
        if not math.isfinite(s):
            out.append(n)
        elif math.isfinite(s0):
            if s > checks.weak_fraction * s0:
                out.append(n)
        elif u in ("rad", "mm") and group_kind(n) != "extra":
            bound = math.radians(checks.angle_deg) if u == "rad" else checks.length_mm
            if s > bound / 3:
                out.append(n)
    return tuple(out)
