"""Self-observation: a camera on one tip of a kinematic tree sees a target on another tip
(`jaxcal.Camera(..., mount="tip_to_tip", tip=, target_tip=)`, a head camera looking at a hand).
The image runs through both chains; checked against an independent NumPy product of the URDF's
4×4 transforms and a NumPy pinhole projection, its Jacobian against central differences, the
closed-form start (Park–Martin with the hands' relative motion), a fit at the statistical floor
on held-out images, the data file's `# tip:` / `# target_tip:` lines and the errors that name a
tip the robot lacks."""

from __future__ import annotations

import importlib.util
import pathlib
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import central_differences

import jaxcal
from jaxcal import Camera, Dataset, checkerboard, resolve_tip
from jaxcal._calibration._io import measurement_from_dict, measurement_to_dict
from jaxcal._core._rotvec import rotvec_to_matrix
from jaxcal._datasets._dataset import mm_joints_metadata
from jaxcal._models._urdf import load_urdf
from jaxcal._sensors._camera import _T, _residual_jit, camera_floor
from jaxcal._simulation._simulate import draw_deviations

TESTS = pathlib.Path(__file__).resolve().parents[1]
HUMANOID = TESTS / "data" / "urdf" / "humanoid_tree.urdf"
TIPS = ["left_tool", "right_tool", "head_camera"]
CAMERA_TIP, TARGET_TIP = "head_camera", "left_tool"
INTR = [800.0, 810.0, 640.0, 512.0, -0.05, 0.02, 0.0005, -0.0003, 0.001]
SIGMA = 0.3  # px
#: the hand in front of the head: torso raised, left arm forward with the elbow bent, head turned to it
HOME = {"torso_lift_joint": 100.0, "l_shoulder_pitch_joint": -1.2, "l_elbow_joint": -1.3, "l_wrist_pitch_joint": 0.3,
        "head_pan_joint": 0.4, "head_tilt_joint": 0.2}
#: views: ± degrees per joint around HOME (the right arm still; it is on neither path)
SPREAD = {"torso_yaw_joint": 10.0, **{n: 10.0 for n in ("l_shoulder_pitch_joint", "l_shoulder_roll_joint",
          "l_shoulder_yaw_joint", "l_elbow_joint", "l_forearm_yaw_joint", "l_wrist_pitch_joint", "l_wrist_roll_joint")},
          "head_pan_joint": 6.0, "head_tilt_joint": 6.0}


def _numpy_urdf_fk():
    """``numpy_urdf_fk`` of tests/models/test_chain.py (its own URDF parser and 4×4 products)."""
    spec = importlib.util.spec_from_file_location("_chain_reference", TESTS / "models" / "test_chain.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.numpy_urdf_fk


def _per_joint(tree, values: dict, default=0.0) -> np.ndarray:
    out = np.full(tree.dof, default)
    for name, v in values.items():
        out[tree.joint_names.index(name)] = v
    return out


def _camera(tree, **frames) -> Camera:
    return Camera(checkerboard(5, 4, 15.0), INTR, "tip_to_tip", image_size=(1280, 1024),
                  tip=resolve_tip(tree, CAMERA_TIP), target_tip=resolve_tip(tree, TARGET_TIP), **frames)


@pytest.fixture(scope="module")
def tree():
    jaxcal.enable_x64()
    return load_urdf(HUMANOID, tips=TIPS)


@pytest.fixture(scope="module")
def simulated(tree):
    """100 views of the hand's target by the head camera (0.3 px), the robot deviated; the true
    camera with its true hand-eye transform and target pose as nominal frames."""
    truth = draw_deviations(jax.random.key(21), tree, angle_std_deg=0.2, length_std_mm=0.5)
    q, y, cam, truth = jaxcal.simulate_camera(jax.random.key(22), tree, _camera(tree), n_views=100, noise_px=SIGMA,
                                              true_deviations=truth, home=_per_joint(tree, HOME),
                                              joint_spread_deg=_per_joint(tree, SPREAD))
    v = {g: np.asarray(truth.values[g], np.float64) for g in ("handeye_rotation", "handeye_translation",
                                                                "target_rotation", "target_translation")}
    X = _T(rotvec_to_matrix(v["handeye_rotation"]), v["handeye_translation"])
    B = _T(rotvec_to_matrix(v["target_rotation"]), v["target_translation"])
    return q, y, cam, truth, cam.with_frames(X, B)


def test_image_is_the_pinhole_projection_through_both_tips(tree, simulated):
    """Nominal robot, nominal frames: the predicted pixels are a NumPy pinhole projection (OpenCV's
    distortion written out here) of ``X⁻¹·T_A⁻¹·T_B·B·b``, ``T_A``, ``T_B`` the head camera's and the
    hand's link frames as a plain product of the URDF's 4×4 transforms."""
    numpy_urdf_fk = _numpy_urdf_fk()
    q = np.asarray(simulated[0][:6])
    cam = simulated[4]  # nominal frames = the simulation's true ones: the target in view
    got = np.asarray(cam.predict(tree, None, jnp.asarray(q)))
    text = HUMANOID.read_text()
    X, B = (_T(np.asarray(R), np.asarray(t)) for R, t in ((cam.handeye_rotation, cam.handeye_translation),
                                                          (cam.target_rotation, cam.target_translation)))
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = INTR
    b = np.c_[np.asarray(cam.points), np.ones(cam.n_points)]
    for n in range(q.shape[0]):
        T = {}
        for tip in (CAMERA_TIP, TARGET_TIP):
            cols = [tree.joint_names.index(j) for j in load_urdf(HUMANOID, tip=tip).joint_names]
            T[tip] = numpy_urdf_fk(text, "base_link", tip, q[n, cols])
        p = (np.linalg.inv(X) @ np.linalg.inv(T[CAMERA_TIP]) @ T[TARGET_TIP] @ B @ b.T)[:3].T
        x, y = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        u = fx * (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)) + cx
        v = fy * (y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y) + cy
        np.testing.assert_allclose(got[n], np.c_[u, v], rtol=0, atol=1e-8)


def test_jacobian_against_central_differences(tree, simulated):
    """Robot and camera parameters free (the default space: every joint's errors, the tips', the
    hand-eye transform and the target pose), away from the nominal point: the structured derivative
    against central differences; the right arm (on neither path) has no column, nor the joints the
    two tips share (they cancel out of ``T_A⁻¹T_B``), the head and the left arm have."""
    q, y, _, _, cam = simulated
    q, y = q[:8], y[:8]
    space = jaxcal.ParameterSpace.for_robot(tree, measurement=cam)
    pr = jaxcal.Problem(tree, cam, q, y, space)
    x = pr.x0() + 1e-3 * jax.random.normal(jax.random.key(5), pr.x0().shape)
    J = np.asarray(eqx.filter_jit(lambda p, x: p.jacobian(x))(pr, x))  # one program, not op by op
    fd = central_differences(pr.residual, x, 1e-6)
    np.testing.assert_allclose(J, fd, rtol=0, atol=1e-5 * np.abs(J).max())
    names = space.free_names
    col = {n: np.abs(J[:, i]).max() for i, n in enumerate(names)}
    joint = {j + 1: branch for branch, _, js in tree.branches for j in js}
    per_joint = {n: joint[int(n.rsplit("_", 1)[1])] for n in names if "@" not in n and n.rsplit("_", 1)[-1].isdigit()}
    unseen = [n for n, branch in per_joint.items() if branch in ("right_tool", "torso_link")]  # off both paths / shared
    assert {"right_tool", "torso_link"} <= {per_joint[n] for n in unseen}
    assert all(col[n] < 1e-9 * np.abs(J).max() for n in unseen), {n: col[n] for n in unseen}
    assert all(col[n] > 0 for n in names if n.startswith(("handeye_", "target_")))
    for branch in ("left_tool", "head_camera"):
        js = [j + 1 for b, _, jj in tree.branches if b == branch for j in jj]
        assert max(col.get(f"offset_{j}", 0.0) for j in js) > 0, branch


def test_closed_form_start_recovers_the_frames(tree, simulated):
    """Noise-free images, robot at the truth: per-image PnP and Park–Martin with the hand's motion
    relative to the head (``T_B⁻¹T_A`` as the gripper) give the hand-eye transform and the target
    pose to round-off."""
    q, _, cam, truth, _ = simulated
    q = q[:12]
    y = jnp.asarray(cam.predict(tree, truth, q))
    start = truth.replace(**{g: jnp.zeros(3) for g in ("handeye_rotation", "handeye_translation", "target_rotation",
                                                       "target_translation")})
    est = jaxcal.initial_extras(tree, cam, (q, y), start=start)
    for g in ("handeye_rotation", "handeye_translation", "target_rotation", "target_translation"):
        np.testing.assert_allclose(np.asarray(est.deviations.values[g]), np.asarray(truth.values[g]), rtol=0,
                                   atol=1e-6, err_msg=g)
    assert est.rmse_after < 1e-6 and "camera on tip head_camera" in est.message and "target on tip left_tool" in est.message


def test_fit_at_the_floor_on_held_out_images(tree, simulated):
    """30 training images, the hand-eye transform and target pose unknown (started in closed form),
    robot deviated; least squares over what the images see: held-out whitened RMS within 4 % of the
    statistical floor (70 held-out images); the shared torso joints, which the camera cannot see,
    stay out of the fit."""
    q, y, cam, truth, _ = simulated
    train, test = slice(0, 30), slice(30, 100)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # narrow joint coverage: views around one posture
        res = jaxcal.calibrate(tree, cam, (q[train], y[train]), "lm")
    assert res.ok
    p = res.identifiability.rank
    r = np.asarray(_residual_jit(cam, tree, res.deviations, q[test], y[test])) / SIGMA
    whitened = float(np.sqrt(np.mean(r**2)))
    floor = camera_floor(SIGMA, p, y[train]).test / (SIGMA * np.sqrt(2))  # per entry, whitened
    print(f"tip-to-tip camera: held-out whitened RMS {whitened:.4f}, floor {floor:.4f} (p = {p}), "
          f"ratio {whitened / floor:.4f}")
    assert abs(whitened / floor - 1) < 0.04
    free = set(res.space.free_names)
    assert not free & {f"{g}_{j}" for g in ("offset", "dx", "dy", "dz", "drx", "dry", "drz") for j in (1, 2)}
    assert {"handeye_x", "target_x"} <= free


def test_data_file_lines_and_plain_data(tree, simulated, tmp_path):
    q, y, cam, _, _ = simulated
    meta = {"target": "checkerboard:5x4:15", "camera_intrinsics": ",".join(map(str, INTR)), "mount": "tip_to_tip",
            "image_size_px": "1280,1024", "tip": CAMERA_TIP, "target_tip": TARGET_TIP, **mm_joints_metadata(tree)}
    Dataset(q[:5], y[:5], "camera", meta).to_csv(tmp_path / "seen.csv")
    data = jaxcal.load_csv(tmp_path / "seen.csv")
    setup = jaxcal.measurement_for(data, tree)
    m = setup.measurement
    assert (m.mount, m.tip, m.target_tip) == ("tip_to_tip", CAMERA_TIP, None)  # left_tool: the default tip
    assert any("camera on tip head_camera, target on tip left_tool" in n for n in setup.notes)
    no_mount = Dataset(q[:5], y[:5], "camera", {k: v for k, v in meta.items() if k != "mount"})
    assert jaxcal.measurement_for(no_mount, tree).measurement.mount == "tip_to_tip"  # the target_tip line says it
    back = measurement_from_dict(measurement_to_dict(cam))
    assert (back.mount, back.tip, back.target_tip) == ("tip_to_tip", CAMERA_TIP, None)
    assert measurement_to_dict(back) == measurement_to_dict(cam)
    d = measurement_to_dict(Camera(cam.points, cam.intrinsics, "tip_to_tip", tip="right_tool", target_tip="head_camera"))
    assert d["tip"] == "right_tool" and d["target_tip"] == "head_camera"
    assert "target_tip" not in measurement_to_dict(Camera(cam.points, cam.intrinsics))  # the other mounts as before


def test_bad_tips_are_named(tree, simulated):
    q, y, cam, _, _ = simulated
    tips = r"its tips: \['left_tool', 'right_tool', 'head_camera'\]"
    nose = Camera(cam.points, cam.intrinsics, "tip_to_tip", tip="head_camera", target_tip="nose")
    with pytest.raises(ValueError, match=r"target_tip: tip 'nose' is not a tip of robot 'humanoid_tree'; " + tips):
        nose.predict(tree, None, q[:2])
    with pytest.raises(ValueError, match=r"tip 'eye' is not a tip of robot 'humanoid_tree'; " + tips):
        Camera(cam.points, cam.intrinsics, "tip_to_tip", tip="eye", target_tip="right_tool").predict(tree, None, q[:2])
    meta = {"target": "checkerboard:5x4:15", "camera_intrinsics": ",".join(map(str, INTR)), "tip": CAMERA_TIP,
            **mm_joints_metadata(tree)}
    with pytest.raises(ValueError, match=r"'# target_tip: nose' line: tip 'nose' is not a tip of robot "
                                         r"'humanoid_tree'; " + tips):
        jaxcal.measurement_for(Dataset(q[:5], y[:5], "camera", {**meta, "target_tip": "nose"}), tree)
    with pytest.raises(ValueError, match=r"'# tip: eye' line: tip 'eye' is not a tip"):
        jaxcal.measurement_for(Dataset(q[:5], y[:5], "camera", {**meta, "tip": "eye", "target_tip": "right_tool"}),
                               tree)
    with pytest.raises(ValueError, match=r"need a '# target_tip: NAME' line"):
        jaxcal.measurement_for(Dataset(q[:5], y[:5], "camera", {**meta, "mount": "tip_to_tip"}), tree)
    with pytest.raises(ValueError, match=r"'# target_tip: right_tool' line applies to mount tip_to_tip"):
        jaxcal.measurement_for(Dataset(q[:5], y[:5], "camera", {**meta, "mount": "eye_in_hand",
                                                                 "target_tip": "right_tool"}), tree)
    with pytest.raises(ValueError, match="two different tips; both are on 'right_tool'"):
        Camera(cam.points, cam.intrinsics, "tip_to_tip", tip="right_tool", target_tip="right_tool")
    with pytest.raises(ValueError, match="two different tips; both are on the robot's default tip"):
        Camera(cam.points, cam.intrinsics, "tip_to_tip")
    with pytest.raises(ValueError, match="two different tips"):
        cam.at_tip(None)  # the camera moved onto the target's tip (left_tool, the default)
    with pytest.raises(ValueError, match="target_tip='right_tool' applies to mount='tip_to_tip'"):
        Camera(cam.points, cam.intrinsics, "eye_in_hand", target_tip="right_tool")
    # a serial robot has no second tip
    with pytest.raises(ValueError, match=r"tip 'left_tool' is not a tip of robot 'hsr_jr680'; its tips: none"):
        Camera(cam.points, cam.intrinsics, "tip_to_tip", target_tip="left_tool").predict(
            jaxcal.robots.hsr_jr680(), None, jnp.zeros((2, 6)))


def test_cli_simulate_writes_both_tips(tree, tmp_path, capsys):
    """`jaxcal simulate --measurement camera --mount tip-to-tip` on a URDF with two tips: the camera on
    the first, the target on the second, written as `# tip:` / `# target_tip:` lines that
    `measurement_for` reads back; a robot with one tip is a usage error (exit 2) that says so."""
    from jaxcal.cli import main

    out = tmp_path / "seen.csv"
    assert main(["simulate", "--measurement", "camera", "--mount", "tip-to-tip", "--robot", str(HUMANOID), "--tip",
                 "head_camera,left_tool", "--samples", "4", "--noise-std", "0.3", "--out", str(out)]) == 0
    assert "camera on head_camera, target on left_tool" in capsys.readouterr().out
    data = jaxcal.load_csv(out)
    assert (data.meta["mount"], data.meta["tip"], data.meta["target_tip"]) == ("tip_to_tip", "head_camera", "left_tool")
    two = load_urdf(HUMANOID, tips=["head_camera", "left_tool"])
    m = jaxcal.measurement_for(data, two).measurement
    assert (m.mount, m.tip, m.target_tip) == ("tip_to_tip", None, "left_tool")  # head_camera: that robot's default
    assert main(["simulate", "--measurement", "camera", "--mount", "tip-to-tip", "--samples", "4",
                 "--out", str(tmp_path / "x.csv")]) == 2
    assert "--mount tip-to-tip needs a robot with two tips" in capsys.readouterr().err
