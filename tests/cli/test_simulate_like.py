"""``jaxcal simulate --like``: a new day of a simulated set-up for every kind ``jaxcal simulate``
writes and for a combined result (issue 53). Before, it refused everything but cable, position and
pose data, so a plane, point, bar, camera or self-contact calibration (and any combined set-up) had
no new day to be evaluated on.

Each kind is calibrated on its own robot type (a preset, a DH table file, a URDF chain, a tree), so
every robot type is crossed without the product: the new day's file must repeat the first file's
set-up lines and true robot (with the first file's seed, its rows bit for bit), and ``jaxcal
evaluate`` of the result on it must exit 0 with the expected RMSE within 0.8–1.25 of the measured.
"""

import json
import pathlib

import pytest
from test_robot_types import _run, robot_type_args

from jaxcal._calibration._blocks import COMBINED_FORMAT
from jaxcal._datasets._dataset import load_csv

TREE = pathlib.Path(__file__).parents[1] / "data" / "urdf" / "humanoid_tree.urdf"

#: kind: (robot type, `jaxcal simulate` options of the first file, `jaxcal calibrate` options): the
#: sizes and options of other tests' files of the kind (test_contact, test_camera, test_pose_sigma,
#: test_robot_types, test_verdicts), whose compiled programs the test run has already
CASES = {
    "cable": ("preset", ["--unknown-anchor", "--samples", "300"], []),
    "position": ("preset", ["--samples", "200"], []),
    "pose": ("preset", ["--samples", "150", "--noise-std", "0.3", "--orientation-noise-deg", "0.002"],
             ["--test-fraction", "0"]),
    "camera": ("preset", ["--samples", "30", "--noise-std", "0.3", "--missing-corners", "0.05"],
               ["--prior", "none", "--loss", "linear"]),
    "plane": ("preset", ["--samples", "300"], ["--test-fraction", "0"]),
    "point": ("preset", ["--radius-mm", "30", "--samples", "300"], ["--test-fraction", "0"]),
    "distance": ("dh_file", ["--samples", "300"], ["--test-fraction", "0"]),
    "self_contact": ("tree", ["--samples", "150", "--noise-std", "0.1"], []),
}
#: the lines that differ between a first file and its new day
_DAY_LINES = {"seed", "true_robot_seed", "like"}


def _robot_args(rtype: str, d: pathlib.Path) -> list[str]:
    if rtype == "tree":  # a kinematic tree: two arms of one body
        return ["--robot", str(TREE), "--tip", "left_tool,right_tool"]
    return robot_type_args(rtype, d)


def _ratio(capsys, result, data, out) -> float:
    """``jaxcal evaluate RESULT DATA``: exits 0; expected / measured RMSE."""
    code, printed = _run(["evaluate", str(result), str(data), "--out", str(out)], capsys)
    assert code == 0, printed.out + printed.err
    ev = json.loads(pathlib.Path(out).read_text())
    unit = "px" if "expected_rmse_px" in ev else "mm"
    return ev[f"expected_rmse_{unit}"] / ev[f"metrics_{unit}"]["after"]["rmse"]


@pytest.mark.parametrize("kind", list(CASES))
def test_new_day_of_every_kind(kind, tmp_path, capsys):
    rtype, sim, cal = CASES[kind]
    robot = _robot_args(rtype, tmp_path)
    a, b, res = tmp_path / "a.csv", tmp_path / "b.csv", tmp_path / "a.json"
    assert _run(["simulate", *robot, "--measurement", kind, *sim, "--seed", "1", "--out", str(a)], capsys)[0] == 0
    code, out = _run(["calibrate", str(a), *robot, "--measurement", kind, *cal, "--out", str(res)], capsys)
    assert code == 0, out.out + out.err
    code, out = _run(["simulate", "--like", str(res), "--seed", "3", "--out", str(b)], capsys)
    assert code == 0, out.err
    assert "the robot and set-up of a.json (data a.csv)" in out.out
    first, day = load_csv(a), load_csv(b)
    assert (day.kind, day.n, day.meta["seed"], day.meta["true_robot_seed"]) == (kind, first.n, "3", "1")
    same = {k: v for k, v in first.meta.items() if k not in _DAY_LINES}
    assert {k: v for k, v in day.meta.items() if k not in _DAY_LINES} == same  # the set-up lines, as written
    assert 0.8 < _ratio(capsys, res, b, tmp_path / "e.json") < 1.25
    # the truth to the last bit: the first file's seed gives the first file's rows
    assert _run(["simulate", "--like", str(res), "--seed", "1", "--out", str(tmp_path / "again.csv")], capsys)[0] == 0
    rows = lambda p: [ln for ln in p.read_text().splitlines() if not ln.startswith("#")]  # noqa: E731
    assert rows(tmp_path / "again.csv") == rows(a)
    if rtype == "tree":
        _tree_result_exports_and_reports(res, tmp_path, capsys)


def _tree_result_exports_and_reports(res, tmp_path, capsys):
    """A calibrated tree through `jaxcal export` and `jaxcal report` (issue 51): the URDF written
    reloads with the result's tips and gives its calibrated tool points within 1e-9 mm (the
    right tool becomes an added link: the tree has no fixed joint to hold its correction); the
    HTML report is written and well-formed; `--dh-out` refuses in one line naming the branches."""
    import xml.etree.ElementTree as ET

    import jax.numpy as jnp
    import numpy as np

    from jaxcal import load_result, load_urdf
    from jaxcal._models._kinematics import fk_position

    urdf = tmp_path / "cal.urdf"
    code, out = _run(["export", str(res), "--out", str(urdf)], capsys)
    assert code == 0, out.err
    r = load_result(res)
    again = load_urdf(urdf, tips=["left_tool", "jaxcal_calibrated_tip_right_tool"])
    q = jnp.asarray(np.random.default_rng(5).uniform(-0.8, 0.8, (8, r.robot.dof)))
    for tip, tip2 in (("left_tool", "left_tool"), ("right_tool", "jaxcal_calibrated_tip_right_tool")):
        want = np.asarray(fk_position(r.robot, q, r.deviations, tip=tip))
        got = np.asarray(fk_position(again, q, tip=tip2))
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    code, out = _run(["export", str(res), "--dh-out", str(tmp_path / "x.csv")], capsys)
    assert code == 2 and len(out.err.strip().splitlines()) == 1 and "left_tool" in out.err, out.err
    pytest.importorskip("matplotlib")
    code, out = _run(["report", str(res), "--html", str(tmp_path / "r.html")], capsys)
    assert code == 0, out.err
    ET.fromstring((tmp_path / "r.html").read_text(encoding="utf-8").split("\n", 1)[1])


def test_new_day_of_a_combined_set_up(tmp_path, capsys):
    """``--like DIR/combined.json --out-dir NEW``: one new file per block under its file's name; each
    block's result evaluates on its new file as expected, and the new files combine again."""
    robot = robot_type_args("urdf", tmp_path)  # test_robot_types's files of one seed, on a URDF chain
    sim = ["simulate", *robot, "--seed", "1"]
    data = tmp_path / "day1"
    data.mkdir()
    assert _run([*sim, "--measurement", "plane", "--samples", "300", "--out", str(data / "plane.csv")], capsys)[0] == 0
    assert _run([*sim, "--measurement", "distance", "--samples", "200", "--out", str(data / "bar.csv")], capsys)[0] == 0
    fit = tmp_path / "fit"
    code, out = _run(["calibrate", str(data / "plane.csv"), str(data / "bar.csv"), "--combine", *robot,
                      "--out-dir", str(fit)], capsys)
    assert code == 0, out.err
    like = ["simulate", "--like", str(fit / "combined.json"), "--seed", "3"]
    code, out = _run([*like, "--out-dir", str(data)], capsys)  # the first files' folder: refused, nothing written
    assert code == 2 and "would overwrite" in out.err and str(data / "plane.csv") in out.err, out.err
    code, out = _run([*like, "--out", str(tmp_path / "x.csv")], capsys)
    assert code == 2 and "give --out-dir DIR" in out.err, out.err
    new = tmp_path / "day2"
    code, out = _run([*like, "--out-dir", str(new)], capsys)
    assert code == 0, out.err
    assert sorted(p.name for p in new.iterdir()) == ["bar.csv", "plane.csv"]
    assert "combined.json, block plane (data plane.csv)" in out.out
    for block in ("plane", "bar"):
        assert load_csv(new / f"{block}.csv").meta["true_robot_seed"] == "1"
        assert 0.8 < _ratio(capsys, fit / f"{block}.json", new / f"{block}.csv", tmp_path / f"{block}.e.json") < 1.25


def test_like_refuses_what_it_cannot_repeat(tmp_path, capsys):
    """Exit 2 and one line: a kind ``jaxcal simulate`` does not write (named), a data file it did
    not write, options that would change the set-up, ``--out-dir`` of a single result."""
    a, res = tmp_path / "a.csv", tmp_path / "a.json"
    assert _run(["simulate", "--measurement", "position", "--samples", "60", "--out", str(a)], capsys)[0] == 0
    assert _run(["calibrate", str(a), "--robot", "hsr_jr680", "--measurement", "position", "--out", str(res)],
                capsys)[0] == 0

    def refused(argv, *words):
        code, out = _run(["simulate", "--like", *argv], capsys)
        lines = out.err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and all(w in lines[0] for w in words), out.err

    refused([str(res), "--mount", "eye-to-hand", "--out", str(tmp_path / "x.csv")], "drop --mount")
    refused([str(res), "--out-dir", str(tmp_path / "new")], "--out-dir applies to --like of a combined result")
    raw = json.loads(res.read_text())
    raw["measurement"] = {"kind": "markers"}
    (tmp_path / "m.json").write_text(json.dumps(raw))
    refused([str(tmp_path / "m.json"), "--out", str(tmp_path / "x.csv")], "cannot re-simulate markers data")
    a.write_text("".join(ln for ln in a.read_text().splitlines(keepends=True) if not ln.startswith("# source:")))
    refused([str(res), "--out", str(tmp_path / "x.csv")], "was not written by `jaxcal simulate`")
    (tmp_path / "c.json").write_text(json.dumps({"format": COMBINED_FORMAT}))
    refused([str(tmp_path / "c.json"), "--out", str(tmp_path / "x.csv")], "combined result", "--out-dir")
