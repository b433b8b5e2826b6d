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
no-bucket run uses ``--calls-off`` counts, default 10, because each one compiles). A learning
curve as a notebook runs it: ``--both --calls 31 --calls-off 31 --min 200 --max 2000 --order ascending``.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time
import warnings

HERE = pathlib.Path(__file__).resolve().parent


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


def sample_counts(calls: int, lo: int, hi: int, seed: int = 0, order: str = "random"):
    """``calls`` different sample counts spread evenly over ``lo..hi``, in a random order (or
    ``order="ascending"``: a learning curve as a notebook runs it)."""
    import numpy as np

    counts = np.unique(np.linspace(lo, hi, calls).round().astype(int))
    if order == "random":
        np.random.default_rng(seed).shuffle(counts)
    return [int(n) for n in counts]


def run_counts(call, counts, events, warm_repeats: int = 5) -> dict:
    """``call(n)`` for every count (XLA compilations, time, result summary each), then the last
    count of each bucket ``warm_repeats`` times more (a warm call of that bucket's program);
    resident memory after the first and after the last count."""
    import numpy as np

    from jaxcal._core._buckets import bucket_size, buckets_enabled
    from jaxcal._core._buckets import resident_mb as rss_mb

    rows = []
    rss_start, rss0 = rss_mb(), None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for n in counts:
            c0, s0 = events["n"], events["s"]
            t = time.perf_counter()
            info = call(n)
            dt = time.perf_counter() - t
            rows.append(dict(n=n, bucket=bucket_size(n), s=dt, compiles=events["n"] - c0,
                             compile_s=events["s"] - s0, **info))
            if rss0 is None:  # after the first call: the process's fixed set-up (imports, first programs)
                rss0 = rss_mb()
        rss1 = rss_mb()
        # warm calls: the last count of each bucket again (its program is compiled; with buckets
        # off only the last few counts' programs are still cached, see the LRU)
        warm = {}
        for r in rows[::-1]:
            if r["bucket"] in warm or len(warm) >= 12:
                continue
            ts = []
            for _ in range(warm_repeats):
                t = time.perf_counter()
                call(r["n"])
                ts.append(time.perf_counter() - t)
            warm[r["bucket"]] = float(np.median(ts))
    return dict(rows=rows, rss_start=rss_start, rss0=rss0, rss1=rss1, warm=warm, buckets=buckets_enabled(),
                load=os.getloadavg(), compiles_after=events["n"])


def run(calls: int, lo: int, hi: int, seed: int = 0, order: str = "random") -> dict:
    """``jaxcal.calibrate(..., "lm")`` on ``calls`` sample counts (issue 25's first acceptance row)."""
    import jax
    import numpy as np

    import jaxcal

    jaxcal.enable_x64()
    events = count_compilations()
    ex = jaxcal.simulate_experiment(jax.random.key(0), n_samples=int(hi / 0.8) + 2)
    robot, meas = ex.robot, ex.measurement
    qn, yn = np.asarray(ex.train.q), np.asarray(ex.train.y)

    def call(n):
        res = jaxcal.calibrate(robot, meas, (qn[:n], yn[:n]), "lm")
        return dict(rmse=res.train_metrics.rmse, status=int(res.status))

    return run_counts(call, sample_counts(calls, lo, hi, seed, order), events)


def run_sweep(calls: int, lo: int, hi: int, n_seeds: int, seed: int = 0) -> dict:
    """``jaxcal.sweep("lm", n_seeds, n_samples=n)`` on ``calls`` sample counts (issue 25's second
    acceptance row). ``sweep`` simulates the data inside its compiled trial; with buckets it
    simulates padded to the count's bucket, so one program per bucket serves every count."""
    import numpy as np

    import jaxcal

    jaxcal.enable_x64()
    events = count_compilations()

    def call(n):
        r = jaxcal.sweep("lm", n_seeds, n_samples=n, progress=False)
        return dict(rmse=float(np.mean(r["lm"].test.rmse)), n_train=r.settings["n_train"])

    return run_counts(call, sample_counts(calls, lo, hi, seed), events, warm_repeats=3)


def summarise(out: dict, what: str = "calls") -> list[str]:
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
              f"{len(rows)} {what} on {len(rows)} sample counts, {len(by)} buckets; "
              f"{sum(1 for r in rows if r['compiles'])} of the calls compiled anything: {total} XLA compilations "
              f"({sum(r['compile_s'] for r in rows):.1f} s of compiling); {out['compiles_after'] - total} more in the "
              f"warm repeats; resident memory {out['rss_start']:.0f} MB before the first call, {out['rss0']:.0f} MB after it, {out['rss1']:.0f} MB after "
              f"the last (+{out['rss1'] - out['rss0']:.0f} MB); load average {out['load'][0]:.2f} at the end."]
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--calls", type=int, default=100)
    ap.add_argument("--calls-off", type=int, default=10, help="calls of the --both run without buckets")
    ap.add_argument("--min", type=int, default=200)
    ap.add_argument("--max", type=int, default=5000)
    ap.add_argument("--no-buckets", action="store_true")
    ap.add_argument("--order", choices=("random", "ascending"), default="random",
                    help="order of the sample counts (ascending: a learning curve)")
    ap.add_argument("--json", help="write the raw numbers here")
    ap.add_argument("--both", action="store_true", help="with and without buckets, fresh processes; writes the md")
    ap.add_argument("--sweep", type=int, metavar="K", default=0,
                    help="instead: jaxcal.sweep('lm') over K sample counts in --min..--max with buckets on "
                         "(--sweep-seeds trials each); writes results/buckets_sweep_cpu.md")
    ap.add_argument("--sweep-seeds", type=int, default=2)
    args = ap.parse_args()
    if args.sweep:
        from _common import machine

        os.environ.setdefault("JAXCAL_BUCKETS", "on")
        load0 = os.getloadavg()
        out = run_sweep(args.sweep, args.min, args.max, args.sweep_seeds)
        md = ["# Shape buckets: `sweep` over many sample counts in one session (issue 25)", "",
              f"Machine: {machine()}. `python benchmarks/bench_buckets.py --sweep {args.sweep}` "
              f"(`jaxcal.sweep('lm', {args.sweep_seeds}, n_samples=n)`, the default simulated experiment, counts "
              f"{args.min}..{args.max} in random order, `JAXCAL_BUCKETS={os.environ['JAXCAL_BUCKETS']}`; every XLA "
              f"compilation of the process counted; warm call: the bucket's last count 3 times more). Load average "
              f"{load0[0]:.2f} at the start.", "", *summarise(out, "sweeps")]
        (HERE / "results" / "buckets_sweep_cpu.md").write_text("\n".join(md) + "\n")
        print("\n".join(md))
        return
    if args.both:
        from _common import machine  # noqa: F401  (imports jax only in this branch's parent)

        res = {}
        for name, calls, env in (("buckets", args.calls, {}), ("off", args.calls_off, {"JAXCAL_BUCKETS": "off"})):
            path = HERE / "results" / f".buckets_{name}.json"
            cmd = [sys.executable, __file__, "--calls", str(calls), "--min", str(args.min), "--max", str(args.max),
                   "--order", args.order, "--json", str(path)]
            load0 = os.getloadavg()
            with tempfile.TemporaryDirectory() as cache:  # cold: nothing loaded from an earlier run
                subprocess.run(cmd, check=True, env={**os.environ, "JAXCAL_CACHE_DIR": cache, **env})
            res[name] = json.loads(path.read_text())
            res[name]["load0"] = load0
            path.unlink()
        md = ["# Shape buckets: many sample counts in one session (issue 25)", "",
              f"Machine: {machine()}. `python benchmarks/bench_buckets.py --both --calls {args.calls} "
              f"--calls-off {args.calls_off} --min {args.min} --max {args.max} --order {args.order}` "
              f"(`calibrate(..., 'lm')` with its defaults, default experiment robot, counts {args.min}..{args.max} in "
              f"{args.order} order; every XLA compilation of the process counted, each process with an empty "
              "persistent compilation cache).", "",
              f"## Defaults (shape buckets on; load average {res['buckets']['load0'][0]:.2f} at the start)", ""]
        md += summarise(res["buckets"])
        md += ["", f"## `JAXCAL_BUCKETS=off` (one program per sample count, as before; load average "
               f"{res['off']['load0'][0]:.2f} at the start)", ""]
        md += summarise(res["off"])
        (HERE / "results" / "buckets_cpu.md").write_text("\n".join(md) + "\n")
        print("\n".join(md))
        return
    if args.no_buckets:
        os.environ["JAXCAL_BUCKETS"] = "off"
    out = run(args.calls, args.min, args.max, order=args.order)
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(out))
    print("\n".join(summarise(out)))


if __name__ == "__main__":
    main()
