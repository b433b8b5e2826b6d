"""Seed sweeps: vmapped trials equal single calibrations, resume, grids, given data, devices, tables."""

import json
import os
import pathlib
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcal
from jaxcal import Dataset, Problem, calibrate, simulate_experiment, statistical_floor
from jaxcal._experiments._sweep import PAPER_METHODS, load_sweep, sweep, trial_keys
from jaxcal._experiments._sweep_chunks import _chunking
from jaxcal.methods import METHODS
from jaxcal.report import (
    accuracy_rows,
    accuracy_table,
    convergence_table,
    dh_rows,
    dh_table,
    grid_table,
    rows_to_csv,
    write_report,
)

N = 120  # samples per simulated trial: 96 train / 24 test
SEED = 7
SMALL = {"adamodw": {"steps": 60}}
KW = dict(seed=SEED, n_samples=N, hyperparameters=SMALL, chunk_size=2, progress=False)
VMAP = KW | {"batching": "vmap"}  # the fixture: vmapped chunks (the multi-device path; CPU default is lax.map)
REPO = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep")
    # 3 trials in per-device batches of 2: the second chunk is padded (trial 2 + a dropped copy)
    return sweep(["lm", "adamodw"], 3, out_dir=out, **VMAP), out


def _trial_data(i):
    k_data, k_method = jax.random.split(trial_keys(jax.random.key(SEED), i, i + 1)[0])
    return simulate_experiment(k_data, n_samples=N), k_method


def test_shapes_metrics_and_floor(swept):
    res, _ = swept
    p = res.space.n_free
    assert res.n_seeds == 3 and list(res.runs) == ["lm", "adamodw"]
    lm, ad = res["lm"], res["adamodw"]
    assert lm.x.shape == (3, p) and ad.history.shape == (3, 61) and ad.test_errors.shape == (3, 24)
    assert res.before_errors.shape == (3, 24)
    assert np.all(lm.status == int(jaxcal.Status.CONVERGED))
    assert res.floor == statistical_floor(0.5, p, 96, 1)
    # calibration helps by an order of magnitude; LM is within noise of the true model
    assert np.all(res.before.rmse > 3 * lm.test.rmse)
    assert np.all(lm.test.rmse < 1.5 * res.oracle.rmse)
    assert np.all(np.abs(lm.train.rmse - 0.5) < 0.15)
    # metrics agree with the kept per-sample errors
    np.testing.assert_allclose(lm.test.rmse, np.sqrt(np.mean(lm.test_errors**2, axis=1)), rtol=1e-12)
    np.testing.assert_allclose(res.before.max, np.max(np.abs(res.before_errors), axis=1), rtol=1e-12)
    s = lm.summary()
    assert s["status"] == {"converged": 3}
    assert s["test_rmse"][0] == pytest.approx(float(np.mean(lm.test.rmse)))
    assert np.all(lm.time_per_trial_s > 0) and np.all(lm.time_to_converge_s <= lm.time_per_trial_s)


def test_trial_equals_its_own_simulation_and_calibration(swept):
    """Trial 2 (in the padded chunk) reproduces simulate_experiment + calibrate with its keys."""
    res, _ = swept
    ex, k_method = _trial_data(2)
    np.testing.assert_allclose(np.asarray(res.true_deviation(2).ravel()), np.asarray(ex.true_deviations.ravel()),
                               rtol=0, atol=0)
    nominal = Problem(ex.robot, ex.measurement, ex.test.q, ex.test.y)
    np.testing.assert_allclose(res.before_errors[2], np.asarray(nominal.sample_errors(nominal.x0())), rtol=1e-12)
    # AdaModW through calibrate(), same key and free parameters
    one = calibrate(ex.robot, ex.measurement, ex.train, "adamodw", key=k_method, space=res.space, steps=60)
    ad = res["adamodw"]
    np.testing.assert_allclose(ad.x[2], one.x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ad.history[2], one.history, rtol=1e-9)
    assert ad.iterations_to_converge[2] == one.iterations_to_converge
    assert ad.test.rmse[2] == pytest.approx(one.evaluate(ex.test).rmse, rel=1e-9)
    # LM: the sweep's estimate is a least-squares stationary point of trial 2's training data
    pr = Problem(ex.robot, ex.measurement, ex.train.q, ex.train.y, res.space)
    x = jnp.asarray(res["lm"].x[2])
    J, r = np.asarray(pr.jacobian(x)), np.asarray(pr.residual(x))
    g = J.T @ r / np.linalg.norm(J, axis=0)
    assert np.max(np.abs(g)) < 1e-6 * np.linalg.norm(r)
    test = Problem(ex.robot, ex.measurement, ex.test.q, ex.test.y, res.space)
    assert res["lm"].test.rmse[2] == pytest.approx(float(jnp.sqrt(jnp.mean(test.sample_errors(x) ** 2))), rel=1e-12)


def test_resume_loads_finished_chunks(swept, monkeypatch):
    res, out = swept
    import jaxcal._experiments._sweep_chunks as sw

    calls = []
    real = sw._Runner.__call__

    def counting(self, inputs, hyper):
        calls.append(1)
        return real(self, inputs, hyper)

    monkeypatch.setattr(sw._Runner, "__call__", counting)
    again = sweep(["lm", "adamodw"], 3, out_dir=out, **VMAP)
    assert calls == []  # everything loaded from disk
    for k in res.runs:
        np.testing.assert_array_equal(again[k].x, res[k].x)
        np.testing.assert_array_equal(again[k].history, res[k].history)
    # an interrupted sweep: the last LM chunk is missing → only that chunk is computed
    missing = out / "chunks" / "lm" / "trials_000002-000003.npz"
    missing.unlink()
    again = sweep(["lm", "adamodw"], 3, out_dir=out, **VMAP)
    assert len(calls) == 1 and missing.exists()
    np.testing.assert_array_equal(again["lm"].x, res["lm"].x)
    # other settings in the same directory are refused, not mixed in
    with pytest.raises(ValueError, match="other settings"):
        sweep(["lm"], 3, out_dir=out, **(VMAP | {"n_samples": 100}))


def test_load_sweep_and_tables(swept, tmp_path):
    res, out = swept
    back = load_sweep(out)
    assert back.labels == res.labels and back.space == res.space
    for k in res.runs:
        for f in ("x", "history", "test_errors", "n_iterations", "status"):
            np.testing.assert_array_equal(getattr(back[k], f), getattr(res[k], f))
    np.testing.assert_array_equal(back.oracle.rmse, res.oracle.rmse)
    assert accuracy_table(back) == accuracy_table(res)
    assert dh_table(back) == dh_table(res)
    # Table III: BC, methods (with paper numbering), floor, oracle
    rows = accuracy_rows(res)
    assert [r["model"] for r in rows] == ["BC", "M4", "M8", "floor", "oracle"]
    assert rows[1]["rmse_mean_mm"] == pytest.approx(float(np.mean(res["lm"].test.rmse)))
    text = accuracy_table(res)
    assert "M8" in text and "± " in text and "0.646" in text  # the paper's AdaModW RMSE beside ours
    md = convergence_table(res, markdown=True)
    assert md.count("\n| ") >= 3 and "Iterations (RMSE)" in md
    # Table V: the calibrated table = nominal + deviations; non-identifiable entries stay nominal
    d = {r["parameter"]: r for r in dh_rows(res, "adamodw")}
    fixed = [n for n, r in d.items() if not r["free"]]
    assert fixed and all(d[n]["calibrated"] == pytest.approx(d[n]["nominal"]) for n in fixed)
    assert d["a_1"]["calibrated"] == pytest.approx(250 + res.deviations("adamodw", 0).a[0])
    assert "not identifiable" in dh_table(res)
    files = write_report(res, tmp_path)
    assert {"table3_accuracy.csv", "table4_convergence.md", "table5_dh.txt", "summary.json"} <= set(files)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["summary"]["runs"]["lm"]["status"] == {"converged": 3}
    assert rows_to_csv(rows).splitlines()[0].startswith("model,method,rmse_mean_mm")
    # incomplete directories: refused, or loaded partially
    (out / "chunks" / "adamodw" / "trials_000002-000003.npz").rename(tmp_path / "moved.npz")
    with pytest.raises(ValueError, match="incomplete"):
        load_sweep(out)
    assert load_sweep(out, partial=True).n_seeds == 2
    (tmp_path / "moved.npz").rename(out / "chunks" / "adamodw" / "trials_000002-000003.npz")


def test_grid_is_vmapped_and_matches_plain_runs(swept):
    res, _ = swept
    grid = sweep([], 3, grid={"adamodw": {"b3": [0.9, 0.99], "weight_decay": [1e-4, 1e-2]}}, **KW)
    # the default of the platform: lax.map over trials and grid points on one CPU device, else vmap
    assert grid.settings["batching"] == ("map" if jax.default_backend() == "cpu" else "vmap")
    assert grid.labels == ["adamodw[b3=0.9, weight_decay=0.0001]", "adamodw[b3=0.9, weight_decay=0.01]",
                           "adamodw[b3=0.99, weight_decay=0.0001]", "adamodw[b3=0.99, weight_decay=0.01]"]
    units = {r["unit"] for r in grid.settings["runs"]}
    assert len(units) == 1  # one compiled function for the whole grid
    # the point with the default settings equals the plain run (traced vs constant hyperparameters,
    # lax.map vs vmap: equal to rounding)
    g = grid["adamodw[b3=0.9, weight_decay=0.0001]"]
    np.testing.assert_allclose(g.x, res["adamodw"].x, rtol=1e-9, atol=1e-12)
    assert g.hyperparameters["b3"] == 0.9 and g.grid_point == {"b3": 0.9, "weight_decay": 0.0001}
    # the grid axes matter: a larger b3 (longer implicit warm-up) converges later
    slow = grid["adamodw[b3=0.99, weight_decay=0.0001]"]
    assert np.mean(slow.iterations_to_converge) > np.mean(g.iterations_to_converge)
    table = grid_table(grid)
    assert table.count("adamodw") == 4 and "floor" in table


def test_given_data(swept):
    res, _ = swept
    ex, _ = _trial_data(0)
    robot, m = ex.robot, ex.measurement
    whole = Dataset(jnp.concatenate([ex.train.q, ex.test.q]), jnp.concatenate([ex.train.y, ex.test.y]))
    # one data set, a different random split per trial
    a = sweep(["lm"], 2, data=whole, robot=robot, measurement=m, noise_std=None, chunk_size=2, progress=False)
    assert a.floor is None and np.all(np.isnan(a.oracle.rmse)) and a.true_deviations is None
    assert a.before.rmse[0] != a.before.rmse[1]
    assert np.all(a["lm"].status == int(jaxcal.Status.CONVERGED))
    # a fixed split (an Experiment): the oracle is known, trials only differ in the method key
    b = sweep(["lm"], 2, data=ex, chunk_size=2, progress=False)
    np.testing.assert_array_equal(b["lm"].x[0], b["lm"].x[1])
    # trial 0 of the simulation (lax.map here, vmap there: equal to rounding, and an LM stopping
    # test may flip by one iteration, moving the estimate far below the noise)
    np.testing.assert_allclose(b["lm"].x[0], res["lm"].x[0], rtol=1e-6, atol=1e-9)
    assert np.isfinite(b.oracle.rmse).all()


def test_bad_arguments():
    with pytest.raises(ValueError, match="n_seeds"):
        sweep(["lm"], 0)
    with pytest.raises(ValueError, match="unknown method"):
        sweep(["nope"], 2)
    with pytest.raises(ValueError, match="grid keys"):
        sweep([], 2, grid={"nope": {"x": [1.0]}})
    with pytest.raises(TypeError):
        sweep([], 2, grid={"adamodw": {"no_such_setting": [1.0, 2.0]}})
    with pytest.raises(TypeError, match="experiment option"):
        sweep(["lm"], 2, experiment={"nonsense": 1})
    with pytest.raises(ValueError, match="give the robot and measurement arguments"):
        sweep(["lm"], 2, data=Dataset(np.zeros((10, 6)), np.zeros(10)))
    with pytest.raises(ValueError, match="labelled"):
        sweep(["lm", "lm"], 2)
    with pytest.raises(ValueError, match="batching"):
        sweep(["lm"], 2, batching="pmap")


def test_chunking():
    assert _chunking(20, 16, 1) == (10, 10)  # balanced, not 16 + 4
    assert _chunking(20, None, 4) == (5, 20)
    assert _chunking(3, 2, 4) == (2, 8)  # per-device batch independent of the device count
    assert _chunking(3, 2, 1) == (2, 2)
    assert _chunking(1, None, 8) == (1, 8)


_DEVICE_SCRIPT = """
import os, sys
os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=4"
os.environ["JAX_PLATFORMS"] = "cpu"  # 4 CPU devices also on a GPU machine
import jax, numpy as np
jax.config.update("jax_enable_x64", True)
from jaxcal._experiments._sweep import sweep
methods, out, kw = sys.argv[1].split(","), sys.argv[2], eval(sys.argv[3])
assert len(jax.devices()) == 4
res = sweep(methods, 3, devices=4, **kw)
assert res.settings["n_devices"] == 4
np.savez(out, **{f"{m}.{f}": getattr(res[m], f) for m in methods
                 for f in ("x", "history", "n_iterations", "status", "test_errors")},
         before=res.before_errors)
"""


def _run_devices(methods, kw, tmp_path):
    out = tmp_path / "dist.npz"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.run([sys.executable, "-c", _DEVICE_SCRIPT, ",".join(methods), str(out), repr(kw)],
                          capture_output=True, text=True, env=env, timeout=1200)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return np.load(out)


def _on_one_cpu(methods, n, **kw):
    """The sweep on one CPU device, whatever the default backend (a GPU's results differ by rounding)."""
    cpu = jax.devices("cpu")[:1]
    with jax.default_device(cpu[0]):
        return sweep(methods, n, devices=cpu, **kw)


def test_four_devices_equal_one_device(swept, tmp_path):
    """LM (optimistix + lineax, which fail under shard_map) on 4 forced CPU devices: bitwise the
    single-device results (same per-device batches). Every method: the slow test below."""
    res = swept[0] if jax.default_backend() == "cpu" else _on_one_cpu(["lm"], 3, **VMAP)
    dist = _run_devices(["lm"], VMAP, tmp_path)
    np.testing.assert_array_equal(dist["before"], res.before_errors)
    for m in ("lm",):
        for f in ("x", "history", "n_iterations", "status", "test_errors"):
            np.testing.assert_array_equal(dist[f"{m}.{f}"], getattr(res[m], f), err_msg=f"{m}.{f}")


@pytest.mark.slow
def test_four_devices_equal_one_device_every_method(tmp_path):
    methods = [m for m in (*PAPER_METHODS, "gn", "adam", "adamw", "adamod") if m in METHODS]
    methods = list(dict.fromkeys(methods))
    small = {"adamodw": {"steps": 30}, "adam": {"steps": 30}, "adamw": {"steps": 30}, "adamod": {"steps": 30},
             "ga": {"generations": 8, "population_size": 16}, "bso": {"generations": 8, "population_size": 8},
             "iwoa": {"iterations": 8, "population_size": 8}, "rbfnn": {"n_centres": 12, "lloyd_iterations": 2}}
    kw = dict(seed=3, n_samples=N, chunk_size=1, progress=False, batching="vmap",
              hyperparameters={m: h for m, h in small.items() if m in methods})
    dist = _run_devices(methods, kw, tmp_path)
    one = _on_one_cpu(methods, 3, **kw)
    for m in methods:
        for f in ("n_iterations", "status"):  # the same decisions
            np.testing.assert_array_equal(dist[f"{m}.{f}"], getattr(one[m], f), err_msg=f"{m}.{f}")
        # the same numbers: bitwise for most methods, but the partitioned program is a different
        # compilation and may round a reduction differently (seen: 1 ulp in an RBF history entry)
        for f in ("x", "history", "test_errors"):
            np.testing.assert_allclose(dist[f"{m}.{f}"], getattr(one[m], f), rtol=1e-13, atol=1e-13, err_msg=f"{m}.{f}")


def test_prior_in_a_sweep_equals_calibrate_with_that_prior():
    """``sweep(prior=...)``: each trial is the MAP fit calibrate() gives with the same fixed noise σ."""
    prior = jaxcal.Prior(angle_deg=0.05, length_mm=0.2)
    res = sweep(["lm"], 1, prior=prior, **KW)
    ex, k_method = _trial_data(0)
    one = calibrate(ex.robot, ex.measurement, ex.train, "lm", key=k_method, space=res.space,
                    prior=jaxcal.Prior(angle_deg=0.05, length_mm=0.2, noise_std=0.5))
    np.testing.assert_allclose(res["lm"].x[0], one.x, rtol=1e-7, atol=1e-10)
    plain = sweep(["lm"], 1, **KW)
    assert np.linalg.norm(res["lm"].x[0]) < np.linalg.norm(plain["lm"].x[0])


def test_figures_are_honest(swept):
    """Fig. 2 bars start at zero; Fig. 3 explains its band and ▼ markers and titles its panels apart."""
    pytest.importorskip("matplotlib")
    from jaxcal import plots

    res, _ = swept
    fig = plots.fig2_accuracy(res)
    assert all(ax.get_ylim()[0] == 0.0 for ax in fig.axes[:3])
    fig = plots.fig3_training(res)
    a, b = fig.axes[:2]
    assert a.get_title() != b.get_title()
    for ax in (a, b):
        labels = [t.get_text() for t in ax.get_legend().get_texts()]
        assert any("range over seeds" in t for t in labels) and "mean iteration to converge" in labels


@pytest.fixture
def buckets_reset():
    from jaxcal._core import _buckets

    yield _buckets
    _buckets.set_buckets(None)


def test_bucketed_sweep_equals_unbucketed_and_compiles_once_per_bucket(buckets_reset):
    """With shape buckets a simulated sweep runs padded to its bucket: every per-trial number
    equals the unpadded sweep's to round-off (a gradient method and LM, under a prior with the
    Huber loss), the per-sample errors keep the real test rows only, and a second sample count of
    the same bucket compiles nothing (the compiled units are reused)."""
    import collections

    events = collections.Counter()

    def listener(event, duration, **kw):
        if event == "/jax/core/compile/backend_compile_duration":
            events["n"] += 1

    kw = dict(KW, prior=jaxcal.Prior(angle_deg=0.1, length_mm=0.5), loss="huber")
    res = {}
    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        setting = None
        # 100 makes the bucket (104: the fine grid above 64), 97 reuses it
        for on, n in ((64, 100), (64, 97), (False, 97)):
            if on != setting:
                buckets_reset.set_buckets(on)
                setting = on
            before = events["n"]
            res[on, n] = sweep(["lm", "adamodw"], 2, **(kw | {"n_samples": n}))
            if on and n == 97:
                assert events["n"] == before, "a sample count of a known bucket compiled something"
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert res[64, 100].settings["n_train"] == 80 and res[64, 100]["lm"].test_errors.shape == (2, 20)
    a, b = res[False, 97], res[64, 97]
    assert a.settings["source"]["bucket"] is None and b.settings["source"]["bucket"] == 104
    assert (b.settings["n_train"], b.settings["n_test"]) == (a.settings["n_train"], a.settings["n_test"])
    assert b.space.free_names == a.space.free_names and b.floor == a.floor
    for f in ("before", "oracle"):
        for m in ("rmse", "mean", "max"):
            np.testing.assert_allclose(getattr(getattr(b, f), m), getattr(getattr(a, f), m), rtol=1e-12)
    np.testing.assert_allclose(b.before_errors, a.before_errors, rtol=0, atol=1e-12)
    for m in ("lm", "adamodw"):
        for split in ("test", "train"):
            for f in ("rmse", "mean", "max"):
                np.testing.assert_allclose(getattr(getattr(b[m], split), f), getattr(getattr(a[m], split), f),
                                           rtol=1e-9, err_msg=f"{m} {split} {f}")
        np.testing.assert_allclose(b[m].x, a[m].x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(b[m].history, a[m].history, rtol=1e-9)
        assert b[m].test_errors.shape == a[m].test_errors.shape == (2, a.settings["n_test"])
        np.testing.assert_allclose(b[m].test_errors, a[m].test_errors, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(b[m].n_iterations, a[m].n_iterations)


def test_unpaddable_method_sweeps_unpadded(buckets_reset):
    """A method whose result depends on the row count (the RBF network) is never padded."""
    buckets_reset.set_buckets(64)
    res = sweep(["rbfnn"], 1, **(KW | {"hyperparameters": {"rbfnn": {"n_centres": 20}}}))
    assert res.settings["source"]["bucket"] is None


def test_plan_before_data_equals_the_plain_order(monkeypatch):
    """The accelerator path (trial 0's data on the host CPU choose the free parameters, then the
    data unit compiles with the method units) gives the same sweep as the plain order: forced here
    on the CPU, where both run on one device."""
    from jaxcal._experiments import _sweep

    runs = {}
    for early in (True, False):
        monkeypatch.setattr(_sweep, "_PLAN_BEFORE_DATA", early)
        runs[early] = sweep(["lm", "adamodw"], 3, **VMAP)
    a, b = runs[True], runs[False]
    assert a.space.free_names == b.space.free_names and a.floor == b.floor
    np.testing.assert_array_equal(a.before.rmse, b.before.rmse)
    np.testing.assert_array_equal(a.before_errors, b.before_errors)
    for m in ("lm", "adamodw"):
        for f in ("x", "history", "test_errors", "n_iterations", "status"):
            np.testing.assert_array_equal(getattr(a[m], f), getattr(b[m], f), err_msg=f"{m}.{f}")
