"""Kinematic trees from DH tree files (issue 51): one standard DH table per branch after a
``# branch: NAME parent=root|PARENT@ROW tip=TIP`` line (``jaxcal._calibration._io.load_tree_csv``,
``load_robot_csv`` and ``--robot FILE`` read it).

Each tip of a two-branch file against the same branch written as one :class:`jaxcal.DHRobot`
(the parent's rows before the branching row, then the branch's rows) at random joint angles; the
dual-arm preset written in this form (cameras as a repeated torso row and a fixed row) against the
preset; every malformed file names its line; the command line reads it (``--robot FILE --tip``)."""

import numpy as np
import pytest

import jaxcal
from jaxcal import robots
from jaxcal._calibration._io import load_robot_csv, load_tree_csv
from jaxcal._models._dh_tree import dh_row
from jaxcal._models._kinematics import fk_pose
from jaxcal.cli import main

HEADER = "alpha_deg,a_mm,d_mm,theta_deg,q_min_deg,q_max_deg,type\n"
#: (alpha°, a mm, d mm, theta°, q_min°, q_max°) rows of the arm (on the root) and of the head, which
#: hangs from the arm's joint 2: its first row is joint 2 again, with the head's own d, θ, a, α.
ARM = [(-90, 120.0, 400.0, 10, -170, 170), (0, 500.0, 30.0, -90, -100, 120), (-90, 60.0, 0.0, 5, -120, 150),
       (90, 0.0, 420.0, 0, -180, 180)]
HEAD = [(35, 80.0, -60.0, 25, -100, 120), (-90, 40.0, 150.0, -20, -60, 60)]
HEAD_FIXED = (12, 30.0, 45.0, -7)  # a fixed row after the head's joint: the camera frame
TOOL = (10.0, -5.0, 90.0)


def _rows(rows, first_blank=False):
    out = []
    for k, (al, a, d, th, lo, hi) in enumerate(rows):
        lim = ",," if first_blank and k == 0 else f"{lo},{hi},"
        out.append(f"{al},{a},{d},{th},{lim}\n")
    return "".join(out)


def _tree_text():
    return ("# name: arm_and_head\n" + HEADER
            + f"# branch: arm parent=root tip=hand tool_mm={','.join(map(str, TOOL))}\n" + _rows(ARM)
            + "# branch: head parent=arm@2 tip=eye\n" + _rows(HEAD, first_blank=True)
            + ",".join(map(str, HEAD_FIXED)) + ",,,fixed\n")


def _dh(rows, tool=(0.0, 0.0, 0.0)):
    al, a, d, th, lo, hi = np.array(rows, np.float64).T
    return jaxcal.DHRobot.from_degrees(alpha_deg=al, a_mm=a, d_mm=d, theta_deg=th, q_min_deg=lo, q_max_deg=hi,
                                       tool_mm=tool)


def _q(robot, n, seed):
    lo, hi = np.asarray(robot.q_min), np.asarray(robot.q_max)
    return np.random.default_rng(seed).uniform(lo, hi, (n, robot.dof))


def test_each_tip_is_its_branch_as_one_dh_chain(tmp_path):
    path = tmp_path / "tree.csv"
    path.write_text(_tree_text())
    tree = load_robot_csv(path)  # the chain loader hands a file with '# branch:' lines to load_tree_csv
    assert isinstance(tree, jaxcal.KinematicTree) and tree.name == "arm_and_head"
    assert tree.tips == ("hand", "eye") and tree.dof == 5 and tree.parents == (-1, 0, 1, 2, 1)
    np.testing.assert_allclose(np.degrees(np.asarray(tree.q_min)), [-170, -100, -120, -180, -60], atol=1e-12)
    q = _q(tree, 64, seed=3)
    # the hand: the arm's four rows; the eye: arm row 1, the head's rows (row 1 = joint 2 again), the fixed row
    hand = _dh(ARM, TOOL)
    eye = _dh(ARM[:1] + HEAD)
    fixed = dh_row(*np.array(HEAD_FIXED, np.float64)[[1, 2, 0, 3]])  # (a, d, α, θ)
    cases = [("hand", hand, q[:, :4], np.eye(4)), ("eye", eye, q[:, [0, 1, 4]], fixed)]
    for tip, chain, qc, after in cases:  # the eye has no tool point: its frame is the one after the fixed row
        got = np.asarray(fk_pose(tree, q, tip=tip, tool=True))
        ref = np.asarray(fk_pose(chain, qc, tool=True)) @ after
        np.testing.assert_allclose(got[:, :3, 3], ref[:, :3, 3], rtol=0, atol=1e-9)
        np.testing.assert_allclose(got[:, :3, :3], ref[:, :3, :3], rtol=0, atol=1e-12)
    assert np.ptp(np.asarray(fk_pose(tree, q, tip="eye"))[:, :3, 3], axis=0).min() > 10.0  # it moves


def _ma1400_text():
    """The dual-arm preset's published rows (``jaxcal.robots``' constants) as a DH tree file."""
    row = lambda a, d, al, th, lim=None: ",".join(repr(float(v)) for v in (al, a, d, th)) + "," + (",," if lim is None else f"{lim[0]},{lim[1]},")  # noqa: E731
    lines = [HEADER, "# branch: torso parent=root\n",
             row(*robots._MA1400_TORSO_ROW["left"], robots._MA1400_LIMITS_DEG["torso"]) + "\n"]
    for side in ("left", "right"):
        lines += [f"# branch: {side}_arm parent=torso@1 tip={side}_tool tool_mm=0,0,354\n",
                  row(*robots._MA1400_TORSO_ROW[side]) + "\n"]
        lines += [row(*r, lim) + "\n" for r, lim in zip(robots._MA1400_ARM_ROWS, robots._MA1400_LIMITS_DEG["arm"],
                                                           strict=True)]
    for side in ("left", "right"):
        first, second = robots._MA1400_CAMERA_ROWS[side]
        lines += [f"# branch: {side}_eye parent=torso@1 tip={side}_camera\n", row(*first) + "\n",
                  row(*second) + "fixed\n"]
    return "".join(lines)


def test_dual_arm_preset_round_trips(tmp_path):
    path = tmp_path / "ma1400.csv"
    path.write_text(_ma1400_text())
    tree, preset = load_tree_csv(path), robots.dual_arm_ma1400()
    assert tree.tips == preset.tips and tree.parents == preset.parents
    np.testing.assert_array_equal(np.asarray(tree.q_min), np.asarray(preset.q_min))
    q = _q(preset, 64, seed=4)
    for tip in preset.tips:
        got, ref = (np.asarray(fk_pose(r, q, tip=tip, tool=True)) for r in (tree, preset))
        np.testing.assert_allclose(got[:, :3, 3], ref[:, :3, 3], rtol=0, atol=1e-9)
        np.testing.assert_allclose(got[:, :3, :3], ref[:, :3, :3], rtol=0, atol=1e-12)


GOOD = ("# branch: torso parent=root\n0,0,500,0,-170,170,\n"
        "# branch: left parent=torso@1 tip=left_tool\n90,0,500,0,,,\n-90,300,0,0,-90,90,\n")


@pytest.mark.parametrize("text, message", [
    ("0,0,1,0,-1,1,\n" + GOOD, r"joint row 1 \(line 2\) comes before the first '# branch:' line"),
    (GOOD.replace("torso@1", "trunk@1"), r"line 4 \('# branch: left parent=trunk@1 tip=left_tool'\): parent branch "
                                         "'trunk' is not defined above"),
    (GOOD.replace("torso@1", "torso@2"), "line 4 .*torso@2: branch 'torso' has 1 rows"),
    (GOOD + "# branch: left parent=root tip=x\n0,0,1,0,-1,1,\n", "line 7 .*branch 'left' is defined twice"),
    (GOOD + "# branch: right parent=torso@1 tip=left_tool\n0,0,1,0,,,\n", "line 7 .*tip 'left_tool' is already "
                                                                          "the tip of branch 'left'"),
    (GOOD.replace("90,0,500,0,,,", "90,0,500,0,-10,10,"), r"line 5\): .*joint torso@1 again; its limits -10..10 deg "
                                                         "differ from the parent's -170..170"),
    (GOOD.replace("parent=root", "root"), r"line 2 .*'root' is not one of parent=\.\.\., tip=\.\.\."),
    (GOOD.replace("torso@1 tip", "torso@1 tool_mm=1,2 tip"), "line 4 .*tool_mm= must be 3 finite comma-separated"),
    (GOOD.replace("-90,300,0,0,-90,90,", "-90,300,0,0,-90,90,weld"), r"line 6\), column type: .weld. is not a row type"),
])
def test_bad_tree_files_name_their_line(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(HEADER + text)
    with pytest.raises(ValueError, match=message):
        load_tree_csv(path)


def test_cli_reads_a_dh_tree_file(tmp_path, capsys):
    """``jaxcal simulate --robot tree.csv --tip hand``: the arm's four joint columns (``jaxcal
    calibrate``/``plan``/``evaluate`` read ``--robot``/``--tip`` through the same code; a calibrate
    run on such data costs ~8 s of compilation, so it is not repeated here); a tip the file lacks:
    exit 2 naming it."""
    path, data = tmp_path / "tree.csv", tmp_path / "data.csv"
    path.write_text(_tree_text())
    assert main(["simulate", "--robot", str(path), "--tip", "hand", "--measurement", "position", "--samples", "20",
                 "--out", str(data)]) == 0
    assert jaxcal.load_csv(data).q.shape == (20, 4)
    capsys.readouterr()
    assert main(["simulate", "--robot", str(path), "--tip", "foot", "--samples", "5", "--out", str(data)]) == 2
    assert "unknown tip 'foot'" in capsys.readouterr().err
