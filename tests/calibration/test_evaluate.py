"""Checking a saved calibration on new data (issue 24): ``jaxcal evaluate``, ``calibrate --test``, the
honest "before", the measured-data defaults, and the HTML report."""

import html.parser
import inspect
import json
import math
import os
import warnings
import xml.etree.ElementTree as ET

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcal
from jaxcal import Dataset, Position, robots, statistical_floor
from jaxcal._models._kinematics import rotvec_to_matrix
from jaxcal._models._robot import sample_joint_angles
from jaxcal._simulation._simulate import draw_deviations
from jaxcal.cli import main

SIGMA = 0.1


def _session(key, robot, dev, n, rotvec, shift):
    """``n`` tracker positions of the true robot ``dev`` seen in the frame ``(exp(rotvec), shift)``."""
    kq, kn = jax.random.split(key)
    q = sample_joint_angles(kq, robot, n)
    m = Position(rotvec_to_matrix(jnp.asarray(rotvec)), jnp.asarray(shift))
    y = m.predict(robot, dev, q) + SIGMA * jax.random.normal(kn, (n, 3))
    return Dataset(q, y, "position", {"robot": robot.name}), m


@pytest.fixture(scope="module")
def two_days(tmp_path_factory):
    """One robot, two sessions with different tracker frames; day 1 calibrated by the CLI."""
    d = tmp_path_factory.mktemp("evaluate")
    robot = robots.hsr_jr680()
    dev = draw_deviations(jax.random.key(1), robot)
    day1, _ = _session(jax.random.key(2), robot, dev, 500, [0.05, -0.1, 0.3], [400.0, -250.0, 80.0])
    day2, m2 = _session(jax.random.key(3), robot, dev, 300, [-0.2, 0.05, -1.1], [-900.0, 600.0, -40.0])
    day1.to_csv(d / "day1.csv")
    day2.to_csv(d / "day2.csv")
    oracle = float(jnp.sqrt(jnp.mean(m2.sample_error(m2.residual(robot, dev, day2.q, day2.y)) ** 2)))
    assert main(["calibrate", str(d / "day1.csv"), "--robot", "hsr_jr680", "--measurement", "position",
                 "--estimate", "base", "--out", str(d / "result.json")]) == 0
    return d, oracle


def test_evaluate_registers_a_new_frame_and_reaches_the_floor(two_days, capsys):
    d, oracle = two_days
    capsys.readouterr()
    assert main(["evaluate", str(d / "result.json"), str(d / "day2.csv"), "--out", str(d / "eval.json")]) == 0
    out = capsys.readouterr().out
    assert "re-registered on the new data" in out and "base_rotation, base_translation" in out
    ev = json.loads((d / "eval.json").read_text())
    assert ev["format"] == "jaxcal-evaluation/1"
    assert ev["extras"]["source"] == "registered" and "base_rotation" in ev["extras"]["registered"]
    m = ev["metrics_mm"]
    assert set(m["before"]) == set(m["after"]) == {"rmse", "mean", "max"}
    res = jaxcal.load_result(d / "result.json")
    floor = statistical_floor(SIGMA, res.space.n_free, 400, 3).test
    assert m["after"]["rmse"] <= 1.05 * max(floor, oracle), (m["after"], floor, oracle)
    assert m["before"]["rmse"] > 3 * m["after"]["rmse"]  # nominal robot, frame registered: far worse
    assert m["raw_nominal"]["rmse"] > 100  # the guessed (identity) frame is ~1 m off
    assert len(ev["rows"]["after_mm"]) == 300 and ev["worse"] is False
    # what the calibration expects of itself on day 2: the floor of a new pose with its own σ̂ and
    # effective parameter count (statistical_floor: an independent formula), and day 2 meets it
    unc = res.uncertainty  # restored from the file
    assert unc is not None and unc.noise_std == pytest.approx(json.loads((d / "result.json").read_text())
                                                              ["uncertainty"]["noise_std_mm"], rel=1e-12)
    own = statistical_floor(unc.noise_std, unc.effective_parameters, 400, 3).test
    assert ev["expected_rmse_mm"] == pytest.approx(own, rel=0.05)
    assert m["after"]["rmse"] == pytest.approx(ev["expected_rmse_mm"], rel=0.15)
    assert ev["worse_than_expected"] is False and "expected from the calibration" in out and "WARNING" not in out
    # the same through the Python API
    day2 = jaxcal.load_csv(d / "day2.csv")
    e = jaxcal.evaluate_result(res, day2, extras="auto")
    assert e.extras == "registered" and math.isclose(e.rmse, m["after"]["rmse"], rel_tol=1e-6)


def test_registration_runs_the_calibrations_solve(two_days):
    """A new day's frame registration (extras only, robot fixed) runs the calibration's compiled
    solve — same program space and objective kind, the free set a run-time mask — and equals the
    registration compiled for itself (no prior, its own candidates) to round-off."""
    from jaxcal._calibration import _programs
    from jaxcal._calibration._evaluate import register_extras

    d, _ = two_days
    res = jaxcal.load_result(d / "result.json")  # prior + Huber (the measured-data defaults)
    day2 = jaxcal.load_csv(d / "day2.csv")  # 300 rows: the bucket of the 400 training rows holds them
    groups = ("base_rotation", "base_translation")
    before = set(_programs._COMPILED._d)
    shared, _ = register_extras(res.robot, res.measurement, day2, res.deviations, groups, like=res)
    assert set(_programs._COMPILED._d) == before
    own, _ = register_extras(res.robot, res.measurement, day2, res.deviations, groups)
    assert len(set(_programs._COMPILED._d) - before) == 1
    a, b = np.asarray(shared._ravel_numpy()), np.asarray(own._ravel_numpy())
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * np.abs(b).max())
    assert np.any(a != np.asarray(res.deviations._ravel_numpy()))  # the frame moved


def test_evaluation_programs_are_shared(two_days, monkeypatch):
    """evaluate's programs: the expected RMSE's Jacobian is compiled on the background thread while
    the extras are registered (and the evaluation equals one without it); the per-row errors of
    a fit's (committed) deviations and of fresh zeros come from one residual program and equal the
    model's own; residuals at two free sets run one program, equal to the residuals at the
    deviations the free entries make."""
    import threading

    from jaxcal._calibration import _evaluate as ev_mod
    from jaxcal._core._params import Deviations, ParameterSpace
    from jaxcal._core._precision import uncommitted
    from jaxcal._fit._problem import Problem, sample_errors_at, signed_residuals
    from jaxcal._sensors._initialise import _residual_rows as residual_blocks

    d, _ = two_days
    res = jaxcal.load_result(d / "result.json")
    day2 = jaxcal.load_csv(d / "day2.csv")
    threads = []
    program = ev_mod._jacobian_program()
    monkeypatch.setattr(ev_mod, "_jacobian_program",
                        lambda: (lambda pr: threads.append(threading.current_thread().name) or program(pr)))
    e = jaxcal.evaluate_result(res, day2, extras="register")
    ahead = (os.cpu_count() or 1) >= 2 and os.environ.get("JAXCAL_COMPILE_AHEAD", "on") != "off"
    assert len(threads) == 1 + ahead and threads[0].startswith("jaxcal-compile") == ahead, threads
    assert not ev_mod._JACOBIAN_AHEAD
    monkeypatch.setenv("JAXCAL_COMPILE_AHEAD", "off")
    ref = jaxcal.evaluate_result(res, day2, extras="register")
    assert e.expected_rmse == ref.expected_rmse and np.array_equal(e.after_errors, ref.after_errors)

    # committed to the device, as a compiled program's outputs are (device_put with a device)
    committed = jax.tree_util.tree_map(lambda a: jax.device_put(a, jax.devices()[0]), e.deviations_after)
    assert all(a.committed for a in committed.arrays)
    assert not any(getattr(a, "committed", False) for a in uncommitted(committed).arrays)
    zero = Deviations.zeros(res.space.layout, np.float64)
    # a position's per-row errors come from the residual program of the checks: no program of
    # their own, one residual program for a fit's deviations and fresh zeros, the model's own errors
    jitted = getattr(sample_errors_at, "_optioned", sample_errors_at)  # the jit a top-level call runs
    rows = Dataset(day2.q[:37], day2.y[:37], "position", day2.meta)  # a row count no program has seen
    n, n_res = jitted._cache_size(), len(residual_blocks.cache)
    errors = [ev_mod.sample_errors(res.robot, res.measurement, d, rows) for d in (zero, committed)]
    assert jitted._cache_size() == n and len(residual_blocks.cache) <= n_res + 1
    for d, e in zip((zero, committed), errors):
        want = res.measurement.sample_error(res.measurement.residual(res.robot, d, jnp.asarray(rows.q),
                                                                     jnp.asarray(rows.y)))
        np.testing.assert_allclose(e, np.asarray(want), rtol=0, atol=1e-9)

    q, y = jnp.asarray(rows.q), jnp.asarray(rows.y)
    layout = res.space.layout
    before = len(residual_blocks.cache)
    for names in (res.space.free_names, ("base_x", "d_2")):
        space = ParameterSpace.from_names(layout, names)
        pr = Problem(res.robot, res.measurement, q, y, space, committed)
        x = np.asarray(space.to_vector_numpy(committed)) + 1e-3
        got = signed_residuals(pr, x)
        want = np.asarray(res.measurement.residual(res.robot, space.from_vector(x, committed), q, y))
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    assert len(residual_blocks.cache) - before <= 1


def test_evaluate_with_the_old_frame_is_worse_and_exits_1(two_days, capsys):
    d, _ = two_days
    assert main(["evaluate", str(d / "result.json"), str(d / "day2.csv"), "--keep-extras"]) == 1
    cap = capsys.readouterr()
    assert "taken from the calibration result" in cap.out and "worse than the nominal robot" in cap.err
    # day 1's frame is ~1 m off on day 2: far beyond what the calibration expects of itself
    assert "worse than the calibration predicts" in cap.out and "has the set-up changed" in cap.err


def test_expected_rmse_flags_a_changed_robot():
    """The same sensor set-up, but the robot changed after calibration (a tool flange remounted 2 mm
    further out, d_6): the new rows fit ~2.7× worse than the calibration expects, and say so;
    rows of the unchanged robot meet the expectation (the statistical floor with σ̂)."""
    ex = jaxcal.simulate_experiment(jax.random.key(7), n_samples=750)
    res = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm", objective="measured")
    same = jaxcal.evaluate_result(res, ex.test)
    unc = res.uncertainty
    assert same.expected_rmse == pytest.approx(
        statistical_floor(unc.noise_std, unc.effective_parameters, ex.train.n, 1).test, rel=0.05)
    assert not same.worse_than_expected and same.after.rmse == pytest.approx(same.expected_rmse, rel=0.15)
    truth = ex.true_deviations
    moved = truth.replace(d=truth.d.at[5].add(2.0))
    new = jaxcal.simulate_experiment(jax.random.key(8), n_samples=100, true_deviations=moved, test_fraction=0.5)
    changed = jaxcal.evaluate_result(res, new.test)
    assert changed.worse_than_expected and "WARNING" in str(changed)
    assert changed.to_dict()["worse_than_expected"] is True


def test_calibrate_with_a_test_file(two_days, capsys):
    d, _ = two_days
    capsys.readouterr()
    assert main(["calibrate", str(d / "day1.csv"), "--robot", "hsr_jr680", "--measurement", "position",
                 "--estimate", "base", "--test", str(d / "day2.csv"), "--out", str(d / "r2.json")]) == 0
    out = capsys.readouterr().out
    assert "all 500 for training; test: 300 samples" in out and "measured-data defaults" in out
    assert "test, raw nominal" in out and "re-registered" in out
    r = json.loads((d / "r2.json").read_text())
    assert r["settings"]["n_test"] == 300 and r["test_extras"]["source"] == "registered"
    assert r["metrics_mm"]["test, after"]["rmse"] < 0.5 * r["metrics_mm"]["test, before"]["rmse"]
    assert set(r["rows"]) == {"train", "test"} and len(r["rows"]["test"]["before_mm"]) == 300
    assert main(["calibrate", str(d / "day1.csv"), "--robot", "hsr_jr680", "--measurement", "position",
                 "--test", str(d / "day2.csv"), "--test-fraction", "0.3"]) == 2


def test_html_report_is_valid_and_self_contained(two_days, tmp_path, capsys):
    pytest.importorskip("matplotlib")
    d, _ = two_days
    main(["evaluate", str(d / "result.json"), str(d / "day2.csv"), "--out", str(d / "eval.json")])
    for src in ("result.json", "eval.json"):
        page = tmp_path / f"{src}.html"
        assert main(["report", str(d / src), "--html", str(page)]) == 0
        text = page.read_text(encoding="utf-8")
        ET.fromstring(text.split("\n", 1)[1])  # well-formed (after the doctype line)
        html.parser.HTMLParser().feed(text)
        assert text.startswith("<!DOCTYPE html>")
        assert text.count("data:image/png;base64,") >= 4  # histogram, joints, workspace, correlations
        assert "http://" not in text and "https://" not in text  # no network
        assert "max-width: 60em" in text and "max-width: 100%" in text  # no sideways scrolling
        for section in ("Summary", "Before / after", "Parameters", "Identifiability", "Outlier rows",
                        "Error over the workspace"):
            assert f"<h2>{section}</h2>" in text, section
    assert main(["report", str(d / "day2.csv"), "--html", str(tmp_path / "x.html")]) == 2


def test_objective_presets():
    from jaxcal._calibration._evaluate import describe_objective, resolve_objective

    assert resolve_objective(None, None, None) == (None, "linear")  # calibrate()'s bare default
    assert resolve_objective("measured", None, None) == ("default", "huber")
    assert resolve_objective("measured", "none", "linear") == ("none", "linear")  # explicit values win
    assert jaxcal.MEASURED_DEFAULTS == {"prior": "default", "loss": "huber"}
    with pytest.raises(ValueError, match="unknown objective"):
        resolve_objective("robust", None, None)
    sig = inspect.signature(jaxcal.holdout_session).parameters  # one set of defaults for measured data
    assert (sig["prior"].default, sig["loss"].default) == ("default", "huber")
    assert "measured-data defaults" in describe_objective("default", "huber")
    assert "not the measured-data defaults" in describe_objective(None, "linear")


def test_one_gross_outlier_under_the_measured_defaults():
    """Acceptance (issue 24): one gross outlier in the training data moves the held-out RMSE by < 2 %."""
    ex = jaxcal.simulate_messy(jax.random.key(4), n_samples=500, n_outliers=1, outlier_mm=(60.0, 200.0),
                               far_samples=0)
    keep = np.setdiff1d(np.arange(ex.train.n), ex.outlier_rows)
    extras = ("anchor", "cable_offset")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, extras=extras, objective="measured")
        clean = jaxcal.calibrate(ex.robot, ex.measurement, ex.train.subset(keep), extras=extras, objective="measured")
        plain = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, extras=extras)
    assert res.loss == "huber" and res.prior is not None and plain.loss == "linear" and plain.prior is None
    a, b = res.evaluate(ex.test).rmse, clean.evaluate(ex.test).rmse
    assert abs(a / b - 1) < 0.02, (a, b)
    assert plain.evaluate(ex.test).rmse > 1.02 * b  # least squares does not shrug it off
    assert list(res.diagnostics.outliers_after) == list(ex.outlier_rows)  # reported, and down-weighted
