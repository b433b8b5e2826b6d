"""Extended Kalman filter identification, the paper's M2 (Table II: "the EKF algorithm in [72]").

The kinematic deviations are the filter's static state (in the scaled coordinates ``z`` of
:class:`ScaledProblem`); the measurements are assimilated one sample at a time (Fin et al. /
the classic EKF calibration of Park, Kim et al.). For sample ``i`` with residual
``r_i(z) = prediction − measured`` (``[m]``: ``m = 1`` wire length, 3 for positions):

.. code-block:: text

    H = ∂r_i/∂z (jax.jacfwd, relinearised at the current state)      [m, p]
    S = H P Hᵀ + R,   K = P Hᵀ S⁻¹                                    (R = σ² I_m)
    z ← z − K r_i(z)                                                  (innovation = −r_i)
    P ← (I − K H) P (I − K H)ᵀ + K R Kᵀ + Q                          (Joseph form, Q = q² I)

with ``jax.lax.scan`` over the samples. One iteration is one pass over the training data.
Each pass restarts from the previous pass's estimate with the prior covariance ``P0`` (an
iterated EKF: the relinearisation of the whole data set at the new estimate; carrying ``P``
over would count every measurement again). ``P0 = diag((prior_fraction · half-width)²)``: the
physical search box of the population methods (±2°, ±5 mm, ±50 mm) as ``1/prior_fraction``
standard deviations — or, for parameters with a MAP prior (``calibrate(..., prior=...)``), that
prior's σ (relative to ``noise_std``, so the filter weighs prior and data as the MAP objective
does). ``R`` comes from ``noise_std`` (mm), by default the simulated sensor's
0.5 mm; with many samples the estimate is insensitive to it (it only weighs the prior).

The filter is deterministic (the key is unused). The history holds the training RMSE after
each pass; status COMPLETED, or DIVERGED when the state or covariance turns non-finite (the
last finite estimate is returned).
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp

from .._fit._result import Status
from ._base import DIVERGENCE_FACTOR, RawRun, ScaledProblem, register_method
from ._population import BoxSearch, check_positive, start_rmse

__all__ = ["ExtendedKalmanFilter"]


@register_method("ekf")
class ExtendedKalmanFilter(BoxSearch):
    """Sequential EKF over the samples with the deviations as static state (the paper's M2).

    Defaults (the paper gives none): ``passes = 3``, ``noise_std = 0.5`` mm,
    ``prior_fraction = 0.5`` (box half-width = 2σ of the prior), ``process_noise = 0``,
    box ±2° / ±5 mm / ±50 mm.

    Args:
        passes: passes over the training data (iterations, ≥ 1).
        noise_std: measurement noise σ (mm) → ``R = σ² I`` (> 0).
        prior_fraction: prior standard deviation as a fraction of the box half-width (> 0).
        process_noise: standard deviation (in ``z`` units, ~mm of RMS residual) of the random
            walk added to the state per sample (≥ 0; 0 = static parameters).
        box_angle_deg, box_length_mm, box_extra_mm: box half-widths for ``P0`` (°, mm, mm).
    """

    passes: int = 3
    noise_std: float = 0.5
    prior_fraction: float = 0.5
    process_noise: float = 0.0
    name: ClassVar[str] = "ekf"

    def __check_init__(self):
        check_positive("passes", self.passes, integer=True, minimum=1)
        check_positive("noise_std", self.noise_std)
        check_positive("prior_fraction", self.prior_fraction)
        check_positive("process_noise", self.process_noise, allow_zero=True)

    @property
    def max_iterations(self) -> int:
        return self.passes

    def run(self, problem: ScaledProblem, key) -> RawRun:
        del key  # deterministic
        pr = problem.problem
        p, m, dtype = problem.n_free, pr.measurement.size, problem.dtype
        hw = self.box_half_width_z(problem)
        prior_sd = self.prior_fraction * hw
        ob = problem.objective
        if ob is not None and ob.loss != "linear":
            raise ValueError("the EKF assimilates one sample at a time and supports no robust loss; "
                             "use the linear loss (--loss linear; loss \"linear\" in Python), or a least-squares, gradient or "
                             "population method")
        if ob is not None and ob.has_prior:
            # the MAP prior: residual w·(x − m) with w = σ/s  →  std of z = (noise_std/w)/scale
            w_z = ob.prior_precision * problem.scale
            prior_sd = jnp.where(w_z > 0, self.noise_std / jnp.where(w_z > 0, w_z, 1.0), prior_sd)
        P0 = jnp.diag(prior_sd**2)
        R = jnp.eye(m, dtype=dtype) * (self.noise_std**2)
        Q = jnp.eye(p, dtype=dtype) * (self.process_noise**2)
        eye = jnp.eye(p, dtype=dtype)
        z0 = jnp.zeros(p, dtype)
        rmse0 = start_rmse(problem)

        # with a MAP prior each pass is an iterated EKF (Gauss-Newton on the MAP objective): it
        # starts from the prior mean with P0 and uses the residuals linearised at the previous
        # pass's estimate, so the prior stays centred where it belongs; without a prior, each
        # pass restarts from the previous estimate and relinearises per sample (the paper's M2)
        map_prior = ob is not None and ob.has_prior
        z_prior = (ob.prior_mean - problem.x_start) / problem.scale if map_prior else z0

        def update(carry, sample):
            z, P, z_lin = carry
            q_i, y_i, w_i = sample
            # one forward pass: r [m], H [m, p]
            if map_prior:
                r, H = problem.residual_and_jacobian(z_lin, pr.with_data(q_i[None], y_i[None]))
                r = r + H @ (z - z_lin)
            else:
                r, H = problem.residual_and_jacobian(z, pr.with_data(q_i[None], y_i[None]))
            PHt = P @ H.T
            S = H @ PHt + R
            K = jnp.linalg.solve(S, PHt.T).T  # [p, m]  (S symmetric)
            z = z - K @ r
            A = eye - K @ H
            P = A @ P @ A.T + K @ R @ K.T + Q
            z_new, P_new = z, 0.5 * (P + P.T)
            if w_i is not None:  # a padding row (weight 0) leaves the filter as it was
                z_new = jnp.where(w_i > 0, z_new, carry[0])
                P_new = jnp.where(w_i > 0, P_new, carry[1])
            return (z_new, P_new, z_lin), None

        def one_pass(carry, _):
            z, diverged = carry
            z_first = z_prior if map_prior else z
            (z_new, P_new, _), _ = jax.lax.scan(update, (z_first, P0, z), (pr.q, pr.y, pr.weight))
            rmse = problem.rmse(z_new)
            bad = (
                ~jnp.all(jnp.isfinite(z_new))
                | ~jnp.all(jnp.isfinite(P_new))
                | ~jnp.isfinite(rmse)
                | (rmse > DIVERGENCE_FACTOR * rmse0)
            )
            diverged = diverged | bad
            z_keep = jnp.where(diverged, z, z_new)
            return (z_keep, diverged), jnp.where(diverged, jnp.nan, rmse)

        (z, diverged), hist = jax.lax.scan(one_pass, (z0, ~jnp.isfinite(rmse0)), None, length=self.passes)
        hist = jnp.concatenate([rmse0[None], hist])
        first_bad = jnp.argmax(~jnp.isfinite(hist))
        n_it = jnp.where(diverged, jnp.maximum(first_bad - 1, 0), self.passes)
        status = jnp.where(diverged, int(Status.DIVERGED), int(Status.COMPLETED))
        return RawRun(z, hist, jnp.asarray(n_it), status)
