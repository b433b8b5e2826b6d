"""End-to-end latency of a calibration as a user meets it (issue: the command line as a user meets it).

Three numbers, on the default simulated experiment (HSR-JR680, 2 000 draw-wire samples, 1 600 for
training), next to ``scipy.optimize.least_squares(method="lm")`` on the same data:

1. a warm ``jaxcal.calibrate(..., "lm")`` call, end to end (identifiability, scaling, the solve,
   uncertainty and diagnostics, result assembly) vs scipy end to end (numeric Jacobian, NumPy FK);
2. the first ``calibrate`` in a fresh Python process with a warm persistent compilation cache
   (``jax_compilation_cache_dir`` set, every compilation cached);
3. ``jaxcal calibrate data.csv --robot hsr_jr680`` wall time with a warm cache (the CLI turns the
   cache on by default), and where its time goes (``--verbose``).

Run: ``python benchmarks/bench_latency.py`` (a minute or two). Writes
``benchmarks/results/latency_cpu.md``. The 2-core machine may be shared and its speed drifts: the
script reports the load average, times the warm ``calibrate`` calls and the scipy fits in
interleaved rounds (:data:`ROUNDS` × :data:`PER_ROUND` calls and one fit) and takes medians.
"""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys
import tempfile
import time
import warnings

import jax
import numpy as np
from _common import machine
from bench_lm_scipy import numpy_cable_model
from scipy.optimize import least_squares

import jaxcal

jaxcal.enable_x64()
HERE = pathlib.Path(__file__).resolve().parent
#: the warm calls are timed in ROUNDS rounds of PER_ROUND ``calibrate`` calls and one scipy fit
ROUNDS, PER_ROUND = 9, 15

FRESH = """
import time, warnings
t0 = time.perf_counter()
import jax
jax.config.update("jax_compilation_cache_dir", {cache!r})
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
import jaxcal
jaxcal.enable_x64()
t1 = time.perf_counter()
from jaxcal._simulation._simulate import default_anchor  # (untimed, as the data and models)
data = jaxcal.load_csv({csv!r})
robot = jaxcal.robots.hsr_jr680()
m = jaxcal.CableLength(default_anchor(robot))
t2 = time.perf_counter()
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    res = jaxcal.calibrate(robot, m, data, "lm")
t3 = time.perf_counter()
print(f"{{t1 - t0:.4f}} {{t3 - t2:.4f}} {{res.compile_time_s:.4f}}")
"""


def main() -> None:
    load = os.getloadavg()
    ex = jaxcal.simulate_experiment(jax.random.key(0))
    robot, meas = ex.robot, ex.measurement
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(5):  # compiled, then warm
            res = jaxcal.calibrate(robot, meas, ex.train, "lm")
    predict = numpy_cable_model(robot, res.space, np.asarray(meas.anchor), np.asarray(ex.train.q))
    yn = np.asarray(ex.train.y)

    def scipy_fit():
        return least_squares(lambda x: predict(x) - yn, np.zeros(res.space.n_free), method="lm")

    scipy_fit()
    # interleaved rounds (ROUNDS × (PER_ROUND calibrate calls, one scipy fit)), so that both see
    # the same load on a shared machine whose speed drifts by ±20 % within minutes
    ts, tss = [], []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(ROUNDS):
            for _ in range(PER_ROUND):
                t = time.perf_counter()
                res = jaxcal.calibrate(robot, meas, ex.train, "lm")
                ts.append(time.perf_counter() - t)
            t = time.perf_counter()
            sol = scipy_fit()
            tss.append(time.perf_counter() - t)
    t_cal, t_solve = float(np.median(ts)), res.wall_time_s
    q_cal = np.percentile(ts, [25, 75])
    t_scipy = float(np.median(tss))
    q_scipy = np.percentile(tss, [25, 75])
    gap = float(np.max(np.abs(sol.x - res.x)))

    with tempfile.TemporaryDirectory() as tmp:
        csv = pathlib.Path(tmp) / "data.csv"
        cache = pathlib.Path(tmp) / "cache"
        subprocess.run([sys.executable, "-m", "jaxcal.cli", "simulate", "--out", str(csv), "--samples", "2000"],
                       check=True, capture_output=True)
        env = os.environ | {"JAXCAL_CACHE_DIR": str(cache)}
        code = FRESH.format(cache=str(cache), csv=str(csv))
        fresh = []
        for i in range(4):  # first run fills the cache
            out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True, env=env)
            if i:
                fresh.append([float(v) for v in out.stdout.split()])
        fresh = np.median(np.asarray(fresh), axis=0)
        cli = []
        verbose = ""
        for i in range(4):
            t = time.perf_counter()
            out = subprocess.run([sys.executable, "-m", "jaxcal.cli", "calibrate", str(csv), "--robot", "hsr_jr680",
                                  "--verbose"], capture_output=True, text=True, env=env)
            if i:
                cli.append(time.perf_counter() - t)
                verbose = next((ln for ln in out.stdout.splitlines() if ln.startswith("times:")), verbose)
        t_cli = float(np.median(cli))
        helps = []
        for _ in range(5):
            t = time.perf_counter()
            subprocess.run([sys.executable, "-m", "jaxcal.cli", "--help"], check=True, capture_output=True, env=env)
            helps.append(time.perf_counter() - t)
        t_help = float(np.median(helps))
    lines = [
        "# End-to-end latency: calibrate() and the command line",
        "",
        f"Machine: {machine()}; load average at start {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} "
        "(a shared machine inflates every number). Generated by `python benchmarks/bench_latency.py`.",
        "Data: default simulated experiment (HSR-JR680, 2 000 draw-wire samples; 1 600 train), LM; `calibrate()` with no prior (its default), the CLI with its measured-data defaults.",
        "",
        "| what | time | goal |",
        "|---|---:|---:|",
        f"| warm `jaxcal.calibrate(..., \"lm\")`, end to end (median of {len(ts)}; quartiles "
        f"{1e3 * q_cal[0]:.1f}–{1e3 * q_cal[1]:.1f}) | {1e3 * t_cal:.1f} ms | |",
        f"| of which the compiled solve (last call) | {1e3 * t_solve:.1f} ms | |",
        f"| `scipy.optimize.least_squares(method=\"lm\")`, numeric Jacobian (median of {len(tss)}, interleaved; quartiles "
        f"{1e3 * q_scipy[0]:.1f}–{1e3 * q_scipy[1]:.1f}) | {1e3 * t_scipy:.1f} ms | |",
        f"| **speed-up, end to end** (ratio of the medians) | **{t_scipy / t_cal:.1f}×** | ≥ 15× |",
        f"| fresh process, warm persistent cache: import jax + jaxcal | {fresh[0]:.2f} s | |",
        f"| fresh process, warm persistent cache: first `calibrate()` | **{fresh[1]:.2f} s** (compilation loaded: {fresh[2]:.2f} s) | ≤ 1 s |",
        f"| `jaxcal calibrate data.csv --robot hsr_jr680` (measured-data defaults: prior + Huber), warm cache, wall (median of 3) | **{t_cli:.2f} s** | ≤ 2.0 s |",
        f"| `jaxcal --help`, wall (median of 5) | **{t_help:.2f} s** | ≤ 0.5 s |",
        "",
        f"Largest parameter difference jaxcal vs scipy: {gap:.2e} (rad/mm). CLI `--verbose`: {verbose}",
    ]
    out_path = HERE / "results" / "latency_cpu.md"
    out_path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
