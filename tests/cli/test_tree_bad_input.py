"""Bad input on a kinematic tree (issue 51's acceptance): a tip the robot lacks (a data file's
``# tip:`` line, ``--tip``, a self-contact file's ``# tips:``), a joint column missing for a tip's
chain, a self-contact file naming one tip, two ``--combine`` blocks giving one object two nominal
values. Each exits 2 with one ``jaxcal: error:`` line naming the culprit, before anything is
compiled (tiny hand-written files)."""

import pytest

from jaxcal.cli import main

ROBOT = ["--robot", "dual_arm_ma1400", "--tip", "left_tool,right_tool"]
N_JOINTS = 13  # the torso, then the left arm's six joints, then the right arm's six
ROWS = [[f"{(7 * i + 3 * j) % 50 - 25}" for j in range(N_JOINTS)] for i in range(6)]


def _file(tmp_path, name, meta, cols=None, value_cols=(), values=()):
    """A data file: ``meta`` lines, the joint columns ``cols`` (1-based numbers, default all), then
    the value columns (``values``: one cell per row)."""
    cols = list(range(1, N_JOINTS + 1)) if cols is None else cols
    head = ",".join([f"q{j}_deg" for j in cols] + list(value_cols))
    body = [",".join([r[j - 1] for j in cols] + ([values[i % len(values)]] if values else []))
            for i, r in enumerate(ROWS)]
    path = tmp_path / name
    path.write_text("\n".join(["# jaxcal dataset v1", *meta, head, *body]) + "\n")
    return str(path)


def _position(tmp_path, name="pos.csv", meta=(), cols=None):
    path = _file(tmp_path, name, ["# kind: position", *meta], cols)
    text = open(path).read().splitlines()
    out = text[:-len(ROWS) - 1] + [text[-len(ROWS) - 1] + ",x_mm,y_mm,z_mm"] + [r + ",100,200,300" for r in text[-len(ROWS):]]
    open(path, "w").write("\n".join(out) + "\n")
    return path


def _labelled(tmp_path, name, kind, meta=()):
    return _file(tmp_path, name, [f"# kind: {kind}", *meta, f"# {kind}_labels: table,wall"], value_cols=(kind,),
                 values=("table", "wall"))


def _self_contact(tmp_path, name, tips):
    return _file(tmp_path, name, ["# kind: self_contact", f"# tips: {tips}"], value_cols=("contact_distance_mm",),
                 values=("116.0",))


CASES = {
    # (a) a tip not in the robot
    "file_tip": (lambda t: [_position(t, meta=["# tip: left_hand"]), *ROBOT], ["'# tip: left_hand'",
                                                                                "['left_tool', 'right_tool']"]),
    "flag_tip": (lambda t: [_position(t), "--robot", "dual_arm_ma1400", "--tip", "left_tool,right_hand"],
                 ["--tip", "'right_hand'", "left_camera"]),
    "self_contact_tip": (lambda t: [_self_contact(t, "sc.csv", "left_tool,right_hand"), *ROBOT], ["'right_hand'"]),
    "combine_file_tip": (lambda t: [_labelled(t, "pl.csv", "plane"), _position(t, meta=["# tip: left_hand"]),
                                    *ROBOT, "--combine", "--out-dir", str(t / "fit")], ["left_hand"]),
    # (b) a joint column missing: within the chain (a gap) or after it (the other arm's joints)
    "column_gap": (lambda t: [_position(t, cols=[j for j in range(1, 14) if j != 3]), *ROBOT], ["q3_deg"]),
    "other_arm": (lambda t: [_position(t, cols=list(range(1, 8))), *ROBOT], ["q8 … q13", "branch right_tool"]),
    "combine_other_arm": (lambda t: [_labelled(t, "pl.csv", "plane"), _position(t, cols=list(range(1, 8))),
                                     *ROBOT, "--combine", "--out-dir", str(t / "fit")], ["pos.csv", "q8 … q13"]),
    # (c) a self-contact file that names one tip (or one tip twice)
    "self_contact_one_tip": (lambda t: [_self_contact(t, "sc.csv", "left_tool"), *ROBOT], ["['left_tool']"]),
    "self_contact_same_tip": (lambda t: [_self_contact(t, "sc.csv", "left_tool,left_tool"), *ROBOT],
                              ["['left_tool', 'left_tool']"]),
    # (d) two blocks of a combined fit giving one object two nominal values
    "shared_point": (lambda t: [_labelled(t, "balls_a.csv", "point", ["# radius_mm: 10"]),
                                _labelled(t, "balls_b.csv", "point", ["# tip: right_tool", "# radius_mm: 12"]),
                                *ROBOT, "--combine", "--out-dir", str(t / "fit")],
                     ["point 'table'", "balls_a.csv", "balls_b.csv", "radius 10 mm", "radius 12 mm"]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_tree_bad_input_exits_2_naming_it(case, tmp_path, capsys):
    make, named = CASES[case]
    assert main(["calibrate", *make(tmp_path), "--method", "lm"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith("jaxcal: error: "), err
    for name in named:
        assert name in err[0], (name, err[0])
    assert not (tmp_path / "fit").exists()
