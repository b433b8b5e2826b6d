"""The outlier scan's threshold and its false-alarm rate on clean Gaussian data (issue 53), in
closed form and NumPy only: each file's rows in their own robust σ̂, the threshold for a stated
chance that any clean row of the file is flagged (Šidák over the rows, χ²/F over a row's entries)."""

import numpy as np
import pytest
from scipy import stats

from jaxcal import Checks
from jaxcal._fit._diagnostics import file_rate, outlier_threshold, scan_rows


def _false_alarms(n, m, rate, k, reps=4000, seed=0):
    """Share of ``reps`` clean Gaussian files of ``n`` rows × ``m`` entries in which some row's
    residual norm exceeds ``k`` robust σ̂ (1.4826·MAD of the file's entries, as the scan takes it)."""
    x = np.random.default_rng(seed).standard_normal((reps, n, m))
    flat = x.reshape(reps, -1)
    med = np.median(flat, axis=1)
    s = 1.4826 * np.median(np.abs(flat - med[:, None]), axis=1)
    norm = np.sqrt(np.sum((x - med[:, None, None]) ** 2, axis=2))
    return float(np.mean(np.any(norm > k * s[:, None], axis=1)))


@pytest.mark.parametrize("n, m", [(200, 1), (150, 3)])
def test_false_alarm_rate_is_the_stated_one(n, m):
    """On replicate clean files the threshold's false-alarm rate is the stated one within sampling
    error (and at most ~20 % below it: leverage-free draws, the F tail slightly conservative),
    whereas the same Šidák threshold with σ taken as known (χ² alone) alarms far more often: the
    robust σ̂'s own scatter matters at these sizes."""
    rate, reps = 0.05, 4000
    se = np.sqrt(rate * (1 - rate) / reps)
    fa = _false_alarms(n, m, rate, outlier_threshold(n, m, rate=rate), reps)
    assert 0.8 * rate - 3 * se < fa < rate + 3 * se, fa
    naive = _false_alarms(n, m, rate, outlier_threshold(n, m, n_entries=10**12, rate=rate), reps)
    assert naive > rate + 4 * se, naive


def test_threshold_closed_form():
    """k² is m times the F(m, 0.3675·N) quantile at the Šidák tail; with N → ∞ the χ²_m quantile."""
    p = 1 - (1 - 0.01) ** (1 / 800)
    assert outlier_threshold(800, 1, n_entries=10**12) == pytest.approx(np.sqrt(stats.chi2.isf(p, 1)), rel=1e-6)
    assert outlier_threshold(800, 3) == pytest.approx(np.sqrt(3 * stats.f.isf(p, 3, 0.3675 * 2400)), rel=1e-9)
    assert 4.3 < outlier_threshold(800, 1) < 4.5  # the docstrings' numbers
    ks = outlier_threshold(800, np.array([3, 1, 0]), n_entries=2400)  # masked readings: a lower one, none
    assert ks[1] < ks[0] and np.isinf(ks[2])
    # the training and test rows of one file at their shares keep each row's tail, so the file's rate
    assert 1 - (1 - file_rate(0.01, 160, 200)) * (1 - file_rate(0.01, 40, 200)) == pytest.approx(0.01)


def test_scan_names_a_planted_row_in_its_own_sigma():
    """A 10σ row among clean ones is flagged, in the rows' own σ̂ and unit; a fixed ``k``
    (:attr:`Checks.outlier_k`) still works; NaN rows are flagged; bad settings are refused."""
    rng = np.random.default_rng(3)
    r = 0.05 * rng.standard_normal((300, 1))
    assert scan_rows(r).rows == ()
    r[41, 0] += 0.5
    sc = scan_rows(r, unit="mm")
    assert sc.rows == (41,) and sc.scale == pytest.approx(0.05, rel=0.15) and sc.rate == 0.01
    assert sc.norms[0] == pytest.approx(0.5, abs=0.2)
    text = sc.message("plane.csv", [42], "check it")
    assert text.startswith("plane.csv: 1 outlier row at data row 42: residual ") and " mm, above the threshold " in text
    assert "what a file of 300 clean rows crosses with a 1 % chance" in text and text.endswith("— check it")
    assert scan_rows(r, k=100.0).rows == () and scan_rows(r, k=100.0).rate is None
    r[7, 0] = np.nan
    assert 7 in scan_rows(r).rows
    with pytest.raises(ValueError, match="outlier_rate"):
        Checks(outlier_rate=1.0)


def _images(rng, n=30, points=54, missing=0.1, width=2):
    """Camera-shaped clean residuals ``[n, width·points]`` (unit σ) with ``missing`` of the points
    masked (not detected: zero residual, not observed), and the mask."""
    r = rng.standard_normal((n, points, width))
    seen = rng.random((n, points)) > missing
    r[~seen] = 0.0
    return r.reshape(n, -1), np.repeat(seen, width, axis=1)


def test_point_scan_false_alarm_rate_is_the_stated_one():
    """A reading of several points (30 camera images × 54 corners × 2 px, 10 % of the corners not
    detected) is judged per corner and per image, the rate split between them: on replicate clean
    files the chance that anything is flagged is at most the stated rate, within sampling error of
    it or up to ~30 % below (measured 3.5–4.2 % for 5 %, 0.65–0.82 % for 1 %: the σ̂ every corner and
    image shares makes their crossings dependent, which Šidák's independence ignores)."""
    rate, reps = 0.05, 1500
    se = np.sqrt(rate * (1 - rate) / reps)
    rng = np.random.default_rng(0)
    hits = 0
    for _ in range(reps):
        r, obs = _images(rng)
        hits += bool(scan_rows(r, obs, rate=rate, point_entries=2, point_word="corner", unit="px").rows)
    fa = hits / reps
    assert 0.7 * rate - 3 * se < fa < rate + 3 * se, fa


def test_point_scan_names_a_planted_corner_and_a_shifted_image():
    """One 10σ corner coordinate among 30 images × 54 corners is named in every seed, as its row and
    its corner (1-based in the message); masked corners are never flagged; an image shifted as a
    whole is named by its corners (far off) or as a row (a little off in every corner); marker sets
    (3 entries per point) likewise; the row scan is the one-point case."""
    for seed in range(20):
        rng = np.random.default_rng(seed)
        r, obs = _images(rng)
        i, j = int(rng.integers(30)), int(rng.integers(54))
        obs[i, 2 * j: 2 * j + 2] = True
        r[i, 2 * j] = 10.0 + rng.standard_normal()
        sc = scan_rows(r, obs, point_entries=2, point_word="corner", unit="px")
        assert sc.rows == (i,) and sc.points == ((j,),), (seed, sc.rows, sc.points)
    text = sc.message("camera.csv", [i + 1], "check it")
    assert text.startswith(f"camera.csv: 1 outlier corner at data row {i + 1} (corner {j + 1}: ")
    assert "on a corner's residual" in text and text.endswith("— check it")
    # masked corners carry garbage: not flagged (nor counted in σ̂)
    r2 = r.copy()
    r2[~obs] = 1e3
    assert scan_rows(r2, obs, point_entries=2, point_word="corner").rows == sc.rows
    # an image far off in every corner: all its corners; a little off in every corner: the row
    r3, obs3 = _images(np.random.default_rng(99))
    r3[4] += np.where(obs3[4], 8.0, 0.0)
    r3[9] += np.where(obs3[9], 1.5, 0.0)
    sc3 = scan_rows(r3, obs3, point_entries=2, point_word="corner", unit="px")
    assert sc3.rows == (4, 9) and len(sc3.points[0]) == obs3[4].sum() // 2 and sc3.points[1] == ()
    assert "data row 10 (all its corners together: " in sc3.message("camera.csv", [5, 10])
    # markers: 3 mm entries per point
    rng = np.random.default_rng(5)
    r4 = 0.1 * rng.standard_normal((200, 12))
    r4[17, 7] += 1.0
    sc4 = scan_rows(r4, point_entries=3, point_word="marker")
    assert sc4.rows == (17,) and sc4.points == ((2,),) and sc4.entries == 3
    assert "(marker 3: " in sc4.message("markers.csv", [18])
    one = scan_rows(r4, point_entries=12)  # a row of one point: the row scan
    assert one.points == () and one.point_word == "" and one.k_row is None
