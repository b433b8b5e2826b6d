"""Per-generation cost of the population methods (GA, BSO, IWOA) at P = 64 and P = 512.

The default experiment (HSR-JR680, 1600 training samples, float64, the identifiable 19
parameters). For each method and population size, ``method.run`` is compiled for two
generation counts (``G0`` and ``G1``) and timed after compilation (median of ``REPEATS``); the
per-generation cost is ``(t(G1) − t(G0)) / (G1 − G0)``, which removes the fixed cost (scaling
Jacobian excluded anyway, initial population, final bookkeeping). Also timed: one batched
evaluation of ``P`` candidates, ``ScaledProblem.rmse_batch`` (the evaluator the methods use: one
vmapped FK call, the mean over samples as a matrix–vector product).

Run:  python benchmarks/bench_population.py   (writes benchmarks/results/population_cpu.md)
"""

from __future__ import annotations

import os
import pathlib

import jax
import jax.numpy as jnp
from _common import machine, median_time

import jaxcal
from jaxcal import Problem, identifiability, simulate_experiment
from jaxcal.methods import ScaledProblem, make_method

jaxcal.enable_x64()

SIZES = (64, 512)
G0, G1 = 5, 25
REPEATS = 5
#: generation-count keyword and per-generation evaluations of each method
METHODS = {
    "ga": ("generations", lambda P, m: P - m.n_elite),
    "bso": ("generations", lambda P, m: 3 * P),
    "iwoa": ("iterations", lambda P, m: P + m.n_local),
}


def main():
    ex = simulate_experiment(jax.random.PRNGKey(0))
    space = identifiability(ex.robot, ex.measurement, ex.train.q).space
    problem = Problem(ex.robot, ex.measurement, ex.train.q, ex.train.y, space)
    sp = jax.jit(ScaledProblem.build)(problem)
    key = jax.random.key(0)
    rows = []
    for P in SIZES:
        Z = 0.1 * jax.random.normal(jax.random.PRNGKey(1), (P, sp.n_free), jnp.float64)
        t_eval = median_time(jax.jit(lambda sp, Z: sp.rmse_batch(Z)), sp, Z, repeats=REPEATS)
        rows.append(("(evaluation)", P, P, t_eval))
        print(f"P={P}: rmse_batch {t_eval * 1e3:.1f} ms", flush=True)
        for name, (gen_kw, evals) in METHODS.items():
            ts = []
            for G in (G0, G1):
                method = make_method(name, population_size=P, **{gen_kw: G})
                f = jax.jit(lambda sp, k, method=method: method.run(sp, k).history)
                f = f.lower(sp, key).compile()
                ts.append(median_time(f, sp, key, repeats=REPEATS))
            per_gen = (ts[1] - ts[0]) / (G1 - G0)
            n_eval = evals(P, make_method(name, population_size=P))
            rows.append((name, P, n_eval, per_gen))
            print(f"P={P} {name}: {per_gen * 1e3:.1f} ms/generation ({n_eval} evaluations)", flush=True)

    lines = [
        "# Population methods: cost per generation (CPU)",
        "",
        f"Machine: {machine()}; float64. Load average (1 min) at the end: {os.getloadavg()[0]:.1f} "
        "(this benchmark alone keeps both cores busy, ~2; well above 2 means other jobs shared the cores "
        "and the timings are upper bounds).",
        "",
        "Default experiment: HSR-JR680, draw-wire, 1600 training samples, 19 identifiable parameters. "
        f"Per generation = (t({G1} generations) − t({G0} generations)) / {G1 - G0}, compiled, median of "
        f"{REPEATS} runs. (evaluation): one `ScaledProblem.rmse_batch` call on P candidates, the "
        "evaluator the methods use (one vmapped FK call, mean over samples as a matrix–vector product).",
        "",
        "| method | P | evaluations / generation | ms / generation | µs / evaluation |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for name, P, n_eval, t in rows:
        lines.append(f"| {name} | {P} | {n_eval} | {t * 1e3:.1f} | {t / n_eval * 1e6:.0f} |")
    out = pathlib.Path(__file__).parent / "results" / "population_cpu.md"
    out.parent.mkdir(exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print(out.read_text())


if __name__ == "__main__":
    main()
