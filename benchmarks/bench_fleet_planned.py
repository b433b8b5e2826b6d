"""Why 15 poses under the learned prior sit at 1.20× of 200 poses at σ = 0.05 mm (issue 37): planned poses and the prior's noise σ.

The set-up of ``bench_fleet_prior.py`` (its simulated fleet, seed 3: 50 teaching units of 200
random poses, generic prior, measured-data defaults; ``--new`` new units), one sensor σ
(``--noise``). For the new units, the mean held-out RMSE (200 fresh noisy poses, 3-D distance)
of:

* 200 random poses, generic prior (the reference of the 1.2× criterion);
* 15 poses, learned prior: the first 15 random poses (what ``bench_fleet_prior.py`` uses), and
  15 *planned* poses — :func:`jaxcal.select_poses` (D-optimal, greedy + exchange, the learned
  prior's σ as its diagonal prior information, the sensor σ as ``noise_std``) picking 15 of the
  unit's 200 training poses (the candidates a cell could reach); each once with the prior's
  noise σ estimated from the 15-pose fit (the default) and once given (the sensor's σ, as
  ``Prior.from_fleet(noise_std=σ)`` allows);
* the same 15 random / planned poses under the generic prior;
* the noise floor: the truth's own held-out RMSE (the readings' noise alone), and each row's
  model error ``√(RMSE² − floor²)``.

Run: ``python benchmarks/bench_fleet_planned.py`` (σ = 0.05 mm; writes
``benchmarks/results/fleet_planned_cpu.md``), ``--noise 0.1 --no-write`` etc.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import pathlib
import time
import warnings

HERE = pathlib.Path(__file__).resolve().parent


def run(units: int, new: int, noise: float, seed: int = 3) -> dict:
    import numpy as np
    from bench_fleet_prior import _fit, simulated_fleet

    import jaxcal
    from jaxcal._fit._problem import predict_jit

    t0 = time.perf_counter()
    robot, fl, meas, sim = simulated_fleet(units, new, noise, seed)
    fresh = fl.units[units:]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        taught = _fit(robot, meas, [u.train for u in fl.units[:units]])
        prior = jaxcal.Prior.from_fleet(taught)
        prior_known = dataclasses.replace(prior, noise_std=noise)
        generic = jaxcal.Prior()
        t = time.perf_counter()
        planned_idx = [np.asarray(jaxcal.select_poses(robot, meas, np.asarray(u.train.q), 15, prior=prior,
                                                      noise_std=noise).index) for u in fresh]
        plan_s = (time.perf_counter() - t) / len(fresh)

        def subset(u, idx):
            return jaxcal.Dataset(u.train.q[idx], u.train.y[idx], u.train.kind)

        random15 = [subset(u, np.arange(15)) for u in fresh]
        planned15 = [subset(u, i) for u, i in zip(fresh, planned_idx)]
        fits = {
            "200 random, generic prior": _fit(robot, meas, [u.train for u in fresh]),
            "15 random, learned prior": _fit(robot, meas, random15, prior=prior),
            "15 planned, learned prior": _fit(robot, meas, planned15, prior=prior),
            "15 random, learned prior, noise σ given": _fit(robot, meas, random15, prior=prior_known),
            "15 planned, learned prior, noise σ given": _fit(robot, meas, planned15, prior=prior_known),
            "15 random, generic prior": _fit(robot, meas, random15, prior=generic),
            "15 planned, generic prior": _fit(robot, meas, planned15, prior=generic),
        }
    floor = float(np.mean([float(np.sqrt(np.mean(np.sum(
        (np.asarray(predict_jit(meas, robot, u.true_deviations, u.test.q)) - np.asarray(u.test.y)) ** 2, axis=1))))
        for u in fresh]))
    held = {k: float(np.mean([r.evaluate(u.test).rmse for r, u in zip(rs, fresh)])) for k, rs in fits.items()}
    z = {}
    for k, rs in fits.items():
        z2 = []
        for r, u in zip(rs, fresh):
            tr = np.asarray(predict_jit(meas, robot, u.true_deviations, u.test.q))
            err = np.asarray(r.predict(u.test.q)) - tr
            z2.append(float(np.mean(np.sum(err**2, axis=1) / r.prediction_std(u.test.q) ** 2)))
        z[k] = math.sqrt(float(np.mean(z2)))
    sigma_hat = {k: float(np.median([r.uncertainty.noise_std for r in rs])) for k, rs in fits.items()}
    return dict(units=units, new=new, noise=noise, floor=floor, held=held, z=z, sigma_hat=sigma_hat, plan_s=plan_s,
                total_s=time.perf_counter() - t0)


def table(r: dict) -> list[str]:
    ref = r["held"]["200 random, generic prior"]
    ref_model = math.sqrt(max(ref**2 - r["floor"] ** 2, 0.0))
    out = ["| fit | held-out RMSE / mm | / 200 poses | model error √(RMSE² − floor²) / mm | / 200 poses' | "
           "median σ̂ / mm | √mean z² |", "|---|---|---|---|---|---|---|"]
    for k, v in r["held"].items():
        m = math.sqrt(max(v**2 - r["floor"] ** 2, 0.0))
        out.append(f"| {k} | {v:.4f} | {v / ref:.3f} | {m:.4f} | {m / ref_model:.2f} | {r['sigma_hat'][k]:.4f} "
                   f"| {r['z'][k]:.2f} |")
    out.append(f"| noise floor (the truth's own held-out RMSE) | {r['floor']:.4f} | {r['floor'] / ref:.3f} | 0 | | | |")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--units", type=int, default=50)
    ap.add_argument("--new", type=int, default=50)
    ap.add_argument("--noise", type=float, default=0.05)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    load0 = os.getloadavg()
    r = run(args.units, args.new, args.noise)
    from _common import machine

    md = [f"# 15 planned poses under the learned prior, σ = {args.noise} mm (issue 37)", "",
          f"Machine: {machine()}; load average {load0[0]:.1f} at the start, {os.getloadavg()[0]:.1f} at the end "
          f"(shared). `python benchmarks/bench_fleet_planned.py --noise {args.noise}` ({r['total_s']:.0f} s): "
          f"the fleet of `bench_fleet_prior.py` (seed 3), {r['units']} teaching units, {r['new']} new units; "
          f"held-out RMSE on 200 fresh noisy poses (3-D distance per sample), mean over the new units; "
          f"planned = `select_poses` (D-optimal, learned prior, noise_std = σ) choosing 15 of the unit's 200 "
          f"training poses ({r['plan_s']:.2f} s per unit).", "", *table(r), ""]
    text = "\n".join(md)
    print(text)
    if not args.no_write:
        out = HERE / "results" / "fleet_planned_cpu.md"
        keep = ""
        if out.exists() and "\n## Reading\n" in out.read_text():
            keep = "\n## Reading\n" + out.read_text().split("\n## Reading\n", 1)[1]
        out.write_text(text + keep)


if __name__ == "__main__":
    main()
