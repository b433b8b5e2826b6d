"""Datasets: CSV round trips, reproducible splits, and refusal of malformed input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcal
from jaxcal import Dataset, load_csv, simulate_experiment


@pytest.fixture(scope="module")
def data():
    ex = simulate_experiment(jax.random.PRNGKey(0), n_samples=300)
    return ex.train


def test_csv_roundtrip_radians_exact(data, tmp_path):
    path = tmp_path / "d.csv"
    data.to_csv(path, angle_unit="rad")
    back = load_csv(path)
    np.testing.assert_array_equal(np.asarray(back.q), np.asarray(data.q))
    np.testing.assert_array_equal(np.asarray(back.y), np.asarray(data.y))
    assert back.kind == "cable" and back.meta["robot"] == "hsr_jr680"


def test_csv_roundtrip_degrees(data, tmp_path):
    path = tmp_path / "d.csv"
    data.to_csv(path)
    text = path.read_text()
    assert "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,length_mm" in text
    back = load_csv(path, dof=6)
    np.testing.assert_array_equal(np.asarray(back.y), np.asarray(data.y))
    # deg -> rad conversion: within one ulp
    np.testing.assert_array_max_ulp(np.asarray(back.q), np.asarray(data.q), maxulp=2)
    # data loaded from a degree file saves back to the identical file, and reloads exactly
    back.to_csv(tmp_path / "e.csv")
    assert (tmp_path / "e.csv").read_text() == text
    np.testing.assert_array_equal(np.asarray(load_csv(tmp_path / "e.csv").q), np.asarray(back.q))


def test_position_and_pose_roundtrip(tmp_path):
    r = jaxcal.robots.ur5()
    q = jnp.asarray(np.random.default_rng(0).uniform(-2, 2, size=(20, 6)))
    for meas in (jaxcal.Position(), jaxcal.Pose()):
        d = Dataset(q, meas.predict(r, None, q), meas.kind)
        d.to_csv(tmp_path / "p.csv", angle_unit="rad")
        back = load_csv(tmp_path / "p.csv")
        assert back.kind == meas.kind
        np.testing.assert_allclose(np.asarray(back.y), np.asarray(d.y), rtol=0, atol=1e-9)


def test_split_reproducible_and_disjoint(data):
    a_tr, a_te = data.split(jax.random.PRNGKey(5), 0.25)
    b_tr, b_te = data.split(jax.random.PRNGKey(5), 0.25)
    np.testing.assert_array_equal(np.asarray(a_te.q), np.asarray(b_te.q))
    assert a_te.n == 60 and a_tr.n == 180
    rows = {tuple(r) for r in np.asarray(a_tr.q)} | {tuple(r) for r in np.asarray(a_te.q)}
    assert len(rows) == data.n


def _write(path, text):
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "text, message",
    [
        ("q1_deg,q2_deg,length_mm\n1,2,3\n", "robot has 6 joints"),
        ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n1,2,3,4,5,6\n", "no measurement columns"),
        ("# kind: position\nq1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm\n1,2,3,4,5,6,7,8\n",
         r"missing column\(s\) \['z_mm'\]"),
        ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,length_mm\n1,2,3,4,5,6,7\n1,2,nan,4,5,6,7\n",
         r"NaN/inf \(data rows \[2\]\)"),
        ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,length_mm\n1,2,3,4,5,6,inf\n", "NaN/inf"),
        ("q1_rad,q2_rad,q3_rad,q4_rad,q5_rad,q6_rad,length_mm\n10,45,90,0,30,170,7\n", "look like degrees"),
        ("q1_deg,q2_rad,q3_deg,q4_deg,q5_deg,q6_deg,length_mm\n1,2,3,4,5,6,7\n", "mix degrees and radians"),
        ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,length_mm\n1,2,x,4,5,6,7\n", "data row 1"),
        ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,length_mm\n1,2,3,4,5,6\n", "has 6 fields"),
        ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,length_mm\n", "no data rows"),
        ("# only comments\n", "no header row"),
        ("a,b\n1,2\n", "no joint-angle columns"),
    ],
)
def test_malformed_csv_rejected(tmp_path, text, message):
    with pytest.raises(ValueError, match=message):
        load_csv(_write(tmp_path / "bad.csv", text), dof=6)


def test_missing_file():
    with pytest.raises(FileNotFoundError, match="data file not found"):
        load_csv("/nonexistent/data.csv")


def test_unknown_columns_warn(tmp_path):
    p = _write(tmp_path / "w.csv", "q1_deg,length_mm,temperature_c\n1,2,20\n")
    with pytest.warns(UserWarning, match="temperature_c"):
        d = load_csv(p)
    assert d.n == 1


def test_dataset_constructor_checks():
    with pytest.raises(ValueError, match="look like degrees"):
        Dataset(jnp.full((3, 6), 90.0), jnp.zeros(3))
    with pytest.raises(ValueError, match=r"cable measurements must have shape \[3\]"):
        Dataset(jnp.zeros((3, 6)), jnp.zeros((3, 3)))
    with pytest.raises(ValueError, match="NaN/inf in 1 sample"):
        Dataset(jnp.zeros((3, 6)), jnp.asarray([1.0, np.nan, 2.0]))
    with pytest.raises(ValueError, match="unknown measurement kind"):
        Dataset(jnp.zeros((3, 6)), jnp.zeros(3), kind="laser")


# -- files as they come from spreadsheets and instruments -------------------------------------
_HEADER = ["q1_deg", "q2_deg", "q3_deg", "q4_deg", "q5_deg", "q6_deg", "length_mm"]
_ROWS = [["10", "-20.5", "30", "0", "45.25", "-90", "1500.125"],
         ["11", "-21", "31.5", "1", "46", "-91", "1499.5"]]


def _text(header=_HEADER, rows=_ROWS, sep=","):
    return "".join(sep.join(r) + "\n" for r in [header, *rows])


@pytest.fixture
def reference(tmp_path):
    """The dataset that every variant of the same file below must give."""
    return load_csv(_write(tmp_path / "ref.csv", _text()))


def _assert_same(a, b):
    np.testing.assert_array_equal(np.asarray(a.q), np.asarray(b.q))
    np.testing.assert_array_equal(np.asarray(a.y), np.asarray(b.y))
    assert a.kind == b.kind


def test_utf8_byte_order_mark(tmp_path, reference):
    """Excel's "CSV UTF-8" starts with a BOM; it once gave a column-order error naming q2_deg."""
    p = tmp_path / "bom.csv"
    p.write_text("\ufeff" + _text(), encoding="utf-8")
    _assert_same(load_csv(p, dof=6), reference)
    p.write_text("\ufeff# kind: cable\n" + _text(), encoding="utf-8")
    _assert_same(load_csv(p), reference)


def test_utf16_with_byte_order_mark_and_tabs(tmp_path, reference):
    """Excel's "Unicode text": UTF-16 with a BOM, tab-delimited."""
    p = tmp_path / "u16.txt"
    p.write_text(_text(sep="\t"), encoding="utf-16")
    _assert_same(load_csv(p), reference)


def test_not_utf8_is_refused_clearly(tmp_path):
    p = tmp_path / "latin1.csv"
    p.write_bytes(("# operator: Müller\n" + _text()).encode("latin-1"))
    with pytest.raises(ValueError, match=r"latin1.csv: not UTF-8 text \(byte 0xfc on line 1\)"):
        load_csv(p)


@pytest.mark.parametrize("sep", [";", "\t"])
def test_semicolon_and_tab_delimiters(tmp_path, reference, sep):
    """These once gave "no joint-angle columns"."""
    _assert_same(load_csv(_write(tmp_path / "d.csv", _text(sep=sep))), reference)


def test_decimal_comma_in_semicolon_files(tmp_path, reference):
    rows = [[v.replace(".", ",") for v in r] for r in _ROWS]
    _assert_same(load_csv(_write(tmp_path / "de.csv", _text(rows=rows, sep=";"))), reference)
    # elsewhere a comma in a number is an error, not a misreading
    quoted = "\n".join([",".join(_HEADER), '10,"-20,5",30,0,45.25,-90,1500.125']) + "\n"
    with pytest.raises(ValueError, match=r"data row 1 \(line 2\), column q2_deg: '-20,5' is not a number "
                                         r"\(decimal commas are read only in ';'-delimited files\)"):
        load_csv(_write(tmp_path / "q.csv", quoted))


def test_explicit_delimiter(tmp_path, reference):
    p = _write(tmp_path / "pipe.csv", _text(sep="|"))
    _assert_same(load_csv(p, delimiter="|"), reference)
    _assert_same(load_csv(_write(tmp_path / "s.csv", _text(sep=";")), delimiter=";"), reference)
    with pytest.raises(ValueError, match="delimiter must be one character"):
        load_csv(p, delimiter="||")
    # the wrong explicit delimiter is not guessed around
    with pytest.raises(ValueError, match="no joint-angle columns"):
        load_csv(_write(tmp_path / "c.csv", _text()), delimiter=";")


def test_ambiguous_delimiter_is_an_error(tmp_path):
    p = _write(tmp_path / "amb.csv", "q1_deg;q2_deg,length_mm\n1;2,3\n")
    with pytest.raises(ValueError, match="cannot tell the delimiter.*load_csv.s delimiter argument"):
        load_csv(p)


def test_column_names_case_insensitive_and_stripped(tmp_path, reference):
    header = [" Q1_deg", "Q2_DEG ", "q3_Deg", "Q4_deg", "q5_deg", "Q6_deg", "  Length_MM  "]
    _assert_same(load_csv(_write(tmp_path / "caps.csv", _text(header=header))), reference)
    spaced = _text(sep=", ")  # "1, 2": cells with surrounding spaces
    _assert_same(load_csv(_write(tmp_path / "sp.csv", spaced)), reference)


def test_columns_matched_by_name_in_any_order(tmp_path, reference):
    order = [6, 1, 0, 3, 2, 5, 4]
    header = [_HEADER[i] for i in order]
    rows = [[r[i] for i in order] for r in _ROWS]
    _assert_same(load_csv(_write(tmp_path / "perm.csv", _text(header=header, rows=rows)), dof=6), reference)


@pytest.mark.parametrize(
    "header, message",
    [
        ("q1_deg,q2_deg,q4_deg,length_mm", r"without gaps; missing \['q3_deg'\]"),
        ("q0_deg,q1_deg,length_mm", "found q0"),
        ("q1_deg,q01_deg,length_mm", r"\['q1_deg', 'q01_deg'\] name the same joint"),
        ("q1_deg,Q1_DEG,length_mm", r"duplicate column\(s\) \['q1_deg'\]"),
    ],
)
def test_joint_numbering_checked(tmp_path, header, message):
    with pytest.raises(ValueError, match=message):
        load_csv(_write(tmp_path / "g.csv", header + "\n" + ",".join(["1"] * (header.count(",") + 1)) + "\n"))


@pytest.mark.parametrize("cell, what", [("", "empty field"), ("  ", "empty field"), ("abc", "'abc' is not a number"),
                                        ("1_000", "'1_000' is not a number")])
def test_bad_cell_names_row_line_column_and_text(tmp_path, cell, what):
    """An empty field once gave "data row 101: could not convert string to float: " and no column."""
    rows = [list(_ROWS[0]), list(_ROWS[1])]
    rows[1][2] = cell
    text = "# kind: cable\n\n" + _text(rows=rows)
    p = _write(tmp_path / "cell.csv", text)
    with pytest.raises(ValueError) as err:
        load_csv(p)
    msg = str(err.value)
    assert msg == f"{p}: data row 2 (line 5), column q3_deg: {what}"
    assert "could not convert" not in msg and "\n" not in msg


def test_nan_cell_names_the_first_one(tmp_path):
    rows = [list(_ROWS[0]), list(_ROWS[1])]
    rows[1][6] = "NaN"
    with pytest.raises(ValueError, match=r"NaN/inf \(data rows \[2\]\); first at data row 2 \(line 3\), "
                                         r"column length_mm: 'NaN'"):
        load_csv(_write(tmp_path / "nan.csv", _text(rows=rows)))


def test_comments_blank_lines_and_empty_spreadsheet_cells(tmp_path, reference):
    """Comments and blank lines anywhere, ';;;' rows and trailing separators are not data."""
    lines = _text(sep=";").splitlines()
    text = "\n".join(["# robot: hsr_jr680", "", lines[0] + ";;", "# a comment: here", lines[1] + ";;", ";;;;;;;;",
                      "", lines[2] + ";", "# end"]) + "\n"
    d = load_csv(_write(tmp_path / "xl.csv", text))
    _assert_same(d, reference)
    assert d.meta == {"robot": "hsr_jr680", "a comment": "here"}
    # a nameless column with values is not dropped
    with pytest.raises(ValueError, match=r"column 8 has no name but holds '7' at data row 1 \(line 2\)"):
        load_csv(_write(tmp_path / "nameless.csv", _text(header=[*_HEADER, ""], rows=[[*_ROWS[0], "7"]])))
    # extra non-empty cells are an error naming the row and line
    with pytest.raises(ValueError, match=r"data row 2 \(line 3\) has 8 fields, the header has 7"):
        load_csv(_write(tmp_path / "long.csv", _text().replace("1499.5", "1499.5,3")))


def test_unknown_columns_named_and_strict(tmp_path, reference):
    header = ["Index", *_HEADER, "temperature_C"]
    rows = [["1", *_ROWS[0], "20"], ["2", *_ROWS[1], "21"]]
    p = _write(tmp_path / "extra.csv", _text(header=header, rows=rows))
    with pytest.warns(UserWarning) as rec:
        d = load_csv(p)
    _assert_same(d, reference)
    (w,) = rec
    msg = str(w.message)
    assert msg.startswith(f"{p}: unknown column(s) ['temperature_c'] and bookkeeping column(s) ['index'] are not used")
    assert "strict=True" in msg and "ignoring" not in msg
    with pytest.raises(ValueError, match=r"unknown column\(s\) \['temperature_c'\].*\(strict=True\)"):
        load_csv(p, strict=True)
    only_index = _write(tmp_path / "i.csv", _text(header=header[:-1], rows=[r[:-1] for r in rows]))
    with pytest.warns(UserWarning, match=r"bookkeeping column\(s\) \['index'\] are not used"):
        load_csv(only_index)
    with pytest.raises(ValueError, match="bookkeeping"):
        load_csv(only_index, strict=True)
