"""Beetle swarm optimisation, the paper's M3 (Table II: "the BSO algorithm introduced in [67]",
Chen et al.'s improved BSO for the kinematic parameters of an industrial robot).

The cited work's improvements are not given in the paper; this is the standard beetle swarm
optimisation (Wang & Yang, 2018: particle swarm optimisation whose particles also sense the
landscape with the two antennae of beetle antennae search, Jiang & Li, 2017). For beetle ``i``
at generation ``t`` (``T`` generations, positions ``x`` in the scaled deviations ``z``):

.. code-block:: text

    b      = random unit direction (isotropic)                      BAS antennae direction
    x_r, x_l = x + d_t b,  x − d_t b                                 right / left antenna
    ξ      = −δ_t · b · sign(f(x_r) − f(x_l))                       step toward the better antenna
    ω_t    = ω_max − (ω_max − ω_min) t / T                          linearly decreasing inertia
    v      ← ω_t v + c1 r1 (pbest − x) + c2 r2 (gbest − x),  |v_j| ≤ v_max,j
    x      ← clip(x + λ v + (1 − λ) ξ, box)
    δ_{t+1} = γ δ_t,  d_t = δ_t / antenna_ratio                     step and antenna decay

(``r1, r2`` uniform per component; ``f`` the training RMSE, minimised, so the BAS step moves
toward the antenna with the *lower* RMSE.) Following BAS, the antennae point along a random
direction; the step sizes are in ``z`` units (a unit of ``z`` moves the RMS residual by
~1 mm) and the velocity limit is ``v_max_fraction`` of the box width per coordinate.

Because the antennae direction does not depend on the fitness of ``x``, each generation
evaluates the ``3P`` points ``x, x_r, x_l`` of all beetles in **one** batched call; personal
and global bests are taken over the positions ``x`` (as in BSO). Beetle 0 starts at ``z = 0``
(the nominal robot), the others uniform in the box ±2°/±5 mm/±50 mm; velocities start at 0.
The history holds the best training RMSE so far (non-increasing); status COMPLETED, or
DIVERGED where no finite candidate was ever found.
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp

from ._base import RawRun, ScaledProblem, register_method
from ._population import (
    BoxSearch,
    check_positive,
    check_unit_interval,
    finish_population_run,
    initial_population,
    normal_from_uniform,
    start_rmse,
    uniform_parts,
)

__all__ = ["BeetleSwarm"]


@register_method("bso")
class BeetleSwarm(BoxSearch):
    """Beetle swarm optimisation (PSO + beetle-antennae search), the paper's M3.

    One iteration = one generation (``3 × population_size`` evaluations in one batched call).

    Defaults (the paper gives none; PSO constants of Shi & Eberhart, BSO's λ = 0.4 of Wang &
    Yang; step sizes and budget chosen on training data of the simulated experiment, method
    keys 100–101, for ~5–10 s on 2 CPU cores):
    ``population_size = 40``, ``generations = 400``, ``step = 1.0`` (z units),
    ``step_decay = 0.99``, ``antenna_ratio = 2``, ``lam = 0.4``, ``c1 = c2 = 2``,
    ``w_max = 0.9``, ``w_min = 0.4``, ``v_max_fraction = 0.2``, box ±2° / ±5 mm / ±50 mm.

    Args:
        population_size: beetles (≥ 2).
        generations: iterations (≥ 1).
        step: initial BAS step δ₀ in ``z`` units (> 0).
        step_decay: per-generation factor γ of the step (0 < γ ≤ 1).
        antenna_ratio: step / antenna length ratio (> 0); the antenna length is ``δ_t / ratio``.
        lam: weight λ of the PSO velocity vs the BAS step, in [0, 1].
        c1, c2: cognitive and social acceleration constants (≥ 0).
        w_max, w_min: inertia weight at the first and last generation (0 ≤ w_min ≤ w_max).
        v_max_fraction: velocity limit as a fraction of the box width (> 0).
        box_angle_deg, box_length_mm, box_extra_mm: search-box half-widths (°, mm, mm).
    """

    population_size: int = 40
    generations: int = 400
    step: float = 1.0
    step_decay: float = 0.99
    antenna_ratio: float = 2.0
    lam: float = 0.4
    c1: float = 2.0
    c2: float = 2.0
    w_max: float = 0.9
    w_min: float = 0.4
    v_max_fraction: float = 0.2
    name: ClassVar[str] = "bso"

    def __check_init__(self):
        check_positive("population_size", self.population_size, integer=True, minimum=2)
        check_positive("generations", self.generations, integer=True, minimum=1)
        check_positive("step", self.step)
        check_unit_interval("step_decay", self.step_decay, open_low=True)
        check_positive("antenna_ratio", self.antenna_ratio)
        check_unit_interval("lam", self.lam)
        check_positive("c1", self.c1, allow_zero=True)
        check_positive("c2", self.c2, allow_zero=True)
        check_positive("w_min", self.w_min, allow_zero=True)
        check_positive("w_max", self.w_max, allow_zero=True)
        if self.w_min > self.w_max:
            raise ValueError(f"w_min must be <= w_max, got w_min={self.w_min} > w_max={self.w_max}")
        check_positive("v_max_fraction", self.v_max_fraction)

    @property
    def max_iterations(self) -> int:
        return self.generations

    def run(self, problem: ScaledProblem, key) -> RawRun:
        P, p, T = self.population_size, problem.n_free, self.generations
        dtype = problem.dtype
        hw = self.box_half_width_z(problem)
        v_max = self.v_max_fraction * 2.0 * hw
        k_init, k_run = jax.random.split(key)
        X0 = initial_population(k_init, hw, P)
        rmse0 = start_rmse(problem)
        inf = jnp.asarray(jnp.inf, dtype)

        def generation(carry, inp):
            X, V, Xp, fp, g, fg = carry
            t, k = inp
            u_b, r1, r2 = uniform_parts(k, [(P, p)] * 3, dtype)  # one draw (see uniform_parts)
            delta = self.step * self.step_decay ** t.astype(dtype)
            d = delta / self.antenna_ratio
            b = normal_from_uniform(u_b)
            b = b / jnp.maximum(jnp.linalg.norm(b, axis=1, keepdims=True), 1e-12)
            # positions and both antennae of every beetle: one batched evaluation
            f_all = problem.rmse_batch(jnp.concatenate([X, X + d * b, X - d * b]))
            f, f_r, f_l = f_all[:P], f_all[P : 2 * P], f_all[2 * P :]
            # personal and global bests (over positions)
            better = f < fp
            Xp = jnp.where(better[:, None], X, Xp)
            fp = jnp.where(better, f, fp)
            i = jnp.argmin(fp)
            g, fg = jnp.where(fp[i] < fg, Xp[i], g), jnp.minimum(fp[i], fg)
            # BAS step toward the better antenna (sign 0 when both are equal or non-finite)
            diff = jnp.where(jnp.isfinite(f_r - f_l), f_r - f_l, 0.0)
            xi = -delta * b * jnp.sign(diff)[:, None]
            w = self.w_max - (self.w_max - self.w_min) * t.astype(dtype) / T
            V = w * V + self.c1 * r1 * (Xp - X) + self.c2 * r2 * (g - X)
            V = jnp.clip(V, -v_max, v_max)
            X = jnp.clip(X + self.lam * V + (1.0 - self.lam) * xi, -hw, hw)
            return (X, V, Xp, fp, g, fg), fg

        carry0 = (X0, jnp.zeros_like(X0), X0, jnp.full((P,), inf), X0[0], inf)
        steps = (jnp.arange(T), jax.random.split(k_run, T))
        (_, _, _, _, g, fg), best = jax.lax.scan(generation, carry0, steps)
        return finish_population_run(rmse0, best, g)
