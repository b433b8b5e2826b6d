"""A fleet that learns (issue 37): the robot model's prior learned from its calibrated units.

A simulated fleet of HSR-JR680 units (tool point (60, 0, 120) mm, a position sensor with σ per
coordinate ``--noise``; a shared systematic deviation of the paper's size, 0.2°/0.6 mm, and a
unit spread of 0.005°/0.02 mm), ``jaxcal.simulate_fleet``:

* ``--units`` units, each calibrated from 200 random poses (generic prior, measured-data
  defaults), teach ``Prior.from_fleet``; the learned population mean and spread against the truth
  in units of their stated σ (the spread where the units' data determine it, data share ≥ 0.8);
* ``--new`` new units of the population, each calibrated from 200 poses under the generic prior,
  and from 15 poses under the learned prior and under the generic prior: mean held-out RMSE
  (200 fresh poses, noisy readings, the 3-D distance per sample) and the ratios; the root mean of
  ‖prediction − truth‖²/prediction variance at the fresh poses under the learned prior (1 if the
  posterior σ is honest), pooled and per unit;
* drift: every teaching unit measured again at new poses, unchanged (false alarms of
  ``jaxcal.drift``, family-wise α = 0.01) and with joint 3's offset turned 0.1° (detections).

Run: ``python benchmarks/bench_fleet_prior.py`` (50 units, 50 new, σ 0.1 and 0.05 mm; writes
``benchmarks/results/fleet_prior_cpu.md``), or ``--noise 0.1 --units 20`` to print one run.
"""

from __future__ import annotations

import argparse
import math
import os
import pathlib
import time
import warnings

HERE = pathlib.Path(__file__).resolve().parent


def _fit(robot, meas, datasets, **kw):
    import jaxcal

    out = []
    for i in range(0, len(datasets), 10):  # one compiled program for every batch of ten
        out += jaxcal.calibrate_many(robot, meas, datasets[i:i + 10], "lm", objective="measured", **kw).results
    return out


def simulated_fleet(units: int, new: int, noise: float, seed: int):
    """``(robot, fleet, measurement, sim settings)``: the benchmark's fleet of ``units + new``
    units of the HSR-JR680 with a tool (400 tracker samples each)."""
    import jax

    import jaxcal

    jaxcal.enable_x64()
    robot = jaxcal.robots.hsr_jr680(tool_mm=(60.0, 0.0, 120.0))
    sim = dict(n_units=units + new, n_samples=400, noise_std=noise, spread_angle_deg=0.005, spread_length_mm=0.02)
    fl = jaxcal.simulate_fleet(jax.random.key(seed), robot, **sim)
    return robot, fl, fl.units[0].measurement, sim


def run(units: int, new: int, noise: float, seed: int = 3) -> dict:
    import jax
    import numpy as np

    import jaxcal
    from jaxcal._fit._problem import predict_jit

    t0 = time.perf_counter()
    robot, fl, meas, sim = simulated_fleet(units, new, noise, seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        taught = _fit(robot, meas, [u.train for u in fl.units[:units]])
        t = time.perf_counter()
        prior = jaxcal.Prior.from_fleet(taught)
        learn_s = time.perf_counter() - t
        pop = prior.population
        z_mean, z_spread = fl.z_scores(pop)
        seen = np.asarray(pop.data_share) >= 0.8

        fresh = fl.units[units:]
        few = [jaxcal.Dataset(u.train.q[:15], u.train.y[:15], u.train.kind) for u in fresh]
        r200 = _fit(robot, meas, [u.train for u in fresh])
        r15 = _fit(robot, meas, few, prior=prior)
        g15 = _fit(robot, meas, few)
        held = {k: float(np.mean([r.evaluate(u.test).rmse for r, u in zip(rs, fresh)]))
                for k, rs in (("200 generic", r200), ("15 learned", r15), ("15 generic", g15))}
        z2 = []
        for r, u in zip(r15, fresh):
            tr = np.asarray(predict_jit(meas, robot, u.true_deviations, u.test.q))
            err = np.asarray(r.predict(u.test.q)) - tr
            z2.append(float(np.mean(np.sum(err**2, axis=1) / r.prediction_std(u.test.q) ** 2)))

        again = jaxcal.simulate_fleet(jax.random.key(seed), robot, measure_key=jax.random.key(seed + 100), **sim)
        redo = _fit(robot, meas, [u.train for u in again.units[:units]])
        false_alarms = sum(bool(jaxcal.drift(a, b).moved) for a, b in zip(taught, redo))
        flat = np.zeros(fl.mean.layout.size)
        flat[fl.mean.layout.names.index("theta_3")] = math.radians(0.1)
        moved = jaxcal.simulate_fleet(jax.random.key(seed), robot, measure_key=jax.random.key(seed + 100),
                                      shift=jaxcal.Deviations.unravel(flat, fl.mean.layout), **sim)
        after = _fit(robot, meas, [u.train for u in moved.units[:units]])
        reps = [jaxcal.drift(a, b) for a, b in zip(taught, after)]
        detected = sum("theta_3" in r.moved for r in reps)
        others = sum(len(set(r.moved) - {"theta_3"}) > 0 for r in reps)
        th3 = [next(row for row in r.rows if row.name == "theta_3") for r in reps]
    return {
        "units": units, "new": new, "noise": noise, "learn_s": learn_s, "total_s": time.perf_counter() - t0,
        "max_z_mean": float(np.max(np.abs(z_mean))), "max_z_spread_seen": float(np.max(np.abs(z_spread[seen]))),
        "n_seen": int(seen.sum()), "n_params": len(pop.names), "shrinkage": pop.shrinkage,
        "held": held, "ratio": held["15 learned"] / held["200 generic"],
        "ratio_generic": held["15 generic"] / held["200 generic"],
        "z_rms": math.sqrt(float(np.mean(z2))), "z_unit_min": math.sqrt(min(z2)), "z_unit_max": math.sqrt(max(z2)),
        "false_alarms": false_alarms, "detected": detected, "others_flagged": others,
        "theta3_change_deg": float(np.mean([r.change for r in th3])), "theta3_std_deg": float(np.mean([r.std for r in th3])),
        "population": pop.table(markdown=True), "example": str(reps[0]).split("\n\n")[0],
    }


def _rows(r: dict) -> list[str]:
    h = r["held"]
    return [
        f"| σ = {r['noise']} mm | {r['units']} | {h['200 generic']:.4f} | {h['15 learned']:.4f} | "
        f"{h['15 generic']:.4f} | {r['ratio']:.3f} | {r['ratio_generic']:.3f} | {r['z_rms']:.3f} "
        f"({r['z_unit_min']:.2f}–{r['z_unit_max']:.2f}) | {r['max_z_mean']:.2f} | {r['max_z_spread_seen']:.2f} "
        f"({r['n_seen']}/{r['n_params']}) | {r['false_alarms']}/{r['units']} | {r['detected']}/{r['units']} "
        f"({r['others_flagged']} also others) | {r['learn_s']:.2f} |",
    ]


HEADER = ("| sensor | units | held-out RMSE 200 poses generic / mm | 15 poses learned / mm | 15 poses generic / mm "
          "| ratio learned | ratio generic | √mean z² (per unit) | max |z| mean | max |z| spread (params) "
          "| drift false alarms | drift θ3 +0.1° found | learn / s |\n" + "|" + " --- |" * 13)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--units", type=int, default=50)
    ap.add_argument("--new", type=int, default=50)
    ap.add_argument("--noise", type=float, nargs="+", default=[0.1, 0.05])
    args = ap.parse_args()
    from _common import machine

    load = os.getloadavg()
    runs = [run(args.units, args.new, s) for s in args.noise]
    lines = [HEADER] + [ln for r in runs for ln in _rows(r)]
    print("\n".join(lines))
    if args.units == 50 and args.new == 50:
        out = HERE / "results" / "fleet_prior_cpu.md"
        r0 = runs[0]
        text = [
            "# A fleet that learns: the robot model's prior from its calibrated units (issue 37)",
            "",
            f"Machine: {machine()}; load average at the start {load[0]:.1f} (other jobs shared the 2 cores).",
            f"Made by `python benchmarks/bench_fleet_prior.py` on {time.strftime('%Y-%m-%d')} ({sum(r['total_s'] for r in runs):.0f} s).",
            "",
            "HSR-JR680 with a tool point (60, 0, 120) mm, position sensor, random poses; population: shared "
            "deviation drawn at 0.2°/0.6 mm, unit spread 0.005°/0.02 mm. Teaching units: 200 poses each, "
            "generic prior (measured-data defaults). New units: 50 of the same population; held-out RMSE "
            "on 200 fresh noisy poses (3-D distance per sample), mean over the new units. z: ‖prediction − "
            "truth‖²/prediction variance at the fresh poses, 15-pose fits under the learned prior. Drift: the "
            "teaching units measured again (200 poses), family-wise α = 0.01.",
            "",
            HEADER, *lines[1:],
            "",
            "Acceptance (issue 37): ratio learned ≤ 1.2, √mean z² within 0.85–1.15, drift false alarms ≤ 5 %.",
            "",
            f"## The population learned at σ = {r0['noise']} mm (mean ± its σ, spread ± its σ; data share: how "
            "much the units' data determine the spread; below ~0.5 the generic prior's is kept)",
            "",
            r0["population"],
            "",
            "## A drift report (first unit, θ3 turned 0.1°)",
            "",
            "```",
            r0["example"],
            "```",
        ]
        out.write_text("\n".join(text) + "\n", encoding="utf-8")
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
