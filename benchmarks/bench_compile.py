"""What a command-line user waits for: XLA programs and wall time of `jaxcal calibrate`, then
`jaxcal evaluate` and `jaxcal report` on the same set-up, with an empty and with a warm
persistent compilation cache (issue 33).

The set-up is the issue's: a 1 500-row laser-tracker file (`jaxcal simulate --measurement position
--samples 1500`), calibrated with `--measurement position --estimate base,tool` (the measured-data
defaults: prior + Huber), evaluated on a second file of the same robot (another seed), reported as
HTML. Each command runs in a fresh process with ``JAX_LOG_COMPILES=1`` and Python's bytecode
cached (``PYTHONPYCACHEPREFIX`` in the work directory: what a pip install leaves); the script counts the
programs XLA compiled ("Finished XLA compilation of …") and those loaded from the cache ("cache
hit"), sums their compile seconds and lists the slowest programs. Before them, what every process
pays before jaxcal does anything (issue 52): ``python -c "import ml_dtypes"``, ``"import jax"`` and
``"import jaxcal; jaxcal.calibrate"`` (the library's calibration chain; ``import jaxcal`` alone is
lazy), each the fastest of ``--import-runs`` fresh processes.

``--source DIR`` runs another checkout of jaxcal (``PYTHONPATH``), e.g. an older commit in a ``git
worktree``; ``--python EXE`` another interpreter (a virtual environment with other dependency
versions, e.g. ml_dtypes 0.7.0 against the bounded one; jaxcal from this checkout unless a
``--source`` is given too). Each repeatable, paired with ``--label`` in order; the set-ups run one
after the other in one invocation. Appends a dated section to ``benchmarks/results/compile_cpu.md``
(``--out``) with the machine and the load average.

Run: ``python benchmarks/bench_compile.py [--python /tmp/venv-old/bin/python --label before]``.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import pathlib
import re
import subprocess
import sys
import tempfile
import time

HERE = pathlib.Path(__file__).resolve().parent
_DONE = re.compile(r"Finished XLA compilation of (\S+) in ([0-9.]+) sec")


def run_cli(args: list[str], env: dict, cwd: str, python: str = sys.executable) -> dict:
    """One ``jaxcal`` command in a fresh process: wall time, exit code, compiled programs."""
    t = time.perf_counter()
    p = subprocess.run([python, "-m", "jaxcal.cli", *args], env=env, cwd=cwd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    done = [(m.group(1), float(m.group(2))) for m in _DONE.finditer(p.stderr)]
    hits = p.stderr.count("Persistent compilation cache hit")
    slow = collections.Counter()
    for name, s in done:
        slow[name] += s
    return dict(cmd=" ".join(["jaxcal", *args]), rc=p.returncode, wall=wall, programs=len(done),
                compile_s=sum(s for _, s in done), hits=hits, slowest=slow.most_common(4),
                err=p.stderr[-800:] if p.returncode not in (0, 1) else "")


#: what every process pays before jaxcal does anything: (row label, the statement timed)
IMPORTS = (("import ml_dtypes", "import ml_dtypes"), ("import jax", "import jax"),
           ("import jaxcal; jaxcal.calibrate", "import jaxcal; jaxcal.calibrate"))


def import_times(python: str, env: dict, cwd: str, runs: int) -> dict:
    """Wall time of each :data:`IMPORTS` statement in a fresh process, the fastest of ``runs`` (s),
    with the version of ml_dtypes the interpreter has."""
    out = {}
    for label, stmt in IMPORTS:
        best = float("inf")
        for _ in range(runs):
            p = subprocess.run([python, "-c", f"import time; t = time.perf_counter(); {stmt}; "
                                "print(time.perf_counter() - t)"], env=env, cwd=cwd, capture_output=True, text=True,
                               check=True)
            best = min(best, float(p.stdout.split()[-1]))
        out[label] = best
    out["ml_dtypes version"] = subprocess.run([python, "-c", "import ml_dtypes; print(ml_dtypes.__version__)"],
                                              env=env, cwd=cwd, capture_output=True, text=True,
                                              check=True).stdout.strip()
    return out


def round_trip(source: str | None, rows: int, python: str = sys.executable, import_runs: int = 3) -> dict:
    """Import times; then with an empty cache: simulate (untimed), calibrate, evaluate, report; then
    calibrate and evaluate again (warm)."""
    with tempfile.TemporaryDirectory() as work:
        env = {k: v for k, v in os.environ.items()
               if not k.startswith(("JAX_", "JAXCAL_")) and k != "PYTHONDONTWRITEBYTECODE"}
        # Python's bytecode cached (in the work directory), as after a pip install: the untimed
        # simulation below writes it, so no timed command compiles jaxcal's source
        env.update(JAX_PLATFORMS="cpu", JAXCAL_CACHE_DIR=str(pathlib.Path(work) / "cache"),
                   PYTHONPYCACHEPREFIX=str(pathlib.Path(work) / "pycache"))
        if source or python != sys.executable:  # another checkout, or this one under another interpreter
            env["PYTHONPATH"] = (source or str(HERE.parent)) + os.pathsep + env.get("PYTHONPATH", "")
        subprocess.run([python, "-m", "jaxcal.cli", "simulate", "--out", "track.csv", "--samples", str(rows),
                        "--measurement", "position", "--seed", "3"], env=env, cwd=work, check=True,
                       capture_output=True)
        shutil_rm(pathlib.Path(work) / "cache")  # the simulation's programs do not count
        env["JAX_LOG_COMPILES"] = "1"
        cal = ["calibrate", "track.csv", "--robot", "hsr_jr680", "--measurement", "position", "--estimate",
               "base,tool", "--out", "res.json"]
        imports = import_times(python, env, work, import_runs)  # after the simulation: bytecode cached
        out = {"calibrate (empty cache)": run_cli(cal, env, work, python)}
        # a new day of the same robot and set-up (same true deviations, new poses and noise), made
        # with the cache the calibration filled (not counted)
        day2 = ["simulate", "--like", "res.json", "--out", "track2.csv", "--seed", "4"]
        if subprocess.run([python, "-m", "jaxcal.cli", *day2], env=env, cwd=work, capture_output=True
                          ).returncode != 0:  # a checkout without --like: another seed of the same robot preset
            subprocess.run([python, "-m", "jaxcal.cli", "simulate", "--out", "track2.csv", "--samples",
                            str(rows), "--measurement", "position", "--seed", "4"], env=env, cwd=work, check=True,
                           capture_output=True)
        ev = ["evaluate", "res.json", "track2.csv"]
        out |= {"evaluate (right after)": run_cli(ev, env, work, python),
                "report (right after)": run_cli(["report", "res.json", "--html", "r.html"], env, work, python),
                "calibrate (warm cache)": run_cli(cal, env, work, python),
                "evaluate (warm cache)": run_cli(ev, env, work, python)}
    return {"imports": imports, "commands": out}


def shutil_rm(path: pathlib.Path) -> None:
    import shutil

    shutil.rmtree(path, ignore_errors=True)


def table(res: dict, label: str) -> list[str]:
    imp = res["imports"]
    lines = [f"### {label}", "", f"Imports in a fresh process (fastest of the runs; ml_dtypes {imp['ml_dtypes version']}): "
             + ", ".join(f"`{what}` {imp[what]:.2f} s" for what, _ in IMPORTS) + ".", "",
             "| command | exit | wall (s) | programs compiled | compile (s) | loaded from cache | "
             "slowest programs (s) |", "|---|---|---|---|---|---|---|"]
    for what, r in res["commands"].items():
        slow = ", ".join(f"`{n}` {s:.1f}" for n, s in r["slowest"])
        lines.append(f"| {what} | {r['rc']} | {r['wall']:.1f} | {r['programs']} | {r['compile_s']:.1f} | {r['hits']} | "
                     f"{slow} |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--source", action="append", default=[],
                    help="a jaxcal checkout to run instead of the installed one (repeatable, with --label)")
    ap.add_argument("--python", action="append", default=[],
                    help="an interpreter to run the commands with (repeatable, with --label)")
    ap.add_argument("--label", action="append", default=[])
    ap.add_argument("--rows", type=int, default=1500)
    ap.add_argument("--import-runs", type=int, default=3, help="fresh processes per import row (the fastest counts)")
    ap.add_argument("--title", default="CLI round trip and imports", help="the appended section's heading")
    ap.add_argument("--out", default=str(HERE / "results" / "compile_cpu.md"))
    ap.add_argument("--json")
    args = ap.parse_args()
    n = max(len(args.source), len(args.python), 1)
    if any(len(x) not in (0, n) for x in (args.source, args.python, args.label)):
        ap.error("give --source, --python and --label as many times each (or not at all)")
    sources = args.source or [None] * n
    pythons = [os.path.abspath(p) for p in args.python] or [sys.executable] * n  # the commands run elsewhere
    labels = args.label or ["this checkout"] * n
    sys.path.insert(0, str(HERE))
    from _common import machine

    md = [f"## {args.title} ({time.strftime('%Y-%m-%d')})", "",
          f"Machine: {machine()}. `python benchmarks/bench_compile.py` (a {args.rows}-row simulated tracker "
          "file, `jaxcal calibrate --measurement position --estimate base,tool` with the measured-data defaults, "
          "then `evaluate` on a second file of the same robot and `report`; each command a fresh process with "
          "`JAX_LOG_COMPILES=1` and Python's bytecode cached, as after a pip install; the cache starts empty).", ""]
    raw = {}
    for src, python, label in zip(sources, pythons, labels):
        load = os.getloadavg()[0]
        res = round_trip(src, args.rows, python, args.import_runs)
        raw[label] = res
        md += table(res, f"{label} (load average {load:.2f} at the start, {os.getloadavg()[0]:.2f} at the end)")
        md.append("")
        for r in res["commands"].values():
            if r["err"]:
                md += ["```", r["err"], "```"]
    text = "\n".join(md) + "\n"
    with pathlib.Path(args.out).open("a", encoding="utf-8") as f:
        f.write("\n" + text)
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(raw, indent=1))
    print(text)


if __name__ == "__main__":
    main()
