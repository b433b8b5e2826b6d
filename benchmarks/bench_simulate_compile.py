"""What a first ``simulate_experiment`` costs: its XLA programs' compile time, fresh processes.

For each case (robot, measurement model, sample counts) one fresh Python process with the
persistent compilation cache off (``JAXCAL_CACHE_DIR=off``) and ``JAX_LOG_COMPILES=1`` simulates
the first sample count (the cold call), then the second one (a new size in a warm process).
Reports the wall time of each call and the compile seconds of the simulation's programs, for this
checkout and for any ``--source DIR`` (another checkout, e.g. an older commit in a ``git
worktree``). Appends a section to ``benchmarks/results/compile_cpu.md`` (``--out``) with the load.

Run: ``python benchmarks/bench_simulate_compile.py [--source /tmp/old --label before]``.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_compile import _DONE  # noqa: E402  (the compile log's "Finished XLA compilation" line)

CASES = [("hsr_jr680", "cable", (2000, 1000)), ("hsr_jr680", "position", (1500, 300)),
         ("puma560", "pose", (200, 400))]

CHILD = """
import json, sys, time
import jax
jax.config.update("jax_enable_x64", True)
import jaxcal
robot = jaxcal.robots.get_robot(sys.argv[1])
measurement = {"cable": None, "position": jaxcal.Position(), "pose": jaxcal.Pose()}[sys.argv[2]]
walls = []
for i, n in enumerate(json.loads(sys.argv[3])):
    t = time.perf_counter()
    ex = jaxcal.simulate_experiment(jax.random.key(i), robot, n_samples=n, measurement=measurement)
    jax.block_until_ready(ex.train.y)
    walls.append(time.perf_counter() - t)
    print("CALL DONE", file=sys.stderr, flush=True)
print(json.dumps(walls))
"""


def run_case(source: str | None, robot: str, kind: str, sizes) -> dict:
    env = dict(os.environ, JAXCAL_CACHE_DIR="off", JAX_LOG_COMPILES="1")
    env["PYTHONPATH"] = str(HERE.parent) + os.pathsep + env.get("PYTHONPATH", "")
    if source:
        env["PYTHONPATH"] = source + os.pathsep + env["PYTHONPATH"]
    # from an empty directory: ``python -c`` puts the working directory first on sys.path, and
    # in this checkout that would import its jaxcal instead of ``source``'s
    with tempfile.TemporaryDirectory() as cwd:
        p = subprocess.run([sys.executable, "-c", CHILD, robot, kind, json.dumps(list(sizes))], env=env,
                           capture_output=True, text=True, timeout=900, cwd=cwd)
    if p.returncode:
        raise RuntimeError(p.stderr[-3000:])
    walls = json.loads(p.stdout.strip().splitlines()[-1])
    # compile seconds per call: the log lines before each "CALL DONE"
    compile_s, names = [], []
    for part in p.stderr.split("CALL DONE")[: len(sizes)]:
        done = [(m.group(1), float(m.group(2))) for m in _DONE.finditer(part)]
        compile_s.append(sum(s for _, s in done))
        names.append(", ".join(f"`{n}` {s:.1f}" for n, s in sorted(done, key=lambda d: -d[1])[:2]))
    return dict(walls=walls, compile_s=compile_s, names=names)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--source", action="append", default=[], help="another jaxcal checkout (repeatable, with --label)")
    ap.add_argument("--label", action="append", default=[])
    ap.add_argument("--out", default=str(HERE / "results" / "compile_cpu.md"))
    args = ap.parse_args()
    from _common import append_section

    runs = [(None, "this checkout")] + list(zip(args.source, args.label or args.source))
    load0 = os.getloadavg()[0]
    rows = ["| code | robot, model | samples | wall (s) | compiled (s) | slowest programs (s) |",
            "|---|---|---|---|---|---|"]
    for src, label in runs:
        for robot, kind, sizes in CASES:
            r = run_case(src, robot, kind, sizes)
            for i, n in enumerate(sizes):
                what = "first call" if i == 0 else "then"
                rows.append(f"| {label} | {robot}, {kind} | {n} ({what}) | {r['walls'][i]:.2f} | "
                            f"{r['compile_s'][i]:.1f} | {r['names'][i]} |")
            print(rows[-2], rows[-1], sep="\n", flush=True)
    append_section(args.out, "A first simulate_experiment: compile time of its programs", "`python benchmarks/"
                   "bench_simulate_compile.py`: per case one fresh process, no persistent cache, "
                   "`JAX_LOG_COMPILES=1`; a cold call, then a second sample count in the same process.",
                   "\n".join(rows), (load0, os.getloadavg()[0]))


if __name__ == "__main__":
    main()
