"""A fleet in one program (jaxcal._calibration._fleet.calibrate_many, `jaxcal calibrate a.csv b.csv --out-dir`):
every unit equals calibrating it alone; failing units do not stop the others."""

import warnings

import jax
import numpy as np
import pytest
from test_buckets import _compare  # the round-off comparison of two CalibrationResults

from jaxcal import calibrate, calibrate_many, load_result, simulate_experiment
from jaxcal._calibration import _fleet
from jaxcal.cli import main


@pytest.fixture(scope="module")
def units():
    """Two simulated units with their own true deviations and poses, of different sizes (300, 260)."""
    exs = [simulate_experiment(jax.random.PRNGKey(10 + i), n_samples=375) for i in range(2)]
    return exs[0].robot, exs[0].measurement, [(np.asarray(e.train.q)[:n], np.asarray(e.train.y)[:n])
                                              for e, n in zip(exs, (300, 260))]


def _quiet(f, *a, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return f(*a, **kw)


def test_fleet_equals_single_and_failures_stay_local(units):
    """Plain least squares (the default objective): each unit — 300 and 260 samples, padded to
    one bucket in one mapped program — equals calibrate() alone; a unit with a NaN reading and a
    unit with too few samples fail with their own errors while the others succeed. In chunks of
    two units (pipelined: the second chunk's host steps run while the first one's solves do),
    one compiled program for both chunks."""
    robot, meas, (a, b) = units
    y_nan = a[1].copy()
    y_nan[17] = np.nan
    tiny = (a[0][:5], a[1][:5])
    n_before = len(_fleet._COMPILED_MANY)
    fleet = _quiet(calibrate_many, robot, meas, [a, (a[0], y_nan), b, tiny], "lm", names=["A", "nan", "B", "tiny"],
                   tolerance_mm=0.49, noise_std=0.5, chunk_size=2)
    assert len(_fleet._COMPILED_MANY) - n_before <= 1  # none if an earlier test compiled it
    res, summary = fleet.results, fleet.summary
    assert res[1] is None and res[3] is None
    for got, data in ((res[0], a), (res[2], b)):
        _compare(got, _quiet(calibrate, robot, meas, data, "lm"))
    rows = {r.unit: r for r in summary.rows}
    assert rows["nan"].status == rows["tiny"].status == "error"
    assert "NaN" in rows["nan"].error and "too few samples" in rows["tiny"].error
    assert [rows[u].n for u in ("A", "nan", "B", "tiny")] == [300, 300, 260, 5]
    for u, r in (("A", res[0]), ("B", res[2])):
        assert rows[u].status == "converged" and rows[u].error is None
        assert rows[u].rmse_mm == pytest.approx(r.train_metrics.rmse, rel=1e-12)
        assert rows[u].out_of_tolerance == (r.train_metrics.rmse > 0.49)
        # σ = 0.5 mm simulated: the train RMSE is at its floor (statistical, not a threshold we chose)
        assert 0.85 < rows[u].floor_ratio < 1.15
    assert {"nan", "tiny"} <= set(summary.flagged)
    assert "tiny" in summary.table() and "| unit" in summary.table(markdown=True)
    # every unit failing alike before any solve is a usage error, whatever the chunks
    with pytest.raises(ValueError, match="every unit failed: ValueError: unknown loss"):
        calibrate_many(robot, meas, [a, b, a], "lm", loss="nope", chunk_size=1)
    with pytest.raises(ValueError, match="chunk_size"):
        calibrate_many(robot, meas, [a], "lm", chunk_size=0)


def test_fleet_equals_single_measured_objective(units):
    """The measured-data objective (default prior + Huber, noise σ and loss scale re-estimated
    over rounds), the units vectorised (``batching="vmap"``; the test above runs the CPU default,
    ``"map"``), one unit per chunk (pipelined: a unit's next rounds queue behind the other's): the
    units' rounds run batched and each unit equals calibrate() alone, rounds included; one compiled
    program serves every chunk and round."""
    robot, meas, (a, b) = units
    b = (b[0], b[1].copy())
    b[1][3] += 30.0  # a gross outlier in one unit only: its robust scale is its own
    n_before = len(_fleet._COMPILED_MANY)
    fleet = _quiet(calibrate_many, robot, meas, [a, b], "lm", objective="measured", batching="vmap", chunk_size=1)
    assert len(_fleet._COMPILED_MANY) - n_before == 1
    for got, data in zip(fleet.results, (a, b)):
        single = _quiet(calibrate, robot, meas, data, "lm", objective="measured")
        # the later rounds start LM with the trust region the last one ended with (near Gauss–Newton
        # steps), so the batched and the single run's round-off meet LM's stopping rule at points
        # ~2e-9 apart in the metrics (1e-12 while every round started from optimistix's own)
        _compare(got, single, rtol=1e-8)
        assert got.diagnostics.rounds == single.diagnostics.rounds >= 2
    assert fleet.results[0].loss_scale_mm != pytest.approx(fleet.results[1].loss_scale_mm, rel=1e-3)
    assert 3 in fleet.results[1].diagnostics.outliers_after


def test_cli_fleet_writes_results_and_summary(tmp_path, capsys):
    """`jaxcal calibrate a.csv b.csv --out-dir DIR`: one loadable result per file and the summary."""
    files = []
    for seed in (1, 2):
        path = tmp_path / f"unit{seed}.csv"
        # 300 training samples each: the bucket (384) and program of the tests above
        assert main(["simulate", "--out", str(path), "--samples", "375", "--seed", str(seed)]) == 0
        files.append(str(path))
    out = tmp_path / "fleet"
    code = main(["calibrate", *files, "--robot", "hsr_jr680", "--prior", "none", "--loss", "linear",
                 "--out-dir", str(out), "--tolerance-mm", "100"])
    text = capsys.readouterr().out
    assert code == 0, text
    for stem in ("unit1", "unit2"):
        res = load_result(out / f"{stem}.json")
        assert res.status.name == "CONVERGED" and stem in text
    md = (out / "summary.md").read_text().splitlines()
    assert sum(line.startswith("| unit1 ") or line.startswith("| unit2 ") for line in md) == 2
    csv = (out / "summary.csv").read_text().splitlines()
    assert csv[0].startswith("unit,n,status") and len(csv) == 3
    # one file, several-file options refused with one error line
    assert main(["calibrate", *files, "--robot", "hsr_jr680", "--out", str(tmp_path / "x.json")]) == 2


def test_fleet_flags_an_implausible_unit(units):
    """A unit whose readings are in metres (lengths 1 000× too small) fails the whole-result checks
    as calibrate() alone does (issue 35): not plausible, flagged in the summary, its result kept."""
    robot, meas, (a, b) = units
    fleet = _quiet(calibrate_many, robot, meas, [a, (a[0], a[1] / 1000.0)], "lm", names=["mm", "m"], noise_std=0.5)
    rows = {r.unit: r for r in fleet.summary.rows}
    assert rows["mm"].plausible and not rows["mm"].out_of_tolerance
    assert not rows["m"].plausible and rows["m"].out_of_tolerance and "m" in fleet.summary.flagged
    assert fleet.results[1] is not None and not fleet.results[1].plausible
    assert fleet.results[1].plausible == _quiet(calibrate, robot, meas, (a[0], a[1] / 1000.0), "lm").plausible
    assert "NO" in fleet.summary.table()
