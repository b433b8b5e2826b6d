"""Metrics, statistical floor and table formatting against closed forms."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from jaxcal import compute_metrics, format_table, statistical_floor


def test_metrics_closed_form():
    e = jnp.asarray([3.0, -4.0, 0.0, 1.0])
    m = compute_metrics(e)
    assert float(m.rmse) == pytest.approx(math.sqrt((9 + 16 + 0 + 1) / 4), rel=1e-15)
    assert float(m.mean) == pytest.approx(2.0, rel=1e-15)
    assert float(m.max) == 4.0


def test_floor_formula_and_monte_carlo():
    f = statistical_floor(0.5, 19, 1600)
    assert f.train == pytest.approx(0.5 * math.sqrt(1 - 19 / 1600))
    assert f.test == pytest.approx(0.5 * math.sqrt(1 + 19 / (1600 - 20)))
    # Monte Carlo check of both on a linear least-squares problem with Gaussian regressors
    rng = np.random.default_rng(0)
    n, p, s = 200, 10, 0.5
    tr, te = [], []
    for _ in range(400):
        A, B = rng.normal(size=(n, p)), rng.normal(size=(2000, p))
        w = rng.normal(size=p)
        y = A @ w + s * rng.normal(size=n)
        wh = np.linalg.lstsq(A, y, rcond=None)[0]
        tr.append(np.mean((A @ wh - y) ** 2))
        te.append(np.mean((B @ wh - (B @ w + s * rng.normal(size=2000))) ** 2))
    f = statistical_floor(s, p, n)
    assert math.sqrt(np.mean(tr)) == pytest.approx(f.train, rel=0.01)
    assert math.sqrt(np.mean(te)) == pytest.approx(f.test, rel=0.01)
    assert statistical_floor(1.0, 3, 100, size=3).test == pytest.approx(math.sqrt(3) * math.sqrt(1 + 3 / 296))
    with pytest.raises(ValueError, match="more residuals"):
        statistical_floor(1.0, 30, 20)


def test_format_table():
    txt = format_table([["lm", 0.51234567, 12], ["adamodw", 1e-5, 3]], ["method", "rmse", "it"])
    lines = txt.splitlines()
    assert lines[0].split() == ["method", "rmse", "it"]
    assert "0.5123" in lines[2] and "1.000e-05" in lines[3]
    md = format_table([["a", 1.0]], ["x", "y"], markdown=True)
    assert md.splitlines()[1].startswith("|--")
