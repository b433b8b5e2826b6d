"""A combined tracker + camera fit: each row's own residual entries vs rows padded to the widest block.

A laser tracker (500 rows, 3 entries each: the tool point) and an eye-in-hand camera (30 images of
a 9×6 checkerboard: 108 entries each) on hsr_jr680, σ of both blocks given (one fit, no variance
rounds), LM, the measured defaults otherwise. ``own entries`` is jaxcal as it is: the residual
vector and the Jacobian hold each row's own entries (4 740); ``padded`` switches that off
(``Combined.residual_entries`` → ``None``): every row carries the camera's 108 entries (57 240,
the tracker's padded with zeros), as before. Each mode runs in a fresh process without the
persistent cache (``JAXCAL_CACHE_DIR=off``): the first call, then three warm calls.
Appends a section to ``benchmarks/results/camera_cpu.md``.

    PYTHONPATH=. python benchmarks/bench_combined.py
"""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys

OUT = pathlib.Path(__file__).resolve().parent / "results" / "camera_cpu.md"

WORKER = r"""
import json, sys, time, warnings
import jax
import numpy as np
import jaxcal
jaxcal.enable_x64()
from jaxcal import Block, Camera, Position, calibrate_blocks
from jaxcal._sensors._blocks import Combined, combine
from jaxcal._simulation._simulate import simulate_experiment
from jaxcal._simulation._simulate_sensors import simulate_camera
if sys.argv[1] == "padded":
    Combined.residual_entries = lambda self, n: None
robot = jaxcal.robots.hsr_jr680()
q_c, y_c, cam, truth = simulate_camera(jax.random.key(0), robot, n_views=30, noise_px=0.3)
from jaxcal._core._params import layout_for
layout = layout_for(robot)
dh = jaxcal.Deviations({g: v for g, v in truth.values.items() if g in layout.group_names}, layout)
ex = simulate_experiment(jax.random.key(20), robot, n_samples=1000, noise_std=0.05, measurement=Position(),
                         true_deviations=dh.replace(tool=np.array([20.0, -10.0, 90.0])), test_fraction=0.5)
nominal = Camera(cam.points, cam.intrinsics, cam.mount, image_size=cam.image_size)
blocks = [Block("tracker", Position(), ex.train, 0.05, extras="tool,base"), Block("camera", nominal, (q_c, y_c), 0.3)]
model, q, y = combine(robot, blocks)
entries = model.residual_entries(q.shape[0])
rows = []
for i in range(4):
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate_blocks(robot, blocks, method="lm")
    rows.append(dict(wall=time.perf_counter() - t, solve=res.wall_time_s, compile=res.compile_time_s,
                     its=int(res.n_iterations), rmse=[s.rmse for s in res.blocks]))
print(json.dumps(dict(entries=int(q.shape[0] * model.size if entries is None else entries.size), rows=rows)))
"""


def run(mode: str) -> dict:
    env = dict(os.environ, JAXCAL_CACHE_DIR="off", JAX_PLATFORMS="cpu")
    root = pathlib.Path(__file__).resolve().parents[1]
    env["PYTHONPATH"] = str(root) + os.pathsep + env.get("PYTHONPATH", "")
    p = subprocess.run([sys.executable, "-c", WORKER, mode], env=env, capture_output=True, text=True, check=True)
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    from _common import append_section

    load0 = os.getloadavg()[0]
    out = {mode: run(mode) for mode in ("own entries", "padded")}
    load1 = os.getloadavg()[0]
    lines = ["| mode | residual entries | first call (s) | its solve compile (s) | warm calls (s) | "
             "their LM solves (s) | iterations | train RMSE tracker mm / camera px |",
             "|---|---|---|---|---|---|---|---|"]
    for mode, r in out.items():
        first, warm = r["rows"][0], r["rows"][1:]
        walls = ", ".join(f"{w['wall']:.2f}" for w in warm)
        solves = ", ".join(f"{w['solve']:.2f}" for w in warm)
        lines.append(f"| {mode} | {r['entries']:,} | {first['wall']:.1f} | {first['compile']:.1f} | {walls} | "
                     f"{solves} | {first['its']} | {first['rmse'][0]:.5f} / {first['rmse'][1]:.4f} |")
    table = "\n".join(lines)
    print(table)
    append_section(OUT, "A tracker and a camera in one fit: each row's own entries",
                   "`PYTHONPATH=. python benchmarks/bench_combined.py`: 500 tracker rows (3 entries) and 30 camera "
                   "images (108 entries) on hsr_jr680, σ given, `calibrate_blocks(..., method='lm')`, a fresh "
                   "process per mode, no persistent cache. *padded*: every row carries the widest block's "
                   "entries, the narrower ones zero (the code before each row kept its own entries).",
                   table, (load0, load1))


if __name__ == "__main__":
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
    main()
