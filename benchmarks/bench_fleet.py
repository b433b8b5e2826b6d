"""A fleet in one program: ``calibrate_many`` vs a Python loop of warm ``calibrate`` calls (issue 25).

``--units`` simulated units of the default experiment (HSR-JR680, draw-wire to the default
anchor, σ = 0.5 mm), each with its own random deviations and poses (``simulate_experiment`` with
its own key), ``--samples`` training samples each, calibrated with ``"lm"``:

* ``calibrate_many`` cold (compiling its program) and warm (the same call again), with
  ``batching="map"`` (the default on a CPU) and ``"vmap"``;
* a loop of ``calibrate`` over the units after one warm-up call (its program compiled);
* the largest ``|x_many − x_single|`` over all units and parameters (absolute, rad/mm, and
  relative to ``max(|x|, 1e-3)``), and whether every unit has the same free set and status.

Also the time inside the compiled solves: the fleet's batched solves (``solve_time_s``) vs the
sum of the loop's ``wall_time_s``; the rest of either is the per-unit host work (data checks,
identifiability, diagnostics), which ``calibrate_many`` runs per unit like ``calibrate``.

Run: ``python benchmarks/bench_fleet.py`` (100 units × 1 000 samples, plain least squares and
``objective="measured"``; writes ``benchmarks/results/fleet_cpu.md``), or ``--units 20`` etc. to
print one configuration without writing.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import time
import warnings

HERE = pathlib.Path(__file__).resolve().parent


def run(units: int, samples: int, objective: str | None, batchings=("map", "vmap"), seed: int = 0) -> list[dict]:
    import jax
    import numpy as np

    import jaxcal

    jaxcal.enable_x64()
    keys = jax.random.split(jax.random.key(seed), units)
    n_all = int(round(samples / 0.8))
    exs = [jaxcal.simulate_experiment(k, n_samples=n_all) for k in keys]  # one compiled program, k calls
    robot, meas = exs[0].robot, exs[0].measurement
    datas = [(np.asarray(e.train.q), np.asarray(e.train.y)) for e in exs]
    assert all(d[0].shape[0] == samples for d in datas)
    kw = {} if objective is None else {"objective": objective}
    load0 = os.getloadavg()[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        jaxcal.calibrate(robot, meas, datas[0], "lm", **kw)
        first_single = time.perf_counter() - t
        t = time.perf_counter()
        singles = [jaxcal.calibrate(robot, meas, d, "lm", **kw) for d in datas]
        loop = time.perf_counter() - t
        out = []
        for batching in batchings:
            t = time.perf_counter()
            jaxcal.calibrate_many(robot, meas, datas, "lm", batching=batching, **kw)
            cold = time.perf_counter() - t
            t = time.perf_counter()
            fleet = jaxcal.calibrate_many(robot, meas, datas, "lm", batching=batching, **kw)
            warm = time.perf_counter() - t
            same = all(a is not None and a.space.free_names == b.space.free_names and a.status == b.status
                       for a, b in zip(fleet.results, singles))
            pairs = [(a.x, b.x) for a, b in zip(fleet.results, singles) if len(a.x) == len(b.x)]
            d_abs = max(float(np.max(np.abs(a - b))) for a, b in pairs)
            d_rel = max(float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-3))) for a, b in pairs)
            out.append(dict(units=units, samples=samples, objective=objective or "plain least squares (default)",
                            batching=batching, cold=cold, warm=warm, first_single=first_single, loop=loop,
                            fleet_solve=fleet.solve_time_s, loop_solve=sum(r.wall_time_s for r in singles),
                            d_abs=d_abs, d_rel=d_rel, same=same, rounds=sorted({r.diagnostics.rounds for r in singles}),
                            load0=load0, load1=os.getloadavg()[0]))
    return out


def row(r: dict) -> str:
    return (f"| {r['units']} × {r['samples']} | {r['objective']} | {r['rounds']} | {r['batching']} | {r['cold']:.1f} "
            f"| {r['warm']:.2f} "
            f"| {r['first_single']:.1f} | {r['loop']:.2f} | {r['loop'] / r['warm']:.2f} | {r['fleet_solve']:.2f} / "
            f"{r['loop_solve']:.2f} | {r['d_abs']:.1e} ({r['d_rel']:.1e}) | {'yes' if r['same'] else 'NO'} | "
            f"{r['load0']:.1f}–{r['load1']:.1f} |")


HEADER = ["| units × samples | objective | rounds | batching | `calibrate_many` cold (s) | `calibrate_many` warm (s) | "
          "first `calibrate` (s) | loop of warm `calibrate` (s) | loop / many | compiled solves: many / loop (s) | "
          "max abs Δx (rel) | same free sets and status | load average |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--units", type=int, default=None, help="one configuration, printed, nothing written")
    ap.add_argument("--samples", type=int, default=1000)
    ap.add_argument("--objective", default=None, help="e.g. measured (default: plain least squares)")
    ap.add_argument("--out", default=str(HERE / "results" / "fleet_cpu.md"), help="the results file")
    args = ap.parse_args()
    if args.units is not None:
        rows = run(args.units, args.samples, args.objective)
        print("\n".join([*HEADER, *map(row, rows)]))
        return
    from _common import machine

    rows = [*run(100, args.samples, None), *run(100, args.samples, "measured")]
    md = ["# A fleet in one program: `calibrate_many` vs a loop of `calibrate` (issue 25)", "",
          f"Machine: {machine()}; float64 (load averages in the table). `python benchmarks/bench_fleet.py`: simulated HSR-JR680 units (draw-wire, σ = 0.5 mm), each "
          "with its own random deviations and poses, `method='lm'`.", "", *HEADER, *map(row, rows), "",
          "batching: `map` (the default on a CPU) runs the units one after the other inside the one compiled "
          "program (`jax.lax.map`), `vmap` vectorises them (a vmapped LM batch iterates until its slowest unit "
          "converges; what fills a GPU). "
          "Cold = compiling the fleet's program (one per free set and bucket; the measured objective's "
          "re-estimation rounds reuse it); warm = the same call again. The loop's first call compiles the "
          "single-unit program; the loop itself is warm. Δx: the largest difference of any parameter of any unit "
          "between the fleet and that unit calibrated alone (rad/mm; relative to max(|x|, 1e-3))."]
    pathlib.Path(args.out).write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
