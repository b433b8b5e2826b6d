"""Priors (MAP) and robust losses: independent checks against scipy and closed forms."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize
from conftest import central_differences

import jaxcal
from jaxcal import Prior
from jaxcal._fit._diagnostics import robust_consistency
from jaxcal._fit._objective import Objective, robust_factor
from jaxcal._fit._problem import Problem


@pytest.fixture(scope="module")
def ex():
    return jaxcal.simulate_experiment(jax.random.key(11), n_samples=300)


def _scipy_fit(ex, space, augment, loss="linear", f_scale=1.0):
    """scipy's least_squares on the residuals written out here (numpy callbacks, numeric Jacobian)."""
    pr = Problem(ex.robot, ex.measurement, ex.train.q, ex.train.y, space)
    res_fn = jax.jit(lambda x: pr.residual(x))

    def fun(x):
        r = np.asarray(res_fn(jnp.asarray(x)))
        return np.concatenate([r, augment(x)])

    sol = scipy.optimize.least_squares(fun, np.zeros(space.n_free), method="trf", loss=loss, f_scale=f_scale,
                                       x_scale="jac", xtol=1e-14, ftol=1e-14, gtol=1e-14)
    return sol.x


def test_lm_with_prior_is_the_map_estimate(ex):
    """LM on the augmented residuals = scipy on [r; σ·(x − m)/s] written out independently."""
    prior = Prior(angle_deg=0.05, length_mm=0.2, noise_std=0.5)  # strong enough to move every parameter
    res = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm", prior=prior, rtol=1e-10, atol=1e-10)
    s = np.where(np.asarray(res.space.free_units) == "rad", math.radians(0.05), 0.2)
    x_ref = _scipy_fit(ex, res.space, lambda x: 0.5 * x / s)
    plain = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm")
    # under the prior every DH deviation is free (MAP, issue 22); plain least squares frees the
    # identifiable subset: compare on that
    idx = [res.space.free_names.index(n) for n in plain.space.free_names]
    assert res.space.n_free == 24 and plain.space.n_free == 19
    assert np.max(np.abs(plain.x - x_ref[idx]) / s[idx]) > 0.05  # the prior matters here
    # equal to a thousandth of the parameters' posterior σ (scipy: numeric Jacobian, its own stopping)
    assert np.max(np.abs(res.x - x_ref) / res.uncertainty.std) < 1e-3
    assert res.diagnostics.rounds == 1  # noise σ given: one round
    # the reported condition number is the posterior information's (the MAP fit inverts it; the
    # data Jacobian of all 24 is singular): column-scaled J over σ̂ stacked on the prior rows, with J
    # by central differences here
    pr = Problem(ex.robot, ex.measurement, ex.train.q, ex.train.y, res.space)
    x0, h = np.asarray(res.x, np.float64), 1e-6
    J = central_differences(pr.residual, x0, h)
    d = np.linalg.norm(J, axis=0)
    blind = d < 1e-6 * d.max()  # columns the distance data cannot see at all (zero, unscaled)
    J[:, blind], d[blind] = 0.0, 1.0
    H = (J / d).T @ (J / d) / res.uncertainty.noise_std ** 2 + np.diag(1.0 / (s * d) ** 2)
    ev = np.linalg.eigvalsh(H)
    assert res.diagnostics.condition_number == pytest.approx(math.sqrt(ev[-1] / ev[0]), rel=1e-4)


@pytest.mark.parametrize("method", ["adam", "ekf"])
def test_other_methods_reach_the_map_estimate(ex, method):
    prior = Prior(angle_deg=0.05, length_mm=0.2, noise_std=0.5)
    ref = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm", prior=prior)
    hyper = {"steps": 1500} if method == "adam" else {"noise_std": 0.5, "passes": 4}
    res = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, method, prior=prior, **hyper)
    s = np.asarray(res.uncertainty.std)
    assert np.max(np.abs(res.x - ref.x) / s) < 0.05, method


def test_prior_shrinks_toward_nominal_and_no_prior_is_unchanged(ex):
    plain = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm")
    none = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm", prior="none")
    np.testing.assert_array_equal(plain.x, none.x)  # bit for bit
    strong = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm", prior=Prior(0.01, 0.05, noise_std=0.5))
    assert np.linalg.norm(strong.x) < 0.5 * np.linalg.norm(plain.x)
    assert strong.train_metrics.rmse > plain.train_metrics.rmse


def test_huber_matches_scipy_huber(ex):
    """Huber with a fixed scale: the same minimiser as scipy's ``loss="huber", f_scale=c``."""
    c = 0.6
    res = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm", loss="huber", loss_scale=c,
                           rtol=1e-10, atol=1e-10)
    x_ref = _scipy_fit(ex, res.space, lambda x: np.zeros(0), loss="huber", f_scale=c)
    assert np.max(np.abs(res.x - x_ref) / res.uncertainty.std) < 1e-3


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_robust_factor_closed_form(loss):
    c = 2.0
    e = np.array([0.0, 1e-6, 0.5, 1.9, 2.0, 2.1, 10.0, 1e6])
    f = np.asarray(robust_factor(loss, jnp.asarray(e * e), jnp.asarray(c)))
    u = e / c
    rho = np.where(u <= 1, u**2 / 2, u - 0.5) if loss == "huber" else 0.5 * np.log1p(u**2)
    np.testing.assert_allclose((f * e) ** 2, 2 * c**2 * rho, rtol=1e-7, atol=1e-18)
    # smooth at zero: finite derivatives
    g = jax.grad(lambda r: (robust_factor(loss, r * r, jnp.asarray(c)) * r))(0.0)
    assert np.isfinite(g) and g == pytest.approx(1.0)


def _chi_expectation(g, m):
    """E[g(‖z‖)]/m for z ~ N(0, I_m), by trapezoid quadrature over the χ_m density (the
    Euclidean-norm case, independent of the library's Monte Carlo)."""
    r = np.linspace(0.0, math.sqrt(m) + 14.0, 40001)[1:]
    pdf = np.exp((m - 1) * np.log(r) - 0.5 * r * r - (0.5 * m - 1) * math.log(2.0) - math.lgamma(0.5 * m))
    y = g(r) * pdf
    return float(np.sum((y[1:] + y[:-1]) * np.diff(r)) / 2 / m)


def _chi_quadrature(loss, k, m):
    """E[c²·2ρ(‖z‖/c)]/m for z ~ N(0, I_m), c = k."""
    if loss == "huber":
        return _chi_expectation(lambda r: np.where(r <= k, r * r, 2.0 * k * r - k * k), m)
    return _chi_expectation(lambda r: k * k * np.log1p((r / k) ** 2), m)


def test_robust_consistency_against_closed_form_and_quadrature():
    """κ(k) of robust_consistency (Monte Carlo with the model's own sample error): Huber on a
    draw-wire length against its closed form (Φ, φ), tracker positions and Cauchy against
    quadrature over the χ distribution, markers (an RMS over 3 markers: the norm of 9 entries over
    √3) against the χ_9 quadrature at k·√3; a masked entry leaves the χ of the real ones."""
    k = 1.345
    Phi, phi = (lambda t: 0.5 * (1 + math.erf(t / math.sqrt(2)))), (lambda t: math.exp(-t * t / 2) / math.sqrt(2 * math.pi))
    closed = (2 * Phi(k) - 1 - 2 * k * phi(k)) + 4 * k * phi(k) - 2 * k * k * (1 - Phi(k))
    cable = jaxcal.CableLength(np.zeros(3))
    assert robust_consistency(cable, "huber")(k) == pytest.approx(closed, rel=0.01)
    assert closed == pytest.approx(_chi_quadrature("huber", k, 1), rel=1e-9)
    pos = jaxcal.Position()
    for loss, kk in (("huber", 1.345), ("cauchy", 2.385)):
        assert robust_consistency(pos, loss)(kk) == pytest.approx(_chi_quadrature(loss, kk, 3), rel=0.01), loss
    mk = jaxcal.Markers(np.zeros((3, 3)))
    # e = ‖r‖/√3 > c  ⇔  ‖r‖ > c√3, and Σ(f r)² = 3·g(e) = g₉(‖r‖) at threshold k√3
    assert robust_consistency(mk, "huber")(k) == pytest.approx(_chi_quadrature("huber", k * math.sqrt(3), 9), rel=0.01)
    # a masked entry (zero residual) leaves the norm of the real ones: χ with 2 degrees of freedom
    assert robust_consistency(pos, "huber", np.array([[True, False, True]]))(k) == pytest.approx(
        _chi_quadrature("huber", k, 2), rel=0.01)
    assert robust_consistency(pos, "huber")(1e9) == pytest.approx(1.0)
    # β(k) of the capped sum (Proposal 2): E[min(z², k²)] in closed form for m = 1, and
    # E[min(‖z‖², k²)]/m by χ quadrature for positions (a block capped at error k)
    beta = (2 * Phi(k) - 1) - 2 * k * phi(k) + 2 * k * k * (1 - Phi(k))
    assert robust_consistency(cable, "huber").capped(k) == pytest.approx(beta, rel=0.01)
    assert robust_consistency(pos, "huber").capped(k) == pytest.approx(_chi_capped(k, 3), rel=0.01)
    assert robust_consistency(mk, "huber").capped(k) == pytest.approx(_chi_capped(k * math.sqrt(3), 9), rel=0.01)


def _chi_capped(k, m):
    """E[min(‖z‖², k²)]/m for z ~ N(0, I_m)."""
    return _chi_expectation(lambda r: np.minimum(r * r, k * k), m)


def test_noise_estimate_consistent_under_huber():
    """Tracker positions (m = 3), σ = 0.5 mm, the Huber loss at its default scale (1.345 robust σ,
    which a sample's residual norm exceeds in 61 % of clean samples): σ̂ estimates the noise as
    least squares does (it came out 7.4 % low before the consistency factor; sampling sd of σ̂
    here ~1.5 %)."""
    ex = jaxcal.simulate_experiment(jax.random.key(4), n_samples=1000, measurement=jaxcal.Position())
    ls = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm")
    hub = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm", loss="huber")
    assert ls.uncertainty.noise_std == pytest.approx(0.5, rel=0.045)
    assert hub.uncertainty.noise_std == pytest.approx(ls.uncertainty.noise_std, rel=0.02)


def test_noise_estimate_bounded_under_gross_outliers():
    """Gross outliers neither inflate σ̂ nor the posterior σ under a robust loss (bounded-influence
    scale, RobustNoise): 6 of 600 draw-wire rows off by 50–150 mm. Huber's own residual sum grows
    by ~2c|e| per outlier (σ̂ came out 1.25 mm against the clean 0.50 mm before); the capped sum
    by at most k²σ̂². The clean data's least-squares fit is the reference; the prior (default,
    fixed noise σ) keeps the parameter set the same in both fits."""
    ex = jaxcal.simulate_experiment(jax.random.key(5), n_samples=750)
    train = ex.train
    rows = np.array([3, 50, 101, 222, 333, 444])
    bad = np.asarray(train.y, np.float64).copy()
    bad[rows] += np.array([50.0, -80.0, 120.0, -150.0, 70.0, 95.0]).reshape((-1,) + (1,) * (bad.ndim - 1))
    dirty = dataclasses.replace(train, y=jnp.asarray(bad))
    prior = Prior(noise_std=0.5)
    ls = jaxcal.calibrate(ex.robot, ex.measurement, train, "lm", prior=prior)
    hub = jaxcal.calibrate(ex.robot, ex.measurement, dirty, "lm", prior=prior, loss="huber")
    assert set(rows) <= set(hub.diagnostics.outliers_after)
    assert hub.uncertainty.noise_std == pytest.approx(ls.uncertainty.noise_std, rel=0.05)
    # posterior σ: the Huber fit's (6 rows down-weighted, Huber efficiency) within 15 % of the clean fit's
    ratio = hub.uncertainty.std / ls.uncertainty.std
    assert np.all(np.abs(ratio - 1) < 0.15), ratio


def test_prior_parse_and_errors():
    assert Prior.parse("none") is None and Prior.parse("default") == Prior()
    p = Prior.parse("angle_deg=1,length_mm=3,d_1=10")
    assert p.angle_deg == 1 and p.length_mm == 3 and p.overrides == (("d_1", 10.0),)
    assert p.scaled(2).angle_deg == 0.5 and p.scaled(2).overrides == (("d_1", 5.0),)
    with pytest.raises(ValueError, match="unknown parameter name 'wings'"):
        Prior.parse("wings=3")
    with pytest.raises(ValueError, match="angle_deg must be > 0"):
        Prior(angle_deg=0)
    with pytest.raises(ValueError, match="unknown loss"):
        Objective.build(jaxcal.ParameterSpace.for_robot(jaxcal.robots.ur5()), None, 1.0, "l1")


def test_unknown_loss_and_ekf_refuses_robust(ex):
    with pytest.raises(ValueError, match="unknown loss 'l1'"):
        jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm", loss="l1")
    with pytest.raises(ValueError, match="EKF .* no robust loss"):
        jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "ekf", loss="huber")


def test_uncertainty_without_prior_is_cramer_rao(ex):
    """σ̂²(JᵀJ)⁻¹ with σ̂² = RSS/(N − p), computed here with numpy from a finite-difference Jacobian."""
    res = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm")
    pr = Problem(ex.robot, ex.measurement, ex.train.q, ex.train.y, res.space)
    f = lambda x: np.asarray(pr.residual(jnp.asarray(x)))  # noqa: E731
    x = res.x
    h = np.where(np.asarray(res.space.free_units) == "rad", 1e-7, 1e-5)
    J = np.stack([(f(x + h[k] * np.eye(len(x))[k]) - f(x - h[k] * np.eye(len(x))[k])) / (2 * h[k])
                  for k in range(len(x))], axis=1)
    r = f(x)
    s2 = r @ r / (len(r) - len(x))
    C = s2 * np.linalg.inv(J.T @ J)
    np.testing.assert_allclose(res.uncertainty.std, np.sqrt(np.diag(C)), rtol=1e-4)
    assert res.uncertainty.effective_parameters == pytest.approx(len(x))
    # predicted reading std at new poses: sqrt(diag(J C Jᵀ))
    q_new = ex.test.q[:5]
    pr_new = Problem(ex.robot, ex.measurement, q_new, ex.test.y[:5], res.space)
    Jn = np.asarray(pr_new.jacobian(jnp.asarray(x)))
    np.testing.assert_allclose(res.prediction_std(q_new), np.sqrt(np.einsum("np,pk,nk->n", Jn, C, Jn)), rtol=1e-3)


def _correlated_prior(names, units, seed=0):
    """A random correlated covariance (σ 0.05°, 0.2 mm scale) and mean over ``names``."""
    rng = np.random.default_rng(seed)
    s = np.where(np.asarray(units) == "rad", math.radians(0.05), 0.2)
    A = rng.normal(size=(len(names), len(names)))
    R = A @ A.T / len(names) + np.eye(len(names))
    R = R / np.sqrt(np.outer(np.diag(R), np.diag(R)))
    C = np.outer(s, s) * R
    m = 0.5 * s * rng.normal(size=len(names))
    return C, m


def test_lm_with_full_covariance_prior_is_the_map_estimate(ex):
    """A prior with a full covariance (a learned prior): LM = scipy on [r; σ·L⁻¹(x − m)] written out
    here (L the Cholesky factor of the covariance), and the posterior covariance is
    (JᵀJ/σ̂² + C⁻¹)⁻¹ from a finite-difference Jacobian."""
    space = jaxcal.ParameterSpace.for_robot(ex.robot, measurement=ex.measurement, beta=False)
    names, units = list(space.free_names), list(space.free_units)
    C, m = _correlated_prior(names, units)
    prior = Prior(noise_std=0.5, mean=tuple(zip(names, m)), covariance=(tuple(names), tuple(map(tuple, C))))
    res = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm", prior=prior, rtol=1e-10, atol=1e-10)
    assert list(res.space.free_names) == names
    Linv = np.linalg.inv(np.linalg.cholesky(C))
    x_ref = _scipy_fit(ex, res.space, lambda x: 0.5 * Linv @ (x - m))
    assert np.max(np.abs(res.x - x_ref) / res.uncertainty.std) < 1e-3
    pr = Problem(ex.robot, ex.measurement, ex.train.q, ex.train.y, res.space)
    x0, h = np.asarray(res.x, np.float64), 1e-6
    J = central_differences(pr.residual, x0, h)
    cov = np.linalg.inv(J.T @ J / res.uncertainty.noise_std ** 2 + np.linalg.inv(C))
    np.testing.assert_allclose(res.uncertainty.std, np.sqrt(np.diag(cov)), rtol=1e-3)


def test_prior_with_covariance_whitening_files_and_errors(tmp_path):
    """Whitening: WᵀW = C⁻¹ over the parameters with a prior, the free set's marginal for a subset;
    a diagonal covariance is the plain σ prior; save/load round trip; bad covariances are named."""
    robot = jaxcal.robots.hsr_jr680()
    space = jaxcal.ParameterSpace.for_robot(robot)
    names, units = list(space.free_names), list(space.free_units)
    C, m = _correlated_prior(names[:10], units[:10], seed=1)
    prior = Prior(mean=tuple(zip(names[:10], m)), covariance=(tuple(names[:10]), tuple(map(tuple, C))))
    W = prior.whitening(space)
    np.testing.assert_allclose(W[:10, :10].T @ W[:10, :10], np.linalg.inv(C), rtol=1e-9)
    np.testing.assert_allclose(np.diag(W)[10:], 1.0 / Prior().std(space)[10:], rtol=1e-12)
    np.testing.assert_allclose(prior.std(space)[:10], np.sqrt(np.diag(C)), rtol=1e-12)
    np.testing.assert_allclose(prior.mean_vector(space)[:10], m)
    sub = jaxcal.ParameterSpace.from_names(space.layout, names[2:6])
    Ws = prior.whitening(space, free=sub)[2:6, 2:6]
    np.testing.assert_allclose(Ws.T @ Ws, np.linalg.inv(C[2:6, 2:6]), rtol=1e-9)  # the marginal, not C⁻¹'s block
    assert Prior().whitening(space) is None
    np.testing.assert_allclose(prior.scaled(2.0).std(space), prior.std(space) / 2.0, rtol=1e-12)
    diag = Prior(covariance=(tuple(names), tuple(map(tuple, np.diag(Prior().std(space) ** 2)))))
    np.testing.assert_allclose(diag.whitening(space), np.diag(1.0 / Prior().std(space)), rtol=1e-12)
    prior.save(tmp_path / "p.json")
    back = Prior.load(tmp_path / "p.json")
    assert back == prior and Prior.parse(str(tmp_path / "p.json")) == prior
    with pytest.raises(ValueError, match="positive definite"):
        Prior(covariance=(("d_1", "d_2"), ((1.0, 2.0), (2.0, 1.0))))
    with pytest.raises(ValueError, match="symmetric finite"):
        Prior(covariance=(("d_1",), ((1.0, 0.0),)))
    with pytest.raises(ValueError, match="unknown parameter name 'wings'"):
        Prior(covariance=(("wings",), ((1.0,),)))
    (tmp_path / "bad.json").write_text('{"format": "something else"}')
    with pytest.raises(ValueError, match="not a jaxcal prior file"):
        Prior.load(tmp_path / "bad.json")
    with pytest.raises(FileNotFoundError, match="not found"):
        Prior.parse(str(tmp_path / "missing.json"))
