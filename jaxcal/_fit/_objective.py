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

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core._metrics import robust_scale
from .._core._params import ParameterSpace
from .._core._precision import to_device
from ._prior import Prior, resolve_prior

__all__ = ["Prior", "Objective", "LOSSES", "robust_factor", "robust_scale", "resolve_prior", "MEASURED_DEFAULTS",
           "OBJECTIVES", "resolve_objective", "describe_objective"]

#: robust losses and their 95 %-efficiency tuning constants ``k`` (scale ``c = k·σ̂``).
LOSSES: dict[str, float] = {"linear": math.inf, "huber": 1.345, "cauchy": 2.385}


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
