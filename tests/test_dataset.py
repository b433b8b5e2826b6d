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
