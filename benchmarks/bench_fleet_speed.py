"""Fleet speed (issue 37): warm ``calibrate_many`` vs a loop of warm ``calibrate``, and where the time goes.

``--units`` simulated units of the default experiment (HSR-JR680, draw-wire, σ = 0.5 mm), each
with its own random deviations and poses, ``--samples`` training samples each, ``method="lm"``
with the defaults (plain least squares). Warm = the second call in the same process. Measured
interleaved (loop, fleet pipelined, fleet in one chunk; ``--repeats`` times, medians), in wall
seconds and in the process's CPU seconds (user + system, all threads), since the machine is
shared and its load varies:

* the loop of ``calibrate`` over the units;
* ``calibrate_many`` with its default chunks (:func:`jaxcal._calibration._fleet.default_chunk_size`:
  the chunks' compiled solves run in a worker thread beside the next chunk's host steps);
* ``calibrate_many`` with ``chunk_size=units`` (one batch, no pipelining: what it did before);
* the compiled work alone, replayed: the identifiability program (``_start_factor``: Jacobian at
  the start, its pivoted QR, the start residuals) and the solve program (LM, Jacobian products
  and metrics at the solution) of every unit, called again with the very arguments the loop gave
  them — the floor that batching the host steps cannot go below while each unit keeps its own
  identifiability and its own solve;
* the largest ``|x_fleet − x_single|`` and whether free sets and status agree.

``--thousand`` also runs 1 000 units in one call in a fresh process (cold, then warm) and
reports its peak resident memory (``ru_maxrss``).

Run: ``python benchmarks/bench_fleet_speed.py`` (writes ``benchmarks/results/fleet_speed_cpu.md``),
``--units 20 --no-write`` to print only.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import time
import warnings

HERE = pathlib.Path(__file__).resolve().parent


def _units(units: int, samples: int, seed: int = 0):
    import jax
    import numpy as np

    import jaxcal

    jaxcal.enable_x64()
    keys = jax.random.split(jax.random.key(seed), units)
    n_all = int(round(samples / 0.8))
    exs = [jaxcal.simulate_experiment(k, n_samples=n_all) for k in keys]  # one compiled program, k calls
    datas = [(np.asarray(e.train.q), np.asarray(e.train.y)) for e in exs]
    assert all(d[0].shape[0] == samples for d in datas)
    return exs[0].robot, exs[0].measurement, datas


def _timed(fn):
    t, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - t, time.process_time() - c


def _compiled_floor(robot, meas, datas, kw):
    """CPU seconds of the compiled programs alone (identifiability, solve) of a loop over ``datas``,
    replayed with the arguments the loop gave them."""
    import jax

    import jaxcal
    from jaxcal._calibration import _calibrate as C
    from jaxcal._fit import _identifiability as ident

    factors, solves = [], []
    factor, launch = ident._start_factor, C._launch

    def spy_factor(*a, **k):
        factors.append((a, k))
        return factor(*a, **k)

    def spy_launch(*a):
        solves.append(a)
        return launch(*a)

    ident._start_factor, C._launch = spy_factor, spy_launch
    try:
        for d in datas:
            jaxcal.calibrate(robot, meas, d, "lm", **kw)
    finally:
        ident._start_factor, C._launch = factor, launch
    out = {}
    for name, calls in (("identifiability", [lambda a=a, k=k: factor(*a, **k) for a, k in factors]),
                        ("solve", [lambda a=a: launch(*a)[0] for a in solves])):
        for f in calls:  # warm
            jax.block_until_ready(f())
        _, wall, cpu = _timed(lambda: [jax.block_until_ready(f()) for f in calls])
        out[name] = (wall, cpu)
    return out


def run(units: int, samples: int, repeats: int, objective: str | None = None) -> dict:
    import numpy as np

    import jaxcal

    robot, meas, datas = _units(units, samples)
    kw = {} if objective is None else {"objective": objective}
    load0 = os.getloadavg()
    rows = {"loop": [], "fleet": [], "fleet, one chunk": []}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, first_single, _ = _timed(lambda: jaxcal.calibrate(robot, meas, datas[0], "lm", **kw))
        _, cold, _ = _timed(lambda: jaxcal.calibrate_many(robot, meas, datas, "lm", **kw))
        _, cold1, _ = _timed(lambda: jaxcal.calibrate_many(robot, meas, datas, "lm", chunk_size=units, **kw))
        for _ in range(repeats):  # interleaved: the load drifts alike over the three
            singles, w, c = _timed(lambda: [jaxcal.calibrate(robot, meas, d, "lm", **kw) for d in datas])
            rows["loop"].append((w, c))
            fleet, w, c = _timed(lambda: jaxcal.calibrate_many(robot, meas, datas, "lm", **kw))
            rows["fleet"].append((w, c))
            one, w, c = _timed(lambda: jaxcal.calibrate_many(robot, meas, datas, "lm", chunk_size=units, **kw))
            rows["fleet, one chunk"].append((w, c))
        floor = _compiled_floor(robot, meas, datas, kw)
    same = all(a is not None and a.space.free_names == b.space.free_names and a.status == b.status
               for r in (fleet, one) for a, b in zip(r.results, singles))
    d_abs = max(float(np.max(np.abs(a.x - b.x))) for r in (fleet, one) for a, b in zip(r.results, singles))
    med = {k: (float(np.median([v[0] for v in vs])), float(np.median([v[1] for v in vs]))) for k, vs in rows.items()}
    from jaxcal._calibration._fleet import default_chunk_size

    return dict(units=units, samples=samples, repeats=repeats, med=med, raw=rows, floor=floor, same=same, d_abs=d_abs,
                first_single=first_single, cold=cold, cold_one=cold1, chunk=default_chunk_size(units, True),
                solve_fleet=fleet.solve_time_s, load0=load0, load1=os.getloadavg())


def thousand(samples: int) -> dict:
    """1 000 units in one call (this process: run it fresh), cold then warm, and the peak RSS."""
    import resource

    import jaxcal

    robot, meas, datas = _units(1000, samples, seed=1)
    rss_data = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, cold, cold_cpu = _timed(lambda: jaxcal.calibrate_many(robot, meas, datas, "lm"))
        fleet, warm, warm_cpu = _timed(lambda: jaxcal.calibrate_many(robot, meas, datas, "lm"))
    ok = sum(r is not None and r.status.name == "CONVERGED" for r in fleet.results)
    return dict(cold=cold, cold_cpu=cold_cpu, warm=warm, warm_cpu=warm_cpu, converged=ok,
                rss_after_data_mb=rss_data, peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                load=os.getloadavg())


def table(r: dict) -> list[str]:
    loop_w, loop_c = r["med"]["loop"]
    out = ["| what | warm wall (s) | warm CPU (s) | loop / this, wall | loop / this, CPU |", "|---|---|---|---|---|"]
    for k, (w, c) in r["med"].items():
        out.append(f"| {k} | {w:.2f} | {c:.2f} | {loop_w / w:.2f} | {loop_c / c:.2f} |")
    fw, fc = r["floor"]["identifiability"]
    sw, sc = r["floor"]["solve"]
    out.append(f"| compiled work alone: identifiability + solve programs, replayed | {fw + sw:.2f} | {fc + sc:.2f} "
               f"| {loop_w / (fw + sw):.2f} | {loop_c / (fc + sc):.2f} |")
    out.append(f"| — of it the identifiability programs | {fw:.2f} | {fc:.2f} | | |")
    out.append(f"| — of it the solve programs | {sw:.2f} | {sc:.2f} | | |")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--units", type=int, default=100)
    ap.add_argument("--samples", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--thousand", action="store_true", help="also 1 000 units in one call (a fresh process)")
    ap.add_argument("--thousand-only", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--objective", default=None, help="e.g. measured (default: plain least squares)")
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--out", default=str(HERE / "results" / "fleet_speed_cpu.md"))
    args = ap.parse_args()
    if args.thousand_only:
        print(json.dumps(thousand(args.samples)))
        return
    r = run(args.units, args.samples, args.repeats, args.objective)
    big = None
    if args.thousand:
        p = subprocess.run([sys.executable, __file__, "--thousand-only", "--samples", str(args.samples)],
                           capture_output=True, text=True, check=True)
        big = json.loads(p.stdout.strip().splitlines()[-1])
    from _common import machine

    nproc = subprocess.run(["nproc"], capture_output=True, text=True).stdout.strip()
    obj = f" --objective {args.objective}" if args.objective else ""
    md = ["# Fleet speed: warm `calibrate_many` vs a loop of warm `calibrate` (issue 37)", "",
          f"Machine: {machine()}; `nproc` = {nproc}; float64; shared with other jobs: load average "
          f"{r['load0'][0]:.2f} / {r['load0'][1]:.2f} / {r['load0'][2]:.2f} (1/5/15 min) at the start, "
          f"{r['load1'][0]:.2f} / {r['load1'][1]:.2f} / {r['load1'][2]:.2f} at the end. "
          f"`python benchmarks/bench_fleet_speed.py{' --thousand' if big else ''}{obj}`: {r['units']} simulated HSR-JR680 units × "
          f"{r['samples']} samples (draw-wire, σ = 0.5 mm), `method='lm'`, "
          f"{'objective=' + repr(args.objective) if args.objective else 'the defaults'}; medians of {r['repeats']} "
          f"interleaved repeats; CPU = the process's user + system seconds (all threads).", "",
          *table(r), "",
          f"Default chunks: {r['chunk']} units (pipelined). Cold: `calibrate_many` {r['cold']:.1f} s (default "
          f"chunks), {r['cold_one']:.1f} s (one chunk); first `calibrate` {r['first_single']:.1f} s. The fleet's batched "
          f"solves: {r['solve_fleet']:.2f} s of worker time. Every unit equals its own `calibrate`: largest "
          f"|Δx| {r['d_abs']:.1e} (rad/mm), free sets and status {'the same' if r['same'] else 'DIFFERENT'}.", ""]
    if big:
        md += [f"1 000 units × {args.samples} samples in one call (fresh process): cold {big['cold']:.1f} s "
               f"({big['cold_cpu']:.1f} s CPU), warm {big['warm']:.1f} s ({big['warm_cpu']:.1f} s CPU), "
               f"{big['converged']} converged; peak RSS {big['peak_rss_mb']:.0f} MB ({big['rss_after_data_mb']:.0f} MB "
               f"after simulating the data); load {big['load'][0]:.2f} at the end.", ""]
    md += ["Raw (wall s, CPU s) per repeat: " + "; ".join(
        f"{k}: " + ", ".join(f"({w:.2f}, {c:.2f})" for w, c in v) for k, v in r["raw"].items()), ""]
    text = "\n".join(md)
    print(text)
    if not args.no_write:
        notes = pathlib.Path(args.out)
        keep = ""
        if notes.exists() and "\n## Reading\n" in notes.read_text():  # hand-written notes survive a rerun
            keep = "\n## Reading\n" + notes.read_text().split("\n## Reading\n", 1)[1]
        notes.write_text(text + keep)


if __name__ == "__main__":
    main()
