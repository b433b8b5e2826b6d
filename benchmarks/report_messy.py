"""The example HTML report (issue 24): messy simulated draw-wire data through the command line.

``jaxcal.simulate_messy`` (seed 0: HSR-JR680, 1 000 draw-wire lengths, wrist joints moving 16°,
0.1° quantisation, anchor guessed 500 mm off, unknown cable offset, unmodelled compliance and gear
error, 2 gross outliers) written as CSV files, then::

    jaxcal calibrate train.csv --robot hsr_jr680 --anchor GUESS --estimate anchor,offset \\
        --test test.csv --keep-extras --out result.json
    jaxcal report result.json --html benchmarks/results/report_messy.html

(the measured-data defaults: default prior + Huber loss). Run: ``python benchmarks/report_messy.py``.
"""

from __future__ import annotations

import os
import pathlib
import sys
import tempfile

import jax

jax.config.update("jax_enable_x64", True)

import jaxcal  # noqa: E402
from jaxcal.cli import main  # noqa: E402


def run() -> int:
    out = pathlib.Path(__file__).resolve().parent / "results" / "report_messy.html"
    ex = jaxcal.simulate_messy(jax.random.key(0))
    print(ex.describe())
    cwd = os.getcwd()
    with tempfile.TemporaryDirectory() as tmp:
        os.chdir(tmp)  # the page names the data files as given: train.csv, not a temporary directory
        try:
            ex.train.to_csv("train.csv")
            ex.test.to_csv("test.csv")
            guess = ",".join(f"{float(v):.3f}" for v in ex.measurement.anchor)
            rc = main(["calibrate", "train.csv", "--robot", "hsr_jr680", "--anchor", guess, "--estimate",
                       "anchor,offset", "--test", "test.csv", "--keep-extras", "--out", "result.json"])
            print(f"calibrate: exit status {rc}")
            return main(["report", "result.json", "--html", str(out)]) or rc
        finally:
            os.chdir(cwd)


if __name__ == "__main__":
    sys.exit(run())
