"""Peak resident memory of the test run's worker processes (issue 25's memory row).

Runs a pytest command (default: the README's test command, ``python -m pytest -q -n 2 --dist loadscope -m "not slow"``) and
samples every process under it every ``--every`` seconds from ``/proc/<pid>/statm``: the peak
resident set size (RSS) of each process that reached 500 MB, with its command line (the xdist
controller and its workers), the wall time, the test summary line and the load average.
``--env NAME=VALUE`` sets variables for the run (``JAXCAL_TEST_KEEP_COMPILED=1`` keeps every
compiled program for the whole run, as before ``tests/conftest.py`` freed them after each module).

Run: ``python benchmarks/bench_test_memory.py [--label TEXT] [--env N=V ...] [--log FILE] [-- pytest args]``;
appends a section to ``benchmarks/results/test_memory_cpu.md``. Linux only (``/proc``).
"""

from __future__ import annotations

import argparse
import os
import pathlib
import subprocess
import sys
import time

HERE = pathlib.Path(__file__).resolve().parent


def children(pid: int) -> set[int]:
    """Every descendant of ``pid`` (from ``/proc/*/stat``'s parent field)."""
    parent = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as f:
                    parent[int(d)] = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                pass
    out, todo = set(), [pid]
    while todo:
        p = todo.pop()
        for c, pp in parent.items():
            if pp == p and c not in out:
                out.add(c)
                todo.append(c)
    return out


def cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace").strip()
    except OSError:
        return "?"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--every", type=float, default=2.0)
    ap.add_argument("--label", default="")
    ap.add_argument("--env", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--log", help="write pytest's whole output here")
    ap.add_argument("pytest_args", nargs="*", default=["-q", "-n", "2", "--dist", "loadscope", "-m", "not slow"])
    args = ap.parse_args()
    from _common import machine

    from jaxcal._core._buckets import resident_mb as rss_mb

    env = dict(os.environ)
    for kv in args.env:
        k, v = kv.split("=", 1)
        env[k] = v
    cmd = [sys.executable, "-m", "pytest", *args.pytest_args]
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            cwd=HERE.parent)
    peak: dict[int, float] = {}
    names: dict[int, str] = {}
    lines: list[str] = []
    import threading

    reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
    reader.start()
    while proc.poll() is None:
        for pid in children(proc.pid) | {proc.pid}:
            r = rss_mb(pid)
            if r is not None and r > peak.get(pid, 0.0):
                peak[pid] = r
                names.setdefault(pid, cmdline(pid))
        time.sleep(args.every)
    reader.join(timeout=10)
    wall = time.perf_counter() - t0
    if args.log:
        pathlib.Path(args.log).write_text("".join(lines))
    summary = next((ln.strip() for ln in reversed(lines) if " passed" in ln or " failed" in ln), "?")
    big = sorted(((r, p) for p, r in peak.items() if r >= 500), reverse=True)
    md = ["", f"## {args.label or ' '.join(args.pytest_args)}", "",
          f"Machine: {machine()}. `{' '.join(['python', '-m', 'pytest', *args.pytest_args])}`"
          + (f" with {', '.join(f'`{kv}`' for kv in args.env)}" if args.env else "")
          + f"; RSS sampled every {args.every:g} s. Load average {load0[0]:.2f} at the start, "
          f"{os.getloadavg()[0]:.2f} at the end. Wall {wall:.0f} s; pytest: {summary}; exit code {proc.returncode}.",
          "", "| process | peak resident memory (MB) |", "|---|---|"]
    for r, p in big:
        name = names[p]
        kind = ("pytest (controller)" if p == proc.pid else "xdist worker" if "exec(eval(sys.stdin" in name
                else "notebook kernel" if "ipykernel" in name else f"subprocess `{name[:50]}`")
        md.append(f"| {kind} (pid {p}) | {r:.0f} |")
    out = HERE / "results" / "test_memory_cpu.md"
    if not out.exists():
        out.write_text("# Peak resident memory of the test run's processes (`bench_test_memory.py`)\n")
    with open(out, "a") as f:
        f.write("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
