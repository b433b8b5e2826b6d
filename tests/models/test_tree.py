"""Kinematic trees (issue 51): a humanoid-style URDF (``tests/data/urdf/humanoid_tree.urdf``, made up
for these tests: prismatic lift + torso yaw shared, a 7-joint and a 6-joint arm, a 2-joint head with a
camera, a chest camera). Every tip against an independent NumPy product of the URDF's 4×4 transforms
and against the chain error model written out per joint name; the Jacobian against finite
differences; a shared torso joint is one parameter that moves every tip; a one-tip tree is the
SerialChain; file form round trip; export → reload within 1e-9 mm; bad input errors."""

import json
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import central_differences
from test_chain import numpy_urdf_fk
from test_chain_tip import numpy_chain_fk

import jaxcal
from jaxcal import export_urdf, load_urdf
from jaxcal._core._params import Deviations, group_of, layout_for
from jaxcal._models._chain import GEOMETRIC_GROUPS
from jaxcal._models._kinematics import fk_pose, fk_position, fk_position_jit, tool_point_soa
from jaxcal._models._nongeometric import nongeometric_from_dict
from jaxcal._models._tree import KinematicTree
from jaxcal._models._urdf import tree_from_dict

URDF = pathlib.Path(__file__).parents[1] / "data" / "urdf" / "humanoid_tree.urdf"
TIPS = ["left_tool", "right_tool", "head_camera"]
TOOLS = {"left_tool": (0.0, 0.0, 45.0), "right_tool": (10.0, -5.0, 30.0), "head_camera": (0.0, 0.0, 0.0)}

pose_jit = jax.jit(fk_pose, static_argnames=("tool", "tip"))
position_jit = jax.jit(fk_position, static_argnames=("tool", "tip"))


@pytest.fixture(scope="module")
def tree():
    return load_urdf(URDF, tips=TIPS, tool=TOOLS)


def _q(robot, n, seed=0):
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(robot.q_min), np.asarray(robot.q_max)
    return rng.uniform(lo, hi, size=(n, robot.dof))


def _random_dev(robot, seed=1, scale=1.0) -> Deviations:
    """Random geometric deviations of every robot group (mm ~0.5, rad ~0.003) and tool points."""
    rng = np.random.default_rng(seed)
    layout = layout_for(robot)
    flat = np.zeros(layout.size)
    for i, (unit, kind) in enumerate(zip(layout.units, layout.kinds)):
        if kind == "geometric" or layout.names[i].startswith("tool"):
            flat[i] = rng.normal(0, scale * (0.003 if unit == "rad" else 0.5))
    return Deviations.unravel(jnp.asarray(flat), layout)


def _by_name(tree, dev, chain):
    """The chain's deviations picked from the tree's by joint name (independent of ``tree.path``)."""
    cols = [tree.joint_names.index(n) for n in chain.joint_names]
    out = {g: np.asarray(dev.values[g])[cols] for g, _ in GEOMETRIC_GROUPS}
    tt, tr = tree.tip_group_names(chain.tip)
    return out | {"tip_translation": np.asarray(dev.values[tt]), "tip_rotation": np.asarray(dev.values[tr])}, cols


# ---------------------------------------------------------------- structure


def test_structure_joint_order_branches_and_groups(tree):
    assert isinstance(tree, jaxcal.AbstractRobot) and tree.dof == 17 and tree.tips == tuple(TIPS)
    # order of first appearance along the tips' paths: lift, yaw, left arm, right arm, head
    assert tree.joint_names[:3] == ("torso_lift_joint", "torso_yaw_joint", "l_shoulder_pitch_joint")
    assert tree.joint_names[9] == "r_shoulder_pitch_joint" and tree.joint_names[-1] == "head_tilt_joint"
    assert tree.joint_units()[0] == "mm" and set(tree.joint_units()[1:]) == {"rad"}
    assert [(b, p, len(j)) for b, p, j in tree.branches] == [
        ("torso_link", None, 2), ("left_tool", "torso_link", 7), ("right_tool", "torso_link", 6),
        ("head_camera", "torso_link", 2)]
    assert tree.path("head_camera") == (0, 1, 15, 16)
    layout = layout_for(tree)
    # one entry per tree joint per group, then each tip's own tip groups, named by the tip
    assert layout.group("offset").size == 17
    assert "tip_dx@right_tool" in layout.names and "tip_drz@head_camera" in layout.names
    assert group_of("tip_dy@left_tool") == "tip_translation@left_tool"
    assert tree.entry_labels()["offset_6"] == "left_tool / l_elbow_joint"
    assert tree.entry_labels()["dz_2"] == "torso_link / torso_yaw_joint"
    assert not tree.free_by_default("drz_2") and tree.free_by_default("drz_1")  # revolute / prismatic
    assert tree.dh_rows_deg() is None
    # reach: at least the farthest tool point seen at random joint angles
    q = _q(tree, 64, seed=5)
    far = max(np.linalg.norm(np.asarray(position_jit(tree, jnp.asarray(q), tip=t)), axis=1).max() for t in TIPS)
    assert far <= tree.reach_mm() < 3 * far


# ---------------------------------------------------------------- kinematics


def test_tips_match_numpy_urdf_transforms(tree):
    """Nominal tip frames and tool points against a plain product of the URDF's 4×4 transforms
    (its own parser: tests/models/test_chain.py); the tree's columns of each path picked by name."""
    text = URDF.read_text()
    q = _q(tree, 6, seed=2)
    for tip in TIPS:
        T = np.asarray(pose_jit(tree, jnp.asarray(q), tip=tip))
        p = np.asarray(position_jit(tree, jnp.asarray(q), tip=tip))
        chain_joints = load_urdf(URDF, tip=tip).joint_names
        cols = [tree.joint_names.index(n) for n in chain_joints]
        for n in range(q.shape[0]):
            ref = numpy_urdf_fk(text, "base_link", tip, q[n, cols])
            np.testing.assert_allclose(T[n, :3, 3], ref[:3, 3], rtol=0, atol=1e-9)
            np.testing.assert_allclose(T[n, :3, :3], ref[:3, :3], rtol=0, atol=1e-12)
            np.testing.assert_allclose(p[n], ref[:3, :3] @ np.asarray(TOOLS[tip]) + ref[:3, 3], rtol=0, atol=1e-9)


@pytest.mark.parametrize("urdf", ["humanoid", "fetch"])
def test_deviated_tips_match_chain_error_model(tree, urdf):
    """With deviations, each tip's frame is the chain error model (written out as 4×4 products in
    tests/models/test_chain_tip.py) of that tip's URDF chain, its entries picked by joint name; also
    on the Fetch URDF (a real robot: arm and head on a shared prismatic torso lift)."""
    path = URDF if urdf == "humanoid" else URDF.with_name("fetch.urdf")
    tips = TIPS if urdf == "humanoid" else ["gripper_link", "head_tilt_link"]
    tree = tree if urdf == "humanoid" else load_urdf(path, tips=tips)
    dev = _random_dev(tree, seed=3)
    q = _q(tree, 5, seed=4)
    for tip in tips:
        chain = load_urdf(path, tip=tip)
        g, cols = _by_name(tree, dev, chain)
        T = np.asarray(pose_jit(tree, jnp.asarray(q), dev, tip=tip))
        for n in range(q.shape[0]):
            ref = numpy_chain_fk(chain, g, q[n, cols])
            np.testing.assert_allclose(T[n, :3, 3], ref[:3, 3], rtol=0, atol=1e-9)
            np.testing.assert_allclose(T[n, :3, :3], ref[:3, :3], rtol=0, atol=1e-12)
    # the default tip (no tip named) is the first: the single-tip protocol of the rest of jaxcal
    np.testing.assert_array_equal(np.asarray(pose_jit(tree, jnp.asarray(q), dev)),
                                  np.asarray(pose_jit(tree, jnp.asarray(q), dev, tip=tips[0])))


def test_jacobian_matches_finite_differences(tree):
    """∂(left tool point, right tool point, head camera frame)/∂(every layout entry): jax.jacfwd
    against central differences, at random deviations."""
    layout = layout_for(tree)
    q = jnp.asarray(_q(tree, 4, seed=6))
    x0 = _random_dev(tree, seed=7).ravel()

    def f(x):
        dev = Deviations.unravel(x, layout)
        pl = jnp.stack(tool_point_soa(tree, dev, q, tip="left_tool"))
        pr = jnp.stack(tree.point_in_base(dev, q, jnp.asarray(TOOLS["right_tool"]), tip="right_tool"))
        X, Y, Z, P = tree.frame_soa(dev, q, tip="head_camera")
        return jnp.concatenate([pl.ravel(), pr.ravel(), *(jnp.stack(c).ravel() for c in (X, Y, Z, P))])

    J = np.asarray(jax.jit(jax.jacfwd(f))(x0))
    Jfd = central_differences(f, x0, 1e-6)
    np.testing.assert_allclose(J, Jfd, rtol=1e-6, atol=1e-5)
    # a head joint's entries do not move the arms, an arm's do not move the head
    n = q.shape[0]
    idx = {name: i for i, name in enumerate(layout.names)}
    assert np.all(J[: 6 * n, idx["offset_17"]] == 0) and np.all(J[6 * n:, idx["offset_5"]] == 0)
    assert np.all(J[:, idx["tip_dx@right_tool"]][: 3 * n] == 0) and np.any(J[3 * n: 6 * n, idx["tip_dx@right_tool"]])


def test_shared_torso_joint_is_one_parameter_moving_every_tip(tree):
    """The torso yaw (tree joint 2) has one ``offset_2``: δ there is, for every tip, exactly the
    torso reading q₂ + δ (closed form); a translation error ``dx_1`` of the lift's origin (in the
    base frame) moves every tip by exactly that vector."""
    layout = layout_for(tree)
    assert layout.names.count("offset_2") == 1
    q = _q(tree, 6, seed=8)
    zero = Deviations.zeros(layout)
    delta = 0.01
    turned = zero.replace(offset=jnp.zeros(tree.dof).at[1].set(delta))
    shifted = zero.replace(dx=jnp.zeros(tree.dof).at[0].set(3.0))
    q_turned = q.copy()
    q_turned[:, 1] += delta
    for tip in TIPS + [None]:
        T = np.asarray(pose_jit(tree, jnp.asarray(q), turned, tip=tip, tool=True))
        np.testing.assert_allclose(T, np.asarray(pose_jit(tree, jnp.asarray(q_turned), tip=tip, tool=True)),
                                   rtol=0, atol=1e-9)
        moved = np.asarray(position_jit(tree, jnp.asarray(q), shifted, tip=tip))
        np.testing.assert_allclose(moved - np.asarray(position_jit(tree, jnp.asarray(q), tip=tip)),
                                   np.broadcast_to([3.0, 0.0, 0.0], moved.shape), rtol=0, atol=1e-9)
        assert np.abs(T[:, :3, 3] - np.asarray(pose_jit(tree, jnp.asarray(q), tip=tip, tool=True))[:, :3, 3]).max() > 1


def test_tool_points_of_each_tip(tree):
    """The default tip's tool point moves with the standard ``tool`` group, another tip's with its
    ``tool@<tip>`` group (tree.tool_groups()), and with_tool sets one tip's nominal tool point."""
    q = jnp.asarray(_q(tree, 3, seed=9))
    groups = tree.tool_groups()
    assert [g.name for g in groups] == ["tool@right_tool", "tool@head_camera"]
    layout = layout_for(tree).extend(groups)
    dev = Deviations.zeros(layout).replace(tool=jnp.array([1.0, 2.0, 3.0]))
    dev = dev.replace(**{"tool@right_tool": jnp.array([0.0, 0.0, 7.0])})
    for tip, dt in (("left_tool", [1.0, 2.0, 3.0]), ("right_tool", [0.0, 0.0, 7.0]), ("head_camera", [0.0, 0.0, 0.0])):
        T = np.asarray(pose_jit(tree, q, dev, tip=tip))
        p = np.asarray(position_jit(tree, q, dev, tip=tip))
        np.testing.assert_allclose(p, T[:, :3, 3] + T[:, :3, :3] @ (np.asarray(TOOLS[tip]) + dt), rtol=0, atol=1e-9)
        np.testing.assert_allclose(fk_position_jit(tree, q, dev, tip=tip), p, rtol=0, atol=1e-12)  # host-side form
    moved = tree.with_tool((1.0, 2.0, 3.0), tip="head_camera")
    np.testing.assert_array_equal(np.asarray(moved.tool_of("head_camera")), [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(np.asarray(moved.tool), np.asarray(tree.tool))


# ---------------------------------------------------------------- a one-tip tree is the chain


@pytest.mark.parametrize("tip", ["left_tool", "right_tool"])
def test_one_tip_tree_is_the_serial_chain(tip):
    chain = load_urdf(URDF, tip=tip, tool=TOOLS[tip])
    one = load_urdf(URDF, tips=[tip], tool=TOOLS[tip])
    assert isinstance(chain, jaxcal.SerialChain) and isinstance(one, KinematicTree)
    assert one.error_groups() == chain.error_groups() and layout_for(one) == layout_for(chain)
    assert one.nominal_lengths() == chain.nominal_lengths() and one.joint_names == chain.joint_names
    assert one.reach_mm() == pytest.approx(chain.reach_mm(), rel=1e-12)
    dev = _random_dev(chain, seed=10)
    q = jnp.asarray(_q(chain, 8, seed=11))
    for tool in (False, True):
        np.testing.assert_allclose(np.asarray(pose_jit(one, q, dev, tool=tool)),
                                   np.asarray(pose_jit(chain, q, dev, tool=tool)), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(position_jit(one, q, dev)), np.asarray(position_jit(chain, q, dev)),
                               rtol=0, atol=1e-12)
    fused = [jnp.stack(r.point_in_base(dev, q, jnp.asarray(TOOLS[tip]), fused=True)) for r in (one, chain)]
    np.testing.assert_allclose(np.asarray(fused[0]), np.asarray(fused[1]), rtol=0, atol=1e-12)
    # and the tree of a hand-built chain (no URDF)
    by_hand = jaxcal.chain_from_dh(jaxcal.robots.hsr_jr680())
    t = KinematicTree.from_chain(by_hand)
    qh = jnp.asarray(_q(by_hand, 8, seed=12))
    devh = _random_dev(by_hand, seed=13)
    np.testing.assert_allclose(np.asarray(pose_jit(t, qh, devh, tool=True)),
                               np.asarray(pose_jit(by_hand, qh, devh, tool=True)), rtol=0, atol=1e-12)


# ---------------------------------------------------------------- file form


def _hand_built():
    """A small tree by hand: a prismatic root joint, two revolute branches, three tips (two on
    one joint)."""
    rz = lambda a: np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])  # noqa: E731
    rx90 = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    return KinematicTree.build(
        origin_R=[np.eye(3), rx90, rz(0.3), np.eye(3)], origin_t=[[0, 0, 400.0], [0, 150, 50], [0, -150, 50], [250, 0, 0]],
        joint_types=["prismatic", "revolute", "revolute", "revolute"], q_min=[0, -3, -3, -2], q_max=[300, 3, 3, 2],
        parents=[-1, 0, 0, 1], tips=["a", "b", "c"], tip_parents=[3, 2, 2],
        flange_R=[np.eye(3), rx90, np.eye(3)], flange_t=[[0, 0, 80.0], [10, 0, 0], [0, 20, 30]],
        tools=[[0, 0, 5.0], [0, 0, 0], [1, 2, 3]], name="by_hand")


@pytest.mark.parametrize("kind", ["urdf", "by_hand"])
def test_file_form_round_trip(tree, kind):
    robot = tree.with_harmonics(joints=[2, 5], orders=(1,)) if kind == "urdf" else _hand_built()
    d = json.loads(json.dumps(robot.to_dict()))
    assert d["type"] == "kinematic_tree" and ("urdf" in d) == (kind == "urdf")
    back = nongeometric_from_dict(tree_from_dict(d), d.get("nongeometric"))
    assert type(back) is KinematicTree and back.to_dict() == d
    assert json.loads(json.dumps(back.fingerprint())) == json.loads(json.dumps(robot.fingerprint()))
    assert back.error_groups() == robot.error_groups() and back.branches == robot.branches
    dev = _random_dev(robot, seed=14)
    q = jnp.asarray(_q(robot, 6, seed=15))
    for tip in robot.tips:
        np.testing.assert_allclose(np.asarray(pose_jit(back, q, dev, tip=tip, tool=True)),
                                   np.asarray(pose_jit(robot, q, dev, tip=tip, tool=True)), rtol=0, atol=1e-12)


def test_harmonic_error_of_a_shared_joint_moves_every_tip(tree):
    """A joint-space correction acts on the tree's readings before the paths: one ``h1s_2`` (torso
    yaw) is, for every tip, the torso reading q₂ + h1s·sin(q₂)."""
    robot = tree.with_harmonics(joints=[2], orders=(1,))
    layout = layout_for(robot)
    assert "h1s_2" in layout.names
    dev = Deviations.zeros(layout).replace(h1s=jnp.array([0.004]))
    q = _q(robot, 5, seed=16)
    q2 = q.copy()
    q2[:, 1] += 0.004 * np.sin(q[:, 1])
    for tip in TIPS:
        np.testing.assert_allclose(np.asarray(pose_jit(robot, jnp.asarray(q), dev, tip=tip)),
                                   np.asarray(pose_jit(robot, jnp.asarray(q2), tip=tip)), rtol=0, atol=1e-9)


# ---------------------------------------------------------------- export


def test_export_reload_reproduces_every_tip(tmp_path):
    """Export at random deviations (joint errors, every tip's errors, tool points), reload: the
    reloaded nominal tree's tips are the calibrated ones within 1e-9 mm, and so are the frames a
    plain NumPy product of the exported URDF gives. The chest camera's last moving joint is the
    torso yaw, and its first fixed joint (chest_joint) carries the arms and head: its correction
    goes into its own chest_camera_joint. The right tool has no fixed joint: an added link."""
    tips = TIPS + ["chest_camera"]
    robot = load_urdf(URDF, tips=tips, tool=TOOLS)
    layout = layout_for(robot).extend(robot.tool_groups())
    rng = np.random.default_rng(17)
    flat = rng.normal(0, [0.003 if u == "rad" else 0.6 for u in layout.units])
    flat[[i for i, k in enumerate(layout.kinds) if k == "extra" and not layout.names[i].startswith("tool")]] = 0.0
    dev = Deviations.unravel(jnp.asarray(flat), layout)
    text = export_urdf(robot, dev, tmp_path / "cal.urdf")
    assert 'link name="jaxcal_calibrated_tip_right_tool"' in text
    reload_tips = ["left_tool", "jaxcal_calibrated_tip_right_tool", "head_camera", "chest_camera"]
    again = load_urdf(tmp_path / "cal.urdf", tips=reload_tips)
    assert again.joint_names == robot.joint_names
    q = _q(robot, 20, seed=18)
    for tip, tip2 in zip(tips, reload_tips):
        T = np.asarray(pose_jit(robot, jnp.asarray(q), dev, tip=tip))
        T2 = np.asarray(pose_jit(again, jnp.asarray(q), tip=tip2))
        np.testing.assert_allclose(T2[:, :3, 3], T[:, :3, 3], rtol=0, atol=1e-9)
        np.testing.assert_allclose(T2[:, :3, :3], T[:, :3, :3], rtol=0, atol=1e-12)
        cols = [robot.joint_names.index(n) for n in load_urdf(text, tip=tip2).joint_names]
        p = np.asarray(position_jit(robot, jnp.asarray(q), dev, tip=tip))
        for n in range(3):  # the plain NumPy product of the exported file, to the tip and the tool link
            ref = numpy_urdf_fk(text, "base_link", tip2, q[n, cols])
            np.testing.assert_allclose(ref[:3, 3], T[n, :3, 3], rtol=0, atol=1e-9)
            if tip != "chest_camera":  # (no tool point there: no tool link)
                tool = numpy_urdf_fk(text, "base_link", f"jaxcal_tool_point_{tip}", q[n, cols])
                np.testing.assert_allclose(tool[:3, 3], p[n], rtol=0, atol=1e-9)


def test_export_of_a_hand_built_tree_reloads(tmp_path):
    robot = _hand_built()
    dev = _random_dev(robot, seed=19)
    text = export_urdf(robot, dev, tmp_path / "hand.urdf")
    again = load_urdf(text, tips=list(robot.tips))
    # the reloaded tree numbers its joints by first appearance along the tips' paths: 1, 2, 4, 3
    cols = [robot.joint_names.index(n) for n in again.joint_names]
    assert cols == [0, 1, 3, 2]
    q = _q(robot, 10, seed=20)
    for tip in robot.tips:
        np.testing.assert_allclose(np.asarray(pose_jit(again, jnp.asarray(q[:, cols]), tip=tip)),
                                   np.asarray(pose_jit(robot, jnp.asarray(q), dev, tip=tip)), rtol=0, atol=1e-9)


# ---------------------------------------------------------------- bad input


def test_bad_inputs_are_named(tree):
    with pytest.raises(ValueError, match=r"unknown tip link 'left_hand'; leaf links below 'base_link': \[.*'head_camera'"):
        load_urdf(URDF, tips=["left_hand", "right_tool"])
    with pytest.raises(ValueError, match="'l_elbow_link' and 'left_tool' lie on one path"):
        load_urdf(URDF, tips=["l_elbow_link", "left_tool"])
    with pytest.raises(ValueError, match="either tip .* or tips"):
        load_urdf(URDF, tip="left_tool", tips=["right_tool"])
    with pytest.raises(ValueError, match="different links"):
        load_urdf(URDF, tips=["left_tool", "left_tool"])
    with pytest.raises(ValueError, match="different links"):
        load_urdf(URDF, tips=[])
    with pytest.raises(ValueError, match="'l_finger_b_joint' .* is a mimic joint"):
        load_urdf(URDF, tips=["right_tool", "l_finger_b"])
    with pytest.raises(ValueError, match="not among the tips"):
        load_urdf(URDF, tips=["right_tool"], tool={"left_tool": (0, 0, 1.0)})
    with pytest.raises(ValueError, match="tip link 'head_camera' is not below base link 'l_elbow_link'"):
        load_urdf(URDF, base="l_elbow_link", tips=["left_tool", "head_camera"])
    q = jnp.zeros((2, tree.dof))
    with pytest.raises(ValueError, match=r"unknown tip 'left_hand'; tips of 'humanoid_tree': \['left_tool'"):
        fk_position(tree, q, tip="left_hand")
    with pytest.raises(ValueError, match="has one tip"):
        fk_position(load_urdf(URDF, tip="left_tool"), q[:, :9], tip="left_tool")
    with pytest.raises(NotImplementedError, match="compliance"):
        tree.with_compliance()
    good = dict(origin_R=[np.eye(3)] * 2, origin_t=[[0, 0, 100.0]] * 2, joint_types=["revolute"] * 2, q_min=[-1, -1],
                q_max=[1, 1], tips=["t"])
    with pytest.raises(ValueError, match="lead to no tip"):
        KinematicTree.build(**good, parents=[-1, -1], tip_parents=[0])
    with pytest.raises(ValueError, match="parents must give"):
        KinematicTree.build(**good, parents=[1, -1], tip_parents=[0])
    with pytest.raises(ValueError, match="tip_parents must give"):
        KinematicTree.build(**good, parents=[-1, 0], tip_parents=[2])
