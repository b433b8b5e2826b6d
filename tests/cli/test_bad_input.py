"""Wrong input that parses (issue 35): lengths in metres, radians under ``_deg`` headers, another
robot's DH table, a file of another kind. None may exit 0; each names its likely cause."""

import math

import numpy as np
import pytest

from jaxcal import load_csv, robots
from jaxcal._calibration._io import save_robot_csv
from jaxcal._fit._diagnostics import likely_cause
from jaxcal._sensors._measurement import CableLength, Position
from jaxcal.cli import main

N = 120  # as tests/cli/test_cli.py: the same simulated file and compiled programs


@pytest.fixture(scope="module")
def wire(tmp_path_factory):
    """``(header lines, data rows as lists of cells)`` of a simulated draw-wire file (anchor known)."""
    path = tmp_path_factory.mktemp("bad") / "data.csv"
    assert main(["simulate", "--out", str(path), "--samples", str(N), "--seed", "3"]) == 0
    lines = path.read_text().splitlines()
    h = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    return lines[: h + 1], [line.split(",") for line in lines[h + 1:]]


def _write(path, head, rows):
    path.write_text("\n".join(head + [",".join(r) for r in rows]) + "\n")
    return str(path)


def _calibrate(capsys, argv, code):
    assert main(["calibrate", *argv, "--method", "lm"]) == code
    return capsys.readouterr().err


def test_lengths_in_metres_exit_1(wire, tmp_path, capsys):
    head, rows = wire
    f = _write(tmp_path / "m.csv", head, [r[:6] + [repr(float(r[6]) / 1000)] for r in rows])
    err = _calibrate(capsys, [f, "--robot", "hsr_jr680"], 1)
    assert "the lengths look like metres, expected mm" in err and "not credible" in err


def test_radians_under_deg_headers_exit_1(wire, tmp_path, capsys):
    head, rows = wire
    f = _write(tmp_path / "r.csv", head, [[repr(math.radians(float(v))) for v in r[:6]] + [r[6]] for r in rows])
    err = _calibrate(capsys, [f, "--robot", "hsr_jr680"], 1)
    assert "joint angles look like radians read as degrees" in err


def test_another_robots_dh_file_exit_1(wire, tmp_path, capsys):
    head, rows = wire
    f = _write(tmp_path / "d.csv", head, rows)
    dh = tmp_path / "irb120.csv"
    save_robot_csv(robots.abb_irb120(), dh)
    err = _calibrate(capsys, [f, "--robot", str(dh)], 1)
    assert "the robot model may not match the data" in err and "% of the robot's reach" in err


def test_kind_line_chooses_the_model_and_a_conflict_names_both(tmp_path, capsys):
    pos = tmp_path / "pos.csv"
    assert main(["simulate", "--out", str(pos), "--samples", str(N), "--seed", "3", "--measurement", "position"]) == 0
    capsys.readouterr()
    # --measurement cable against the file's '# kind: position': exit 2 naming both (also jaxcal evaluate)
    err = _calibrate(capsys, [str(pos), "--robot", "hsr_jr680", "--measurement", "cable"], 2)
    assert "'# kind: position'" in err and "cable data were asked for" in err
    with pytest.raises(ValueError, match="kind: position.*cable data were asked for"):
        load_csv(pos, kind="cable")
    # without --measurement the file's own kind line chooses the position model (was: cable, exit 2)
    assert main(["calibrate", str(pos), "--robot", "hsr_jr680", "--method", "lm", "--test-fraction", "0"]) == 0
    assert f"{N} position samples" in capsys.readouterr().out


def test_evaluate_kind_conflict_names_the_result(wire, tmp_path, capsys):
    """`jaxcal evaluate` takes the kind from the result (it has no --measurement): a file of another
    kind is an error naming the result's kind and the file's '# kind:' line, not an option."""
    head, rows = wire
    f = _write(tmp_path / "w.csv", head, rows)
    out = tmp_path / "r.json"
    assert main(["calibrate", f, "--robot", "hsr_jr680", "--method", "lm", "--test-fraction", "0",
                 "--out", str(out)]) in (0, 1)
    pos = tmp_path / "pos.csv"
    assert main(["simulate", "--out", str(pos), "--samples", str(N), "--seed", "4", "--measurement", "position"]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(out), str(pos)]) == 2
    err = capsys.readouterr().err
    assert "'# kind: position'" in err and f"the calibration {out} is of cable data" in err
    assert "--measurement" not in err


def test_likely_cause_from_the_data_alone():
    """The causes as the library names them, on synthetic readings (no fit)."""
    robot = robots.hsr_jr680()
    rng = np.random.default_rng(0)
    q = rng.uniform(-2.5, 2.5, (50, 6))
    y = rng.uniform(1000, 3000, 50)
    r = rng.normal(0, 0.5, (50, 1))  # predictions = y + r: readings in mm
    cable = CableLength(np.zeros(3))
    assert likely_cause(robot, cable, q, y, r) is None
    assert "metres" in likely_cause(robot, cable, q, y / 1000, (y - y / 1000)[:, None])
    pos = rng.uniform(-1000, 1000, (50, 3))
    assert "positions look like µm" in likely_cause(robot, Position(), q, pos * 1000, pos - pos * 1000)
    assert "radians read as degrees" in likely_cause(robot, cable, np.deg2rad(q), y, r)
    assert "robot model may not match" in likely_cause(robot, cable, q, y, r, huge_residual=True)


def test_counts_in_the_rows_of_the_users_file(wire, tmp_path, capsys):
    """Too few rows: the one error line says how many of the file's rows went to the test split and
    how many rows the file needs; a misspelt joint column is named; an unknown robot name says
    that a robot file (DH table or URDF) works too."""
    head, rows = wire
    f = _write(tmp_path / "five.csv", head, rows[:5])
    err = _calibrate(capsys, [f, "--robot", "hsr_jr680"], 2).strip().splitlines()
    assert len(err) == 1 and err[0].startswith("jaxcal: error: too few samples: 4 sample(s)"), err
    assert "has 5 rows, of which 1 went to the test split (--test-fraction 0.2): give at least" in err[0], err
    assert "--test-fraction 0" in err[0]
    typo = _write(tmp_path / "typo.csv", head[:-1] + [head[-1].replace("q1_deg", "q1_dg")], rows)
    err = _calibrate(capsys, [typo, "--robot", "hsr_jr680"], 2)
    assert "missing ['q1_deg']" in err and "found ['q1_dg'], not a joint-angle column name" in err, err
    err = _calibrate(capsys, [f, "--robot", "kuka_kr16"], 2)
    assert "unknown robot 'kuka_kr16'" in err and "URDF (.urdf, with --base LINK and --tip LINK)" in err, err


def test_tree_tips_and_self_contact_files_named(tmp_path, capsys):
    """A tip not in the URDF, a self-contact file without its tips or on a robot without them:
    exit 2, one line naming the problem (issue 51)."""
    import pathlib

    urdf = str(pathlib.Path(__file__).resolve().parents[1] / "data" / "urdf" / "humanoid_tree.urdf")
    sc = tmp_path / "sc.csv"
    assert main(["simulate", "--measurement", "self_contact", "--robot", urdf, "--tip", "left_tool,right_tool",
                 "--samples", "40", "--noise-std", "0.1", "--out", str(sc)]) == 0
    capsys.readouterr()
    for argv, named in (
        ([str(sc), "--robot", urdf, "--tip", "left_tool,right_hand"], "right_hand"),
        # another pair of tips is another tree (the head's joints, not the right arm's): named by its joints
        ([str(sc), "--robot", urdf, "--tip", "left_tool,head_camera"], "has 15 joint columns but robot"),
        ([str(sc), "--robot", "hsr_jr680"], "15 joint"),
    ):
        err = [line for line in _calibrate(capsys, argv, 2).splitlines() if line.strip()]
        assert len(err) == 1 and err[0].startswith("jaxcal: error: ") and named in err[0], err
    no_tips = tmp_path / "no_tips.csv"
    no_tips.write_text("".join(line for line in sc.read_text().splitlines(keepends=True) if not line.startswith("# tips:")))
    err = _calibrate(capsys, [str(no_tips), "--robot", urdf, "--tip", "left_tool,right_tool"], 2)
    assert "'# tips: A,B' line" in err and len(err.strip().splitlines()) == 1
