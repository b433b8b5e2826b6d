"""Shape buckets (jaxcal._core._buckets): padded fits equal unpadded ones; one program per bucket; bounded caches."""

import collections
import warnings

import equinox as eqx
import jax
import numpy as np
import pytest

import jaxcal
from jaxcal import Calibrator, Deviations, calibrate, simulate_experiment
from jaxcal._calibration import _programs
from jaxcal._core import _buckets
from jaxcal._core._buckets import BoundedCache, bucket_size, pad_rows
from jaxcal._core._params import ParameterSpace, layout_for
from jaxcal.methods import make_method


@pytest.fixture(scope="module")
def ex():
    return simulate_experiment(jax.random.PRNGKey(3), n_samples=400)


@pytest.fixture
def buckets_on():
    yield
    _buckets.set_buckets(None)


def test_bucket_rule():
    # the fine grid: eight steps per octave, padding at most 1/9 of the bucket
    assert [bucket_size(n, 256) for n in (1, 200, 256, 257, 288, 289, 512, 513, 1600, 5000)] == [
        256, 256, 256, 288, 288, 320, 512, 576, 1664, 5120]
    for n in range(257, 20000, 37):
        b = bucket_size(n, 256)
        assert n <= b and (b - n) <= b / 9 + 1
    assert bucket_size(1000, 64) == 1024 and bucket_size(100, 64) == 104
    # wide samples (a camera view's 108 image coordinates) have a smaller smallest bucket, so that
    # padding to it adds at most 6·256 residual entries; up to a pose's 6 entries nothing changes
    assert [_buckets.smallest_bucket(256, w) for w in (1, 3, 6, 7, 9, 12, 108, 2000)] == [
        256, 256, 256, 128, 128, 128, 8, 1]
    assert [bucket_size(n, 256, width=108) for n in (1, 8, 9, 30, 31, 200)] == [8, 8, 9, 30, 32, 208]
    assert bucket_size(200, 256, width=6) == 256
    for w in (7, 12, 54, 108, 500):
        for n in range(1, 3000, 7):
            b = bucket_size(n, 256, width=w)
            assert n <= b and (b - n) * w <= max(6 * 256, w * (b / 9 + 1))


def test_bucket_reuse(buckets_on):
    """The process's first bucket is fine; later counts reuse a used bucket within 2x, else the
    octave grid: an ascending learning curve 200..2000 uses a handful of buckets."""
    _buckets.set_buckets(True)
    assert bucket_size(1600) == 1664 and bucket_size(1600) == 1664  # the first: fine, remembered
    assert bucket_size(900) == 1664  # reuses (1664 <= 2 x 900)
    assert bucket_size(700) == 1024  # 1664 > 1400: a new bucket, octave grid
    assert bucket_size(1000) == 1024 and bucket_size(1700) == 2048 and bucket_size(1664) == 1664
    _buckets.set_buckets(True)  # forgets
    used = {bucket_size(int(n)) for n in np.linspace(200, 2000, 31)}
    assert len(used) <= 5, sorted(used)
    for n in np.linspace(200, 2000, 31):
        assert n <= bucket_size(int(n)) <= max(256, 2 * n)


def test_setting(buckets_on, monkeypatch):
    _buckets.set_buckets(False)
    assert not _buckets.buckets_enabled() and bucket_size(300) == 300
    _buckets.set_buckets(100)
    assert bucket_size(101) == 113
    _buckets.set_buckets(None)
    monkeypatch.delenv("JAXCAL_BUCKETS", raising=False)
    assert _buckets.buckets_enabled() and not _buckets.buckets_enabled(explicit=True)  # on by default
    monkeypatch.setenv("JAXCAL_BUCKETS", "on")
    assert _buckets.buckets_enabled(explicit=True)
    monkeypatch.setenv("JAXCAL_BUCKETS", "off")
    assert bucket_size(300) == 300
    monkeypatch.setenv("JAXCAL_BUCKETS", "bad")
    with pytest.raises(ValueError, match="JAXCAL_BUCKETS"):
        bucket_size(300)


def test_pad_rows():
    q = np.arange(12.0).reshape(4, 3)
    y = np.arange(4.0)
    qp, yp, w = pad_rows(q, y, 6)
    np.testing.assert_array_equal(np.asarray(qp)[4:], np.broadcast_to(q[0], (2, 3)))
    np.testing.assert_array_equal(np.asarray(yp), [0, 1, 2, 3, 0, 0])
    np.testing.assert_array_equal(np.asarray(w), [1, 1, 1, 1, 0, 0])
    qs, ys, w = pad_rows(q, y, 4)
    assert qs is q and ys is y and np.all(np.asarray(w) == 1)
    # device arrays (immutable) padded again: the last padding is reused; other arrays, another
    # size or host (mutable NumPy) inputs are padded anew
    qd, yd = jax.device_put(q), jax.device_put(y)
    first = pad_rows(qd, yd, 6)
    assert pad_rows(qd, yd, 6) is first
    assert pad_rows(qd, yd, 8) is not first and pad_rows(jax.device_put(q), yd, 6) is not first
    no_y = pad_rows(qd, None, 6)
    assert no_y[1] is None and pad_rows(qd, yd, 6)[1] is not None  # with readings after without: padded anew
    again = pad_rows(q, y, 6)
    assert again is not pad_rows(q, y, 6)
    np.testing.assert_array_equal(np.asarray(first[0]), np.asarray(again[0]))


def test_bounded_cache():
    c = BoundedCache(2)
    c.put("a", 1)
    c.put("b", 2)
    assert c.get("a") == 1  # a is now the most recent
    c.put("c", 3)
    assert "b" not in c and c.get("a") == 1 and c.get("c") == 3 and len(c) == 2 and c.evictions == 1


def _compare(a, b, rtol=1e-9):
    """Two CalibrationResults equal to round-off: parameters, metrics, statistics, diagnostics."""
    assert a.status == b.status and a.space.free_names == b.space.free_names
    scale = np.maximum(np.abs(a.x), 1e-3)
    # round-off, on the scale of x or of what the data determine (a millionth of the posterior σ):
    # a GPU sums the padded/vmapped rows in another order, and LM stops where its tolerance is met,
    # so two strongly correlated parameters (a_3, d_2: σ 0.31 mm) differed by 2e-8 mm on an H200
    atol = np.maximum(1e-8 * float(np.max(scale)), 1e-6 * np.asarray(a.uncertainty.std))
    np.testing.assert_array_less(np.abs(np.asarray(a.x) - np.asarray(b.x)), atol)
    for f in ("rmse", "mean", "max"):
        np.testing.assert_allclose(getattr(a.train_metrics, f), getattr(b.train_metrics, f), rtol=rtol)
    ua, ub = a.uncertainty, b.uncertainty
    np.testing.assert_allclose(ua.std, ub.std, rtol=1e-7)
    np.testing.assert_allclose(ua.noise_std, ub.noise_std, rtol=rtol)
    np.testing.assert_allclose(ua.effective_parameters, ub.effective_parameters, rtol=rtol)
    assert ua.n_residuals == ub.n_residuals
    assert (a.loss_scale_mm is None) == (b.loss_scale_mm is None)
    if a.loss_scale_mm is not None:
        np.testing.assert_allclose(a.loss_scale_mm, b.loss_scale_mm, rtol=rtol)
    da, db = a.diagnostics, b.diagnostics
    np.testing.assert_allclose(da.outlier_scale_mm, db.outlier_scale_mm, rtol=rtol)
    assert da.outliers_before == db.outliers_before and da.outliers_after == db.outliers_after
    if max(da.condition_number, db.condition_number) < 1e6:  # under a prior (MAP over every candidate,
        # issue 22) the data Jacobian of the free set is rank deficient by design: its condition
        # number is round-off (inf or 1e8-3e8 here), not a statistic of the real rows
        np.testing.assert_allclose(da.condition_number, db.condition_number, rtol=1e-7)
    assert da.rounds == db.rounds
    ia, ib = a.identifiability, b.identifiability
    if ia is not None:
        assert ia.identifiable == ib.identifiable and ia.rank == ib.rank
        np.testing.assert_allclose(ia.singular_values, ib.singular_values, rtol=1e-9, atol=1e-12)
    assert a.n_iterations == b.n_iterations


CASES = [
    ("lm", dict(prior="default", loss="huber")),
    ("adamodw", dict(steps=60, prior="default", loss="huber")),
    ("ga", dict(generations=8, population_size=16, prior="default", loss="huber")),
    ("ekf", dict(passes=2, prior="default")),
]


@pytest.mark.parametrize("method,kw", CASES, ids=[c[0] for c in CASES])
def test_padded_fit_equals_unpadded(ex, buckets_on, method, kw):
    """A fit on 300 samples padded to 384 equals the unpadded fit to round-off: parameters, RMSE,
    MEAN, MAX, σ̂, effective parameters, robust and outlier scales, identifiability, iterations.
    A gross outlier makes the Huber loss and the outlier scan do something."""
    q = np.asarray(ex.train.q)[:300]
    y = np.asarray(ex.train.y)[:300].copy()
    y[7] += 40.0
    res = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for on in (False, True):
            _buckets.set_buckets(on)
            res[on] = calibrate(ex.robot, ex.measurement, (q, y), method, **kw)
    _compare(res[False], res[True])
    assert 7 in res[True].diagnostics.outliers_after


def test_calibrator_weighted_rows_ignored(ex):
    """The pure core: padding rows with garbage data (but weight 0) change nothing."""
    meth = make_method("lm")
    space = ParameterSpace.for_robot(ex.robot, measurement=ex.measurement)
    space = jaxcal.identifiability(ex.robot, ex.measurement, ex.train.q, space).space
    start = Deviations.zeros(layout_for(ex.robot, ex.measurement), ex.train.q.dtype)
    cal = Calibrator(ex.robot, ex.measurement, meth, start, space)
    q, y = np.asarray(ex.train.q)[:200], np.asarray(ex.train.y)[:200]
    qp = np.concatenate([q, q[::-1][:56] + 0.3])
    yp = np.concatenate([y, y[:56] + 100.0])  # far-off readings: they would dominate if counted
    w = np.r_[np.ones(200), np.zeros(56)]
    key = jax.random.key(0)
    run = eqx.filter_jit(lambda c, *args: c(*args))
    a = run(cal, q, y, key)
    b = run(cal, qp, yp, key, w)
    np.testing.assert_allclose(np.asarray(b.x), np.asarray(a.x), rtol=0, atol=1e-10)
    for f in ("rmse", "mean", "max"):
        np.testing.assert_allclose(float(getattr(b.train_metrics, f)), float(getattr(a.train_metrics, f)), rtol=1e-10)
    assert int(a.n_iterations) == int(b.n_iterations)


def test_one_compilation_per_bucket_and_bounded_cache(ex, buckets_on, monkeypatch):
    """Sample counts of one bucket share every compiled program (no XLA compilation after the
    first count); the compiled-calibrator cache never holds more than its bound."""
    counts = collections.Counter()

    def listener(event, duration, **kw):
        if event == "/jax/core/compile/backend_compile_duration":
            counts["n"] += 1

    jax.monitoring.register_event_duration_secs_listener(listener)
    monkeypatch.setattr(_programs, "_COMPILED", BoundedCache(2))
    _buckets.set_buckets(True)
    qn, yn = np.asarray(ex.train.q), np.asarray(ex.train.y)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            calibrate(ex.robot, ex.measurement, (qn[:300], yn[:300]), "lm")
            first = counts["n"]
            for n in (290, 320, 384, 263):  # bucket 384
                calibrate(ex.robot, ex.measurement, (qn[:n], yn[:n]), "lm")
            assert counts["n"] == first, "a sample count of a known bucket compiled something"
            assert first >= 1
            _buckets.set_buckets(64)  # smaller buckets: 100 -> 128, 150 -> 192 rows, new programs
            for n in (100, 150):
                calibrate(ex.robot, ex.measurement, (qn[:n], yn[:n]), "lm")
            assert len(_programs._COMPILED) == 2 and _programs._COMPILED.evictions >= 1
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
