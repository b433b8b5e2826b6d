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
