"""Real-coded genetic algorithm, the paper's M1 (Table II: "the GA introduced in [71]").

The paper gives no details of its GA, so this is the textbook real-coded GA for box-bounded
continuous parameters (Deb, *Multi-Objective Optimization using Evolutionary Algorithms*, 2001):

- **selection**: tournament of ``tournament_size`` (default 3) with replacement, lower RMSE wins;
- **crossover**: simulated binary crossover, SBX (Deb & Agrawal 1995), probability
  ``crossover_prob`` per pair, each gene crossed with probability ½, distribution index
  ``crossover_eta``; children are clipped to the box;
- **mutation**: bounded polynomial mutation (Deb & Goyal 1996, in the form of Deb & Deb 2014),
  probability ``mutation_prob`` per gene (default ``1/p``), distribution index ``mutation_eta``;
- **elitism**: the ``n_elite`` best individuals survive unchanged (generational replacement for
  the rest).

It runs over the scaled deviations ``z`` inside the physical search box of
:func:`~jaxcal.methods.default_half_width` (±2° angles, ±5 mm lengths, ±50 mm sensor extras),
converted to ``z``. Individual 0 of the initial population is the start (``z = 0``, the nominal
robot), the others are uniform in the box. Every generation evaluates all offspring in one
batched forward-kinematics call (``ScaledProblem.rmse_batch``); the generations run in
``jax.lax.scan``. The history holds the best training RMSE found so far (non-increasing).

Written in JAX rather than on ``evosax.algorithms.SimpleGA``: SimpleGA has no tournament/SBX/
polynomial-mutation operators and barely converges with its default mutation std
, and a plain JAX loop is exact, vmappable and adds no dependency.
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._base import RawRun, ScaledProblem, register_method
from ._population import (
    BoxSearch,
    check_positive,
    check_unit_interval,
    finish_population_run,
    initial_population,
    uniform_index,
    uniform_parts,
)

__all__ = [
    "GeneticAlgorithm",
    "sbx_crossover",
    "polynomial_mutation",
    "tournament",
]


# --- the genetic algorithm --------------------------------------------------------------------


def sbx_crossover(a: Array, b: Array, eta: float, prob: float, u: Array, u_gene: Array, u_pair: Array):
    """Simulated binary crossover (Deb & Agrawal 1995) of parent pairs ``a, b`` ``[n, p]``.

    Each pair crosses with probability ``prob`` (``u_pair`` ``[n, 1]``); within a crossing pair
    each gene with probability ½ (``u_gene`` ``[n, p]``). The spread factor ``β`` has the
    polynomial density of index ``eta`` (from ``u`` ``[n, p]``). All ``u`` uniform in [0, 1).
    """
    beta = jnp.where(u <= 0.5, (2.0 * u) ** (1.0 / (eta + 1.0)), (0.5 / (1.0 - u)) ** (1.0 / (eta + 1.0)))
    c1 = 0.5 * ((1.0 + beta) * a + (1.0 - beta) * b)
    c2 = 0.5 * ((1.0 - beta) * a + (1.0 + beta) * b)
    cross = (u_gene < 0.5) & (u_pair < prob)
    return jnp.where(cross, c1, a), jnp.where(cross, c2, b)


def polynomial_mutation(x: Array, lo: Array, hi: Array, eta: float, prob: float, u: Array, u_mutate: Array) -> Array:
    """Bounded polynomial mutation (Deb & Goyal 1996; the form of Deb & Deb 2014) of ``x`` ``[n, p]``:
    each gene mutates with probability ``prob`` (``u_mutate``), by a step of index ``eta`` (``u``)."""
    width = hi - lo
    d1 = (x - lo) / width
    d2 = (hi - x) / width
    e = eta + 1.0
    left = (2.0 * u + (1.0 - 2.0 * u) * (1.0 - d1) ** e) ** (1.0 / e) - 1.0
    right = 1.0 - (2.0 * (1.0 - u) + 2.0 * (u - 0.5) * (1.0 - d2) ** e) ** (1.0 / e)
    delta = jnp.where(u < 0.5, left, right)
    return jnp.clip(jnp.where(u_mutate < prob, x + delta * width, x), lo, hi)


def tournament(fitness: Float[Array, " P"], u: Array) -> Array:
    """Indices ``[n]`` of tournament winners: lowest fitness among ``size`` uniform draws
    (``u`` ``[n, size]`` uniforms in [0, 1))."""
    idx = uniform_index(u, fitness.shape[0])
    return jnp.take_along_axis(idx, jnp.argmin(fitness[idx], axis=1)[:, None], axis=1)[:, 0]


@register_method("ga")
class GeneticAlgorithm(BoxSearch):
    """Real-coded GA (the paper's M1): tournament selection, SBX, polynomial mutation, elitism.

    One iteration = one generation (``population_size − n_elite`` new evaluations, one batched
    call). History: best training RMSE so far. Status: COMPLETED, or DIVERGED where no finite
    candidate was ever found.

    Defaults (the paper gives none): Deb's operators; ``tournament_size`` and ``mutation_eta``
    tuned on training data of the simulated experiment (method keys 100–102: mean training RMSE
    0.509 mm against 0.517 mm with binary tournaments and ``mutation_eta = 20``; LM: 0.506 mm);
    the budget sized for ~10 s on 2 CPU cores: ``population_size = 100``, ``generations = 600``,
    ``n_elite = 2``, ``tournament_size = 3``, ``crossover_prob = 0.9``, ``crossover_eta = 15``,
    ``mutation_prob = None`` (→ ``1/p``), ``mutation_eta = 50``; box ±2°, ±5 mm, ±50 mm.

    Args:
        population_size: individuals per generation (≥ 4).
        generations: number of generations (≥ 1).
        n_elite: best individuals copied unchanged (0 ≤ n_elite < population_size).
        tournament_size: individuals per tournament (≥ 1; 1 = random selection).
        crossover_prob: SBX probability per parent pair, in [0, 1].
        crossover_eta: SBX distribution index (> 0; larger = children closer to parents).
        mutation_prob: per-gene mutation probability in [0, 1], ``None`` = 1/p.
        mutation_eta: polynomial-mutation distribution index (> 0).
        box_angle_deg, box_length_mm, box_extra_mm: search-box half-widths (°, mm, mm).
    """

    population_size: int = 100
    generations: int = 600
    n_elite: int = 2
    tournament_size: int = 3
    crossover_prob: float = 0.9
    crossover_eta: float = 15.0
    mutation_prob: float | None = None
    mutation_eta: float = 50.0
    name: ClassVar[str] = "ga"

    def __check_init__(self):
        check_positive("population_size", self.population_size, integer=True, minimum=4)
        check_positive("generations", self.generations, integer=True, minimum=1)
        check_positive("n_elite", self.n_elite, integer=True, minimum=0)
        if self.n_elite >= self.population_size:
            raise ValueError(f"n_elite must be < population_size, got {self.n_elite} >= {self.population_size}")
        check_positive("tournament_size", self.tournament_size, integer=True, minimum=1)
        check_unit_interval("crossover_prob", self.crossover_prob)
        check_positive("crossover_eta", self.crossover_eta)
        if self.mutation_prob is not None:
            check_unit_interval("mutation_prob", self.mutation_prob)
        check_positive("mutation_eta", self.mutation_eta)

    @property
    def max_iterations(self) -> int:
        return self.generations

    def run(self, problem: ScaledProblem, key) -> RawRun:
        P, p = self.population_size, problem.n_free
        hw = self.box_half_width_z(problem)
        lo, hi = -hw, hw
        pm = 1.0 / p if self.mutation_prob is None else self.mutation_prob
        n_child = P - self.n_elite
        n_pairs = (n_child + 1) // 2
        k_init, k_run = jax.random.split(key)

        X0 = initial_population(k_init, hw, P)
        f0 = problem.rmse_batch(X0)
        rmse0 = f0[0]

        shapes = [(2 * n_pairs, self.tournament_size), (n_pairs, p), (n_pairs, p), (n_pairs, 1), (n_child, p), (n_child, p)]

        def generation(carry, k):
            X, f = carry
            u_sel, u_beta, u_gene, u_pair, u_mut, u_mutate = uniform_parts(k, shapes, X.dtype)
            order = jnp.argsort(f)
            elite_X, elite_f = X[order[: self.n_elite]], f[order[: self.n_elite]]
            parents = tournament(f, u_sel)
            a, b = X[parents[:n_pairs]], X[parents[n_pairs:]]
            c1, c2 = sbx_crossover(a, b, self.crossover_eta, self.crossover_prob, u_beta, u_gene, u_pair)
            children = jnp.clip(jnp.concatenate([c1, c2])[:n_child], lo, hi)
            children = polynomial_mutation(children, lo, hi, self.mutation_eta, pm, u_mut, u_mutate)
            fc = problem.rmse_batch(children)  # one batched call per generation
            X_new = jnp.concatenate([elite_X, children])
            f_new = jnp.concatenate([elite_f, fc])
            return (X_new, f_new), (jnp.min(f_new), X_new[jnp.argmin(f_new)])

        keys = jax.random.split(k_run, self.generations)
        (X, f), (best_f, best_X) = jax.lax.scan(generation, (X0, f0), keys)
        # with elitism (n_elite ≥ 1) the generation best is already the best so far
        best_so_far = jax.lax.cummin(jnp.minimum(best_f, jnp.min(f0)))
        i = jnp.argmin(best_f)
        z_best = jnp.where(best_f[i] <= jnp.min(f0), best_X[i], X0[jnp.argmin(f0)])
        return finish_population_run(rmse0, best_so_far, z_best)
