"""Sweep throughput: trials per second, vmapped chunks vs a Python loop over seeds.

What is measured: one *trial* = calibrate one simulated experiment and evaluate it on its
held-out split — the per-trial function of ``jaxcal._experiments._sweep_trials`` (``_MethodTrial``). The data of
all trials is simulated beforehand (not timed).

* **vmapped**: ``jax.jit(jax.vmap(trial))`` over ``n`` seeds, compiled ahead of time
  (``.lower().compile()``, compile time reported separately); for ``n ≤ 16`` a warm-up call and
  the best of 3 timed calls, for larger ``n`` one timed call; throughput = ``n / wall``. This is
  what one chunk of ``sweep(..., chunk_size=n)`` costs.
* **lax.map**: ``jax.jit(lambda xs: jax.lax.map(trial, xs))``, timed the same way: the trials
  run one after the other inside one compiled function (``sweep``'s default on one CPU device).
* **loop**: ``jax.jit(trial)`` compiled once, a warm-up call, then a Python loop over the ``n``
  seeds (repeated to make at least 16 calls) with a ``block_until_ready`` per trial.
* **sweep API ÷ compiled**: the wall time of a warm ``jaxcal.sweep([method], n, n_samples=...)``
  (defaults: ``lax.map`` chunks of 16, per-sample errors and histories kept; median of 3 calls,
  one call when a call takes more than 5 s) divided by the time of the same work as two bare
  compiled functions: the simulation (``jit(lax.map(data trial))`` over the ``n`` keys, what the
  sweep's data unit computes) plus the trials (``jit(lax.map(trial))`` with the sweep's settings).
  What the ratio exceeds 1 by is the sweep's own overhead: chunking and host copies, the
  identifiability analysis of trial 0, result assembly. Measured for ``n ≥ 16`` (smaller ``n``
  would compile other chunk sizes).

Under ``vmap`` LM's ``while_loop`` runs until the *slowest* trial of the batch converges
(finished trials idle, masked by ``select``), so a vmapped LM batch costs about
``max(iterations)`` steps per trial instead of ``mean(iterations)``. AdaModW runs a fixed
500 steps, so every trial does the same work.

Grid: LM and AdaModW (registry defaults: LM ``rtol = atol = 1e-6``; AdaModW 500 steps),
``n_seeds`` in (1, 4, 16, 64, 256), samples per experiment 200 and 2000 (80 % for training).
AdaModW at 2000 samples stops at 64 seeds (256 would take ~4 min alone). The loop is timed for
``n ≤ 16`` (its per-trial cost does not depend on ``n``); for larger ``n`` the row repeats the
16-seed throughput, marked ``*``.

Run: ``python benchmarks/bench_sweep.py`` (writes ``benchmarks/results/sweep_cpu.md``; about
10 minutes on the project's 2-core machine, compilation included). ``--quick`` runs a reduced
grid for a smoke test and only prints its table.
"""

from __future__ import annotations

import os
import pathlib
import platform
import sys
import time

import equinox as eqx
import jax
import numpy as np

import jaxcal
from jaxcal._experiments._sweep_trials import _DataTrial, _MethodTrial, trial_keys
from jaxcal.methods import make_method

jaxcal.enable_x64()

SEEDS = (1, 4, 16, 64, 256)
SAMPLES = (200, 2000)
METHODS = ("lm", "adamodw")
LOOP_CAP = 16
SKIP = {("adamodw", 2000, 256)}
HYPER: dict = {}  # registry defaults


def machine_info() -> list[str]:
    cpu = platform.processor() or "unknown"
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = os.getloadavg() if hasattr(os, "getloadavg") else ("?",) * 3
    return [
        f"- CPU: {cpu}, {os.cpu_count()} logical cores; {platform.system()} {platform.release()}",
        f"- Python {platform.python_version()}, JAX {jax.__version__}, devices: {jax.devices()}",
        f"- float64 (`jaxcal.enable_x64()`); load average at start: {', '.join(f'{x:.2f}' for x in load)}",
    ]


def simulate(n_samples: int, n: int):
    """Data of trials 0..n-1 (one vmapped simulation), as the sweep's data unit makes it."""
    robot = jaxcal.robots.hsr_jr680()
    from jaxcal import CableLength, Deviations, ParameterSpace
    from jaxcal._experiments._sweep_trials import _Simulated, _simulation_options
    from jaxcal._simulation._simulate import default_anchor

    m = CableLength(default_anchor(robot))
    opts = _simulation_options(robot, n_samples, 0.5, 0.2, {})
    src = _Simulated(robot, m, None, tuple(sorted(opts.items())))
    dtrial = _DataTrial(src, robot, m, Deviations.zeros(6), ParameterSpace.for_robot(robot), False)
    out = eqx.filter_jit(eqx.filter_vmap(lambda k: dtrial(k)))(trial_keys(jax.random.key(0), 0, n))
    space = jaxcal.identifiability(robot, m, out.split.q_train[0]).space
    return robot, m, space, out.split, out.k_method


def sweep_vs_compiled(name: str, n_samples: int, n: int, robot, m, space, hyper: dict) -> tuple[float, float, float]:
    """``(sweep wall, simulation wall, trials wall)`` in s for ``n`` trials: a warm
    ``jaxcal.sweep`` against the same work as two bare compiled ``lax.map`` functions."""
    from jaxcal import Deviations, ParameterSpace
    from jaxcal._experiments._sweep_trials import _Simulated, _simulation_options

    opts = _simulation_options(robot, n_samples, 0.5, 0.2, {})
    src = _Simulated(robot, m, None, tuple(sorted(opts.items())))
    dtrial = _DataTrial(src, robot, m, Deviations.zeros(6), ParameterSpace.for_robot(robot), True)
    trial = _MethodTrial(robot, m, Deviations.zeros(6), make_method(name, **hyper), space)
    keys = jax.block_until_ready(trial_keys(jax.random.key(0), 0, n))
    sim = eqx.filter_jit(lambda t, ks: jax.lax.map(t, ks))
    run = eqx.filter_jit(lambda t, s, k: jax.lax.map(lambda a: t(*a), (s, k)))
    call = lambda: jaxcal.sweep([name], n, n_samples=n_samples, hyperparameters={name: hyper},  # noqa: E731
                                progress=False)
    out = jax.block_until_ready(sim(dtrial, keys))  # compile + warm-up
    jax.block_until_ready(run(trial, out.split, out.k_method))
    call()  # warm-up (compiles the sweep's units the first time)
    walls = {"sweep": [], "sim": [], "trials": []}
    for _ in range(3):
        t0 = time.perf_counter()
        out = jax.block_until_ready(sim(dtrial, keys))
        walls["sim"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        jax.block_until_ready(run(trial, out.split, out.k_method))
        walls["trials"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        call()
        walls["sweep"].append(time.perf_counter() - t0)
        if walls["sweep"][-1] > 5.0:
            break
    return tuple(float(np.median(walls[k])) for k in ("sweep", "sim", "trials"))


def main(argv) -> None:
    quick = "--quick" in argv
    seeds = (1, 4, 16) if quick else SEEDS
    samples = (200,) if quick else SAMPLES
    t_start = time.perf_counter()
    lines = ["# Sweep throughput on CPU (`benchmarks/bench_sweep.py`)", "", *machine_info(), ""]
    lines += [
        "Trials per second; one trial = calibrate a simulated experiment + evaluate on its test split",
        "(data simulated beforehand). *vmap*: one `jit(vmap(trial))` call over `n` seeds; *lax.map*: one",
        "`jit(lax.map(trial))` call (the trials one after the other inside one compiled function: what",
        "`sweep` does on a single CPU device); *loop*: a Python loop of a jitted single trial. Compilation",
        "is excluded (listed separately). A vmapped LM batch runs until its slowest trial converges",
        "(`its max/mean`); AdaModW always runs 500 steps. *sweep ÷ compiled*: a warm `jaxcal.sweep([method], n)`",
        "(defaults) over the same work done by two bare compiled functions, simulation + trials (both",
        "`lax.map`; walls in seconds in the last column); 1.00 = no overhead of the sweep's own.",
        "",
    ]
    for n_samples in samples:
        robot, m, space, split, kmeth = simulate(n_samples, max(seeds))
        for name in METHODS:
            trial = _MethodTrial(robot, m, jaxcal.Deviations.zeros(6), make_method(name), space, keep_errors=False,
                                 keep_history=False)
            single = jax.jit(lambda s, k, trial=trial: trial(s, k))
            t0 = time.perf_counter()
            one = jax.tree.map(lambda a: a[0], (split, kmeth))
            single_c = single.lower(*one).compile()
            compile_single = time.perf_counter() - t0
            rows = []
            loop_tp = None
            for n in seeds:
                if (name, n_samples, n) in SKIP:
                    continue
                args = jax.block_until_ready(jax.tree.map(lambda a, n=n: a[:n], (split, kmeth)))
                small = n <= LOOP_CAP
                timed = {}
                for how, fn in (("vmap", jax.vmap(lambda s, k, trial=trial: trial(s, k))),
                                ("map", lambda s, k, trial=trial: jax.lax.map(lambda a: trial(*a), (s, k)))):
                    t0 = time.perf_counter()
                    comp = jax.jit(fn).lower(*args).compile()
                    t_comp = time.perf_counter() - t0
                    if small:
                        jax.block_until_ready(comp(*args))  # warm-up call (one-time costs)
                    walls = []
                    for _ in range(3 if small else 1):
                        t0 = time.perf_counter()
                        out = jax.block_until_ready(comp(*args))
                        walls.append(time.perf_counter() - t0)
                    timed[how] = (n / min(walls), t_comp, np.asarray(out.n_iterations))
                if small:
                    # per-trial arguments prepared outside the timer (indexing compiles tiny programs);
                    # the n-seed loop is repeated to make at least LOOP_CAP calls
                    items = jax.block_until_ready([jax.tree.map(lambda a, i=i: a[i], args) for i in range(n)])
                    jax.block_until_ready(single_c(*items[0]))  # warm-up
                    reps = -(-LOOP_CAP // n)
                    t0 = time.perf_counter()
                    for _ in range(reps):
                        for item in items:
                            jax.block_until_ready(single_c(*item))
                    loop_tp = reps * n / (time.perf_counter() - t0)
                    loop_cell = f"{loop_tp:.2f}"
                else:
                    loop_cell = f"{loop_tp:.2f}*"
                (vm_tp, vm_c, its), (mp_tp, mp_c, _) = timed["vmap"], timed["map"]
                if n >= LOOP_CAP:
                    sw, sim, tr = sweep_vs_compiled(name, n_samples, n, robot, m, space, HYPER.get(name, {}))
                    sw_cells = [f"{sw / (sim + tr):.2f}", f"{sw:.2f} / {sim:.2f} + {tr:.2f}"]
                    print(f"  sweep {sw:.2f} s vs simulation {sim:.2f} s + trials {tr:.2f} s", file=sys.stderr, flush=True)
                else:
                    sw_cells = ["—", "—"]
                rows.append([n, f"{vm_tp:.2f}", f"{mp_tp:.2f}", loop_cell, f"{vm_tp / loop_tp:.2f}",
                             f"{mp_tp / loop_tp:.2f}", f"{its.max()}/{its.mean():.1f}", f"{vm_c:.1f} / {mp_c:.1f}",
                             *sw_cells])
                print(f"{name} samples={n_samples} n={n}: vmap {vm_tp:.2f}/s, lax.map {mp_tp:.2f}/s, loop {loop_cell}/s",
                      file=sys.stderr, flush=True)
            lines += [f"## {name}, {n_samples} samples per experiment ({int(0.8 * n_samples)} for training)", ""]
            lines.append(jaxcal.format_table(
                rows, ["seeds", "vmap trials/s", "lax.map trials/s", "loop trials/s", "vmap ÷ loop", "map ÷ loop",
                       "its max/mean", "compile vmap / map (s)", "sweep ÷ compiled",
                       "sweep / sim + trials (s)"], markdown=True))
            lines += ["", f"Single-trial compile: {compile_single:.1f} s.", ""]
    skipped = [f"{m} × {s} samples × {n} seeds" for m, s, n in sorted(SKIP) if s in samples and n in seeds]
    if skipped:
        lines += ["Skipped (too slow for the 10-minute budget): " + "; ".join(skipped) + ".", ""]
    lines += ["`*` loop throughput measured over 16 seeds (the loop's per-trial cost does not depend on n).", ""]
    load = os.getloadavg() if hasattr(os, "getloadavg") else ("?",) * 3
    lines += [f"Total benchmark wall time {time.perf_counter() - t_start:.0f} s (compilation included); "
              f"load average at the end: {', '.join(f'{x:.2f}' for x in load)}.", ""]
    text = "\n".join(lines)
    print(text)
    if not quick:
        out = pathlib.Path(__file__).resolve().parent / "results" / "sweep_cpu.md"
        out.parent.mkdir(exist_ok=True)
        out.write_text(text)


if __name__ == "__main__":
    main(sys.argv[1:])
