"""DH table files (``load_robot_csv``): files as they come, column synonyms, nothing ignored."""

import numpy as np
import pytest

from jaxcal._calibration._io import load_robot_csv

# HSR-JR680-like table: alpha_deg, a_mm, d_mm, theta_deg, q_min_deg, q_max_deg
_TABLE = [
    ["-90", "250", "653.5", "0", "-170", "170"],
    ["0", "900", "0", "-90", "-110", "110"],
    ["-90", "-205", "0", "180", "-140", "140"],
    ["90", "0", "1030.2", "0", "-180", "180"],
    ["-90", "0", "0", "90", "-120", "120"],
    ["0", "0", "200.6", "0", "-360", "360"],
]
_DH = ["alpha_deg", "a_mm", "d_mm", "theta_deg"]


def _write(tmp_path, header, rows=_TABLE, sep=",", head="# name: jr680\n", name="robot.csv", **kw):
    p = tmp_path / name
    p.write_text(head + "".join(sep.join(r) + "\n" for r in [header, *rows]), **kw)
    return p


def _limits(robot):
    return np.rad2deg(np.asarray(robot.q_min)), np.rad2deg(np.asarray(robot.q_max))


def _assert_table(robot, limits=True):
    want = np.asarray(_TABLE, float)
    np.testing.assert_allclose(robot.dh_table_deg(), want[:, :4], rtol=1e-12, atol=1e-12)
    lo, hi = _limits(robot)
    np.testing.assert_allclose(lo, want[:, 4] if limits else -180.0, rtol=1e-12)
    np.testing.assert_allclose(hi, want[:, 5] if limits else 180.0, rtol=1e-12)


def test_plain_file(tmp_path):
    r = load_robot_csv(_write(tmp_path, _DH + ["q_min_deg", "q_max_deg"]))
    _assert_table(r)
    assert r.name == "jr680" and r.beta_joints == () and r.dof == 6
    np.testing.assert_array_equal(np.asarray(r.tool), 0.0)


@pytest.mark.parametrize("lo, hi", [("q_min", "q_max"), ("qmin", "qmax"), ("min", "max"), ("lower", "upper"),
                                    ("q_lower", "q_upper"), ("QMin", "QMax")])
def test_joint_limit_synonyms(tmp_path, lo, hi):
    """``qmin_deg,qmax_deg`` were once ignored silently (limits fell back to ±180°)."""
    _assert_table(load_robot_csv(_write(tmp_path, _DH + [f"{lo}_deg", f"{hi}_deg"])))


def test_radian_columns_converted(tmp_path):
    rows = [[r[0], r[1], r[2], r[3], repr(float(np.deg2rad(float(r[4])))), repr(float(np.deg2rad(float(r[5]))))] for r in _TABLE]
    _assert_table(load_robot_csv(_write(tmp_path, _DH + ["q_min_rad", "q_max_rad"], rows)))
    rows = [[repr(float(np.deg2rad(float(r[0])))), r[1], r[2], repr(float(np.deg2rad(float(r[3])))), r[4], r[5]] for r in _TABLE]
    _assert_table(load_robot_csv(_write(tmp_path, ["alpha_rad", "a_mm", "d_mm", "theta_rad", "lower_deg",
                                                   "upper_deg"], rows)))


def test_no_limits_default_to_180(tmp_path):
    _assert_table(load_robot_csv(_write(tmp_path, _DH, [r[:4] for r in _TABLE])), limits=False)


@pytest.mark.parametrize("column", ["q_min_deg", "upper_rad"])
def test_one_limit_column_is_an_error(tmp_path, column):
    k = 4 if "min" in column else 5
    with pytest.raises(ValueError, match=f"joint limit column {column} needs its partner"):
        load_robot_csv(_write(tmp_path, _DH + [column], [r[:4] + [r[k]] for r in _TABLE]))


def test_unknown_column_is_an_error_listing_accepted(tmp_path):
    rows = [r + ["5"] for r in _TABLE]
    with pytest.raises(ValueError) as err:
        load_robot_csv(_write(tmp_path, _DH + ["q_min_deg", "q_max_deg", "Mass_kg"], rows))
    msg = str(err.value)
    assert msg.startswith(f"{tmp_path / 'robot.csv'}: unknown DH table column(s) ['mass_kg']; accepted: ")
    for name in ("alpha_deg", "theta_rad", "qmin_deg/qmax_deg", "lower_deg/upper_deg", "beta_deg", "joint"):
        assert name in msg
    assert "\n" not in msg


def test_same_quantity_twice_is_an_error(tmp_path):
    rows = [r + [r[4]] for r in _TABLE]
    with pytest.raises(ValueError, match=r"columns \['q_min_deg', 'lower_deg'\] give the same quantity"):
        load_robot_csv(_write(tmp_path, _DH + ["q_min_deg", "q_max_deg", "lower_deg"], rows))


def test_bom_semicolons_decimal_commas_any_case_and_order(tmp_path):
    order = [5, 3, 0, 2, 1, 4]
    header = [(_DH + ["QMIN_DEG", " QMax_Deg "])[i].upper() for i in order]
    rows = [[r[i].replace(".", ",") for i in order] for r in _TABLE]
    p = _write(tmp_path, header, rows, sep=";", head="\ufeff# Name: jr680\n# tool_mm: 0;0;150,5\n", encoding="utf-8")
    r = load_robot_csv(p)
    _assert_table(r)
    assert r.name == "jr680"
    np.testing.assert_array_equal(np.asarray(r.tool), [0.0, 0.0, 150.5])


def test_tab_delimited_and_explicit_delimiter(tmp_path):
    _assert_table(load_robot_csv(_write(tmp_path, _DH + ["min_deg", "max_deg"], sep="\t")))
    _assert_table(load_robot_csv(_write(tmp_path, _DH + ["min_deg", "max_deg"], sep="|"), delimiter="|"))


def test_beta_column_marks_hayati_joints(tmp_path):
    rows = [r + ["0.5" if j == 1 else "0"] for j, r in enumerate(_TABLE)]
    r = load_robot_csv(_write(tmp_path, _DH + ["q_min_deg", "q_max_deg", "beta_deg"], rows))
    assert r.beta_joints == (2,)
    np.testing.assert_allclose(np.rad2deg(np.asarray(r.beta)), [0, 0.5, 0, 0, 0, 0], rtol=1e-12)
    r = load_robot_csv(_write(tmp_path, _DH + ["q_min_deg", "q_max_deg", "beta_rad"], [x + ["0"] for x in _TABLE]))
    assert r.beta_joints == ()


def test_joint_column_checked(tmp_path):
    rows = [[str(j + 1)] + r for j, r in enumerate(_TABLE)]
    _assert_table(load_robot_csv(_write(tmp_path, ["Joint"] + _DH + ["q_min_deg", "q_max_deg"], rows)))
    rows[2][0] = "4"
    with pytest.raises(ValueError, match=r"joint column must number the rows 1..6"):
        load_robot_csv(_write(tmp_path, ["joint"] + _DH + ["q_min_deg", "q_max_deg"], rows))


@pytest.mark.parametrize("cell, what", [("", "empty field"), ("abc", "'abc' is not a number")])
def test_bad_cell_names_row_line_and_column(tmp_path, cell, what):
    rows = [list(r) for r in _TABLE]
    rows[2][1] = cell
    p = _write(tmp_path, _DH + ["q_min_deg", "q_max_deg"], rows)
    with pytest.raises(ValueError) as err:
        load_robot_csv(p)
    assert str(err.value) == f"{p}: joint row 3 (line 5), column a_mm: {what}"


@pytest.mark.parametrize(
    "head, header, message",
    [
        ("", _DH[:3], r"lacks column\(s\) \['theta_deg'\]"),
        ("# tool_mm: 1,2\n", _DH, r"'# tool_mm: 1,2' needs 3 numbers"),
        ("# tool_mm: 1,x,2\n", _DH, r"needs 3 numbers"),
        ("", _DH + ["q_min_deg", "q_max_deg", "q_max_rad"], r"\['q_max_deg', 'q_max_rad'\] give the same quantity"),
    ],
)
def test_malformed_file_rejected(tmp_path, head, header, message):
    rows = [r[: len(header)] + ["0"] * (len(header) - 6) for r in _TABLE]
    with pytest.raises(ValueError, match=message):
        load_robot_csv(_write(tmp_path, header, rows, head=head))


def test_limits_must_be_ordered_and_file_must_have_rows(tmp_path):
    with pytest.raises(ValueError, match="q_min < q_max"):
        load_robot_csv(_write(tmp_path, _DH + ["upper_deg", "lower_deg"]))
    with pytest.raises(ValueError, match="no joint rows"):
        load_robot_csv(_write(tmp_path, _DH, []))
    with pytest.raises(FileNotFoundError, match="DH table file not found"):
        load_robot_csv(tmp_path / "none.csv")


@pytest.mark.parametrize("line, convention", [("", "standard"), ("# convention: standard\n", "standard"),
                                              ("# Convention: DH\n", "standard"), ("# convention: modified\n", "modified"),
                                              ("# convention: Craig\n", "modified")])
def test_convention_line(tmp_path, line, convention):
    r = load_robot_csv(_write(tmp_path, _DH + ["q_min_deg", "q_max_deg"], head="# name: jr680\n" + line))
    assert r.convention == convention
    _assert_table(r)


def test_modified_table_round_trips_with_its_convention(tmp_path):
    from jaxcal._calibration._io import save_robot_csv

    r = load_robot_csv(_write(tmp_path, _DH + ["q_min_deg", "q_max_deg"], head="# convention: modified\n"))
    save_robot_csv(r, tmp_path / "back.csv")
    assert "# convention: modified" in (tmp_path / "back.csv").read_text()
    back = load_robot_csv(tmp_path / "back.csv")
    assert back.convention == "modified"
    _assert_table(back)


@pytest.mark.parametrize("head, message", [
    ("# convention: craig-ish\n", r"'# convention: craig-ish' must be standard \(or dh\) or modified \(or craig\)"),
    ("# dh_convention: modified\n", r"'# dh_convention: \.\.\.' is not a DH table file setting; the settings are "
                                    r"'# name:', '# tool_mm:', '# convention:'"),
])
def test_a_setting_is_never_ignored(tmp_path, head, message):
    """A ``# key: value`` line the reader does not know is an error, not silently ignored (a
    modified-DH table read as standard DH puts the tool metres away)."""
    with pytest.raises(ValueError, match=message):
        load_robot_csv(_write(tmp_path, _DH, [r[:4] for r in _TABLE], head=head))
    # free text without a colon is a comment
    load_robot_csv(_write(tmp_path, _DH, [r[:4] for r in _TABLE], head="# from the vendor's data sheet\n"))
