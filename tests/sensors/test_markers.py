"""The marker measurement model (N markers on the flange seen by a motion-capture system or a
laser tracker), pose from markers, marker CSV files, and the FIGAROH TIAGo mocap data."""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import central_differences

import jaxcal
from jaxcal import Dataset, Deviations, Markers, ParameterSpace, Problem, load_csv, robots
from jaxcal._calibration._io import measurement_from_dict, measurement_to_dict
from jaxcal._core._params import layout_for
from jaxcal._models._kinematics import rotvec_to_matrix
from jaxcal._sensors._initial_extras import initial_extras
from jaxcal._sensors._initialise import kabsch, pose_from_markers
from jaxcal._sensors._sessions import marker_columns

#: true marker layout in the flange frame (mm): three markers on a small plate
LAYOUT = np.array([[0.0, 0.0, 80.0], [60.0, 0.0, 60.0], [0.0, 70.0, 50.0]])
ROT_TRUE = np.array([0.1, -0.2, 0.3])       # mocap frame: rotation vector (rad) ...
T_TRUE = np.array([1200.0, -400.0, 150.0])  # ... and the robot base origin in it (mm)


def _truth(robot, key, n, noise=0.0):
    """``(q, y, dev_true)``: DH deviations of Table V size, the true layout and mocap frame."""
    k1, k2, k3, k4 = jax.random.split(key, 4)
    dof = robot.dof
    dev = Deviations.from_dh(
        alpha=jnp.deg2rad(0.2) * jax.random.normal(k1, (dof,)), a=0.6 * jax.random.normal(k2, (dof,)),
        d=0.6 * jax.random.normal(k3, (dof,)), theta=jnp.deg2rad(0.2) * jax.random.normal(k4, (dof,)),
        beta=jnp.zeros(dof), anchor=jnp.zeros(3), tool=jnp.zeros(3), cable_offset=jnp.zeros(()))
    kq, kn = jax.random.split(jax.random.fold_in(key, 7))
    lo, hi = np.asarray(robot.q_min), np.asarray(robot.q_max)
    q = jnp.asarray(lo + (hi - lo) * np.asarray(jax.random.uniform(kq, (n, dof), jnp.float64)))
    truth = Markers(LAYOUT, known=True, rotation=rotvec_to_matrix(jnp.asarray(ROT_TRUE)), translation=T_TRUE)
    y = truth.predict(robot, dev, q)
    y = y + noise * jax.random.normal(kn, y.shape, y.dtype)
    return q, y, dev


def test_predict_matches_fk_pose_and_shapes():
    robot = robots.puma560()
    q = jnp.asarray(np.random.default_rng(0).uniform(-1, 1, (5, 6)))
    m = Markers(LAYOUT)
    assert m.size == 9 and m.sample_shape == (3, 3) and m.kind == "markers"
    assert [g.name for g in m.extra_groups()] == ["marker_1", "marker_2", "marker_3"]
    assert Markers(LAYOUT, known=True).extra_groups() == ()
    y = m.predict(robot, None, q)
    T = np.asarray(jaxcal.fk_pose(robot, q))
    ref = np.einsum("nij,kj->nki", T[:, :3, :3], LAYOUT) + T[:, None, :3, 3]
    np.testing.assert_allclose(np.asarray(y), ref, atol=1e-9)
    r = m.residual(robot, None, q, y + 1.0)  # every coordinate 1 mm off
    assert r.shape == (5, 9)
    np.testing.assert_allclose(np.asarray(m.sample_error(r)), np.sqrt(3.0), rtol=1e-12)  # RMS over markers


def test_marker_deviations_and_sensor_frame_enter_prediction():
    robot = robots.puma560()
    q = jnp.asarray(np.random.default_rng(1).uniform(-1, 1, (4, 6)))
    m = Markers(LAYOUT)
    dev = Deviations.zeros(layout_for(robot, m)).replace(marker_2=jnp.asarray([1.0, -2.0, 3.0]),
                                                          base_rotation=jnp.asarray(ROT_TRUE),
                                                          base_translation=jnp.asarray(T_TRUE))
    shifted = LAYOUT.copy()
    shifted[1] += [1.0, -2.0, 3.0]
    ref = Markers(shifted, known=True, rotation=rotvec_to_matrix(jnp.asarray(ROT_TRUE)), translation=T_TRUE)
    np.testing.assert_allclose(np.asarray(m.predict(robot, dev, q)),
                               np.asarray(ref.predict(robot, None, q)), atol=1e-9)


def test_jacobian_matches_finite_differences():
    robot = robots.hsr_jr680()
    q, y, _ = _truth(robot, jax.random.key(1), 12)
    m = Markers(np.zeros((3, 3)))
    space = ParameterSpace.for_robot(robot, measurement=m, base=True)
    x = 1e-3 * jnp.asarray(np.random.default_rng(2).normal(size=space.n_free))
    start = Deviations.zeros(space.layout).replace(base_translation=jnp.asarray(T_TRUE),
                                                   marker_1=jnp.asarray(LAYOUT[0]))
    pr = Problem(robot, m, q, y, space, start)
    J = np.asarray(pr.jacobian(pr.x0() + x))
    h = 1e-6
    fd = central_differences(pr.residual, pr.x0() + x, h)
    assert J.shape == (12 * 9, space.n_free)
    np.testing.assert_allclose(J, fd, atol=1e-5 * max(1.0, np.abs(fd).max()))


def test_initial_extras_recovers_frame_and_layout_closed_form():
    """Nominal robot = truth: the closed-form start is already exact (markers 0 mm guessed)."""
    robot = robots.hsr_jr680()
    q, y, _ = _truth(robot, jax.random.key(3), 40)
    zero = Deviations.zeros(layout_for(robot, Markers(LAYOUT, known=True)))
    y = Markers(LAYOUT, known=True, rotation=rotvec_to_matrix(jnp.asarray(ROT_TRUE)),
                translation=T_TRUE).predict(robot, zero, q)
    m = Markers(np.zeros((3, 3)))
    est = initial_extras(robot, m, (q, y))
    d = est.deviations
    assert est.rmse_after < 1e-6, est.message
    np.testing.assert_allclose(np.asarray(d.base_translation), T_TRUE, atol=1e-6)
    np.testing.assert_allclose(np.asarray(d.base_rotation), ROT_TRUE, atol=1e-9)
    np.testing.assert_allclose(np.stack([np.asarray(d.values[f"marker_{k + 1}"]) for k in range(3)]), LAYOUT,
                               atol=1e-6)
    # known layout: only the frame
    est2 = initial_extras(robot, Markers(LAYOUT, known=True), (q, y))
    assert est2.rmse_after < 1e-6
    with pytest.raises(ValueError, match="known"):
        initial_extras(robot, Markers(LAYOUT, known=True), (q, y), estimate=["markers"])


@pytest.mark.slow  # ~30 s on 2 cores; the statistical-floor test covers the same fit with noise
def test_noiseless_recovery_dh_markers_frame():
    robot = robots.hsr_jr680()
    q, y, dev_true = _truth(robot, jax.random.key(4), 60)
    m = Markers(np.zeros((3, 3)))
    res = jaxcal.calibrate(robot, m, (q, y), "lm", extras=["base"])
    assert res.ok, res
    assert res.evaluate(Dataset(q, y, "markers")).rmse < 1e-4  # LM stops at its tolerance (~1e-6 mm)
    # fresh poses: the calibrated model predicts the markers as the truth does
    q2, y2, _ = _truth(robot, jax.random.key(5), 30)
    y2 = Markers(LAYOUT, known=True, rotation=rotvec_to_matrix(jnp.asarray(ROT_TRUE)),
                 translation=T_TRUE).predict(robot, dev_true, q2)
    assert res.evaluate(Dataset(q2, y2, "markers")).rmse < 1e-4
    # with the DH table fixed at the truth, the frame and the layout themselves are identified exactly
    start = Deviations.zeros(layout_for(robot, m)).replace(
        **{g: getattr(dev_true, g) for g in ("alpha", "a", "d", "theta")})
    res2 = jaxcal.calibrate(robot, m, (q, y), "lm", extras=["base"], free=["markers"], start=start)
    d = res2.deviations
    np.testing.assert_allclose(np.asarray(d.base_translation), T_TRUE, atol=1e-6)
    np.testing.assert_allclose(np.asarray(d.base_rotation), ROT_TRUE, atol=1e-9)
    np.testing.assert_allclose(np.stack([np.asarray(d.values[f"marker_{k + 1}"]) for k in range(3)]), LAYOUT,
                               atol=1e-6)


def test_noise_reaches_statistical_floor():
    robot = robots.hsr_jr680()
    sigma = 0.1
    q, y, dev_true = _truth(robot, jax.random.key(6), 600, noise=sigma)
    tr, te = slice(0, 400), slice(400, 600)
    m = Markers(np.zeros((3, 3)))
    res = jaxcal.calibrate(robot, m, (q[tr], y[tr]), "lm", extras=["base"])
    p = res.space.n_free
    floor = jaxcal.statistical_floor(sigma, p, 400, size=9)
    # sample_error is the RMS over 3 markers of a 3-D distance: sqrt(3)·σ per sample at best
    test = res.evaluate(Dataset(q[te], y[te], "markers")).rmse
    assert test == pytest.approx(floor.test / np.sqrt(3), rel=0.08), (test, floor)
    train = res.evaluate(Dataset(q[tr], y[tr], "markers")).rmse
    assert train == pytest.approx(floor.train / np.sqrt(3), rel=0.05), (train, floor)


def test_pose_from_markers_closed_form():
    rng = np.random.default_rng(8)
    R = np.asarray(rotvec_to_matrix(jnp.asarray(rng.normal(size=(5, 3)))))
    t = rng.normal(size=(5, 3)) * 500
    L = np.array([[0.0, 0, 80], [60, 0, 60], [0, 70, 50], [-40, -30, 20]])
    Y = np.einsum("nij,kj->nki", R, L) + t[:, None]
    T = pose_from_markers(Y, L)
    assert T.shape == (5, 4, 4)
    np.testing.assert_allclose(T[:, :3, :3], R, atol=1e-12)
    np.testing.assert_allclose(T[:, :3, 3], t, atol=1e-9)
    np.testing.assert_allclose(T[:, 3], np.tile([0, 0, 0, 1.0], (5, 1)))
    # with noise: the same as the Kabsch least-squares fit; a missing marker (NaN) is left out
    Yn = Y + rng.normal(size=Y.shape)
    Yn[2, 3] = np.nan
    T = pose_from_markers(Yn, L)
    for i in range(5):
        ok = np.isfinite(Yn[i]).all(axis=1)
        Rk, tk = kabsch(L[ok], Yn[i][ok])
        np.testing.assert_allclose(T[i, :3, :3], Rk, atol=1e-12)
        np.testing.assert_allclose(T[i, :3, 3], tk, atol=1e-9)
    # the poses go to the Pose model
    robot = robots.puma560()
    q = jnp.asarray(rng.uniform(-1, 1, (6, 6)))
    Tf = np.asarray(jaxcal.fk_pose(robot, q))
    Ym = np.einsum("nij,kj->nki", Tf[:, :3, :3], L) + Tf[:, None, :3, 3]
    np.testing.assert_allclose(pose_from_markers(Ym, L), Tf, atol=1e-9)
    with pytest.raises(ValueError, match="collinear"):
        pose_from_markers(Y[:, :3], np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]))
    with pytest.raises(ValueError, match="finite markers"):
        Yb = Y.copy()
        Yb[0, :2] = np.nan
        pose_from_markers(Yb, L)
    with pytest.raises(ValueError, match="match the layout"):
        pose_from_markers(Y[:, :3], L)


def test_csv_round_trip(tmp_path):
    robot = robots.puma560()
    q, y, _ = _truth(robot, jax.random.key(9), 7)
    data = Dataset(q, y, "markers", {"sensor": "mocap"})
    path = tmp_path / "m.csv"
    data.to_csv(path, angle_unit="rad")
    text = path.read_text()
    assert ",".join(marker_columns(3)) in text and "# kind: markers" in text
    back = load_csv(path)
    assert back.kind == "markers" and back.y.shape == (7, 3, 3) and back.meta["sensor"] == "mocap"
    np.testing.assert_array_equal(np.asarray(back.q), np.asarray(q))
    np.testing.assert_array_equal(np.asarray(back.y), np.asarray(y))
    # recognised from the columns alone, in any order
    lines = [ln for ln in text.splitlines() if not ln.startswith("#")]
    path2 = tmp_path / "m2.csv"
    path2.write_text("\n".join(lines) + "\n")
    assert load_csv(path2, n_markers=3).y.shape == (7, 3, 3)
    with pytest.raises(ValueError, match="3 marker"):
        load_csv(path2, n_markers=4)
    # a marker with a missing coordinate column, a NaN cell
    header = lines[0].split(",")
    cut = [i for i, h in enumerate(header) if h != "marker_2_y_mm"]
    path3 = tmp_path / "m3.csv"
    path3.write_text("\n".join(",".join(r.split(",")[i] for i in cut) for r in lines) + "\n")
    with pytest.raises(ValueError, match="marker_2_y_mm"):
        load_csv(path3)
    bad = lines[:2] + [",".join(["nan"] + lines[2].split(",")[1:])] + lines[3:]
    path4 = tmp_path / "m4.csv"
    path4.write_text("\n".join(bad) + "\n")
    with pytest.raises(ValueError, match="NaN"):
        load_csv(path4)


def test_clear_errors():
    robot = robots.puma560()
    with pytest.raises(ValueError, match=r"\[N, 3\]"):
        Markers(np.zeros(3))
    with pytest.raises(ValueError, match=r"\[N, 3\]"):
        Markers(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="NaN"):
        Markers(np.full((2, 3), np.nan))
    q, y, _ = _truth(robot, jax.random.key(10), 20)
    with pytest.raises(ValueError, match=r"shape \[20, 4, 3\]"):  # N mismatch: model has 4, data 3
        jaxcal.calibrate(robot, Markers(np.zeros((4, 3))), (q, y), "lm", extras=["base"])
    y_nan = y.at[3, 1, 2].set(jnp.nan)
    with pytest.raises(ValueError, match="NaN"):
        jaxcal.calibrate(robot, Markers(np.zeros((3, 3))), (q, y_nan), "lm", extras=["base"])
    with pytest.raises(ValueError, match="markers measurements must have shape"):
        Dataset(q, y[:, :, :2], "markers")
    with pytest.raises(ValueError, match="tool"):
        jaxcal.calibrate(robot, Markers(np.zeros((3, 3))), (q, y), "lm", extras=["base", "tool"])
    with pytest.raises(ValueError, match="'markers'"):
        jaxcal.calibrate(robot, Markers(np.zeros((3, 3))), Dataset(q, y[:, 0], "position"), "lm")


def test_result_round_trip_of_the_model():
    m = Markers(LAYOUT, known=True, rotation=np.asarray(rotvec_to_matrix(jnp.asarray(ROT_TRUE))), translation=T_TRUE)
    back = measurement_from_dict(measurement_to_dict(m))
    assert isinstance(back, Markers) and back.known
    np.testing.assert_allclose(np.asarray(back.positions), LAYOUT)
    np.testing.assert_allclose(np.asarray(back.translation), T_TRUE)


@pytest.mark.slow  # default-run time: test_noise_reaches_statistical_floor covers the fit, test_sessions the CLI
def test_cli_markers(tmp_path, capsys):
    from jaxcal.cli import main

    robot = robots.hsr_jr680()
    q, y, _ = _truth(robot, jax.random.key(11), 80, noise=0.05)
    path = tmp_path / "mocap.csv"
    Dataset(q, y, "markers").to_csv(path)
    rc = main(["calibrate", str(path), "--robot", "hsr_jr680", "--measurement", "markers", "--markers", "3",
               "--out", str(tmp_path / "res.json"), "--prior", "none"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "marker data" in out and "marker_1" in out
    # the estimated marker positions are reported with their posterior σ, like the frame
    extras = next(ln for ln in out.splitlines() if ln.startswith("estimated extras"))
    assert re.search(r"marker_1_z [+-]\d+\.\d+ ± [\d.e-]+ mm", extras), extras
    assert re.search(r"base_rx [+-]\d+\.\d+ ± [\d.e-]+ °", extras), extras
    assert main(["calibrate", str(path), "--robot", "hsr_jr680", "--measurement", "markers", "--markers", "4"]) == 2
    res = jaxcal.load_result(tmp_path / "res.json")
    assert isinstance(res.measurement, Markers) and res.measurement.n_markers == 3


# -- FIGAROH's TIAGo motion-capture data (tests/data/figaroh_tiago, Apache-2.0) ---------------------
def test_figaroh_fixture_reads(figaroh_bench):
    b = figaroh_bench
    if not b.DATA.exists():
        pytest.skip("FIGAROH fixture absent")
    q, y, names = b.load_figaroh_markers()
    assert q.shape == (35, 8) and y.shape == (35, 3, 3)  # marker 4 repeats marker 3: dropped
    assert tuple(names) == b.JOINTS
    assert q[:, 0].max() > 100  # torso in mm
    d12 = np.linalg.norm(y[:, 0] - y[:, 1], axis=1)
    assert np.ptp(np.delete(d12, b.OUTLIER_ROW)) < 5.0  # rigid on the hand (mm)


# slow (35 s of the default run): real marker data stay covered by the Vicon tests in test_sessions.py
@pytest.mark.slow
def test_figaroh_tiago_end_to_end_small(figaroh_bench):
    """Nominal URDF + closed-form mocap frame/layout ≈ 11 mm; calibrated on 28 postures, better on
    the 7 held-out ones (a small version of benchmarks/bench_figaroh.py; ~20 s on 2 cores)."""
    b = figaroh_bench
    text = b.tiago_urdf_text()
    if text is None or not b.DATA.exists():
        pytest.skip("TIAGo URDF (CC BY-NC-ND, not shipped) or the FIGAROH fixture absent")
    chain = b.tiago_chain(text)
    q, y, _ = b.load_figaroh_markers()
    m = Markers(np.zeros((3, 3)))
    est = initial_extras(chain, m, (jnp.asarray(q), jnp.asarray(y)))
    assert 5.0 < est.rmse_after < 20.0 and est.n_trimmed >= 1, est.message  # the 60 mm outlier row
    (f,) = b.held_out(chain, m, q, y, 5, which=[4])  # rows 29-35 held out
    assert f["after_train_clean"] < 0.85 * f["before_train_clean"], f
    assert f["after_test"] < f["before_test"], f
