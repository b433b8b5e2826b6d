"""GPU acceptance numbers of issue 10 ("Performance II") in one command.

What is measured (float64, one process, no persistent compilation cache unless stated):

1. ``jaxcal.sweep(["lm"], N, n_samples=2000)`` (defaults: ``batching="auto"`` = vmap on a GPU,
   one chunk of up to 1 024 trials per device): the first call in the process (*cold*: every
   compilation included) and the median of 3 later calls (*warm*).
2. The same trials as one bare compiled function, ``jax.jit(jax.vmap(trial))`` over the N
   trials' data (simulated beforehand), compiled with jaxcal's XLA options
   (``jaxcal._core._xla.compiler_options``: ``xla_gpu_autotune_level=0`` unless ``JAXCAL_XLA_OPTIONS``
   says otherwise): compile time, and the median of 5 calls after compilation.
3. A warm ``jaxcal.calibrate(..., "lm")`` on the default experiment's training data, end to end
   (median of 21 calls after one that compiles).
4. ``jaxcal reproduce`` at paper scale (8 methods × 20 seeds × 2 000 samples, ``--no-figures
   --quiet``) in a fresh process: once with an empty persistent compilation cache (*cold*), once
   more with the cache it filled (*warm*), each into a new output directory (no resumed chunks).

Run: ``python benchmarks/bench_gpu.py [--trials N] [--out FILE]`` (default N = 1000, writes
``benchmarks/results/sweep_gpu.md``); ``--skip-reproduce`` leaves out item 4. On a machine with
several users of the GPU set ``XLA_PYTHON_CLIENT_PREALLOCATE=false``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import subprocess
import sys
import tempfile
import time

import jax
import numpy as np

import jaxcal

jaxcal.enable_x64()


def _machine() -> list[str]:
    dev = jax.devices()[0]
    lines = [f"- Device: {dev.device_kind} ({dev.platform}), {len(jax.devices())} device(s); "
             f"{os.cpu_count()} CPU cores",
             f"- JAX {jax.__version__} (jaxlib {getattr(jax.lib, '__version__', '?')}), Python {sys.version.split()[0]}, "
             "float64"]
    from jaxcal._core._xla import ENV_VAR, compiler_options

    lines.append(f"- jaxcal's XLA options here: {compiler_options(dev.platform)} (${ENV_VAR}="
                 f"{os.environ.get(ENV_VAR)!r}; XLA_FLAGS={os.environ.get('XLA_FLAGS')!r})")
    return lines


def _compiled_trials(n: int, n_samples: int):
    """``(compile s, run s)`` of ``jit(vmap(trial))`` over ``n`` LM trials (data simulated first)."""
    import equinox as eqx
    from bench_sweep import simulate  # the same simulated trials as the CPU sweep benchmark

    from jaxcal import Deviations
    from jaxcal._core._xla import compile_lowered
    from jaxcal._experiments._sweep_trials import _MethodTrial, _Split
    from jaxcal.methods import make_method

    robot, m, space, split, k_method = simulate(n_samples, n)
    out = _Split(split.q_train, split.y_train, split.q_test, split.y_test, None)
    trial = _MethodTrial(robot, m, Deviations.zeros(6), make_method("lm"), space)
    dyn, static = eqx.partition(trial, eqx.is_array)
    f = jax.jit(lambda d, s, k: jax.vmap(lambda a, b: eqx.combine(d, static)(a, b))(s, k))
    t0 = time.perf_counter()
    comp = compile_lowered(f.lower(dyn, out, k_method))
    t_compile = time.perf_counter() - t0
    jax.block_until_ready(comp(dyn, out, k_method))
    ts = []
    for _ in range(5):
        t0 = time.perf_counter()
        res = jax.block_until_ready(comp(dyn, out, k_method))
        ts.append(time.perf_counter() - t0)
    its = np.asarray(res.n_iterations)
    return t_compile, float(np.median(ts)), its


def _reproduce(cache_dir: str, out_dir: str) -> tuple[float, str]:
    env = dict(os.environ, JAXCAL_CACHE_DIR=cache_dir)
    cmd = [sys.executable, "-m", "jaxcal.cli", "reproduce", "--out", out_dir, "--no-figures", "--quiet"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-3000:])
    return wall, proc.stdout


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=1000)
    ap.add_argument("--samples", type=int, default=2000)
    ap.add_argument("--out", default=str(pathlib.Path(__file__).resolve().parent / "results" / "sweep_gpu.md"))
    ap.add_argument("--skip-reproduce", action="store_true")
    args = ap.parse_args(argv)
    n, ns = args.trials, args.samples
    lines = ["# GPU acceptance numbers (`benchmarks/bench_gpu.py`)", "", *_machine(), ""]
    rows = []

    # 1. the sweep, cold (first call in this process) then warm
    t0 = time.perf_counter()
    res = jaxcal.sweep(["lm"], n, n_samples=ns, progress=True)
    cold = time.perf_counter() - t0
    compile_cold = {k: r.compile_time_s for k, r in res.runs.items()}
    warm = []
    for _ in range(3):
        t0 = time.perf_counter()
        res = jaxcal.sweep(["lm"], n, n_samples=ns, progress=False)
        warm.append(time.perf_counter() - t0)
    lm = res["lm"]
    rows.append([f"`jaxcal.sweep([\"lm\"], {n}, n_samples={ns})`, cold (first call, compilation included)",
                 f"{cold:.2f} s"])
    rows.append(["the same, warm (median of 3 later calls)", f"{np.median(warm):.3f} s (all: "
                 + ", ".join(f"{w:.3f}" for w in warm) + ")"])
    rows.append(["its settings", f"batching {res.settings['batching']}, chunk {res.settings['chunk_size']}, "
                 f"lm unit compiled in {compile_cold['lm']:.1f} s (cold call); mean test RMSE "
                 f"{np.mean(lm.test.rmse):.4f} mm, status {lm.summary()['status']}"])
    print(rows, file=sys.stderr, flush=True)

    # 2. the bare compiled trials
    t_comp, t_run, its = _compiled_trials(n, ns)
    rows.append([f"`jit(vmap(trial))`, {n} LM trials, XLA compile with jaxcal's options", f"{t_comp:.2f} s"])
    rows.append(["the same, run after compile (median of 5)", f"{t_run * 1e3:.1f} ms (iterations max/mean "
                 f"{its.max()}/{its.mean():.1f})"])
    rows.append(["warm sweep ÷ compiled trials", f"{np.median(warm) / t_run:.1f}×"])
    print(rows[-3:], file=sys.stderr, flush=True)

    # 3. warm calibrate() latency on the paper experiment's data (LM, no prior: calibrate's default)
    ex = jaxcal.simulate_experiment(jax.random.key(0), n_samples=ns)
    jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm")
    lat = []
    for _ in range(21):
        t0 = time.perf_counter()
        r = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm")
        lat.append(time.perf_counter() - t0)
    rows.append([f"warm `jaxcal.calibrate(..., \"lm\")` on {ex.train.n} samples, end to end (median of 21)",
                 f"{np.median(lat) * 1e3:.1f} ms (quartiles {np.percentile(lat, 25) * 1e3:.1f}–"
                 f"{np.percentile(lat, 75) * 1e3:.1f}; compiled solve {r.wall_time_s * 1e3:.1f} ms)"])
    print(rows[-1], file=sys.stderr, flush=True)

    # 4. jaxcal reproduce, paper scale, cold and warm persistent cache
    if not args.skip_reproduce:
        with tempfile.TemporaryDirectory() as tmp:
            cache = os.path.join(tmp, "cache")
            w1, out1 = _reproduce(cache, os.path.join(tmp, "r1"))
            rows.append(["`jaxcal reproduce` (8 methods × 20 seeds × 2 000), cold, empty compilation cache",
                         f"{w1:.1f} s"])
            print(rows[-1], file=sys.stderr, flush=True)
            w2, out2 = _reproduce(cache, os.path.join(tmp, "r2"))
            rows.append(["the same, warm persistent compilation cache (new output directory)", f"{w2:.1f} s"])
            print(rows[-1], file=sys.stderr, flush=True)
            n_files = sum(1 for _ in pathlib.Path(cache).rglob("*") if _.is_file())
            rows.append(["compilation-cache entries written", str(n_files)])
            table3 = [ln for ln in out1.splitlines() if ln.strip()][:16]
    lines.append(jaxcal.format_table(rows, ["what", "measured"], markdown=True))
    if not args.skip_reproduce:
        lines += ["", "Table III of the cold reproduce run (first lines):", "", "```", *table3, "```"]
    text = "\n".join(lines) + "\n"
    print(text)
    pathlib.Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    pathlib.Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
