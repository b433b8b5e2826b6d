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
import functools
import math
import warnings

import jax.numpy as jnp
import numpy as np

from .._core._buckets import LeanJit
from .._core._json import from_json_number
from .._core._params import group_kind
from .._core._precision import to_device
from .._core._trig import wrap_angle_deg
from .._core._xla import jit
from ._objective import robust_factor, robust_scale
from ._problem import observed_entries, residual_blocks_numpy, signed_residuals, value_and_jacfwd
from ._verdicts import PRIOR_SHARE, Verdicts

__all__ = ["Checks", "Uncertainty", "Diagnostics", "parameter_uncertainty", "OutlierScan", "scan_outliers",
           "outlier_threshold", "scan_rows", "flagged_rows", "file_rate", "variance_component",
           "component_entries",
           "prior_directions", "fit_findings", "likely_cause", "given_noise_std", "result_findings", "error_dims",
           "stated_noise_warning"]


@dataclasses.dataclass(frozen=True)
class Checks:
    """Thresholds of the post-calibration checks (all configurable).

    Attributes:
        angle_deg, length_mm: a DH deviation beyond these (wrapped angles, degrees; mm) is
            implausible for a real arm (default 5°, 20 mm).
        condition_number: warn above this condition number of the column-scaled Jacobian of the
            free parameters at the solution (default 1e4).
        narrow_joint_deg: warn when a joint moved less than this in the data (default 30°).
        outlier_rate: the outlier scan's false-alarm probability per data file (default 0.01):
            on clean Gaussian data, the chance that anything in a file is flagged. Each file's (each
            block's) rows are judged in their own robust σ̂; the threshold on a row's residual norm
            follows from this rate, the file's row count and the row's entries
            (:func:`outlier_threshold`: 4.4 σ̂ for 800 one-entry rows, 5.1 σ̂ for 800 positions).
            A reading of several points (a camera image's corners, a marker set's markers) is
            judged per point, the rate split between the file's points and its rows as a whole
            (:func:`scan_rows`: 5.1 σ̂ on a corner's residual for 30 images of 54 corners).
        outlier_k: a fixed threshold instead, in robust σ̂ on a row's (a point's) residual norm (its
            entries' root sum of squares; one entry: its absolute value); ``None`` (default): from
            ``outlier_rate``. Before issue 53 this was always 5 on a row's largest entry, whose
            false-alarm rate grows with the row count.
        prior_share: with a prior, a free parameter is held by the prior rather than determined by
            the data when the prior gives more than this share of its posterior variance (default
            0.5: the prior tells more about it than the data; for one parameter alone, a posterior
            σ above 0.71 of its prior σ). See :func:`~jaxcal._fit._verdicts.parameter_verdicts`.

    Checks of the result as a whole (:func:`fit_findings`; readings in mm):

    Attributes:
        residual_fraction: the residual σ̂ above this fraction of the robot's reach
            (``robot.reach_mm()``) is no calibration: the model does not describe the data
            (default 0.01: 32 mm for the HSR-JR680, whose residuals after a calibration are
            ~0.5 mm).
        noise_factor: σ̂ above this multiple of the sensor's given noise σ (``Prior.noise_std``,
            or a data file's ``# noise_std_mm:`` line) fails (default 10).
        noise_warn_factor: σ̂ at or above this multiple of the noise a data file states (its
            ``# noise_std_mm:`` / ``# noise_std_px:`` line) is warned about, naming the file
            (:func:`stated_noise_warning`; default 2): data of another set-up, or a noise line
            that understates the noise.
        extra_fraction, extra_angle_deg: a sensor/set-up extra started from the data in closed
            form (anchor, cable offset, tool, sensor frame, …) that the fit moved further than
            this fraction of the reach (mm) or this angle (°) fails (default 0.25, 10°: a tool
            point started on the flange axis may move ~100 mm); one (mm) further than 10 reaches
            from its nominal or guessed value fails whatever its start.
        worse_rtol: the fit fails when its RMS training residual ends above ``(1 + worse_rtol)``
            times that of its start (default 0.01: a robust loss started from the least-squares
            extras of the nominal robot may end 0.2 % above it with only the extras free).
    """

    angle_deg: float = 5.0
    length_mm: float = 20.0
    condition_number: float = 1e4
    narrow_joint_deg: float = 30.0
    outlier_rate: float = 0.01
    outlier_k: float | None = None
    prior_share: float = PRIOR_SHARE
    residual_fraction: float = 0.01
    noise_factor: float = 10.0
    noise_warn_factor: float = 2.0
    extra_fraction: float = 0.25
    extra_angle_deg: float = 10.0
    worse_rtol: float = 0.01

    def __post_init__(self):
        if not (0.0 < self.outlier_rate < 1.0):
            raise ValueError(f"outlier_rate must be a probability in (0, 1), got {self.outlier_rate!r}")
        if self.outlier_k is not None and not (self.outlier_k > 0):
            raise ValueError(f"outlier_k must be a positive number of robust σ (or None), got {self.outlier_k!r}")


@dataclasses.dataclass(frozen=True)
class Uncertainty:
    """Posterior standard deviations of the free parameters.

    Laplace (Gauss–Markov) approximation at the solution: ``Cov = (JᵀWJ/σ̂² + Λ)⁻¹`` with ``J`` the
    Jacobian of the data residuals, ``W`` the robust-loss weights (identity for least squares),
    ``Λ = diag(1/s_j²)`` the prior precision (0 without a prior) and σ̂ the noise estimated from
    the residuals; without a prior this is ``σ̂²(JᵀJ)⁻¹``, the Cramér–Rao bound.

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
        component_std: ``{component: σ̂}`` in the component's own unit (a pose's ``"position"``
            mm and ``"orientation"`` rad: :attr:`~jaxcal.MeasurementModel.components`), each by
            variance components (:func:`variance_component`); ``noise_std`` is then the first
            one's (the unit the sample errors are in). ``None`` for a model with one σ.
        component_units: ``{component: unit}`` of ``component_std``.
    """

    names: tuple[str, ...]
    units: tuple[str, ...]
    std: np.ndarray
    covariance: np.ndarray
    noise_std: float
    effective_parameters: float
    n_residuals: int
    component_std: dict | None = None
    component_units: dict | None = None

    def component_lines(self) -> str:
        """``"position 0.5 mm, orientation 0.02°"`` (angles in degrees), or ``""``."""
        if not self.component_std:
            return ""
        return ", ".join(f"{c} {math.degrees(v):.4g}°" if self.component_units[c] == "rad" else
                         f"{c} {v:.4g} {self.component_units[c]}" for c, v in self.component_std.items())

    def given_std(self, given) -> np.ndarray:
        """``[p]`` σ of each free parameter with the free parameters named in ``given`` known (held
        at their values; 0 for those): the conditional covariance ``C_aa − C_ag C_gg⁺ C_ga`` of the
        Gaussian posterior (rad, mm; ``inf`` where :attr:`std` is). With ``given`` the robot's
        parameters, a sensor extra's σ relative to the calibrated robot: what the data determine
        of it, without the part it shares with robot parameters it trades with (a plane's offset
        and a base height ``d_1``: the prior's σ of ``d_1`` carried over to the plane)."""
        g = np.asarray([n in set(given) for n in self.names])
        C = np.asarray(self.covariance, np.float64)
        out = np.zeros(len(self.names))
        a = ~g
        if g.any():
            C_ag = C[np.ix_(a, g)]
            cond = C[np.ix_(a, a)] - C_ag @ np.linalg.pinv(C[np.ix_(g, g)], hermitian=True) @ C_ag.T
        else:
            cond = C
        out[a] = np.sqrt(np.clip(np.diag(cond), 0.0, None))
        return np.where(np.isfinite(self.std), out, np.inf)

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
        } | ({} if not self.component_std else {"noise_std_components": component_entries(
            self.component_std, self.component_units)})

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
        comps = {k.rpartition("_")[0]: (num(v), k.rpartition("_")[2])
                 for k, v in (d.get("noise_std_components") or {}).items() if not k.endswith("_deg")}
        return cls(tuple(names), tuple(units), np.asarray([num(d["std"][n]) for n in names], np.float64), cov,
                   num(d.get("noise_std_mm")), num(d.get("effective_parameters")), int(d.get("n_residuals", 0)),
                   {c: v for c, (v, _) in comps.items()} or None, {c: u for c, (_, u) in comps.items()} or None)


def component_entries(std: dict, units: dict) -> dict:
    """``{component_unit: σ̂}`` of :attr:`Uncertainty.component_std` as the JSON writes it
    (``position_mm``, ``orientation_rad`` and, for angles, also ``orientation_deg``)."""
    out = {}
    for c, v in std.items():
        out[f"{c}_{units[c]}"] = float(v)
        if units[c] == "rad":
            out[f"{c}_deg"] = math.degrees(float(v))
    return out


def variance_component(rss: float, n: float, covariance, gram) -> tuple[float, float]:
    """``(σ̂_b, r_b)`` of one block ``b`` of residual entries by variance components (Förstner 1979;
    Koch 1999, §3.6): the redundancy ``r_b = n_b − tr(C·G_b)`` (the sum of ``1 − h_ii`` over its
    ``n`` entries; ``C`` the whitened posterior covariance ``(Σ_b G_b + Λ)⁻¹``, ``G_b`` the block's
    ``JᵀJ``, both in one column scaling) and ``σ̂_b = sqrt(RSS_b / r_b)`` (``nan`` where ``r_b ≤ 0``),
    unbiased for a linear model. :func:`jaxcal.calibrate_blocks` estimates a σ per data block this
    way, :func:`parameter_uncertainty` one per residual component (a pose's position and
    orientation)."""
    red = float(n - np.sum(np.asarray(covariance) * np.asarray(gram)))
    return (math.sqrt(rss / red) if red > 0 else float("nan")), red


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
    return gram_from_jacobian(problem, r, J, loss, loss_scale)


def gram_from_jacobian(problem, r, J, loss: str, loss_scale):
    """:func:`gram_at` from the data residuals ``r`` ``[N]`` and their Jacobian ``J`` ``[N, p]``
    when the caller holds them (a least-squares solve keeps its final Jacobian)."""
    d = jnp.sqrt(jnp.sum(J * J, axis=0))
    Js = J / jnp.where(d > 0, d, 1.0)
    G = Js.T @ Js
    blocks = problem.to_blocks(r)  # the residual returned is [n·m] (zeros where the model has no entry)
    if loss == "linear":
        return d, G, G, jnp.sum(r * r), blocks.reshape(-1), None, _component_grams(problem, Js, None)
    e = problem.measurement.sample_error(blocks)
    f = robust_factor(loss, e * e, loss_scale)
    rows = problem.entry_rows()
    w = jnp.repeat(f * f, problem.measurement.size) if rows is None else (f * f)[rows]
    return (d, (Js * w[:, None]).T @ Js, G, jnp.sum(w * r * r), blocks.reshape(-1), e,
            _component_grams(problem, Js, w))


def _component_grams(problem, Js, w):
    """``[C, p, p]`` each residual component's share of ``JsᵀWJs`` (:attr:`MeasurementModel.components`:
    a pose's position and orientation rows; ``W`` the robust weights ``w`` ``[N]``, or 1), or
    ``None`` for a model with one σ (its solve's program is unchanged)."""
    comps = problem.measurement.components
    if len(comps) < 2:
        return None
    Jb = problem.to_blocks(Js if w is None else Js * jnp.sqrt(w)[:, None])  # [n, m, p]
    return jnp.stack([jnp.einsum("imp,imq->pq", Jb[:, a:b], Jb[:, a:b]) for _, _, a, b in comps])


_gram = jit(gram_at, static_argnames="loss")


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
    fixed = getattr(measurement, "fixed_rows", None)
    if fixed:  # a model whose rows have fixed meanings (combined blocks): whole copies of its rows
        return _consistency_in_copies(measurement, loss, observed, int(fixed), max(1, -(-n // int(fixed))))
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


def _consistency_in_copies(measurement, loss: str, observed, rows: int, copies: int) -> Consistency:
    """:func:`robust_consistency` for a model whose ``sample_error`` reads ``rows`` rows of fixed
    meaning (:class:`~jaxcal._sensors._blocks.Combined`: each row its block's): ``copies`` draws of
    all of them, with the data's mask."""
    m = int(measurement.size)
    real = np.ones((rows, m), bool) if observed is None else np.asarray(observed, bool).reshape(rows, m)
    rng = np.random.default_rng(0)
    e2, z2 = [], []
    for _ in range(copies):
        z = np.zeros((rows, m))
        z[real] = rng.standard_normal(int(real.sum()))
        e2.append(np.asarray(_sample_errors(measurement, to_device(z)), np.float64) ** 2)
        z2.append(np.sum(z * z, axis=1))
    return Consistency(loss, np.concatenate(e2), np.concatenate(z2))


def error_dims(measurement, observed=None) -> int:
    """``E[e²]/σ²`` of a clean sample's error ``e`` (:meth:`~jaxcal.MeasurementModel.sample_error`,
    what a robust loss acts on) under noise σ on every reading, rounded: 1 for a draw-wire length,
    3 for a position's norm (and an RMS over markers of 3-D errors), 2 for image corners. From
    :func:`robust_consistency` (``observed``: the data's pattern of masked readings).

    A robust loss's scale is ``c = k·√(error_dims)·σ̂`` (:func:`jaxcal.calibrate`): its constant
    ``k`` (Huber's 1.345 for 95 % efficiency) is in units of a clean sample's RMS error, as for
    one reading. Before, ``c = k·σ̂`` on a position's norm capped 61 % of clean tracker rows, not
    the 18 % of one reading (13 % now); on tracker data whose residuals are mostly unmodelled
    error it cost the defaults up to 5 % of held-out RMSE against least squares
    (``benchmarks/results/defaults_vs_alternatives_cpu.md``)."""
    return max(1, int(round(robust_consistency(measurement, "linear", observed).mean_sq_error)))


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

    def __init__(self, resid_var: float, kappa: float, n_residuals: int, cap: float = math.inf):
        self.resid_var, self.kappa, self.n_residuals = resid_var, kappa, n_residuals
        #: the cap ``k`` (units of σ) on a block's error
        self.cap = cap

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
        # the cap in units of σ on the sample error: the loss's own threshold, which is its constant
        # times a clean block's RMS error (error_dims), so that it caps the same share of clean
        # blocks for every model (18 % at 1.345 for one reading, 13 % at 1.345·√3 for a
        # position's norm; at 1.345 itself, 61 % of positions and σ̂ ~1.4× as variable)
        cap = k
        N = problem.n_observed_residuals
        return cls(_capped_fixed_point(e2, sq, cap, N * cons.capped(cap)), cons(k), N, cap)

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
                          return_residuals: bool = False, gram=None, prior_information=None):
    """Posterior covariance of the free parameters at ``x`` ``[p]`` for ``problem`` (training data).

    Args:
        prior_inv_std: ``[p]`` ``1/s_j`` of the prior (0 = none).
        prior_information: ``[p, p]`` the prior's information matrix (inverse covariance, of a
            prior with a full covariance: :meth:`jaxcal.Prior.information`); replaces
            ``diag(1/s_j²)``.
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
    d, A, G, rss, r, e, comp_grams = gram
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
    prior_h = (np.diag(lam / (d * d)) if prior_information is None
               else np.asarray(prior_information, np.float64) / np.outer(d, d))

    def posterior(sigma2):  # (eigenvalues, eigenvectors, their inverses, column-scaled Cov, p_eff)
        H = A / sigma2 + prior_h
        try:
            ev, V = np.linalg.eigh(H)
        except np.linalg.LinAlgError:
            ev, V = np.full(p, 0.0), np.eye(p)
        tol = ev.max() * p * np.finfo(np.float64).eps if ev.size else 0.0
        inv = np.where(ev > tol, 1.0 / np.where(ev > tol, ev, 1.0), np.inf)
        Cs = (V * np.where(np.isfinite(inv), inv, 0.0)) @ V.T
        return ev, V, inv, Cs, float(np.trace(A / sigma2 @ Cs))

    sigma2 = objective_var(max(N - p, 1))
    for _ in range(3):
        ev, V, inv, Cs, p_eff = posterior(sigma2)
        used, new = sigma2, objective_var(max(N - p_eff, 1.0))
        if abs(new - sigma2) <= 1e-6 * sigma2:
            sigma2 = new
            break
        sigma2 = new
    comp_std = comp_units = None
    if comp_grams is not None:
        grams = np.asarray(comp_grams, np.float64)
        if tiny.any():
            grams = grams * np.outer(keep, keep)
        sig = _component_sigmas(problem, r, grams, Cs / used, robust)
        if np.all(np.isfinite(sig)) and np.all(sig > 0):
            m = problem.measurement
            scales = m.component_scales()
            comp_std = {c[0]: float(v / w) for c, v, w in zip(m.components, sig, scales)}
            comp_units = {c[0]: c[1] for c in m.components}
            # the covariance at the largest whitened σ̂: the components' common σ at the weights'
            # fixed point, conservative where a weight is held at the end of its range (exact
            # orientation readings); σ̂ itself is the first component's (the sample errors' unit)
            sigma2 = float(np.max(sig)) ** 2 * (1.0 if robust is None else robust.kappa)
            ev, V, inv, Cs, p_eff = posterior(sigma2)
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
    if comp_std is not None:
        noise = float(sig[0])
    unc = Uncertainty(space.free_names, space.free_units, std, C, noise, p_eff, N, comp_std, comp_units)
    if not return_residuals:
        return unc, cond
    return unc, cond, blocks


def _component_sigmas(problem, r, grams, hat, robust) -> np.ndarray:
    """``[C]`` σ̂ of each residual component (:attr:`~jaxcal.MeasurementModel.components`) of the
    whitened residual ``r`` ``[n·m]``: :func:`variance_component` with the component's share
    ``grams[c]`` of the (robust-weighted) information and ``hat`` the covariance it is weighed
    by. Under a robust loss the component's residual sum is its bounded-influence counterpart
    (:class:`RobustNoise`'s capped fixed point on the component's own norms, at the same cap)."""
    m = problem.measurement
    n = problem.n_samples
    rr = np.asarray(r, np.float64)[: n * m.size].reshape(n, m.size)
    out = []
    for (_, _, a, b), G in zip(m.components, grams):
        blk = rr[:, a:b]
        if robust is None:
            rss = float(np.sum(blk * blk))
        else:
            e2 = np.sum(blk * blk, axis=1)
            rss = blk.size * _capped_fixed_point(e2, e2, robust.cap, blk.size * _norm_consistency(b - a).capped(
                robust.cap))
        out.append(variance_component(rss, blk.size, hat, G)[0])
    return np.asarray(out)


@functools.lru_cache(maxsize=8)
def _norm_consistency(dims: int) -> Consistency:
    """:class:`Consistency` of the norm of ``dims`` unit-normal entries (NumPy draws, fixed seed:
    no program), for a residual component's capped sum."""
    z = np.random.default_rng(0).standard_normal((40_000, dims))
    e2 = np.sum(z * z, axis=1)
    return Consistency("huber", e2, e2)


#: efficiency of σ̂ = 1.4826·MAD against the sample standard deviation for Gaussian data
#: (Rousseeuw & Croux 1993, JASA 88(424), Table 1): σ̂ from N entries scatters like a sample SD
#: of ``0.3675·N`` degrees of freedom (``var σ̂ ≈ σ²/(2·0.3675·N)``), which :func:`outlier_threshold`
#: accounts for.
MAD_EFFICIENCY = 0.3675


def outlier_threshold(n_rows: int, entries=1, n_entries: int | None = None, rate: float = 0.01):
    """The outlier threshold ``k`` (in robust σ̂) on a row's residual norm for a false-alarm
    probability ``rate`` over ``n_rows`` clean rows.

    On clean Gaussian data a row's squared residual norm over its ``m`` entries, in units of the
    noise σ, is χ²_m. Šidák's correction gives each row the tail ``p = 1 − (1 − rate)^(1/n_rows)``,
    so that the chance that any of ``n_rows`` independent clean rows exceeds the threshold is
    ``rate``. σ is not known but estimated by σ̂ = 1.4826·MAD of the ``n_entries`` residual
    entries, which scatters like a sample standard deviation of ``ν = 0.3675·n_entries`` degrees
    of freedom (:data:`MAD_EFFICIENCY`): the row statistic ``‖r‖²/(m σ̂²)`` is then about F(m, ν),
    and ``k = √(m · F⁻¹(1 − p; m, ν))`` (χ²_m's quantile as ν → ∞). With rate 0.01: 800 rows of
    one entry (a length, a plane contact), k = 4.4; 800 positions (m = 3), 5.1; 40 rows of one
    entry, 4.8 (3.7 were σ known).

    Measured on replicate Gaussian draws (``tests/fit/test_outlier_threshold.py``): the false-alarm
    rate is ``rate`` or up to ~15 % below it from a few hundred residual entries on (0.87–1.03 % at
    200 and 800 one-entry rows for 1 %; 4.4 % for 5 %; χ² alone, σ taken as known: 2.2 % and
    7.9 %); with fewer, the F tail over-allows for σ̂'s scatter and the rate is lower (0.7 % at 40
    entries, 0.45 % at 20). Fitted residuals are slightly smaller than the
    noise (leverage), which makes the rate after a fit a little lower still.

    A reading of several points is judged per point with ``n_rows`` the file's points and ``m`` a
    point's entries (:func:`scan_rows`).

    Args:
        n_rows: rows (points) the rate is spread over (a file's rows; ≥ 1).
        entries: ``m``, real residual entries per row (an int or an ``[n]`` array: rows with masked
            readings have fewer).
        n_entries: residual entries σ̂ was estimated from (default ``n_rows·m``).
        rate: false-alarm probability over the ``n_rows`` rows, in ``(0, 1)``.

    Returns:
        ``k`` (a float, or an ``[n]`` array for an array ``entries``; ``inf`` where ``m = 0``).
    """
    from scipy import special  # scipy.stats's F and χ² tails, without importing scipy.stats (~0.3 s)

    m = np.asarray(entries, np.float64)
    n_rows = max(int(n_rows), 1)
    p = file_rate(rate, 1, n_rows)  # each row's tail, 1 − (1 − rate)^(1/n)
    n_entries = int(n_rows * np.max(m)) if n_entries is None else int(n_entries)
    nu = MAD_EFFICIENCY * max(n_entries, 1)
    safe = np.where(m > 0, m, 1.0)
    # F⁻¹(1 − p; m, ν) and χ²_m's upper quantile: what scipy.stats.f.isf / chi2.isf evaluate
    k = np.sqrt(safe * special.fdtri(safe, nu, 1.0 - p)) if nu < 1e7 else np.sqrt(special.chdtri(safe, p))
    k = np.where(m > 0, k, np.inf)
    return float(k) if k.ndim == 0 else k


@dataclasses.dataclass(frozen=True)
class OutlierScan:
    """The outlier scan of one data file's (one block's) rows in their own robust σ̂
    (:func:`scan_rows`). A reading of several points (a camera image's corners, a marker set's
    markers) is judged point by point; a flagged row is then named with its flagged points.

    Attributes:
        rows: the flagged rows, 0-based positions among the rows scanned (each once, ascending).
        norms: each flagged row's residual norm (:attr:`unit`; a one-entry row: its absolute
            residual from the median); for points: its largest flagged point's.
        scale: σ̂ = 1.4826·MAD of the scanned rows' real residual entries (:attr:`unit`).
        k: the threshold in σ̂ on a full point's residual norm (a row's where a row is one point;
            :func:`outlier_threshold`; points or rows with masked readings have their own, lower
            one).
        entries: real residual entries of a full point (1 for a length, 3 for a position or a
            pose's position part or a marker, 2 for a camera image's corner).
        rate: the false-alarm probability per file the threshold was chosen for; ``None`` when a
            fixed ``k`` was given (:attr:`Checks.outlier_k`).
        n_rows: rows scanned; ``n_file``: rows of the file the rate is spread over (a file split
            into training and test rows: both parts' scans together keep ``rate``).
        unit: the unit of the residuals (``"mm"``; ``"px"`` for a camera).
        block: the block's name in a combined fit (:func:`jaxcal.calibrate_blocks`), else ``None``.
        offset: the position of the scanned rows' first row among the problem's rows (a combined
            fit's stacked rows); ``offset + rows`` index the problem's data.
        points: per flagged row, its flagged points (0-based, ascending); ``()`` where a row is
            one point. point_norms: their residual norms (:attr:`unit`).
        point_word: what a point is called (``"corner"``, ``"marker"``); ``""`` where a row is one point.
        points_per_row: real (not masked) points per scanned row on average: the rate is spread
            over ``n_file·points_per_row`` points.
        k_row: for points, the threshold in σ̂ on a full row's residual norm (all its points
            together: an image shifted as a whole by a little in every corner); the rate is split
            in halves between the points and the rows. ``None`` where a row is one point or ``k``
            was fixed.
    """

    rows: tuple[int, ...]
    norms: tuple[float, ...]
    scale: float
    k: float
    entries: int
    rate: float | None
    n_rows: int
    n_file: int
    unit: str = "mm"
    block: str | None = None
    offset: int = 0
    points: tuple[tuple[int, ...], ...] = ()
    point_norms: tuple[tuple[float, ...], ...] = ()
    point_word: str = ""
    points_per_row: float = 1.0
    k_row: float | None = None

    @property
    def threshold(self) -> float:
        """The threshold on a full point's (row's) residual norm in :attr:`unit` (``k·σ̂``)."""
        return self.k * self.scale

    def __iter__(self):
        """``rows, scale = scan``: what :func:`jaxcal.residual_outliers` returned before issue 53."""
        return iter((self.rows, self.scale))

    def criterion(self) -> str:
        """How the rows were judged, e.g. ``"threshold 0.215 mm = 4.4 σ̂ (σ̂ = 0.049 mm, these rows'
        robust σ; what a file of 800 clean rows crosses with a 1 % chance)"``; for points ``"threshold
        2.7 px = 5.4 σ̂ on a corner's residual (σ̂ = 0.5 px, these corners' robust σ; what a file of 30
        clean rows, 1 540 corners, crosses with a 1 % chance)"``."""
        u, pw = self.unit, self.point_word
        size = (f"{self.n_file} clean rows" if not pw else
                f"{self.n_file} clean rows, {round(self.n_file * self.points_per_row)} {pw}s,")
        why = (f"what a file of {size} crosses with a {_percent(self.rate)} chance"
               if self.rate is not None else "a fixed threshold")
        on = f" on a {pw}'s residual" if pw else ""
        if pw and self.k_row is not None:
            on += f" or {self.k_row:.3g} σ̂ = {self.k_row * self.scale:.3g} {u} on a row's (all its {pw}s together)"
        return (f"threshold {self.threshold:.3g} {u} = {self.k:.2g} σ̂{on} (σ̂ = {self.scale:.3g} {u}, "
                f"these {pw + 's' if pw else 'rows'}' robust σ; {why})")

    def message(self, where: str, rows=None, action: str = "") -> str:
        """One sentence naming the flagged rows, for every output (``jaxcal calibrate``, its test
        rows, ``--combine``, ``jaxcal evaluate``, the library's warning), e.g. ``"plane.csv: 1
        outlier row at data row 448: residual 0.52 mm, above the threshold 0.215 mm = 4.4 σ̂ (σ̂ =
        0.049 mm, these rows' robust σ; what a file of 800 clean rows crosses with a 1 % chance);
        nothing was dropped — …"``; for points (1-based) ``"camera.csv: 1 outlier corner at data
        row 12 (corner 31: 5.1 px), above the threshold 2.7 px = 5.4 σ̂ on a corner's residual
        (…)"``.

        Args:
            where: what the rows are, e.g. ``"plane.csv"`` or ``"cable.csv, test rows"``.
            rows: how to name each flagged row (default: ``"index i"`` into the rows scanned, as a
                Python user holds them); the CLI passes the 1-based data rows of the file.
            action: what to do about them (flag names), after ``"nothing was dropped — "``.
        """
        n = len(self.rows)
        names = [f"{i}" for i in self.rows] if rows is None else [f"{r}" for r in rows]
        tail = f"above the {self.criterion()}; nothing was dropped" + (f" — {action}" if action else "")
        if not self.point_word:
            shown = ", ".join(names[:12]) + (" …" if n > 12 else "")
            what = ("index " if n == 1 else "indices ") if rows is None else ("data row " if n == 1 else "data rows ")
            norms = ", ".join(f"{v:.3g}" for v in self.norms[:12]) + (" …" if n > 12 else "")
            return f"{where}: {n} outlier row{'s' if n > 1 else ''} at {what}{shown}: residual {norms} {self.unit}, {tail}"
        pw, u = self.point_word, self.unit
        one = "index " if rows is None else "data row "
        parts = []
        for name, pts, pn, rn in zip(names[:12], self.points, self.point_norms, self.norms):
            if not pts:  # the row as a whole, no one point alone
                parts.append(f"{one}{name} (all its {pw}s together: {rn:.3g} {u})")
            elif len(pts) == 1:
                parts.append(f"{one}{name} ({pw} {pts[0] + 1}: {pn[0]:.3g} {u})")
            else:
                parts.append(f"{one}{name} ({pw}s {_ranges([p + 1 for p in pts])}: up to {max(pn):.3g} {u})")
        n_pts = sum(len(p) for p in self.points)
        what = f"{n_pts} outlier {pw}{'s' if n_pts != 1 else ''}"
        whole = sum(not p for p in self.points)
        if whole:
            what = (f"{what} and " if n_pts else "") + f"{whole} outlier row{'s' if whole > 1 else ''}"
        in_rows = f" in {n} rows" if n > 1 and n_pts else ""
        return (f"{where}: {what}{in_rows} at {', '.join(parts)}"
                f"{' …' if n > 12 else ''}, {tail}")

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


def _ranges(values) -> str:
    """``[1, 2, 3, 7]`` → ``"1–3, 7"`` (ascending integers)."""
    out, i = [], 0
    while i < len(values):
        j = i
        while j + 1 < len(values) and values[j + 1] == values[j] + 1:
            j += 1
        out.append(f"{values[i]}" if j == i else f"{values[i]}–{values[j]}")
        i = j + 1
    return ", ".join(out)


def _percent(rate: float) -> str:
    return f"{100 * rate:.3g} %"


def file_rate(rate: float, n_part: int, n_file: int) -> float:
    """The false-alarm probability for ``n_part`` of a file's ``n_file`` rows that keeps each row's
    tail (:func:`outlier_threshold`) at that of ``rate`` over the whole file: ``1 − (1 −
    rate)^(n_part/n_file)``. The training and the test rows of one file scanned at these rates
    together give ``rate`` for the file."""
    return -math.expm1(math.log1p(-float(rate)) * n_part / max(n_file, 1))


def scan_rows(r, observed=None, *, rate: float = 0.01, k: float | None = None, n_file: int | None = None,
              unit: str = "mm", block: str | None = None, offset: int = 0, point_entries: int | None = None,
              point_word: str = "point") -> OutlierScan:
    """The outlier scan of one file's rows in their own robust σ̂ (NumPy, no JAX), point by point.

    A row of ``m`` entries is ``m/w`` points of ``w = point_entries`` entries each (a camera
    image's corners: ``w = 2``; a marker set's markers: 3; default ``w = m``: the row is one
    point). Each point's residual entries, less the median entry, over σ̂ = 1.4826·MAD of the real
    entries, give the point's norm ``‖r_ij − med‖/σ̂``; a point is flagged when that exceeds ``k``
    (given), or :func:`outlier_threshold` of ``rate`` over the file's points (Šidák over the real
    points: the scanned rows' real points scaled to ``n_file`` rows) with the point's own count of
    real entries. Masked entries (``observed`` false: a corner not detected, a marker missing)
    count for nothing and a wholly masked point is never flagged; NaN or infinite real entries
    are flagged. A row is flagged when any of its points is; a row whose points are all off (an
    image shifted as a whole) is flagged with all of them. With several points per row the rate is
    split (Šidák) between the points and the rows as a whole (each row's norm over all its real
    entries against :func:`outlier_threshold` over the file's rows), so that an image a little off
    in every corner (a wrong joint reading) is still named. Measured on NumPy replicates of 30
    images × 54 corners × 2 px, 10 % masked (``tests/fit/test_outlier_threshold.py``): 0.65–0.82 %
    false alarms for 1 %, 3.5–4.2 % for 5 % (the shared σ̂ makes the crossings dependent); one 10σ
    corner coordinate named in 2 000 of 2 000 draws (judged by the image's χ²₁₀₈: 1 917).

    Args:
        r: ``[n, m]`` the rows' residual entries in one unit (a pose's position part).
        observed: ``[n, m]`` bool, the real entries (masked readings left out), or ``None``: all.
        rate, k, n_file: the false-alarm probability per file, a fixed threshold instead, the file's
            rows (default ``n``).
        unit, block, offset: carried to the :class:`OutlierScan`.
        point_entries, point_word: entries per point and its name (``"corner"``) for a reading of
            several points (:attr:`~jaxcal._sensors._measurement.MeasurementModel.point_entries`);
            ``None``: a row is one point.
    """
    r = np.asarray(r, np.float64).reshape(np.shape(r)[0], -1)
    obs = np.ones(r.shape, bool) if observed is None else np.asarray(observed, bool)[:, : r.shape[1]]
    n, m = r.shape
    w = m if point_entries is None or int(point_entries) >= m or m == 0 else int(point_entries)
    if w and m % w:
        raise ValueError(f"rows of {m} residual entries are not points of {w} entries each")
    P = m // w if w else 1
    real = r[obs]
    med = float(np.median(real[np.isfinite(real)])) if np.isfinite(real).any() else 0.0
    s = robust_scale(real)
    dev = np.where(obs, r - med, 0.0).reshape(n, P, max(w, 1))
    norm = np.sqrt(np.sum(dev**2, axis=2))  # [n, P]
    per_pt = obs.reshape(n, P, max(w, 1)).sum(axis=2)
    n_file = n if n_file is None else int(n_file)
    real_pts = int(np.count_nonzero(per_pt))
    per_row = real_pts / n if n else 1.0
    many = P > 1
    row_entries = obs.sum(axis=1)
    row_norm = np.sqrt(np.sum(norm**2, axis=1))
    k_row = None
    if k is None:
        # several points: half the rate (Šidák) to the points, half to the rows as a whole
        part = file_rate(rate, 1, 2) if many else float(rate)
        n_tests = max(1, round(n_file * per_row))  # the file's real points (rows where a row is one point)
        kk = outlier_threshold(n_tests, per_pt, int(real.size), part)
        k_full = outlier_threshold(n_tests, w, int(real.size), part)
        row_hit = np.zeros(n, bool)
        if many:
            real_rows = int(np.count_nonzero(row_entries))
            n_row_tests = max(1, round(n_file * real_rows / n)) if n else 1
            kr = outlier_threshold(n_row_tests, row_entries, int(real.size), part)
            k_row = float(outlier_threshold(n_row_tests, m, int(real.size), part))
            row_hit = ~(row_norm <= kr * s) & (row_entries > 0)
    else:
        kk, k_full = np.where(per_pt > 0, float(k), np.inf), float(k)
        row_hit = np.zeros(n, bool)
    hit = ~(norm <= kk * s) & (per_pt > 0)  # NaN/inf count as outliers
    rows = np.flatnonzero(hit.any(axis=1) | row_hit)
    pts = tuple(tuple(int(j) for j in np.flatnonzero(hit[i])) for i in rows)
    pnorms = tuple(tuple(float(norm[i, j]) for j in p) for i, p in zip(rows, pts))
    norms = tuple(max(v) if v else float(row_norm[i]) for i, v in zip(rows, pnorms))
    return OutlierScan(tuple(int(i) for i in rows), norms, float(s), float(k_full), w,
                       None if k is not None else float(rate), n, n_file, unit, block, offset,
                       pts if many else (), pnorms if many else (), point_word if many else "",
                       float(per_row) if many else 1.0, k_row)


def scan_outliers(problem, x, checks: Checks | None = None, *, residuals=None,
                  n_file: int | None = None) -> tuple[OutlierScan, ...]:
    """The outlier scans of ``problem``'s rows at ``x`` (:func:`scan_rows`): one for a single
    sensor's rows; for a combined model (:func:`jaxcal.calibrate_blocks`) one per data block,
    each block's rows in its own unit and its own robust σ̂ (the relations block is not scanned).
    A reading of several points (:attr:`~jaxcal._sensors._measurement.MeasurementModel.point_entries`:
    a camera image, a marker set) is judged point by point.
    The rate or fixed threshold: ``checks`` (:attr:`Checks.outlier_rate`, :attr:`Checks.outlier_k`),
    each block's rate over its own rows (points).

    ``residuals``: the signed residuals at ``x`` (NumPy ``[n, m]``, :func:`signed_residuals`) when
    the caller has them already (``x`` is then not evaluated). ``n_file``: a single sensor's rows
    are part of a file of this many rows (the rate spread over the file: :func:`scan_rows`).
    """
    checks = Checks() if checks is None else checks
    r = np.asarray(signed_residuals(problem, x) if residuals is None else residuals, np.float64)
    obs = problem.observed()
    obs = np.ones(r.shape, bool) if obs is None else np.asarray(obs, bool)[:, : r.shape[1]]
    keep = None if problem.weight is None else np.asarray(problem.weight) > 0  # padding rows (weight 0): no data
    if keep is not None:
        obs = obs & keep[: obs.shape[0], None]
    model = problem.measurement
    parts = model.outlier_parts() if hasattr(model, "outlier_parts") else None
    if parts is None:
        n = int(problem.n_real) if keep is None else int(np.sum(keep))
        return (scan_rows(r[:n], obs[:n], rate=checks.outlier_rate, k=checks.outlier_k, n_file=n_file,
                          unit=getattr(model, "unit", "mm"), point_entries=getattr(model, "point_entries", None),
                          point_word=getattr(model, "point_word", "point")),)
    out = []
    for name, start, stop, entries, sigma, unit, *point in parts:
        pe, pw = point if point else (None, "point")
        rb = r[start:stop, :entries] * sigma
        out.append(scan_rows(rb, obs[start:stop, :entries], rate=checks.outlier_rate, k=checks.outlier_k,
                             unit=unit, block=name, offset=start, point_entries=pe, point_word=pw))
    return tuple(out)


def flagged_rows(scans) -> tuple[int, ...]:
    """The flagged rows of ``scans`` (:func:`scan_outliers`) as positions among the problem's rows."""
    return tuple(sorted(s.offset + i for s in scans for i in s.rows))


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
        weak_parameters: free parameters the data barely determine: with a prior, those it holds
            (:attr:`verdicts`); without one, posterior σ above a third of the plausibility bound.
        outliers_before, outliers_after: training rows (positions in the data, from 0) flagged as
            outliers at the start and after the fit (each file's rows in their own robust σ̂, at
            the false-alarm rate :attr:`Checks.outlier_rate` per file: :func:`scan_outliers`);
            ``outlier_scale_mm``: the robust residual scale after the fit (a combined fit's: of
            its whitened residual; each block's is in :attr:`outlier_scans`).
        outlier_scans: the scans after the fit (:class:`OutlierScan`: one, or one per data block
            of a combined fit), each with its rows, σ̂, threshold and rate.
        extras: the message of the extras initialisation, if one ran.
        rounds: fits run (more than 1 when a robust-loss scale or the prior's noise σ was
            re-estimated, or the free set grew at the solution).
        reselection: one line per refit after identifiability was judged again at the solution
            (parameters the start could not see and the solution can).
        prior_directions: with a prior, the few combinations of parameters that the prior
            rather than the data determines (the prior's share of their posterior variance above
            ``Checks.prior_share``), each named by its largest members in units of the prior σ, e.g.
            ``"0.71·d_2 + 0.71·d_3"``; the weakest first.
        suspect: failed checks of the result as a whole (:func:`fit_findings`: σ̂ against the
            robot's reach and the sensor's given noise, the fit against its start, the extras
            against their closed-form start), one sentence each; any makes it implausible.
        likely_cause: what the data point to when ``suspect`` is not empty (readings in metres,
            joint angles in radians read as degrees, a robot model that does not match), or
            ``None``.
        verdicts: each parameter's verdict, determined by the data, held by the prior or not
            calibrated (:class:`~jaxcal._fit._verdicts.Verdicts`), which every output of the
            result uses; ``None`` where the uncertainty could not be computed.
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
    suspect: tuple[str, ...] = ()
    likely_cause: str | None = None
    verdicts: Verdicts | None = None
    outlier_scans: tuple[OutlierScan, ...] = ()

    @property
    def plausible(self) -> bool:
        """No implausible deviation and no failed check of the result as a whole."""
        return not self.implausible and not self.suspect

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
            "suspect": list(self.suspect),
            "likely_cause": self.likely_cause,
            "verdicts": None if self.verdicts is None else self.verdicts.to_dict(),
            "outlier_scans": [sc.to_dict() for sc in self.outlier_scans],
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


def coverage(robot, q) -> np.ndarray:
    """``[dof, 2]``: how far each joint moved in ``q`` and the width of its limits, in degrees
    (revolute joints) or mm (prismatic joints, ``robot.joint_units()``)."""
    qn = np.asarray(q, np.float64)
    used = qn.max(axis=0) - qn.min(axis=0) if qn.shape[0] else np.zeros(robot.dof)
    limits = np.asarray(robot.q_max, np.float64) - np.asarray(robot.q_min, np.float64)
    deg = np.asarray([u == "rad" for u in robot.joint_units()])
    return np.stack([np.where(deg, np.rad2deg(used), used), np.where(deg, np.rad2deg(limits), limits)], axis=1)


def narrow_joints(robot, cov: np.ndarray, checks: Checks) -> tuple[int, ...]:
    """1-based joints that moved less than ``checks.narrow_joint_deg`` (revolute) or, prismatic,
    less than the same fraction of a turn of their limit range (the default 30° ↔ 1/12 of it)."""
    out = []
    for j, u in enumerate(robot.joint_units()):
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
    with eigenvalue ``λ`` has posterior variance ``1/(1 + λ)`` of its prior variance, which is
    also the prior's share of it, so it is prior-determined when ``1/(1 + λ) > prior_share``
    (``λ < 1``: the data tell less about it than the prior; the rule of
    :func:`~jaxcal._fit._verdicts.parameter_verdicts`).

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
    weak = lam < 1.0 / checks.prior_share - 1.0
    names = [unc.names[i] for i in c]
    listed = []
    for k in np.flatnonzero(weak)[:max_listed]:
        v = V[:, k] * (1.0 if V[np.argmax(np.abs(V[:, k])), k] > 0 else -1.0)
        top = [i for i in np.argsort(-np.abs(v))[:max_members] if abs(v[i]) >= 0.25 * np.abs(v).max()]
        text = " ".join(f"{'−' if v[i] < 0 else '+'} {abs(v[i]):.2f}·{names[i]}" for i in top)
        listed.append(text[2:] if text.startswith("+ ") else "−" + text[2:])
    return int(weak.sum()), tuple(listed)


def weak_parameters(unc: Uncertainty, checks: Checks) -> tuple[str, ...]:
    """Free parameters the data barely determine in a fit without a prior: posterior σ above a
    third of the plausibility bound (``checks.angle_deg``, ``checks.length_mm``); undetermined
    ones always. (Under a prior: the parameters it holds, :class:`~jaxcal._fit._verdicts.Verdicts`.)"""
    out = []
    for n, u, s in zip(unc.names, unc.units, unc.std):
        if not math.isfinite(s):
            out.append(n)
        elif u in ("rad", "mm") and group_kind(n) != "extra":
            bound = math.radians(checks.angle_deg) if u == "rad" else checks.length_mm
            if s > bound / 3:
                out.append(n)
    return tuple(out)


def _readings_and_predictions(measurement, y, residual):
    """``(readings [n, m], predictions [n, m])`` (mm) of a kind whose residual is ``prediction −
    reading`` in mm entry by entry (``MeasurementModel.readings_mm``), the predictions as
    ``reading + residual``; ``None`` for other kinds."""
    obs = None if residual is None else measurement.readings_mm(y)
    if obs is None:
        return None
    r = np.asarray(residual, np.float64)
    return (obs, obs + r) if r.shape == obs.shape else None


def _spread(v: np.ndarray) -> float:
    """RMS over the columns of each column's standard deviation over rows (NaN cells left out)."""
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN column
        return float(np.sqrt(np.nanmean(np.nanvar(v, axis=0))))


def likely_cause(robot, measurement, q, y, residual, *, huge_residual: bool = False) -> str | None:
    """What the data point to when a calibration fails its checks, or ``None``.

    * Readings 1 000× off: the readings (``y``) vary 100× less (more) than the robot model
      predicts (``y + residual``, ``MeasurementModel.readings_mm``) → they look like metres (µm),
      expected mm.
    * Joint angles in radians read as degrees: every revolute joint (two or more) stays within
      ±2π degrees (±0.11 rad) — a ``q*_deg`` column holding radians.
    * Otherwise, with ``huge_residual`` (σ̂ beyond :attr:`Checks.residual_fraction` of the
      reach): the robot model may not match the data.

    Args:
        robot: the nominal robot (``robot.joint_units()``).
        measurement: the measurement model (its ``kind``).
        q: ``[n, dof]`` joint values (rad; mm at prismatic joints).
        y: ``[n, *sample_shape]`` readings.
        residual: ``[n, m]`` signed residual blocks (``prediction − reading``, mm; a pose's
            position part), or ``None``.
        huge_residual: whether the residual is far beyond any sensor's noise.
    """
    pair = _readings_and_predictions(measurement, y, residual)
    if pair is not None:
        s_y, s_p = _spread(pair[0]), _spread(pair[1])
        what = measurement.reading_words
        if s_p > 0 and 0 < s_y < 0.01 * s_p:
            return (f"the {what} look like metres, expected mm (they vary {s_p / s_y:.0f}× less than the robot "
                    "model predicts)")
        if s_y > 100 * s_p > 0:
            return (f"the {what} look like µm, expected mm (they vary {s_y / s_p:.0f}× more than the robot "
                    "model predicts)")
    revolute = [j for j, u in enumerate(robot.joint_units()) if u == "rad"]
    qn = np.asarray(q, np.float64)
    if len(revolute) >= 2 and qn.shape[0] and np.abs(qn[:, revolute]).max() <= math.radians(2 * math.pi):
        return ("the joint angles look like radians read as degrees (every joint within ±6.3°: radians under "
                "a q*_deg header?)")
    if huge_residual:
        return ("the robot model may not match the data (another robot's DH table or URDF chain?), or the "
                "file holds another sensor's readings")
    return None


def given_noise_std(data, prior, measurement) -> float | None:
    """The sensor's given noise σ (the readings' unit): ``prior.noise_std``, else a data set's
    ``noise_std_mm`` (``noise_std_px`` for camera data) metadata (a file's ``# noise_std_mm:``
    line), else ``None``."""
    if prior is not None and getattr(prior, "noise_std", None) is not None:
        return float(prior.noise_std)
    meta = dict(getattr(data, "metadata", None) or ())  # Dataset.metadata: (key, value) pairs
    text = meta.get(f"noise_std_{getattr(measurement, 'unit', 'mm')}")
    try:
        v = float(text) if text is not None else None
    except ValueError:
        return None
    return v if v is not None and math.isfinite(v) and v > 0 else None


def stated_noise_warning(where: str, sigma_hat: float, stated: float | None, unit: str = "mm",
                         factor: float = Checks.noise_warn_factor) -> str | None:
    """One warning when a fit's residual σ̂ is at least ``factor`` times the noise σ its data file
    states (:func:`given_noise_std` of the data alone: its ``# noise_std_mm:`` / ``# noise_std_px:``
    line), else ``None``. A file whose readings fit the others' robot only at several times its
    stated noise was made on another set-up (another robot or seed, another tool or sensor
    frame), or its noise line understates the noise; this names it. The same check for one file
    (``jaxcal calibrate``) and for each block of a combined fit (:func:`jaxcal.calibrate_blocks`).

    Args:
        where: the data's name in the message (a file path, ``block 'name'``).
        sigma_hat: σ̂, the residual noise estimated by the fit (the readings' unit: mm, px).
        stated: the noise σ the file states (same unit), or ``None`` (no line: no warning).
        unit: the readings' unit. factor: the threshold (:attr:`Checks.noise_warn_factor`).
    """
    if stated is None or not (math.isfinite(sigma_hat) and sigma_hat >= factor * stated):
        return None
    return (f"{where}: residual σ̂ {sigma_hat:.3g} {unit} is {sigma_hat / stated:.2g}× the noise its file states "
            f"('# noise_std_{unit}: {stated:g}'; warned at {factor:g}×) — check that these readings come from the "
            "set-up the fit assumes (the same robot, the same tool and sensor frame as the other files: a different "
            "set-up or seed?) and that the noise line states the sensor's real noise")


def fit_findings(robot, measurement, q, y, residual, residual_start, *, noise_std_hat: float, extras=(),
                 checks: Checks = Checks(),
                 noise_std: float | None = None) -> tuple[tuple[str, ...], str | None]:
    """Checks of a calibration result as a whole, beyond its robot deviations
    (:func:`implausible_deviations`): a wrong unit, angle unit, sensor kind or robot model fits
    to residuals hundreds of mm large with extras far from any physical set-up, and must not
    pass as a result.

    * σ̂ (mm readings) above ``checks.residual_fraction`` of the robot's reach;
    * σ̂ above ``checks.noise_factor`` times the sensor's given noise ``noise_std``;
    * the RMS training residual after the fit above ``(1 + checks.worse_rtol)`` times its start's;
    * an extra moved from its closed-form start by more than ``checks.extra_fraction`` of the
      reach (mm) or ``checks.extra_angle_deg`` (rad extras), or one (mm) further than 10
      reaches from its nominal or guessed value (no physical set-up).

    Args:
        robot: the nominal robot (``reach_mm()``, ``robot.joint_units()``).
        measurement: the measurement model (``kind``, ``unit``: mm, or px for cameras).
        q: ``[n, dof]`` training joint values (rad; mm at prismatic joints).
        y: ``[n, *sample_shape]`` training readings.
        residual, residual_start: ``[n, m]`` signed residual blocks (``prediction − reading``;
            a pose's position part; reading unit) at the solution and at the start (the nominal
            robot, extras from the data), or ``None``.
        noise_std_hat: σ̂, the noise estimated from the residuals (reading unit).
        extras: ``((name, unit, start, final), ...)`` of the free extras: deviations from their
            nominal or guessed value (unit ``"mm"`` or ``"rad"``; others are skipped), ``start``
            ``None`` unless it came from the data in closed form.
        checks: the thresholds.
        noise_std: the sensor's given noise σ (:func:`given_noise_std`), or ``None``.

    Returns:
        ``(findings, cause)``: one sentence per failed check, and :func:`likely_cause` when
        one failed (else ``None``).
    """
    unit = getattr(measurement, "unit", "mm")
    reach = float(robot.reach_mm())
    out = []
    huge = False
    if unit == "mm" and math.isfinite(reach) and reach > 0 and not noise_std_hat <= checks.residual_fraction * reach:
        huge = True
        out.append(f"residual σ̂ {noise_std_hat:.4g} mm is {100 * noise_std_hat / reach:.3g} % of the robot's reach "
                   f"({reach:.0f} mm; bound {100 * checks.residual_fraction:g} %): the model does not describe these "
                   "data")
    if noise_std is not None and not noise_std_hat <= checks.noise_factor * noise_std:
        out.append(f"residual σ̂ {noise_std_hat:.4g} {unit} is {noise_std_hat / noise_std:.3g}× the sensor's given "
                   f"noise σ = {noise_std:g} {unit} (bound {checks.noise_factor:g}×)")
    if residual is not None and residual_start is not None:
        before, after = (float(np.sqrt(np.nanmean(np.square(np.asarray(r, np.float64)))))
                         for r in (residual_start, residual))
        if not after <= (1 + checks.worse_rtol) * before:
            out.append(f"the fit is worse than its start: RMS training residual {before:.4g} → {after:.4g} {unit}")
    moved = []
    far = []
    for name, u, v0, v1 in extras:
        if u == "mm" and math.isfinite(reach) and not abs(float(v1)) <= 10 * reach:
            far.append(f"{name} {float(v1):+.4g} mm")
        if v0 is None:
            continue
        d = float(v1) - float(v0)
        if u == "mm" and math.isfinite(reach) and not abs(d) <= checks.extra_fraction * reach:
            moved.append(f"{name} {d:+.4g} mm")
        elif u == "rad" and not abs(math.degrees(d)) <= checks.extra_angle_deg:
            moved.append(f"{name} {math.degrees(d):+.4g}°")
    if moved:
        out.append(f"sensor extras moved far from their closed-form start: {', '.join(moved[:8])}"
                   f"{' …' if len(moved) > 8 else ''} (bound {100 * checks.extra_fraction:g} % of the reach, "
                   f"{checks.extra_angle_deg:g}°)")
    if far:
        out.append(f"sensor extras beyond any physical set-up (more than 10 reaches from their guess): "
                   f"{', '.join(far[:8])}{' …' if len(far) > 8 else ''}")
    if not out:
        return (), None
    return tuple(out), likely_cause(robot, measurement, q, y, residual, huge_residual=huge)


def result_findings(result, problem, unc, residual, residual_start, checks: Checks, *, extras_started: bool,
                    noise_std: float | None = None) -> tuple[tuple[str, ...], str | None]:
    """:func:`fit_findings` of a :class:`~jaxcal.CalibrationResult` on its training ``problem``
    (``unc``: its :class:`Uncertainty` or ``None``; ``residual``, ``residual_start``: the signed
    residual blocks ``[n, m]`` at the solution and at the start, or ``None``); the free extras
    are compared with their start where that came from the data (``extras_started``)."""
    space = result.space
    v1 = np.asarray(result.deviations._ravel_numpy(), np.float64)
    started = extras_started and result.start is not None
    v0 = np.asarray(result.start._ravel_numpy(), np.float64) if started else [None] * len(v1)
    free = set(space.free_names)
    extras = tuple((n, u, a, b) for n, u, a, b in zip(space.names, space.units, v0, v1)
                   if n in free and group_kind(n) == "extra")
    sigma = unc.noise_std if unc is not None else float(result.train_metrics.rmse)
    return fit_findings(result.robot, result.measurement, problem.q, problem.y, residual, residual_start,
                        noise_std_hat=float(sigma), extras=extras, checks=checks, noise_std=noise_std)
