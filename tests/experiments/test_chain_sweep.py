"""Seed sweeps on generic chains (issue 11): ``jaxcal.sweep`` with a URDF :class:`~jaxcal.SerialChain`
runs seeded trials whose data and results equal :func:`jaxcal.simulate_experiment` + :func:`jaxcal.calibrate`
with the same keys, and the reproduce-style outputs (tables, report files, saved chunks) work for a chain."""

import pathlib

import jax
import numpy as np
import pytest

import jaxcal
from jaxcal import Problem, calibrate, load_urdf, simulate_experiment
from jaxcal._experiments._sweep import load_sweep, sweep, trial_keys
from jaxcal.report import dh_rows, dh_table, write_report

DATA = pathlib.Path(__file__).parents[1] / "data" / "urdf"
N = 120  # samples per simulated trial: 96 train / 24 test
SEED = 5
STEPS = 40  # AdaModW steps (enough to move; the comparison is with calibrate, not the floor)
KW = dict(seed=SEED, n_samples=N, hyperparameters={"adamodw": {"steps": STEPS}}, chunk_size=2, progress=False)


def _ur10e_arm():
    """The UR10e's first three joints (base_link → forearm_link): a small chain, so the module's
    compilations stay short; the tool point sits 300 mm along the forearm."""
    return load_urdf(DATA / "ur10e.urdf", base="base_link", tip="forearm_link", tool=(300.0, -10.0, 60.0))


def _trial_data(robot, measurement, i, n=N):
    k_data, k_method = jax.random.split(trial_keys(jax.random.key(SEED), i, i + 1)[0])
    return simulate_experiment(k_data, robot, n_samples=n, measurement=measurement), k_method


@pytest.fixture(scope="module")
def chain_sweep(tmp_path_factory):
    """3 seeded trials of LM and AdaModW on a UR10e sub-chain, draw-wire (default anchor), chunks of 2
    (the second chunk padded), saved to disk."""
    out = tmp_path_factory.mktemp("chain_sweep")
    res = sweep(["lm", "adamodw"], 3, robot=_ur10e_arm(), out_dir=out / "sweep", **KW)
    return res, out


@pytest.mark.filterwarnings("ignore::jaxcal.CalibrationWarning")  # AdaModW stopped early on purpose
def test_chain_sweep_trials_equal_simulate_and_calibrate(chain_sweep):
    res, _ = chain_sweep
    assert isinstance(res.robot, jaxcal.SerialChain) and res.measurement.kind == "cable"
    assert all(n.split("_")[0] in ("offset", "dx", "dy", "dz", "drx", "dry", "drz", "tip", "anchor", "cable")
               for n in res.space.free_names)
    lm, ad = res["lm"], res["adamodw"]
    assert np.all(lm.status == int(jaxcal.Status.CONVERGED))
    # calibration helps a lot; LM is near the noise. (2.7×, 3.3×, 5.0× here since the simulated truths
    # include the chain's tip errors, issue 22; before that 3.7×, 3.3×, 3.1×.)
    assert np.all(res.before.rmse > 2.5 * lm.test.rmse)
    assert np.all(lm.test.rmse < 1.5 * res.oracle.rmse)
    for i in (0, 2):  # trial 2 sits in the padded chunk
        ex, k_method = _trial_data(res.robot, res.measurement, i)
        np.testing.assert_array_equal(np.asarray(res.true_deviation(i).ravel()), np.asarray(ex.true_deviations.ravel()))
        nominal = Problem(ex.robot, ex.measurement, ex.test.q, ex.test.y)
        np.testing.assert_allclose(res.before_errors[i], np.asarray(nominal.sample_errors(nominal.x0())), rtol=0,
                                   atol=1e-9)  # mm (a wire length minus a reading: round-off of ~1e-13 mm)
        one_lm = calibrate(ex.robot, ex.measurement, ex.train, "lm", key=k_method, space=res.space)
        # the two compiled programs differ (calibrate's also returns the uncertainty's Jacobian
        # products), so their round-off differs in the last bits. Under vmap a trial that has
        # converged keeps taking round-off-level LM steps until the slowest trial of its chunk
        # stops (with the tip error free, trial 0 of this chunk: 24 steps against calibrate's 6,
        # x moving by 7e-8 along a shallow direction) — well inside LM's own stopping tolerance
        # (rtol = atol = 1e-5 on the step), so x is compared at 1e-6 and the held-out RMSE at 1e-7
        np.testing.assert_allclose(lm.x[i], one_lm.x, rtol=1e-6, atol=1e-6)
        assert int(lm.n_iterations[i]) >= one_lm.n_iterations - 1
        k = min(int(lm.n_iterations[i]), one_lm.n_iterations)
        np.testing.assert_allclose(lm.history[i][: k + 1], one_lm.history[: k + 1], rtol=1e-12)
        assert lm.test.rmse[i] == pytest.approx(one_lm.evaluate(ex.test).rmse, rel=1e-7)  # 2e-8 measured
        one_ad = calibrate(ex.robot, ex.measurement, ex.train, "adamodw", key=k_method, space=res.space, steps=STEPS)
        np.testing.assert_allclose(ad.x[i], one_ad.x, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(ad.history[i], one_ad.history, rtol=1e-9)
        assert ad.test.rmse[i] == pytest.approx(one_ad.evaluate(ex.test).rmse, rel=1e-9)


def test_chain_sweep_report_and_reload(chain_sweep, tmp_path):
    """What ``jaxcal reproduce`` writes (Tables III–V, report, chunks) works for a chain: Table V
    lists its per-joint corrections instead of a DH table."""
    res, out = chain_sweep
    rows = dh_rows(res, "lm", trial=1)
    names = [r["parameter"] for r in rows]
    assert names[:3] == [f"offset_{j}" for j in range(1, 4)] and not any(n.startswith("drz") for n in names)
    free = dict(zip(res.space.free_names, res["lm"].x[1]))
    for r in rows:
        assert r["free"] == (r["parameter"] in free)
        v = free.get(r["parameter"], 0.0)
        assert r["calibrated"] == pytest.approx(np.degrees(v) if r["unit"] == "deg" else v, abs=1e-12)
    assert "Joint corrections of ur10e (base_link → forearm_link)" in dh_table(res)
    files = write_report(res, tmp_path)
    assert {"table3_accuracy.md", "table5_dh.csv", "report.md"} <= set(files)
    back = load_sweep(out / "sweep")
    assert isinstance(back.robot, jaxcal.SerialChain) and back.robot.joint_names == res.robot.joint_names
    np.testing.assert_array_equal(back["adamodw"].x, res["adamodw"].x)
    assert dh_table(back, "lm", 1) == dh_table(res, "lm", 1)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::jaxcal.CalibrationWarning")
def test_fetch_position_sweep_equals_calibrate():
    """A prismatic joint (Fetch's torso, mm) and tracker positions: LM and Adam trials equal calibrate."""
    fetch = load_urdf(DATA / "fetch.urdf", base="base_link", tip="gripper_link", tool=(30.0, 0.0, 0.0))
    meas = jaxcal.Position()
    res = sweep(["lm", "adam"], 2, robot=fetch, measurement=meas, **(KW | {"hyperparameters": {"adam": {"steps": STEPS}}}))
    assert res.measurement.size == 3 and np.all(res["lm"].status == int(jaxcal.Status.CONVERGED))
    for i in range(2):
        ex, k_method = _trial_data(fetch, meas, i)
        assert np.ptp(np.asarray(ex.train.q[:, 0])) > 100.0  # the torso moves in mm
        one = calibrate(ex.robot, ex.measurement, ex.train, "lm", key=k_method, space=res.space)
        np.testing.assert_allclose(res["lm"].x[i], one.x, rtol=1e-9, atol=1e-9)
        one = calibrate(ex.robot, ex.measurement, ex.train, "adam", key=k_method, space=res.space, steps=STEPS)
        np.testing.assert_allclose(res["adam"].x[i], one.x, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(res["adam"].history[i], one.history, rtol=1e-9)
