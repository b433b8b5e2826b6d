"""Messy, real-like data: extras from a far-off guess, priors with honest σ, outliers, coverage, CLI exit codes."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcal
from jaxcal import Deviations
from jaxcal.cli import main

N = 500


def _quiet(fn, *a, **k):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(*a, **k)


def _true_extras_start(true: Deviations) -> Deviations:
    z = Deviations.zeros(true.dof, true.anchor.dtype)
    return z.replace(anchor=true.anchor, cable_offset=true.cable_offset, base_rotation=true.base_rotation,
                     base_translation=true.base_translation)


@pytest.fixture(scope="module")
def messy():
    return jaxcal.simulate_messy(jax.random.key(0), n_samples=N)


@pytest.mark.parametrize("kind, extras", [("cable", "anchor,cable_offset"), ("position", "base")])
def test_far_off_guess_reaches_the_fit_from_the_true_extras(kind, extras):
    ex = jaxcal.simulate_messy(jax.random.key(1), n_samples=N, measurement=kind, n_outliers=0)
    guess_error = (np.linalg.norm(np.asarray(ex.true_deviations.anchor)) if kind == "cable"
                   else np.linalg.norm(np.asarray(ex.true_deviations.base_translation)))
    assert guess_error >= 300
    res = _quiet(jaxcal.calibrate, ex.robot, ex.measurement, ex.train, "lm", extras=extras, prior="default")
    ref = _quiet(jaxcal.calibrate, ex.robot, ex.measurement, ex.train, "lm", extras=extras, prior="default",
                 start=_true_extras_start(ex.true_deviations), init="none")
    assert res.ok and res.plausible
    assert res.train_metrics.rmse <= 1.05 * ref.train_metrics.rmse
    assert res.evaluate(ex.test).rmse <= 1.05 * ref.evaluate(ex.test).rmse


def test_prior_posterior_sigma_covers_the_truth():
    """Narrow coverage, quantised readings, far-off anchor: the identifiable combinations — the
    predicted wire lengths at held-out poses, in the measured region and over the whole workspace —
    lie within 3 predicted σ of the true robot's (under the prior every DH deviation is free, MAP,
    so single parameters are partly set by the prior and are not compared with the truth)."""
    ex = jaxcal.simulate_messy(jax.random.key(2), n_samples=N, n_outliers=0, compliance_deg_per_knm=0.0,
                               gear_error_deg=0.0)
    res = _quiet(jaxcal.calibrate, ex.robot, ex.measurement, ex.train, "lm", extras="anchor,cable_offset",
                 prior="default")
    for part in (ex.test, ex.far):  # measured 100 / 500 poses: max |z| 2.96 / 2.65
        truth = np.asarray(ex.measurement.predict(ex.robot, ex.true_deviations, part.q))
        z = (np.asarray(res.predict(part.q)) - truth) / np.asarray(res.prediction_std(part.q))
        assert np.mean(np.abs(z) < 3) >= 0.97 and np.abs(z).max() < 4, np.abs(z).max()
    # predicted error std at far poses is finite and larger than in the measured region
    assert np.median(res.prediction_std(ex.far.q)) > np.median(res.prediction_std(ex.test.q)) > 0


def test_outlier_named_and_robust_loss_ignores_it(messy):
    ex = messy
    assert len(ex.outlier_rows) == 2
    lin = _quiet(jaxcal.calibrate, ex.robot, ex.measurement, ex.train, "lm", extras="anchor,cable_offset",
                 prior="default")
    assert set(ex.outlier_rows) <= set(lin.diagnostics.outliers_after)
    assert any("outlier" in w for w in lin.warnings)
    hub = _quiet(jaxcal.calibrate, ex.robot, ex.measurement, ex.train, "lm", extras="anchor,cable_offset",
                 prior="default", loss="huber")
    keep = np.setdiff1d(np.arange(ex.train.n), ex.outlier_rows)
    clean = _quiet(jaxcal.calibrate, ex.robot, ex.measurement, ex.train.subset(keep), "lm",
                   extras="anchor,cable_offset", prior="default")
    t_hub, t_clean, t_lin = (r.evaluate(ex.test).rmse for r in (hub, clean, lin))
    assert abs(t_hub / t_clean - 1) < 0.02 < t_lin / t_clean - 1


def test_narrow_coverage_and_implausible_parameters_warn(messy):
    ex = messy
    with pytest.warns(jaxcal.CalibrationWarning) as rec:
        res = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm", extras="anchor,cable_offset")
    text = " ".join(str(w.message) for w in rec)
    assert "narrow joint coverage: q4 16.0°, q5 16.0°" in text
    assert res.diagnostics.narrow_joints == (4, 5)
    # no prior on narrow data: absurd parameters, flagged; the default prior keeps them plausible
    assert not res.plausible and "implausible parameters" in text and "--prior default" in text
    assert res.evaluate(ex.far).rmse > 2 * _quiet(
        jaxcal.calibrate, ex.robot, ex.measurement, ex.train, "lm", extras="anchor,cable_offset",
        prior="default").evaluate(ex.far).rmse
    d = res.to_dict()
    assert d["plausible"] is False and d["diagnostics"]["narrow_joints"] == [4, 5]
    assert set(d["uncertainty"]["std"]) == set(res.space.free_names)


def test_cli_exit_codes_and_outlier_rows(messy, tmp_path, capsys):
    ex = messy
    path = tmp_path / "messy.csv"
    data = jaxcal.Dataset(jnp.concatenate([ex.train.q, ex.test.q]), jnp.concatenate([ex.train.y, ex.test.y]),
                          "cable")
    data.to_csv(path)
    anchor = ",".join(f"{float(v):.3f}" for v in ex.measurement.anchor)
    base = ["calibrate", str(path), "--robot", "hsr_jr680", "--anchor", anchor, "--estimate", "anchor,offset",
            "--test-fraction", "0"]
    assert main(base) == 0  # default prior: plausible
    cap = capsys.readouterr()
    rows = [int(r) + 1 for r in ex.outlier_rows]  # 1-based data rows of the file
    assert "± " in cap.out
    # named by the file and its data rows, in the training rows' own σ̂, with what to do
    assert f"{path}, training rows: 2 outlier rows at data rows {rows[0]}, {rows[1]}: residual " in cap.err
    assert f"--exclude-rows {rows[0]},{rows[1]} leaves them out" in cap.err
    tight = ["--max-length-mm", "0.01"]  # every fitted length deviation is "implausible"
    assert main(base + tight) == 1
    assert "implausible" in capsys.readouterr().err
    assert main(base + tight + ["--accept-implausible"]) == 0
    capsys.readouterr()
    # anchor taken as known: the implausibility hint names --estimate; Huber: outliers down-weighted
    known = ["calibrate", str(path), "--robot", "hsr_jr680", "--anchor", anchor, "--test-fraction", "0",
             "--loss", "huber", *tight]
    assert main(known) == 1
    cap = capsys.readouterr()
    assert "--estimate anchor,offset" in cap.err and "down-weighted by the robust loss" in cap.err
    assert "--loss huber guards" not in cap.err
    assert main(base + ["--exclude-outliers"]) == 0
    assert "refitting without data rows" in capsys.readouterr().out
    assert main(base + ["--prior", "wings=2"]) == 2
