"""Camera measurement model (issue 23, part 4): OpenCV as a test-only oracle, the closed-form
start, posterior σ of the calibrated camera positions, the CLI at the statistical floor."""

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import central_differences

import jaxcal
from jaxcal import Camera, Dataset, checkerboard, hand_eye_park, robots, simulate_camera, solve_pnp
from jaxcal._models._kinematics import fk_pose, fk_pose_jit
from jaxcal._sensors._camera import _T, _inv, _residual_jit, camera_floor, masked_corners, project_points

INTR = [1000.0, 1000.0, 640.0, 512.0, -0.05, 0.02, 0.0005, -0.0003, 0.001]


def _camera(mount="eye_in_hand"):
    return Camera(checkerboard(9, 6, 20.0), INTR, mount, image_size=(1280, 1024))


def _K(k):
    return np.array([[k[0], 0, k[2]], [0, k[1], k[3]], [0, 0, 1.0]])


def test_projection_matches_opencv():
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(0)
    p = np.c_[rng.uniform(-300, 300, (50, 2)), rng.uniform(300, 900, 50)]
    ours = project_points(p, INTR)
    ref, _ = cv2.projectPoints(p.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), _K(INTR), np.asarray(INTR[4:]))
    np.testing.assert_allclose(ours, ref[:, 0], atol=1e-9)


@pytest.mark.parametrize("mount", ["eye_in_hand", pytest.param("eye_to_hand", marks=pytest.mark.slow)])
def test_jacobian_of_the_structured_projection(mount):
    """The projection's derivative rule (jaxcal._sensors._camera._affine_project) against central finite
    differences and against plain jax.jacfwd/jacrev through the projection formula, with the
    intrinsics free (every tangent path of the rule) away from the nominal point."""
    from jaxcal._sensors._camera import _distort_project

    robot = robots.hsr_jr680()
    # simulated with the camera model of test_masked_corners_roundtrip_and_residual (the same
    # 5-view simulation program; the intrinsics group only adds zero deviations to the truth),
    # then differentiated with the intrinsics free
    q, y, _, _ = simulate_camera(jax.random.key(4), robot, _camera(mount), n_views=5, noise_px=0.3)
    cam = Camera(checkerboard(9, 6, 20.0), INTR, mount, image_size=(1280, 1024), calibrate_intrinsics=True)
    pr = jaxcal.Problem(robot, cam, q, y, jaxcal.ParameterSpace.for_robot(robot, measurement=cam))
    x = pr.x0() + 1e-3 * jax.random.normal(jax.random.key(5), pr.x0().shape)

    def plain(xx):
        dev = pr.deviations(xx)
        px, py, pz = cam.camera_points(robot, dev, q)
        u, v = _distort_project(px / pz, py / pz, cam.frames(dev, q.dtype)[4])
        return (jnp.stack([u, v], -1) - y).reshape(-1)

    # compiled, not op by op (each eager operation is a program of its own: ~25 s more)
    J = np.asarray(eqx.filter_jit(lambda p, x: p.jacobian(x))(pr, x))
    np.testing.assert_allclose(eqx.filter_jit(lambda p, x: p.residual(x))(pr, x), jax.jit(plain)(x), atol=1e-9)
    np.testing.assert_allclose(J, jax.jit(jax.jacfwd(plain))(x), rtol=0, atol=1e-9 * np.abs(J).max())
    np.testing.assert_allclose(J, eqx.filter_jit(lambda p, x: jax.jacrev(p.residual)(x))(pr, x), rtol=0,
                               atol=1e-9 * np.abs(J).max())
    h = 1e-6
    fd = central_differences(pr.residual, x, h)
    np.testing.assert_allclose(J, fd, rtol=0, atol=1e-5 * np.abs(J).max())


def test_pnp_of_many_images_is_each_image_alone():
    """The batched PnP of initial_camera_extras (issue 51) against one solve_pnp call per image, on
    noise-free images of known poses: the poses are recovered (to 1e-9), also from the minimal 4
    detected corners (the DLT's null vector, not the smallest non-zero direction of an 8×9
    system); an image of random corners (its fit does not converge to a good pose), an image with
    3 corners and one with none do not change the others, and get solve_pnp's own messages."""
    from jaxcal._core._rotvec import rotvec_to_matrix
    from jaxcal._sensors._camera import _solve_pnp_images

    rng = np.random.default_rng(7)
    pts = checkerboard(9, 6, 20.0)
    R = rotvec_to_matrix(rng.normal(0.0, 0.3, (6, 3)))
    t = np.c_[rng.uniform(-120, -40, (6, 2)), rng.uniform(400, 800, 6)]
    uv = project_points(np.einsum("nij,kj->nki", R, pts) + t[:, None], INTR)
    uv[1, rng.permutation(54)[:20]] = np.nan  # some corners not detected
    uv[2, [i for i in range(54) if i not in (0, 8, 45, 53)]] = np.nan  # the four outer corners
    uv[3] = rng.uniform(0, 1000, (54, 2))  # random corners
    uv[4, 3:] = np.nan
    uv[5] = np.nan
    Rb, tb, rms, errors = _solve_pnp_images(pts, uv, INTR)
    for i in range(6):
        if i >= 4:
            assert isinstance(errors[i], ValueError) and np.isnan(rms[i])
            with pytest.raises(ValueError, match=f"PnP needs at least 4 detected points, got {3 if i == 4 else 0}"):
                solve_pnp(pts, uv[i], INTR)
            continue
        assert errors[i] is None
        R1, t1, e1 = solve_pnp(pts, uv[i], INTR)
        np.testing.assert_allclose(Rb[i], R1, rtol=0, atol=1e-12)
        np.testing.assert_allclose(tb[i], t1, rtol=1e-12)
        assert rms[i] == pytest.approx(e1, rel=1e-9, abs=1e-12)
        if i != 3:
            np.testing.assert_allclose(Rb[i], R[i], rtol=0, atol=1e-9)
            np.testing.assert_allclose(tb[i], t[i], rtol=1e-9)
            assert rms[i] < 1e-6
    assert rms[3] > 10.0

@pytest.mark.parametrize("mount", ["eye_in_hand", "eye_to_hand"])
def test_hand_eye_start_matches_opencv(mount):
    """Park–Martin on the same simulated poses as cv2.calibrateHandEye(CALIB_HAND_EYE_PARK): the same
    pairs and formulas in float64, so the two agree to round-off (~1e-15 relative measured; asserted
    1e-10 rad-scale on the rotation matrix, 1e-10 relative on the translation)."""
    cv2 = pytest.importorskip("cv2")
    if not hasattr(cv2, "calibrateHandEye"):  # a cv2 build without the calib3d hand-eye solvers
        pytest.skip(f"cv2 {getattr(cv2, '__version__', '?')} has no calibrateHandEye")
    robot = robots.hsr_jr680()
    q, y, cam, _ = simulate_camera(jax.random.key(3), robot, _camera(mount), n_views=15, noise_px=0.3)
    pts, k = np.asarray(cam.points), np.asarray(cam.intrinsics)
    C = np.stack([_T(*solve_pnp(pts, np.asarray(y[i]), k)[:2]) for i in range(q.shape[0])])
    # our PnP against OpenCV's iterative PnP on the same corners (same minimum of the reprojection error)
    ok, rv, tv = cv2.solvePnP(pts, np.asarray(y[0]), _K(k), k[4:], flags=cv2.SOLVEPNP_ITERATIVE)
    np.testing.assert_allclose(C[0, :3, 3], tv.ravel(), atol=1e-5)
    F = np.asarray(fk_pose_jit(robot, q, None, tool=False))
    G = F if mount == "eye_in_hand" else _inv(F)  # OpenCV: eye-to-hand takes base2gripper
    X = hand_eye_park(G, C)
    R_cv, t_cv = cv2.calibrateHandEye(list(G[:, :3, :3]), list(G[:, :3, 3]), list(C[:, :3, :3]), list(C[:, :3, 3]),
                                      method=cv2.CALIB_HAND_EYE_PARK)
    np.testing.assert_allclose(X[:3, :3], R_cv, atol=1e-10)
    np.testing.assert_allclose(X[:3, 3], t_cv.ravel(), rtol=1e-10, atol=1e-9)


def test_masked_corners_roundtrip_and_residual(tmp_path):
    robot = robots.hsr_jr680()
    q, y, cam, truth = simulate_camera(jax.random.key(1), robot, _camera(), n_views=5, noise_px=0.0, missing=0.1)
    n_mask, n_all, _ = masked_corners(y)
    assert 0 < n_mask < n_all
    Dataset(q, y, "camera").to_csv(tmp_path / "c.csv")
    text = (tmp_path / "c.csv").read_text()
    assert ",," in text or text.rstrip().split("\n")[-1].endswith(",")  # empty cells, not "nan"
    assert "nan" not in text
    back = jaxcal.load_csv(tmp_path / "c.csv")
    assert back.kind == "camera"
    np.testing.assert_array_equal(np.isnan(back.y), np.isnan(np.asarray(y)))
    # compiled, not op by op (each eager operation is a program of its own)
    r = np.asarray(_residual_jit(cam, robot, truth, back.q, back.y)).reshape(5, -1, 2)
    assert np.all(r[np.isnan(np.asarray(y))] == 0)  # masked: zero weight
    assert np.abs(r).max() < 1e-6  # noiseless: the truth reprojects exactly


def _camera_in_target(camera, robot, dev, q):
    """Optical centre of an eye-in-hand camera in the target frame, ``[n, 3]`` mm: ``B⁻¹F(q)X·0``
    (what the images determine; the base frame itself is not observable apart from the target)."""
    T = fk_pose(robot, q, dev, tool=False)
    RX, tX, RB, tB, _ = camera.frames(dev, q.dtype)
    p = jnp.einsum("nij,j->ni", T[:, :3, :3], tX) + T[:, :3, 3]
    return (p - tB) @ RB


@pytest.fixture(scope="module")
def calibrated():
    """20 of 30 simulated views calibrated (deviated DH, hand-eye and target started from the data,
    0.3 px noise, 5 % of the corners undetected); the other 10 held out."""
    robot = robots.hsr_jr680()
    q, y, cam, truth = simulate_camera(jax.random.key(0), robot, _camera(), n_views=30, noise_px=0.3, missing=0.05)
    nominal = Camera(cam.points, cam.intrinsics, cam.mount, image_size=cam.image_size)  # hand-eye, target unknown
    res = jaxcal.calibrate(robot, nominal, (q[:20], y[:20]), "lm")
    return robot, q, y, cam, truth, nominal, res


def test_calibrated_camera_positions_within_3_sigma(calibrated):
    """≥ 15 views, 0.3 px noise, deviated DH, hand-eye and target started from the data: at held-out
    poses the calibrated camera positions lie within 3 posterior σ (per coordinate) of the truth."""
    robot, q, y, cam, truth, nominal, res = calibrated
    te = slice(20, 30)
    assert res.ok
    space = res.space

    # one compiled program, not op by op (each eager operation is a program of its own); every
    # array an argument, not a constant XLA would fold at compile time
    @eqx.filter_jit
    def positions(x, base, truth, qte, nominal, cam, robot):
        def f(x):
            return _camera_in_target(nominal, robot, space.from_vector(x, base), qte)

        return jax.jacfwd(f)(x), f(x), _camera_in_target(cam, robot, truth, qte)

    J, fx, true_pos = (np.asarray(a) for a in positions(jnp.asarray(res.x), res.deviations, truth, q[te], nominal,
                                                        cam, robot))  # J: [10, 3, p]
    cov = np.asarray(res.uncertainty.covariance)
    sd = np.sqrt(np.einsum("nip,pk,nik->ni", J, cov, J))
    err = fx - true_pos
    print(f"camera positions at 10 held-out poses: max |error| {np.abs(err).max():.4f} mm, "
          f"max |error|/σ {(np.abs(err) / sd).max():.2f}, median σ {np.median(sd):.4f} mm")
    assert np.all(np.abs(err) <= 3 * sd), (np.abs(err) / sd).max()
    assert np.abs(err).max() < 1.0  # mm; the start (nominal DH) was several mm off


def test_evaluate_registers_a_moved_camera(calibrated):
    """`evaluate` on held-out views re-registers the hand-eye transform and the target pose (robot
    fixed), reports px and no raw nominal line (the identity hand-eye is no guess); a camera
    remounted 2–3 mm and ~0.6° off is absorbed by the registration (the robot is fine), and judged
    with the result's stale hand-eye (extras="result") it is flagged as far worse than expected."""
    robot, q, y, cam, truth, nominal, res = calibrated
    te = slice(20, 30)
    held = Dataset(q[te], y[te], "camera")
    ev = jaxcal.evaluate_result(res, held)
    assert ev.extras == "registered" and set(ev.registered) == {
        "handeye_rotation", "handeye_translation", "target_rotation", "target_translation"}
    assert ev.unit == "px" and ev.raw_nominal is None and ev.to_dict()["unit"] == "px"
    text = str(ev)
    assert "RMSE/px" in text and "mm" not in text.split("Accuracy")[1].split("expected")[0]
    assert "no sensor" not in text and "raw nominal" not in text and "handeye_rotation" in ev.message
    assert not ev.worse_than_expected and ev.after.rmse == pytest.approx(ev.expected_rmse, rel=0.25)

    @eqx.filter_jit  # one compiled program, not op by op (each eager operation is a program of its own)
    def remounted(truth, q, y, cam, robot):
        moved = truth.replace(handeye_translation=truth.values["handeye_translation"] + jnp.array([2.0, -1.0, 1.5]),
                              handeye_rotation=truth.values["handeye_rotation"] + jnp.array([0.01, 0.0, -0.01]))
        ym = cam.predict(robot, moved, q) + 0.3 * jax.random.normal(jax.random.key(9), y.shape)
        return jnp.where(jnp.isnan(y), jnp.nan, ym)

    new = Dataset(q[te], remounted(truth, q[te], y[te], cam, robot), "camera")
    again = jaxcal.evaluate_result(res, new)
    print(f"moved camera: registered {again.after.rmse:.3f} px (expected {again.expected_rmse:.3f})")
    assert not again.worse_than_expected and again.after.rmse < 1.5 * ev.after.rmse
    stale = jaxcal.evaluate_result(res, new, extras="result")
    print(f"moved camera, the result's hand-eye: {stale.after.rmse:.2f} px (expected {stale.expected_rmse:.3f})")
    assert stale.worse_than_expected and stale.after.rmse > 10 * stale.expected_rmse
    assert "worse than the calibration predicts" in str(stale) and "px" in stale.expectation()[1]


@pytest.mark.slow  # default-run time: test_calibrated_camera_positions_within_3_sigma covers the fit
def test_cli_camera_reaches_floor(tmp_path, capsys):
    """`jaxcal simulate --measurement camera` then `jaxcal calibrate` (deviated DH, hand-eye and target
    unknown: started from the data; 5 % of the corners undetected): training RMSE within 3 % of the
    statistical floor with the detected corners counted (camera_floor)."""
    from jaxcal.cli import main

    data, out = tmp_path / "cam.csv", tmp_path / "res.json"
    sigma = 0.3
    assert main(["simulate", "--measurement", "camera", "--samples", "30", "--noise-std", str(sigma),
                 "--missing-corners", "0.05", "--out", str(data)]) == 0
    assert main(["calibrate", str(data), "--robot", "hsr_jr680", "--measurement", "camera", "--prior", "none",
                 "--loss", "linear", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "not detected (empty cells)" in text and "RMSE/px" in text
    assert "raw nominal" not in text  # the identity hand-eye and target are no guess: no ~1e8 px row
    res = json.loads(out.read_text())
    loaded = jaxcal.load_csv(data)
    train_rows = np.asarray(res["rows"]["train"]["row"]) - 1
    p = len(res["space"]["free"]) if isinstance(res.get("space"), dict) and "free" in res["space"] else None
    p = p or len(jaxcal.load_result(out).space.free_names)
    floor = camera_floor(sigma, p, np.asarray(loaded.y)[train_rows])
    rmse = res["metrics_mm"]["train, after"]["rmse"]
    print(f"CLI camera: train RMSE {rmse:.5f} px, floor {floor.train:.5f} px (p = {p}), "
          f"test RMSE {res['metrics_mm']['test, after']['rmse']:.5f} px, floor {floor.test:.5f}")
    assert rmse == pytest.approx(floor.train, rel=0.03), (rmse, floor)
