"""Many sample counts in one session: compilations, time per call and resident memory (issue 25).

A notebook user calling ``jaxcal.calibrate`` on subsets of different sizes (a learning curve)
paid a full compilation per new sample count and ~28 MB of memory per count that was never
freed. With shape buckets (:mod:`jaxcal._core._buckets`) every count of a bucket runs one compiled
program. This script runs ``--calls`` calibrations (``"lm"``, the default experiment's robot and
draw-wire model) on as many different sample counts spread evenly over ``--min..--max``, each in
a random order, and reports per bucket: the count of XLA compilations (all of them, JAX's
``backend_compile`` events, not only jaxcal's), the first call's time and the median time of the
other calls; next to them the median of a warm call (the bucket's last count, 5 times), and the
resident memory (RSS) before the first and after the last call. ``--no-buckets`` runs the same with
``JAXCAL_BUCKETS=off`` (the behaviour before shape buckets) for comparison; ``--both`` runs both
in fresh processes and writes ``benchmarks/results/buckets_cpu.md``.

Run: ``python benchmarks/bench_buckets.py --both`` (a few minutes on 2 busy cores; the
no-bucket run uses ``--calls-off`` counts, default 12, because each one compiles).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import pathlib
import subprocess
import sys
import time
import warnings

HERE = pathlib.Path(__file__).resolve().parent


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def count_compilations() -> collections.Counter:
    """A counter of this process's XLA compilations from now on: ``["n"]`` (count), ``["s"]`` (seconds)."""
    import jax

    events = collections.Counter()

    def listener(event, duration, **kw):
        if event == "/jax/core/compile/backend_compile_duration":
            events["n"] += 1
            events["s"] += duration

    jax.monitoring.register_event_duration_secs_listener(listener)
    return events


def run(calls: int, lo: int, hi: int, seed: int = 0) -> dict:
    import jax
    import numpy as np

    import jaxcal
    from jaxcal._core._buckets import bucket_size, buckets_enabled

    jaxcal.enable_x64()
    events = count_compilations()
    ex = jaxcal.simulate_experiment(jax.random.key(0), n_samples=int(hi / 0.8) + 2)
    robot, meas = ex.robot, ex.measurement
    qn, yn = np.asarray(ex.train.q), np.asarray(ex.train.y)
    counts = np.unique(np.linspace(lo, hi, calls).round().astype(int))
    np.random.default_rng(seed).shuffle(counts)
    rss0 = rss_mb()
    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for n in counts:
            c0, s0 = events["n"], events["s"]
            t = time.perf_counter()
            res = jaxcal.calibrate(robot, meas, (qn[:n], yn[:n]), "lm")
            dt = time.perf_counter() - t
            rows.append(dict(n=int(n), bucket=bucket_size(int(n)), s=dt, compiles=events["n"] - c0,
                             compile_s=events["s"] - s0, rmse=res.train_metrics.rmse, status=int(res.status)))
        rss1 = rss_mb()
        # warm calls: the last count of each bucket again, 5 times (its program is compiled;
        # with buckets off only the last few counts' programs are still cached, see the LRU)
        warm = {}
        for r in rows[::-1]:
            if r["bucket"] in warm or len(warm) >= 12:
                continue
            ts = []
            for _ in range(5):
                t = time.perf_counter()
                jaxcal.calibrate(robot, meas, (qn[:r["n"]], yn[:r["n"]]), "lm")
                ts.append(time.perf_counter() - t)
            warm[r["bucket"]] = float(np.median(ts))
    return dict(rows=rows, rss0=rss0, rss1=rss1, warm=warm, buckets=buckets_enabled(), load=os.getloadavg(),
                compiles_after=events["n"])


def summarise(out: dict) -> list[str]:
    import numpy as np

    rows = out["rows"]
    by = collections.defaultdict(list)
    for r in rows:
        by[r["bucket"]].append(r)
    warm = {int(k): v for k, v in out["warm"].items()}
    lines = ["| bucket (samples) | counts | XLA compilations (first call / the others) | first call (s) | "
             "median of the others (ms) | warm call, same bucket (ms) | ratio |",
             "|---|---|---|---|---|---|---|"]
    for b in sorted(by):
        rs = by[b]
        rest = [r["s"] for r in rs[1:]]
        med = float(np.median(rest)) if rest else float("nan")
        w = warm.get(b, float("nan"))
        lines.append(f"| {b} | {len(rs)} | {rs[0]['compiles']} / {sum(r['compiles'] for r in rs[1:])} | "
                     f"{rs[0]['s']:.2f} | {1e3 * med:.1f} | {1e3 * w:.1f} | {med / w:.2f} |")
    total = sum(r["compiles"] for r in rows)
    lines += ["",
              f"{len(rows)} calls on {len(rows)} sample counts, {len(by)} buckets: {total} XLA compilations "
              f"({sum(r['compile_s'] for r in rows):.1f} s of compiling); {out['compiles_after'] - total} more in the "
              f"warm repeats; resident memory {out['rss0']:.0f} MB after setup, {out['rss1']:.0f} MB after the last "
              f"call (+{out['rss1'] - out['rss0']:.0f} MB); load average {out['load'][0]:.2f} at the end."]
    return lines


def run_sweep(counts: list[int], n_seeds: int) -> dict:
    """``jaxcal.sweep("lm", n_seeds, n_samples=n)`` for each ``n`` in ``counts`` (issue 25's second
    acceptance row): XLA compilations, time and resident memory per call. ``sweep`` simulates the
    data inside its compiled trial, so the sample count is part of the program's shapes."""

    import jaxcal
    from jaxcal._core._buckets import bucket_size, buckets_enabled

    jaxcal.enable_x64()
    events = count_compilations()
    rss0 = rss_mb()
    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for n in counts:
            c0, s0 = events["n"], events["s"]
            t = time.perf_counter()
            jaxcal.sweep("lm", n_seeds, n_samples=int(n), progress=False)
            rows.append(dict(n=int(n), bucket=bucket_size(int(n)), s=time.perf_counter() - t,
                             compiles=events["n"] - c0, compile_s=events["s"] - s0, rss=rss_mb()))
    return dict(rows=rows, rss0=rss0, buckets=buckets_enabled(), load=os.getloadavg())


def summarise_sweep(out: dict) -> list[str]:
    lines = ["| n_samples | bucket | XLA compilations | compile (s) | call (s) | resident memory after (MB) |",
             "|---|---|---|---|---|---|"]
    for r in out["rows"]:
        lines.append(f"| {r['n']} | {r['bucket']} | {r['compiles']} | {r['compile_s']:.1f} | {r['s']:.1f} | "
                     f"{r['rss']:.0f} |")
    rows = out["rows"]
    lines += ["", f"{len(rows)} sweeps, {sum(r['compiles'] for r in rows)} XLA compilations; resident memory "
              f"{out['rss0']:.0f} MB before, {rows[-1]['rss']:.0f} MB after (+{rows[-1]['rss'] - out['rss0']:.0f} MB); "
              f"buckets {'on' if out['buckets'] else 'off'}; load average {out['load'][0]:.2f} at the end."]
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--calls", type=int, default=100)
    ap.add_argument("--calls-off", type=int, default=10, help="calls of the --both run without buckets")
    ap.add_argument("--min", type=int, default=200)
    ap.add_argument("--max", type=int, default=5000)
    ap.add_argument("--no-buckets", action="store_true")
    ap.add_argument("--json", help="write the raw numbers here")
    ap.add_argument("--both", action="store_true", help="with and without buckets, fresh processes; writes the md")
    ap.add_argument("--sweep", type=int, metavar="K", default=0,
                    help="instead: jaxcal.sweep('lm') over K sample counts in --min..--max with buckets on "
                         "(--sweep-seeds trials each); appends its table to results/buckets_cpu.md")
    ap.add_argument("--sweep-seeds", type=int, default=2)
    args = ap.parse_args()
    if args.sweep:
        import numpy as np
        from _common import machine

        os.environ.setdefault("JAXCAL_BUCKETS", "on")
        counts = [int(c) for c in np.linspace(args.min, args.max, args.sweep).round()]
        out = run_sweep(counts, args.sweep_seeds)
        md = ["", f"## `sweep` over different `n_samples` (`--sweep {args.sweep}`, {args.sweep_seeds} LM trials each, "
              f"`JAXCAL_BUCKETS={os.environ['JAXCAL_BUCKETS']}`; {machine()})", "", *summarise_sweep(out)]
        with open(HERE / "results" / "buckets_cpu.md", "a") as f:
            f.write("\n".join(md) + "\n")
        print("\n".join(md))
        return
    if args.both:
        from _common import machine  # noqa: F401  (imports jax only in this branch's parent)

        res = {}
        for name, calls, env in (("buckets", args.calls, {}), ("off", args.calls_off, {"JAXCAL_BUCKETS": "off"})):
            path = HERE / "results" / f".buckets_{name}.json"
            cmd = [sys.executable, __file__, "--calls", str(calls), "--min", str(args.min), "--max", str(args.max),
                   "--json", str(path)]
            load0 = os.getloadavg()
            subprocess.run(cmd, check=True, env={**os.environ, **env})
            res[name] = json.loads(path.read_text())
            res[name]["load0"] = load0
            path.unlink()
        md = ["# Shape buckets: many sample counts in one session (issue 25)", "",
              f"Machine: {machine()}. `python benchmarks/bench_buckets.py --both` "
              f"(`calibrate(..., 'lm')`, default experiment robot, counts {args.min}..{args.max} in random order; "
              "every XLA compilation of the process counted).", "",
              f"## With shape buckets (`JAXCAL_BUCKETS=on`; off by default; load average {res['buckets']['load0'][0]:.2f} at the start)", ""]
        md += summarise(res["buckets"])
        md += ["", f"## `JAXCAL_BUCKETS=off` (one program per sample count, as before; load average "
               f"{res['off']['load0'][0]:.2f} at the start)", ""]
        md += summarise(res["off"])
        (HERE / "results" / "buckets_cpu.md").write_text("\n".join(md) + "\n")
        print("\n".join(md))
        return
    if args.no_buckets:
        os.environ["JAXCAL_BUCKETS"] = "off"
    out = run(args.calls, args.min, args.max)
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(out))
    print("\n".join(summarise(out)))


if __name__ == "__main__":
    main()
