"""Every measurement model names the tip it sees (`tip=`): on a kinematic tree a model on
``right_tool`` predicts what the frame kernel (`fk_pose` of that tip) gives, its Jacobian has no
column of the other arm, the `# tip:` line of a data file and the model's plain-data form keep
the tip, and a combined fit over the tree (self-contact of the hands, a plane touched by the left
hand, a tracker on the right hand) reaches the statistical floor on held-out rows."""

from __future__ import annotations

import pathlib
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcal
from jaxcal import (
    Block,
    CableLength,
    Camera,
    Dataset,
    DistanceBar,
    FixedPoint,
    Markers,
    PlaneContact,
    Pose,
    Position,
    SelfContact,
    SessionMarkers,
)
from jaxcal._calibration._blocks import combined_floor
from jaxcal._calibration._io import measurement_from_dict, measurement_to_dict
from jaxcal._core._params import Deviations, layout_for
from jaxcal._core._rotvec import rotvec_to_matrix
from jaxcal._datasets._dataset import mm_joints_metadata
from jaxcal._models._kinematics import fk_pose
from jaxcal._models._tree import tip_tool_group
from jaxcal._models._urdf import load_urdf
from jaxcal._sensors._blocks import combine
from jaxcal._sensors._camera import checkerboard, project_points
from jaxcal._sensors._contact import default_setup
from jaxcal._simulation._simulate import draw_deviations

HUMANOID = pathlib.Path(__file__).resolve().parents[1] / "data" / "urdf" / "humanoid_tree.urdf"
TIP = "right_tool"
MARKERS_MM = np.array([[30.0, 0.0, 10.0], [0.0, 40.0, 5.0], [-20.0, -10.0, 30.0]])


@pytest.fixture(scope="module")
def tree():
    jaxcal.enable_x64()
    return load_urdf(HUMANOID, tips=["left_tool", "right_tool", "head_camera"])


def _models(tree):
    """One model of every kind on ``right_tool``, and readings that make sense for it."""
    cam = Camera(checkerboard(4, 3, 20.0), [800.0, 810.0, 320.0, 240.0, -0.05, 0.01, 0.0, 0.0, 0.0])
    X = (rotvec_to_matrix(np.array([0.1, -0.2, 0.3])), np.array([20.0, -10.0, 40.0]))
    B = (rotvec_to_matrix(np.array([3.0, 0.1, -0.2])), np.array([-30.0, 20.0, 600.0]))
    frames = dict(handeye_rotation=X[0], handeye_translation=X[1], target_rotation=B[0], target_translation=B[1])
    return {
        "cable": CableLength([300.0, 200.0, 100.0], tip=TIP),
        "position": Position(tip=TIP),
        "pose": Pose(orientation_scale=100.0, tip=TIP),
        "markers": Markers(MARKERS_MM, tip=TIP),
        "sessions": SessionMarkers(["f"] * 6, ["p"] * 6, 3, MARKERS_MM, tip=TIP),
        "plane": PlaneContact(("a", "b"), [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], [100.0, 50.0], tip=TIP),
        "point": FixedPoint(("a",), [[200.0, -100.0, 300.0]], tip=TIP),
        "sphere": FixedPoint(("a",), [[200.0, -100.0, 300.0]], radii_mm=25.0, tip=TIP),
        "distance": DistanceBar(tree.dof, tip=TIP),
        "camera_in_hand": Camera(cam.points, cam.intrinsics, "eye_in_hand", tip=TIP, **frames),
        "camera_to_hand": Camera(cam.points, cam.intrinsics, "eye_to_hand", tip=TIP, **frames),
    }


def _expected(name, model, tree, dev, q, qb):
    """The model's prediction by a NumPy transcription over the frame kernel (`fk_pose` of the tip)."""
    T = np.asarray(fk_pose(tree, q, dev, tip=TIP), np.float64)  # the tip link frame
    R, P = T[:, :3, :3], T[:, :3, 3]
    t = np.asarray(tree.tool_of(TIP), np.float64) + np.asarray(dev.values["tool@right_tool"], np.float64)
    p = P + R @ t
    if name == "cable":
        return np.linalg.norm(p - np.asarray(model.anchor), axis=1)
    if name == "position":
        return p
    if name == "pose":
        return np.asarray(fk_pose(tree, q, dev, tip=TIP, tool=True))
    if name in ("markers", "sessions"):
        return P[:, None, :] + np.einsum("nij,kj->nki", R, MARKERS_MM)
    if name == "plane":
        return np.stack([p[:, 2] - 100.0, p[:, 0] - 50.0], 1)
    if name == "point":
        return p - [200.0, -100.0, 300.0]
    if name == "sphere":
        return np.linalg.norm(p - [200.0, -100.0, 300.0], axis=1) - 25.0
    if name == "distance":
        Tb = np.asarray(fk_pose(tree, qb, dev, tip=TIP, tool=True), np.float64)
        return np.linalg.norm(p - Tb[:, :3, 3], axis=1)
    # a camera: X = T_tip_camera (in hand) or T_base_camera (to hand); B the target's pose
    X, B = np.eye(4), np.eye(4)
    X[:3, :3], X[:3, 3] = np.asarray(model.handeye_rotation), np.asarray(model.handeye_translation)
    B[:3, :3], B[:3, 3] = np.asarray(model.target_rotation), np.asarray(model.target_translation)
    F = T if name == "camera_to_hand" else np.linalg.inv(T)
    C = np.linalg.inv(X) @ F @ B  # T_camera_target per row
    b = np.asarray(model.points, np.float64)
    return project_points(np.einsum("nij,kj->nki", C[:, :3, :3], b) + C[:, None, :3, 3], model.intrinsics)


def test_every_model_on_a_tip_predicts_that_tip_and_sees_no_other_arm(tree):
    q = jax.random.uniform(jax.random.key(3), (6, tree.dof), minval=tree.q_min, maxval=tree.q_max)
    qb = jnp.roll(q, 1, axis=0)
    left = {j for b, _, js in tree.branches if b == "left_tool" for j in js}
    right = {j for b, _, js in tree.branches if b == "right_tool" for j in js}
    assert left and right
    for name, model in _models(tree).items():
        layout = layout_for(tree, model)
        dev = draw_deviations(jax.random.key(4), tree, angle_std_deg=0.3, length_std_mm=1.0)
        vals = {g: v for g, v in dev.values.items() if g in layout.group_names}
        if "tool@right_tool" not in layout.group_names:  # a marker set / a camera are the tool themselves
            layout = layout.extend([tip_tool_group(TIP)])
        vals["tool@right_tool"] = np.array([3.0, -2.0, 5.0])
        dev = Deviations(vals, layout)
        want = _expected(name, model, tree, dev, q, qb)
        if name == "distance":
            got = model.predict(tree, dev, q)[:, -1]
            want = np.linalg.norm(  # predict pairs each row with the next one
                np.asarray(fk_pose(tree, q, dev, tip=TIP, tool=True))[:, :3, 3]
                - np.asarray(fk_pose(tree, jnp.roll(q, -1, 0), dev, tip=TIP, tool=True))[:, :3, 3], axis=1)
        elif name in ("plane", "point", "sphere"):
            got = model.distances(tree, dev, q) if name == "plane" else model.residual(tree, dev, q, jnp.zeros(6))
            got = got[:, 0] if name == "sphere" else got
        else:
            got = model.predict(tree, dev, q)
        np.testing.assert_allclose(np.asarray(got), want, rtol=1e-10, atol=1e-8, err_msg=name)
        # the Jacobian: no column of the left arm's joints (nor of the left tip), some of the right arm's
        y = jnp.concatenate([qb, jnp.full((6, 1), 100.0)], 1) if name == "distance" else model.predict(tree, dev, q)
        J = jax.jit(jax.jacfwd(lambda d, m=model: m.residual(tree, d, q, y)))(dev).values  # one program
        for g in ("offset", "dx", "dy", "dz", "drx", "dry"):
            Jg = np.asarray(J[g])
            assert np.abs(Jg[..., sorted(left)]).max() == 0.0, (name, g)
        assert np.abs(np.asarray(J["offset"])[..., sorted(right)]).max() > 0, name
        assert np.abs(np.asarray(J["tip_translation@left_tool"])).max() == 0.0, name
        if model.sees_tool_point:  # the tip's tool point moves it; the default tip's does not
            assert model.tool_group == "tool@right_tool" and "tool@right_tool" in layout_for(tree, model).group_names
            assert np.abs(np.asarray(J["tool@right_tool"])).max() > 0 and np.abs(np.asarray(J["tool"])).max() == 0


def test_tip_in_data_files_and_plain_data(tree):
    models = _models(tree)
    for name, model in models.items():
        back = measurement_from_dict(measurement_to_dict(model))
        assert back.tip == TIP and type(back) is type(model), name
        assert "tip" not in measurement_to_dict(model.at_tip(None)), name  # serial robots' files as before
    q = np.zeros((8, tree.dof))
    meta = mm_joints_metadata(tree)
    data = Dataset(q, np.zeros((8, 3)), "position", {**meta, "tip": TIP})
    setup = jaxcal.measurement_for(data, tree, estimate="tool,base")
    assert setup.measurement.tip == TIP and setup.measurement.tool_group == "tool@right_tool"
    assert any("tip right_tool" in n for n in setup.notes)
    space = jaxcal.ParameterSpace.for_robot(tree, measurement=setup.measurement, tool=True, base=True)
    assert {"tool_x@right_tool", "base_x"} <= set(space.free_names) and "tool_x" not in space.free_names
    default = Dataset(q, np.zeros((8, 3)), "position", {**meta, "tip": "left_tool"})
    assert jaxcal.measurement_for(default, tree).measurement.tip is None  # the default tip: the standard tool
    bad = Dataset(q, np.zeros((8, 3)), "position", {**meta, "tip": "nose"})
    with pytest.raises(ValueError, match=r"'# tip: nose' line: tip 'nose' is not a tip of robot 'humanoid_tree'; "
                                         r"its tips: \['left_tool', 'right_tool', 'head_camera'\]"):
        jaxcal.measurement_for(bad, tree)
    with pytest.raises(ValueError, match="is robot 'humanoid_tree''s default tip: a model sees it when it names no tip"):
        Position(tip="left_tool").predict(tree, None, q)
    # a serial robot: no other tip, and its own tip is no tip= at all
    dh = jaxcal.robots.hsr_jr680()
    with pytest.raises(ValueError, match="its tips: none"):
        jaxcal.measurement_for(Dataset(np.zeros((8, 6)), np.zeros((8, 3)), "position", {"tip": TIP}), dh)


SIG_TOUCH, SIG_PLANE, SIG_TRACKER = 0.1, 0.05, 0.1


def test_combined_fit_over_the_tree_at_the_floor(tree, capsys):
    """Self-contact of the two hands + three planes touched by the left hand + a tracker on the right
    hand: one fit at the combined floor on held-out rows; the head (seen by no block) is named."""
    truth = draw_deviations(jax.random.key(11), tree, angle_std_deg=0.2, length_std_mm=0.5)
    tracker, planes = Position(tip=TIP), default_setup("plane", tree)
    layout = layout_for(tree, tracker).extend(planes.extra_groups())  # the planes true as nominal
    vals = {g: v for g, v in truth.values.items() if g in layout.group_names}
    vals |= {"tool": np.array([1.0, -2.0, 1.5]), "tool@right_tool": np.array([-1.5, 1.0, 2.0]),
             "base_rotation": np.array([0.01, -0.02, 0.03]), "base_translation": np.array([5.0, -3.0, 2.0])}
    truth = Deviations(vals, layout)
    touch_q, touch_y = jaxcal.simulate_self_contact(jax.random.key(12), tree, ("left_tool", TIP), n_samples=400,
                                                    noise_std=SIG_TOUCH, true_deviations=truth)
    plane = jaxcal.simulate_contact(jax.random.key(13), tree, planes, n_samples=400, noise_std=SIG_PLANE,
                                    true_deviations=truth, test_fraction=0.5)
    track = jaxcal.simulate_experiment(jax.random.key(14), tree, n_samples=400, noise_std=SIG_TRACKER,
                                       measurement=tracker, true_deviations=truth, test_fraction=0.5)
    touch = SelfContact(("left_tool", TIP))

    def blocks(part):
        sl = slice(0, 200) if part == "train" else slice(200, 400)
        return [Block("touch", touch, (touch_q[sl], touch_y[sl]), SIG_TOUCH),
                Block("plane", planes, getattr(plane, part), SIG_PLANE, extras="tool"),
                Block("tracker", tracker, getattr(track, part), SIG_TRACKER, extras="tool,base")]

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = jaxcal.calibrate_blocks(tree, blocks("train"))
    free = set(res.space.free_names)
    assert {"tool_x", "tool_x@right_tool"} <= free and any(n.startswith("base_x") for n in free)
    # the tracker's tool point is the one the self-contact sees (one group, shared)
    assert np.abs(np.asarray(res.deviations.values["tool@right_tool"]) - [-1.5, 1.0, 2.0]).max() < 0.5
    comb, q, y = combine(tree, blocks("test"))
    r = np.asarray(comb.residual(tree, res.deviations, q, y))[comb.observed(y)]  # the real entries, no padding
    n_train = sum(s.n_residuals for s in res.blocks)
    ratio = float(np.sqrt(np.mean(r**2))) / combined_floor(res.identifiability.rank, n_train).test
    print("held-out whitened RMS / combined floor", ratio)
    assert abs(ratio - 1) < 0.08, ratio
    # what no block sees: the head's joints and its tip, named by the identifiability report
    head = {j + 1 for b, _, js in tree.branches if b == "head_camera" for j in js}
    unseen = set(res.identifiability.unidentifiable) | (set(layout_for(tree, comb).names) - free)
    assert head and all(f"offset_{j}" in unseen and f"offset_{j}" not in free for j in head)
    assert "tip_dx@head_camera" not in free
    # `jaxcal calibrate --combine`'s robot table of a tree: each joint with its branch, a row per tip
    from jaxcal.cli._tables import _print_chain_table

    _print_chain_table(tree, res, res.uncertainty.std_display())
    rows = {ln.strip().split("  ")[0]: ln for ln in capsys.readouterr().out.splitlines()}
    for j, name in enumerate(tree.joint_names):
        assert f"{j + 1} {tree.entry_labels()[f'offset_{j + 1}']}" in rows, name
    for tip in tree.tips:  # a row per tip, its entries * where not calibrated, ± σ where free
        entries = [n for n, lab in tree.entry_labels().items() if lab == f"tip {tip}"]
        assert len(entries) == 6 and rows[f"tip → {tip}"].count("*") == sum(n not in free for n in entries), tip
        assert rows[f"tip → {tip}"].count("±") == sum(n in free for n in entries), tip
