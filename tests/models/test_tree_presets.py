"""Kinematic-tree presets (issue 51): ``jaxcal.robots.dual_arm_ma1400`` (the CTU dual-arm robot of
Stepanova et al. 2022 / Rozlivek et al.'s toolbox) and ``jaxcal.robots.icub`` (iCub v1, iKin).

Every tip's frame against an independent NumPy product of the **published** DH rows, copied here
as the sources print them (metres and radians: ``loadMotoman.m``, ``iKinFwd.cpp``), chain by chain
as the sources compute them (each arm's own torso row, each eye's own tilt row); the shared joints
(torso axis, iCub's torso and eye tilt) as one joint column that moves every tip above it and has
one set of error entries; export → reload within 1e-9 mm; ``with_tips``; the command line."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcal
from jaxcal import export_urdf, load_urdf, robots
from jaxcal._core._params import Deviations, layout_for
from jaxcal._models._kinematics import fk_pose, fk_position
from jaxcal.cli import main

pi = math.pi
D2R = pi / 180.0


def _dh(a, d, alpha, theta):
    """Standard DH ``Rz(θ)·Tz(d)·Tx(a)·Rx(α)`` (the sources' convention), lengths as given."""
    ca, sa, ct, st = math.cos(alpha), math.sin(alpha), math.cos(theta), math.sin(theta)
    return np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1.0]])


def _chain(rows, q, H0=None):
    """``H0·Π A_i(q_i)`` of rows ``(a, d, α, θ offset)`` in metres/radians, returned in mm."""
    T = np.eye(4) if H0 is None else np.array(H0, np.float64)
    for (a, d, alpha, theta), qi in zip(rows, q, strict=True):
        T = T @ _dh(a, d, alpha, theta + qi)
    T[:3, 3] *= 1000.0
    return T


# ---- the dual-arm robot: loadMotoman.m of github.com/ctu-vras/multirobot-calibration (a, d, alpha, offset)
CTU_ARM = [[0.150, 1.4159, -pi / 2, 0.000], [0.614, 0.000, pi, -pi / 2], [0.200, 0.000, -pi / 2, 0.000],
           [0.000, -0.640, pi / 2, 0.000], [0.030, 0.000, pi / 2, -pi / 2], [0.000, 0.200, 0.000, 0.000]]
CTU = {"left": [[0.000, -0.263, -15 * pi / 180, -pi / 2]] + CTU_ARM,
       "right": [[0.000, -0.263, 15 * pi / 180, -pi / 2]] + CTU_ARM}
CTU_EE = [0.000, 0.354, 0.000, 0.000]
CTU_EYES = {"right": [[0.0741, 1.8034, -2.5086, -2.7753], [0.0000, -0.5670, 0.0000, 0.2863]],
            "left": [[0.2315, 1.8602, 2.5486, 0.0860], [0.0000, -0.4982, 0.0000, -3.0618]]}

# ---- iCub v1: iKinFwd.cpp's iCubArm / iCubEye "left"/"right" version 1.0 (A, D, alpha, offset, min°, max°)
ICUB_H0 = np.array([[0, -1.0, 0, 0], [0, 0, -1.0, 0], [1.0, 0, 0, 0], [0, 0, 0, 1.0]])
ICUB_TORSO = [(0.032, 0.0, pi / 2, 0.0, -22, 84), (0.0, -0.0055, pi / 2, -pi / 2, -39, 39)]
ICUB = {
    "right_hand": ICUB_TORSO + [
        (-0.0233647, -0.1433, pi / 2, -105 * D2R, -59, 59), (0.0, -0.10774, pi / 2, -pi / 2, -95.5, 5),
        (0.0, 0.0, -pi / 2, -pi / 2, 0, 160.8), (-0.015, -0.15228, -pi / 2, -105 * D2R, -37, 100),
        (0.015, 0.0, pi / 2, 0.0, 5.5, 106), (0.0, -0.1373, pi / 2, -pi / 2, -50, 50),
        (0.0, 0.0, pi / 2, pi / 2, -65, 10), (0.0625, 0.016, 0.0, pi, -25, 25)],
    "left_hand": ICUB_TORSO + [
        (0.0233647, -0.1433, -pi / 2, 105 * D2R, -59, 59), (0.0, 0.10774, -pi / 2, pi / 2, -95.5, 5),
        (0.0, 0.0, pi / 2, -pi / 2, 0, 160.8), (0.015, 0.15228, -pi / 2, 75 * D2R, -37, 100),
        (-0.015, 0.0, pi / 2, 0.0, 5.5, 106), (0.0, 0.1373, pi / 2, -pi / 2, -50, 50),
        (0.0, 0.0, pi / 2, pi / 2, -65, 10), (0.0625, -0.016, 0.0, 0.0, -25, 25)],
}
for _side, _d in (("right", 0.034), ("left", -0.034)):
    ICUB[f"{_side}_eye"] = ICUB_TORSO + [
        (0.00231, -0.1933, -pi / 2, -pi / 2, -59, 59), (0.033, 0.0, pi / 2, pi / 2, -40, 30),
        (0.0, 0.001, -pi / 2, -pi / 2, -70, 60), (-0.054, 0.0825, -pi / 2, pi / 2, -55, 55),
        (0.0, _d, -pi / 2, 0.0, -35, 15), (0.0, 0.0, pi / 2, -pi / 2, -50, 50)]
# the tree's joint columns of each chain: torso 0-2, left arm 3-9, right arm 10-16, neck 17-19, tilt 20, pans 21, 22
ICUB_COLS = {"left_hand": [0, 1, 2, *range(3, 10)], "right_hand": [0, 1, 2, *range(10, 17)],
             "left_eye": [0, 1, 2, 17, 18, 19, 20, 21], "right_eye": [0, 1, 2, 17, 18, 19, 20, 22]}


@jax.jit
def _tips(robot, q, dev=None):
    """``(frames [n_tips, n, 4, 4], tool points [n_tips, n, 3])`` of every tip of ``robot``: one
    compiled program per robot (and per deviations or none), not one per tip."""
    return (jnp.stack([fk_pose(robot, q, dev, tip=t) for t in robot.tips]),
            jnp.stack([fk_position(robot, q, dev, tip=t) for t in robot.tips]))


def _frames(robot, q, dev=None):
    T, p = _tips(robot, jnp.asarray(q), dev)
    tips = robot.tips
    return {t: np.asarray(T[k]) for k, t in enumerate(tips)}, {t: np.asarray(p[k]) for k, t in enumerate(tips)}


@pytest.fixture(scope="module")
def dual():
    return robots.dual_arm_ma1400()


@pytest.fixture(scope="module")
def icub():
    return robots.icub()


def _q(robot, n, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(np.asarray(robot.q_min), np.asarray(robot.q_max), size=(n, robot.dof))


def _reference(name, tip, q):
    """The tip frame (mm) and tool point of one pose from the published rows."""
    if name == "icub":
        rows = ICUB[tip]
        T = _chain([r[:4] for r in rows], q[ICUB_COLS[tip]], ICUB_H0)
        return T, T[:3, 3]
    side, what = tip.split("_")
    if what == "camera":
        T = _chain(CTU_EYES[side], [q[0], 0.0])
        return T, T[:3, 3]
    cols = [0, *range(1, 7)] if side == "left" else [0, *range(7, 13)]
    T = _chain(CTU[side], q[cols])
    return T, (T @ _dh(CTU_EE[0] * 1000, CTU_EE[1] * 1000, CTU_EE[2], CTU_EE[3]))[:3, 3]


# ---------------------------------------------------------------- structure


def test_presets_are_registered_trees(dual, icub):
    assert set(robots.TREE_PRESETS) == {"dual_arm_ma1400", "icub"}
    assert set(robots.PRESETS) == set(robots.DH_PRESETS) | set(robots.TREE_PRESETS)
    for name, robot, dof, tips in (("dual_arm_ma1400", dual, 13, ("left_tool", "right_tool", "left_camera",
                                                                    "right_camera")),
                                   ("icub", icub, 23, ("left_hand", "right_hand", "left_eye", "right_eye"))):
        got = robots.get_robot(name)
        assert isinstance(got, jaxcal.KinematicTree) and isinstance(got, jaxcal.AbstractRobot)
        assert got.name == name and got.dof == dof and got.tips == tips == robot.tips
        assert got.dh_rows_deg() is None
    assert dual.joint_names[:3] == ("torso_joint", "left_joint_s", "left_joint_l")
    assert dual.joint_names[7] == "right_joint_s" and dual.tip_parents == (6, 12, 0, 0)
    assert [(b, p, j) for b, p, j in dual.branches] == [
        ("torso", None, (0,)), ("left_tool", "torso", tuple(range(1, 7))), ("right_tool", "torso", tuple(range(7, 13)))]
    assert [(b, p, len(j)) for b, p, j in icub.branches] == [
        ("chest", None, 3), ("left_hand", "chest", 7), ("right_hand", "chest", 7), ("head", "chest", 4),
        ("left_eye", "head", 1), ("right_eye", "head", 1)]
    # the iCub's limits are iKin's, column by column
    for tip, rows in ICUB.items():
        for col, row in zip(ICUB_COLS[tip], rows, strict=True):
            assert math.isclose(float(icub.q_min[col]), row[4] * D2R)
            assert math.isclose(float(icub.q_max[col]), row[5] * D2R)
    with pytest.raises(ValueError, match="not a tip of dual_arm_ma1400"):
        robots.dual_arm_ma1400(tools={"head": (0, 0, 1.0)})
    assert np.allclose(robots.icub(tools={"right_hand": (0, 0, 20.0)}).tool_of("right_hand"), [0, 0, 20.0])


# ---------------------------------------------------------------- kinematics


@pytest.mark.parametrize("name", ["dual_arm_ma1400", "icub"])
def test_every_tip_matches_the_published_rows(name, dual, icub):
    """Each tip's frame and tool point at random poses: the product of the source's DH rows."""
    robot = dual if name == "dual_arm_ma1400" else icub
    q = _q(robot, 5, seed=1)
    q[0] = 0.0  # and the zero pose
    frames, points = _frames(robot, q)
    for tip in robot.tips:
        T, p = frames[tip], points[tip]
        for n in range(q.shape[0]):
            ref, tool = _reference(name, tip, q[n])
            np.testing.assert_allclose(T[n, :3, 3], ref[:3, 3], rtol=0, atol=1e-9)
            np.testing.assert_allclose(T[n, :3, :3], ref[:3, :3], rtol=0, atol=1e-12)
            np.testing.assert_allclose(p[n], tool, rtol=0, atol=1e-9)


def test_shared_joints_move_every_tip_above_them_with_one_set_of_errors(dual, icub):
    """The dual-arm torso axis is the base z: turning it by δ (a reading, or its offset error)
    turns all four tips by Rz(δ); it is one joint column and one entry per error group. iCub: the
    torso pitch moves every tip frame, the eye tilt both eyes' and no hand's."""
    d = 0.2
    Rz = np.array([[math.cos(d), -math.sin(d), 0], [math.sin(d), math.cos(d), 0], [0, 0, 1.0]])
    q = _q(dual, 4, seed=2)
    qd = q.copy()
    qd[:, 0] += d
    layout = layout_for(dual)
    assert layout.group("offset").size == dual.dof == 13 and layout.group("dx").size == 13
    labels = dual.entry_labels()
    assert labels["offset_1"] == "torso / torso_joint" and labels["dx_2"] == "left_tool / left_joint_s"
    assert labels["offset_8"] == "right_tool / right_joint_s" and labels["tip_dx@left_camera"] == "tip left_camera"
    flat = np.zeros(layout.size)
    flat[layout.names.index("offset_1")] = d
    dev = Deviations.unravel(jnp.asarray(flat), layout)
    base = _frames(dual, q)[0]
    for turned in (_frames(dual, qd)[0], _frames(dual, q, dev)[0]):
        for tip in dual.tips:
            T = base[tip]
            np.testing.assert_allclose(turned[tip][:, :3, 3], T[:, :3, 3] @ Rz.T, rtol=0, atol=1e-9)
            np.testing.assert_allclose(turned[tip][:, :3, :3], Rz @ T[:, :3, :3], rtol=0, atol=1e-12)

    q = _q(icub, 3, seed=3)
    base = _frames(icub, q)[0]
    moved = {}
    for col in (0, icub.joint_names.index("eyes_tilt")):
        qd = q.copy()
        qd[:, col] += 0.05
        turned = _frames(icub, qd)[0]
        moved[col] = {tip: np.abs(turned[tip] - base[tip]).max() > 1e-3 for tip in icub.tips}  # (an eye turns in place)
    assert moved[0] == dict.fromkeys(icub.tips, True)
    assert moved[20] == {"left_hand": False, "right_hand": False, "left_eye": True, "right_eye": True}
    assert layout_for(icub).group("offset").size == 23
    assert icub.entry_labels()["offset_21"] == "head / eyes_tilt"


@pytest.mark.parametrize("name", ["dual_arm_ma1400", "icub"])
def test_export_reload_reproduces_every_tip(name, dual, icub, tmp_path):
    """export_urdf at random deviations (joints, tips, tool points) → load_urdf(tips=...): every tip
    frame and tool point within 1e-9 mm."""
    robot = dual if name == "dual_arm_ma1400" else icub
    layout = layout_for(robot).extend(robot.tool_groups())
    rng = np.random.default_rng(4)
    flat = rng.normal(0, [0.003 if u == "rad" else 0.6 for u in layout.units])
    flat[[i for i, k in enumerate(layout.kinds) if k == "extra" and not layout.names[i].startswith("tool")]] = 0.0
    dev = Deviations.unravel(jnp.asarray(flat), layout)
    path = tmp_path / f"{name}.urdf"
    export_urdf(robot, dev, path)
    again = load_urdf(path, tips=list(robot.tips))
    tools = load_urdf(path, tips=[f"jaxcal_tool_point_{t}" for t in robot.tips])
    assert again.joint_names == robot.joint_names == tools.joint_names
    q = _q(robot, 6, seed=5)
    frames, points = _frames(robot, q, dev)
    frames2 = _frames(again, q)[0]
    tool_frames = _frames(tools, q)[0]
    for tip in robot.tips:
        T, T2 = frames[tip], frames2[tip]
        np.testing.assert_allclose(T2[:, :3, 3], T[:, :3, 3], rtol=0, atol=1e-9)
        np.testing.assert_allclose(T2[:, :3, :3], T[:, :3, :3], rtol=0, atol=1e-12)
        np.testing.assert_allclose(tool_frames[f"jaxcal_tool_point_{tip}"][:, :3, 3], points[tip], rtol=0, atol=1e-9)


def test_with_tips_keeps_those_tips_and_their_joints(dual, icub):
    """with_tips: the joints on the kept tips' paths, numbered as load_urdf numbers them, the same
    kinematics; one tip is the chain (its groups without '@'); bad tips are named."""
    right = dual.with_tips(["right_tool"])
    assert right.tips == ("right_tool",) and right.joint_names == ("torso_joint", *dual.joint_names[7:])
    assert "tip_dx" in layout_for(right).names and right.tool_of() is not None
    pair = icub.with_tips(["right_eye", "left_hand"])
    assert pair.joint_names == tuple(icub.joint_names[j] for j in (0, 1, 2, 17, 18, 19, 20, 22, *range(3, 10)))
    q = _q(icub, 4, seed=6)
    full = _frames(icub, q)[0]
    for small in (pair, icub.with_tips(["left_eye"])):
        cols = [icub.joint_names.index(n) for n in small.joint_names]
        frames = _frames(small, q[:, cols])[0]
        for tip in small.tips:
            np.testing.assert_allclose(frames[tip], full[tip], rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match=r"unknown tip 'head'; tips of 'dual_arm_ma1400': \['left_tool'"):
        dual.with_tips(["head"])
    with pytest.raises(ValueError, match="one or more different tips"):
        dual.with_tips(["left_tool", "left_tool"])


# ---------------------------------------------------------------- command line


def test_cli_simulates_and_names_bad_tips(tmp_path, capsys):
    """`jaxcal simulate --robot dual_arm_ma1400 --tip right_tool`: the right arm's chain (torso and
    six arm columns); a tip the preset lacks, or --tip on a serial preset: exit 2 with the names."""
    out = tmp_path / "right.csv"
    assert main(["simulate", "--robot", "dual_arm_ma1400", "--measurement", "position", "--tip", "right_tool",
                 "--samples", "20", "--out", str(out)]) == 0
    data = jaxcal.load_csv(out)
    assert data.q.shape == (20, 7) and data.y.shape == (20, 3)
    capsys.readouterr()
    assert main(["simulate", "--robot", "dual_arm_ma1400", "--tip", "left_tool,head", "--samples", "5",
                 "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err
    assert "unknown tip 'head'" in err and "'left_camera', 'right_camera'" in err, err
    assert main(["simulate", "--robot", "ur5", "--tip", "tool0", "--samples", "5",
                 "--out", str(tmp_path / "y.csv")]) == 2
    assert "--tip to a tree preset (dual_arm_ma1400, icub)" in capsys.readouterr().err
