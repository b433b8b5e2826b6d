"""Are σ̂ and the posterior σ honest under a robust loss, with and without gross outliers?

Data: ``jaxcal.simulate_experiment`` (HSR-JR680, σ = 0.5 mm), one fixed set of true deviations,
``--sets`` data sets of ``--samples`` rows (80 % for training), draw-wire lengths and tracker
positions; each data set once clean and once with 1 % of its training rows moved by 40–150 mm
(gross outliers). Fits: LM, no prior (the identifiable subset), least squares on the clean data
and the Huber loss (scale re-estimated) on both. Reported per fit kind:

* σ̂ (``result.uncertainty.noise_std``): mean and sd over the data sets, in units of the true σ;
* reported / empirical σ of the parameters: the mean reported posterior σ of each free
  parameter over the spread (sd) of its estimates across the data sets; median and range over
  the parameters (1 = honest; the sd of an sd from 40 sets is ~11 %).

Run: ``python benchmarks/bench_uncertainty.py [--sets 40] [--samples 625]`` (~5 minutes on 2 CPU
cores). Writes ``benchmarks/results/uncertainty_cpu.md`` (or ``--out``).
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import time
import warnings

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from _common import machine  # noqa: E402

import jaxcal  # noqa: E402
from jaxcal._core._precision import to_device  # noqa: E402

SIGMA = 0.5
KINDS = {"draw-wire": None, "tracker position": jaxcal.Position()}
FITS = ("least squares, clean", "huber, clean", "huber, 1 % gross outliers")


def with_outliers(train, seed: int, fraction: float = 0.01):
    """``train`` with ``fraction`` of its rows moved by 40–150 mm (every entry of the row)."""
    y = np.asarray(train.y, np.float64).copy()
    rng = np.random.default_rng(seed)
    k = max(1, round(fraction * y.shape[0]))
    rows = rng.choice(y.shape[0], k, replace=False)
    shift = rng.uniform(40.0, 150.0, k) * rng.choice([-1.0, 1.0], k)
    y[rows] += shift.reshape((-1,) + (1,) * (y.ndim - 1))
    return dataclasses.replace(train, y=to_device(y))


def run_kind(measurement, sets: int, samples: int):
    kw = {} if measurement is None else {"measurement": measurement}
    truth = jaxcal.simulate_experiment(jax.random.key(999), n_samples=samples, **kw).true_deviations
    xs, stds, sig = ({f: [] for f in FITS} for _ in range(3))
    for s in range(sets):
        ex = jaxcal.simulate_experiment(jax.random.key(1000 + s), n_samples=samples, noise_std=SIGMA,
                                        true_deviations=truth, **kw)
        data = {FITS[0]: (ex.train, "linear"), FITS[1]: (ex.train, "huber"),
                FITS[2]: (with_outliers(ex.train, s), "huber")}
        for f, (train, loss) in data.items():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = jaxcal.calibrate(ex.robot, ex.measurement, train, "lm", prior="none", loss=loss)
            xs[f].append(np.asarray(r.x))
            stds[f].append(np.asarray(r.uncertainty.std))
            sig[f].append(r.uncertainty.noise_std / SIGMA)
    rows = []
    for f in FITS:
        ratio = np.mean(stds[f], axis=0) / np.std(xs[f], axis=0, ddof=1)
        rows.append((f, np.mean(sig[f]), np.std(sig[f], ddof=1), np.median(ratio), ratio.min(), ratio.max(),
                     len(ratio)))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sets", type=int, default=40)
    ap.add_argument("--samples", type=int, default=625)
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "uncertainty_cpu.md"))
    args = ap.parse_args()
    t0 = time.perf_counter()
    lines = ["# σ̂ and posterior σ under a robust loss, with and without gross outliers", "",
             f"`python benchmarks/bench_uncertainty.py --sets {args.sets} --samples {args.samples}` on "
             f"{machine()}; {time.perf_counter() - t0:.0f} s.", ""]
    body = []
    for kind, meas in KINDS.items():
        rows = run_kind(meas, args.sets, args.samples)
        section = [f"## {kind}", "", "| fit | σ̂/σ mean | σ̂/σ sd | reported/empirical σ, median | range | parameters |",
                   "|---|---:|---:|---:|---:|---:|"]
        section += [f"| {f} | {m:.4f} | {s:.4f} | {med:.3f} | {lo:.2f}–{hi:.2f} | {p} |"
                    for f, m, s, med, lo, hi, p in rows]
        print("\n".join(section), flush=True)
        body += [*section, ""]
    lines[2] = (f"`python benchmarks/bench_uncertainty.py --sets {args.sets} --samples {args.samples}` on "
                f"{machine()}; {time.perf_counter() - t0:.0f} s.")
    lines += body
    lines += ["Under a robust loss σ̂ is a bounded-influence scale (`jaxcal._fit._diagnostics.RobustNoise`,"
              " Huber's Proposal 2 on the model's sample errors), and the posterior covariance is weighed"
              " by it: gross outliers inflate neither. Before (the Huber objective's own residual sum),"
              " 6 gross outliers in 600 draw-wire rows gave σ̂ = 1.25 mm for σ = 0.5 mm, and the posterior"
              " σ were inflated by the same factor (tests/fit/test_objective.py). The price of the bound is"
              " a noisier σ̂ for one reading per sample (sd 4.2 % against 3.0 % for least squares on"
              " draw-wire data; the cap touches 18 % of clean samples); a ratio within ±11 % of 1 is"
              " within the sampling noise of 40 data sets."]
    out = pathlib.Path(args.out)
    out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
