"""Measurement planning for the set-ups without a tracker (issue 23): plane contact, fixed points and
spheres, the distance bar and the camera. Candidates satisfy their sensor's constraint on the
nominal robot (checked with the forward kinematics and, for the camera, OpenCV's projection), and
the selected poses beat random candidates of the same number on the D-criterion."""

import math

import jax
import numpy as np
import pytest

import jaxcal
from jaxcal._experiments import _plan
from jaxcal._sensors._camera import planning_camera
from jaxcal._sensors._contact import DistanceBar, FixedPoint, default_setup


def _model(kind, robot):
    if kind == "camera":
        return planning_camera(robot)
    if kind == "distance":
        return DistanceBar(robot.dof)
    if kind == "sphere":
        pts = default_setup("point", robot)
        return FixedPoint(pts.labels, np.asarray(pts.centres), radii_mm=30.0)
    return default_setup(kind, robot)


def _tool_points(robot, q):
    T = np.asarray(jaxcal.fk_pose(robot, jax.numpy.asarray(q), tool=True), np.float64)
    return T[:, :3, 3]


def _check_constraint(robot, m, cand):
    """Every candidate touches its plane / point / sphere, or its bar pair is a bar length apart."""
    q = np.asarray(cand.q, np.float64)
    y = np.asarray(cand.y, np.float64)
    p = _tool_points(robot, q)
    if m.kind == "distance":
        d = np.linalg.norm(p - _tool_points(robot, y[:, :robot.dof]), axis=1)
        assert np.allclose(d, y[:, robot.dof], atol=1e-6)
        assert set(np.round(y[:, robot.dof], 6)) == {150.0, 300.0}
        return
    k = np.round(y).astype(int)
    assert set(k) == set(range(len(m.labels)))  # every label gets candidates
    if m.kind == "plane":
        n, d = (np.asarray(a, np.float64) for a in (m.normals, m.offsets))
        assert np.max(np.abs(np.einsum("ij,ij->i", p, n[k]) - d[k])) < 1e-6
    else:
        c, r = np.asarray(m.centres, np.float64), np.asarray(m.radii, np.float64)
        assert np.max(np.abs(np.linalg.norm(p - c[k], axis=1) - r[k])) < 1e-6
    # orientations differ (a pivot calibration needs them): the flange z axes spread
    z = np.asarray(jaxcal.fk_pose(robot, jax.numpy.asarray(q)), np.float64)[:, :3, 2]
    assert np.linalg.svd(z - z.mean(axis=0), compute_uv=False)[-1] > 0.1 * math.sqrt(len(z))


def _sees_target_opencv(robot, cam, q):
    """[n] bool: the whole target in front of the camera and inside the image, projected by OpenCV."""
    cv2 = pytest.importorskip("cv2")
    F = np.asarray(jaxcal.fk_pose(robot, jax.numpy.asarray(q)), np.float64)
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = np.asarray(cam.handeye_rotation), np.asarray(cam.handeye_translation)
    B = np.eye(4)
    B[:3, :3], B[:3, 3] = np.asarray(cam.target_rotation), np.asarray(cam.target_translation)
    k = np.asarray(cam.intrinsics, np.float64)
    K = np.array([[k[0], 0, k[2]], [0, k[1], k[3]], [0, 0, 1.0]])
    pts = np.asarray(cam.points, np.float64)
    w, h = cam.image_size
    out = []
    for Fi in F:
        C = np.linalg.inv(X) @ np.linalg.inv(Fi) @ B  # eye-in-hand: T_camera_target
        z = (pts @ C[:3, :3].T + C[:3, 3])[:, 2]
        uv = cv2.projectPoints(pts, cv2.Rodrigues(C[:3, :3])[0], C[:3, 3], K, k[4:])[0][:, 0]
        out.append(bool(np.all(z > 0) and np.all((uv >= 0) & (uv <= [w, h]))))
    return np.asarray(out)


# plane and camera (every selected pose sees the target) in the default run; the others are slow
# (30-40 s each on the shared 2-core machine, mostly compilation)
@pytest.mark.parametrize("kind", ["plane", "camera", *(pytest.param(k, marks=pytest.mark.slow)
                                                      for k in ("point", "sphere", "distance"))])
def test_selected_poses_beat_random_candidates(paper_robot, kind):
    m = _model(kind, paper_robot)
    cand = _plan.candidate_poses(jax.random.key(3), paper_robot, m, 150)
    if kind == "camera":
        assert _sees_target_opencv(paper_robot, m, cand).all()
        n = 10
    else:
        _check_constraint(paper_robot, m, cand)
        n = 40
    sel = _plan.select_poses(paper_robot, m, cand, n, exchange=False)
    if kind == "camera":
        assert _sees_target_opencv(paper_robot, m, sel.q).all()
    else:  # the selected rows keep their readings (labels, the bar's second pose)
        assert np.array_equal(np.asarray(sel.data.y), np.asarray(cand.y)[sel.index])
    # D-criterion on the same parameters and column scales: O1 = (∏σ_i)^(1/p)/√N of the scaled
    # Jacobian, so a larger O1 at equal N is a smaller predicted generalised parameter variance
    rows = lambda idx: cand.subset(idx) if hasattr(cand, "subset") else np.asarray(cand)[idx]  # noqa: E731
    o1 = lambda idx: _plan.indices_from_jacobian(  # noqa: E731
        _plan.planning_jacobian(paper_robot, m, rows(idx), sel.space), sel.scale).o1
    assert o1(sel.index) == pytest.approx(sel.indices.o1, rel=1e-9)
    rng = np.random.default_rng(0)
    random_o1 = [o1(rng.choice(150, n, replace=False)) for _ in range(5)]
    assert sel.indices.o1 > max(random_o1), (sel.indices.o1, random_o1)
    # and the predicted per-parameter σ (posterior, scaled by the column scales) is smaller overall
    sd = lambda idx: _plan.predicted_accuracy(paper_robot, m, rows(idx), 0.1, space=sel.space,  # noqa: E731
                                              q_test=cand)
    best = sd(sel.index)
    worst = sd(rng.choice(150, n, replace=False))
    if best.names == worst.names:
        assert np.sum(np.log(best.param_std)) < np.sum(np.log(worst.param_std))


def test_distance_candidates_as_pose_pairs(paper_robot):
    """[N, 2·dof] pose pairs read like a distance Dataset: the same Jacobian rows."""
    m = DistanceBar(paper_robot.dof)
    cand = _plan.candidate_poses(jax.random.key(1), paper_robot, m, 40)
    pairs = np.concatenate([np.asarray(cand.q), np.asarray(cand.y)[:, :paper_robot.dof]], axis=1)
    space = jaxcal.ParameterSpace.for_robot(paper_robot, measurement=m)
    assert np.allclose(_plan.planning_jacobian(paper_robot, m, pairs, space),
                       _plan.planning_jacobian(paper_robot, m, cand, space),
                       atol=1e-12)
    with pytest.raises(ValueError, match="pose pairs"):
        _plan.planning_jacobian(paper_robot, m, np.asarray(cand.q), space)


def test_camera_candidates_fraction_and_errors(paper_robot):
    cam = planning_camera(paper_robot)
    from jaxcal._sensors._camera import target_in_view

    q = _plan.candidate_poses(jax.random.key(2), paper_robot, cam, 60, min_visible=0.5)
    frac = target_in_view(paper_robot, cam, q).mean(axis=1)
    assert frac.min() >= 0.5 and frac.min() < 1.0  # some see only part of the board
    # a 10 × 10 px image far off the principal point (640, 512): the whole board never lands in it
    away = jaxcal.Camera(cam.points, cam.intrinsics, handeye_rotation=cam.handeye_rotation,
                         handeye_translation=cam.handeye_translation, target_rotation=cam.target_rotation,
                         target_translation=cam.target_translation, image_size=(10, 10))
    with pytest.raises(ValueError, match="see at least"):
        _plan.candidate_poses(jax.random.key(2), paper_robot, away, 10)


@pytest.mark.parametrize("kind", ["plane", *(pytest.param(k, marks=pytest.mark.slow) for k in ("camera", "distance"))])
def test_cli_plan_sensor_files_read_back(paper_robot, kind, tmp_path, capsys):
    from jaxcal.cli import main

    out = tmp_path / f"{kind}.csv"
    assert main(["--no-cache", "plan", "--measurement", kind, "--poses", "12", "--candidates", "100",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "predicted test RMSE" in text and ("px" in text) == (kind == "camera")
    data = jaxcal.load_csv(out, kind=kind)
    assert data.n == 12
    if kind == "camera":
        assert np.isnan(np.asarray(data.y)).all()
        assert _sees_target_opencv(paper_robot, planning_camera(paper_robot), data.q).all()
    else:
        _check_constraint(paper_robot, _model(kind, paper_robot), data)
