"""The rows of a data file a calibration trains and tests on (`jaxcal.split_rows`), and gross errors
in held-out rows (`jaxcal.residual_outliers`): what `jaxcal calibrate` does, as library API."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import jaxcal
from jaxcal import Dataset
from jaxcal._datasets._split import seed_split
from jaxcal._sensors._sessions import SessionMarkers


@pytest.fixture(scope="module")
def cable():
    jaxcal.enable_x64()
    return jaxcal.simulate_experiment(jax.random.key(3), n_samples=250, test_fraction=0.2)  # 200 train rows


def test_split_rows_is_the_seeded_split_of_the_kept_rows(cable):
    data = cable.train
    excluded = [1, 5, 6, 200]
    s = jaxcal.split_rows(data, cable.measurement, seed=7, test_fraction=0.25, exclude_rows=excluded)
    assert s.excluded_rows == tuple(excluded) and s.data.n == data.n - len(excluded)
    key, train_idx, test_idx = seed_split(7, data.n - len(excluded), 0.25)
    np.testing.assert_array_equal(s.train_idx, train_idx)
    np.testing.assert_array_equal(s.test_idx, test_idx)
    np.testing.assert_array_equal(jax.random.key_data(s.key), jax.random.key_data(key))
    rows = s.train_rows + s.test_rows  # 1-based data rows of the file, every kept row once
    assert sorted(rows) == sorted(set(range(1, data.n + 1)) - set(excluded))
    # a row's numbers are the file's: row r of the file is data row r
    r = s.train_rows[3]
    np.testing.assert_array_equal(np.asarray(s.train.q)[3], np.asarray(data.q)[r - 1])
    assert s.measurement is cable.measurement and s.test_measurement is cable.measurement
    # the same seed gives the same rows; a separate test file: every kept row trains
    again = jaxcal.split_rows(data, cable.measurement, seed=7, test_fraction=0.25, exclude_rows=excluded)
    np.testing.assert_array_equal(again.train_idx, s.train_idx)
    every = jaxcal.split_rows(data, cable.measurement, seed=7, test_fraction=0.25, test_file=True)
    assert every.train_rows == list(range(1, data.n + 1)) and every.test.n == 0


def test_split_rows_refuses_bad_rows_and_fractions(cable):
    with pytest.raises(ValueError, match=r"data rows are numbered 1\.\.200, got 0\.\.3"):
        jaxcal.split_rows(cable.train, cable.measurement, exclude_rows=[0, 3])
    with pytest.raises(ValueError, match=r"test fraction must be in \[0, 1\)"):
        jaxcal.split_rows(cable.train, cable.measurement, test_fraction=1.0)


def test_without_train_drops_those_training_rows_only(cable):
    s = jaxcal.split_rows(cable.train, cable.measurement, seed=1, test_fraction=0.2)
    dropped = s.file_rows(s.train_idx[[0, 10]])
    t = s.without_train([0, 10])
    assert len(t.train_idx) == len(s.train_idx) - 2 and t.test_rows == s.test_rows
    assert not set(dropped) & set(t.train_rows) and set(t.train_rows) | set(dropped) == set(s.train_rows)


def _session_data(n_per=6):
    """Marker readings of three sessions (labels only matter here: frames f1..f3, placements p1/p2)."""
    rng = np.random.default_rng(0)
    labels = ([("s1", "f1", "p1")] * n_per + [("s2", "f2", "p1")] * n_per + [("s3", "f3", "p2")] * 2)
    n = len(labels)
    return Dataset(rng.uniform(-1, 1, (n, 6)), rng.normal(0, 100, (n, 2, 3)), "markers", labels=labels)


def test_sessions_stay_on_the_training_side():
    data = _session_data()
    model = SessionMarkers.from_dataset(data)
    ok = jaxcal.split_rows(data, model, seed=0, test_fraction=0.0)
    assert isinstance(ok.measurement, SessionMarkers) and len(ok.measurement.frame_index) == data.n
    # exclude one of session s3's two rows: where the split holds the other out, s3's frame and
    # placement have no training row, and the split says so; elsewhere each row set has its model

    def attempt(seed):
        try:
            return jaxcal.split_rows(data, model, seed=seed, test_fraction=0.2, exclude_rows=s3[:1])
        except ValueError as e:
            return e

    s3 = [r for r in range(1, data.n + 1) if data.labels[r - 1][0] == "s3"]
    tries = [attempt(seed) for seed in range(30)]
    refused = [t for t in tries if isinstance(t, ValueError)]
    good = [t for t in tries if not isinstance(t, ValueError)]
    assert refused and good
    assert all("label(s) ['f3', 'p2'] have no training rows" in str(e) for e in refused)
    assert all(s3[1] in g.train_rows for g in good)
    good = good[0]
    frames = [good.data.labels[i][1] for i in good.test_idx]
    assert [good.test_measurement.frames[i] for i in np.asarray(good.test_measurement.frame_index)] == frames


def test_residual_outliers_name_a_planted_gross_error(cable):
    data, truth, sigma = cable.train, cable.true_deviations, float(cable.noise_std)
    clean_rows, scale = jaxcal.residual_outliers(cable.robot, cable.measurement, truth, data)
    assert clean_rows == () and 0.7 * sigma < scale < 1.3 * sigma  # the noise, seen robustly
    y = np.asarray(data.y).copy()
    y[17] += 10 * sigma
    rows, _ = jaxcal.residual_outliers(cable.robot, cable.measurement, truth, Dataset(data.q, y, "cable"))
    assert rows == (17,)
