"""What a user waits for when holding out one real motion-capture session (issue 33's acceptance row).

FIGAROH's TIAGo Vicon files (``tests/data/figaroh_tiago_vicon``, the three rigid-marker gripper3
sessions, the TIAGo URDF from the figaroh-examples mirror), ``jaxcal.holdout_session`` with the
settings of ``bench_figaroh.py``'s leave-one-session-out table (prior ``default``, Huber loss):
calibrate on two sessions, register the held-out session's new frame on its rows with the robot
fixed, and predict it. Each run is a fresh process: first with an empty persistent cache (a new
user's first run), then with the cache that run left (the next day). In each process the three
sessions are held out in turn: the first pays the compilation, the other two show what is left.
The held-out RMSEs must equal ``figaroh_cpu.md``'s table (3.51, 3.52, 3.44 mm).
Appends a section to ``benchmarks/results/compile_cpu.md``.

    PYTHONPATH=. python benchmarks/bench_holdout.py
"""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

HERE = pathlib.Path(__file__).resolve().parent
OUT = HERE / "results" / "compile_cpu.md"

WORKER = r"""
import json, sys, time, warnings
t0 = time.perf_counter()
import jaxcal
jaxcal.enable_x64()
sys.path.insert(0, sys.argv[1])
import bench_figaroh as b
text = b.tiago_urdf_text()
if text is None:
    print(json.dumps({"skip": "TIAGo URDF not available"}))
    raise SystemExit
chain = b.tiago_chain(text)
data = b.load_figaroh_vicon()
sessions = ("gripper3_base1", "gripper3_base2", "gripper3_base3")
d3 = data.subset(b._session_rows(data, sessions))
t_load = time.perf_counter() - t0
rows = []
for s in sessions:
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = jaxcal.holdout_session(chain, d3, s, prior=jaxcal.Prior.parse("default"), loss="huber")
    rows.append(dict(session=s, wall=time.perf_counter() - t, before=h.before_rmse, after=h.after_rmse,
                     registered=list(h.registered)))
print(json.dumps(dict(imports_and_load=t_load, rows=rows)))
"""


def run(cache: str) -> dict:
    env = dict(os.environ, JAXCAL_CACHE_DIR=cache, JAX_PLATFORMS="cpu")
    env["PYTHONPATH"] = str(HERE.parent) + os.pathsep + env.get("PYTHONPATH", "")
    t = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", WORKER, str(HERE)], env=env, capture_output=True, text=True, check=True)
    out = json.loads(p.stdout.strip().splitlines()[-1])
    out["process"] = time.perf_counter() - t
    return out


def main() -> None:
    sys.path.insert(0, str(HERE))
    from _common import append_section

    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        cold = run(str(pathlib.Path(tmp) / "cache"))
        if "skip" in cold:
            print(cold["skip"])
            return
        warm = run(str(pathlib.Path(tmp) / "cache"))
    load1 = os.getloadavg()[0]
    lines = ["| process | imports + data (s) | held-out session | holdout_session (s) | held-out before → after (mm) |",
             "|---|---|---|---|---|"]
    for label, r in (("fresh, empty cache", cold), ("fresh, the cache of the run above", warm)):
        for i, row in enumerate(r["rows"]):
            head = (label, f"{r['imports_and_load']:.1f}") if i == 0 else ("", "")
            lines.append(f"| {head[0]} | {head[1]} | {row['session']} | {row['wall']:.1f} | "
                         f"{row['before']:.2f} → {row['after']:.2f} |")
    table = "\n".join(lines)
    print(table)
    append_section(OUT, "Holding out one real motion-capture session",
                   "`PYTHONPATH=. python benchmarks/bench_holdout.py`: FIGAROH's TIAGo Vicon gripper3 sessions "
                   "(63 rows, 8-joint URDF chain), `jaxcal.holdout_session(chain, data, session, prior=default, "
                   "loss='huber')` for each of the three sessions in one fresh process (the first pays the "
                   "compilation), first with an empty persistent cache, then again with the cache it left. "
                   f"Whole processes: {cold['process']:.1f} s and {warm['process']:.1f} s.", table, (load0, load1))


if __name__ == "__main__":
    main()
