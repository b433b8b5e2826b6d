"""The prior's scale chosen by the evidence (``jaxcal._fit._evidence``, ``prior="evidence"``).

Checked against closed forms and an independent optimiser: a linear-Gaussian model whose data
Jacobian has equal singular values has its type-II maximum-likelihood prior σ and noise σ in
closed form (the data's projections on the Jacobian's columns have variance ``σ² + s²λ``, the
others ``σ²``); with two families and an arbitrary Jacobian, scipy's optimiser on the exact
Gaussian marginal likelihood ``N(y; Jm, σ²I + J S Jᵀ)``. On simulated data the chosen σ are within
a factor 2 of the spread the deviations were drawn with, and a warm ``calibrate`` with the
evidence prior compiles nothing (its rounds change the prior's σ as run-time data).
"""

import collections
import math
import warnings

import jax
import numpy as np
import pytest
from scipy.optimize import minimize

import jaxcal
from jaxcal._fit._evidence import evidence_scales, log_evidence


def _map_gram(J, y, info, noise):
    """A linear MAP solve (prior mean 0, information ``info``, weighed against ``noise``): what the
    evidence takes from a solve — column norms, the column-scaled Gram matrix, RSS, the solution."""
    x = np.linalg.solve(J.T @ J + noise**2 * info, J.T @ y)
    r = J @ x - y
    d = np.linalg.norm(J, axis=0)
    Js = J / np.where(d > 0, d, 1.0)  # as the solve scales them (gram_from_jacobian)
    return Js.T @ Js, d, float(r @ r), x


def test_one_family_equal_singular_values_closed_form():
    rng = np.random.default_rng(1)
    N, p, lam, s_true, sigma = 200, 12, 50.0, 0.7, 0.3
    U, _ = np.linalg.qr(rng.standard_normal((N, N)))
    V, _ = np.linalg.qr(rng.standard_normal((p, p)))
    J = (U[:, :p] * math.sqrt(lam)) @ V.T
    y = J @ (s_true * rng.standard_normal(p)) + sigma * rng.standard_normal(N)
    z = U.T @ y
    a, b = np.mean(z[:p] ** 2), np.mean(z[p:] ** 2)  # σ² + s²λ and σ²: the closed form
    s_ml, sigma_ml = math.sqrt((a - b) / lam), math.sqrt(b)
    base = 2.0  # the requested prior's σ; the solve used it with a wrong noise σ (1.0)
    A, d, rss, x = _map_gram(J, y, np.eye(p) / base**2, 1.0)
    ev, s = evidence_scales(A, d, rss, N, x, np.eye(p) / base**2, ["lengths"] * p, noise_used=1.0)
    assert ev.factors[0] * base == pytest.approx(s_ml, rel=1e-6)
    assert s == pytest.approx(sigma_ml, rel=1e-6)
    # γ = Σ λ_i/(λ_i + α) with the whitened eigenvalues λ/σ² and α = 1/s²
    assert ev.effective[0] == pytest.approx(p * (lam / b) / (lam / b + 1 / s_ml**2), rel=1e-6)

    # the uncertainty of ln s: the curvature of the closed-form log likelihood in (ln s, ln σ²)
    def ll(th):
        s2, v = math.exp(2 * th[0]), math.exp(th[1])
        return (-0.5 * np.sum(np.log(v + s2 * lam) + z[:p] ** 2 / (v + s2 * lam))
                - 0.5 * np.sum(np.log(v) + z[p:] ** 2 / v))

    th, h = np.array([math.log(s_ml), math.log(b)]), 1e-4
    H = np.array([[(ll(th + (ei + ej) * h) - ll(th + (ei - ej) * h) - ll(th - (ei - ej) * h) + ll(th - (ei + ej) * h))
                   / (4 * h * h) for ej in np.eye(2)] for ei in np.eye(2)])
    assert ev.log_std[0] == pytest.approx(math.sqrt(np.linalg.inv(-H)[0, 0]), rel=1e-3)


def test_two_families_and_a_flat_parameter_against_scipy():
    """Angles (rad) and lengths (mm) with their own spread, one parameter without a prior (a sensor
    extra): the factors and σ maximise the exact marginal likelihood (scipy, the flat parameter
    given a 10⁴ times wider prior)."""
    rng = np.random.default_rng(3)
    N, n_ang, n_len = 60, 5, 6
    p = n_ang + n_len + 1
    J = rng.standard_normal((N, p)) * np.r_[np.full(n_ang, 300.0), np.full(n_len, 1.0), 1.0]  # mm/rad, mm/mm
    s_ang, s_len, sigma = math.radians(0.2), 0.8, 0.1
    x_true = np.r_[s_ang * rng.standard_normal(n_ang), s_len * rng.standard_normal(n_len), 5.0]
    y = J @ x_true + sigma * rng.standard_normal(N)
    base = np.r_[np.full(n_ang, math.radians(0.5)), np.full(n_len, 2.0)]
    info = np.diag(np.r_[1 / base**2, 0.0])
    family = ["angles"] * n_ang + ["lengths"] * n_len + [""]
    A, d, rss, x = _map_gram(J, y, info, 0.3)
    ev, s = evidence_scales(A, d, rss, N, x, info, family, noise_used=0.3)

    def neg(th):  # the exact Gaussian marginal likelihood in (ln k_angles, ln k_lengths, ln σ)
        k = np.exp(th[:2])
        S = np.diag(np.r_[(base[:n_ang] * k[0]) ** 2, (base[n_ang:] * k[1]) ** 2, 1e8])
        Cy = np.exp(2 * th[2]) * np.eye(N) + J @ S @ J.T
        _, logdet = np.linalg.slogdet(Cy)
        return 0.5 * (logdet + y @ np.linalg.solve(Cy, y))

    start = np.array([0.0, 0.0, math.log(0.3)])
    ref = minimize(neg, start, method="Nelder-Mead", options={
        "xatol": 1e-7, "fatol": 1e-10, "maxiter": 2000, "initial_simplex": np.vstack([start, start + 0.5 * np.eye(3)])})
    assert ev.families == ("angles", "lengths")
    np.testing.assert_allclose(ev.factors, np.exp(ref.x[:2]), rtol=5e-3)
    assert s == pytest.approx(math.exp(ref.x[2]), rel=5e-3)
    # the log evidence of the linearised model differs from the exact one by a constant only
    at = [log_evidence(A, d, rss, N, x, info, family, np.exp(t[:2]), math.exp(t[2]), noise_used=0.3) + neg(t)
          for t in (ref.x, ref.x + [0.3, -0.2, 0.1])]
    assert at[0] == pytest.approx(at[1], abs=1e-3)


@pytest.fixture(scope="module")
def fits():
    """Position data of the HSR-JR680 (150 poses, σ = 0.05 mm) with deviations drawn at two
    sizes, each calibrated with the evidence prior; a compile counter around a third, warm call."""
    out = {}
    for seed, (ang, ln) in enumerate(((0.05, 0.2), (1.0, 5.0))):
        ex = jaxcal.simulate_experiment(jax.random.key(seed), None, n_samples=150, noise_std=0.05,
                                        measurement=jaxcal.Position(), angle_std_deg=ang, length_std_mm=ln,
                                        coverage=0.5)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out[ang, ln] = ex, jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm", prior="evidence",
                                                loss="huber")
    return out


@pytest.mark.parametrize("size", [(0.05, 0.2), (1.0, 5.0)])
def test_scale_recovered_on_simulated_data(fits, size):
    """The chosen σ within a factor 2 of the σ the deviations were drawn with, and of their spread
    over the parameters the data determine."""
    ex, res = fits[size]
    ev = res.prior.evidence
    chosen = dict(zip(ev.families, ev.std))
    assert set(chosen) == {"angles", "lengths"} and ev.rounds >= 2
    true = ex.true_deviations.named()
    det = set(res.identifiability.verdicts.determined)
    for fam, drawn, unit in (("angles", size[0], "rad"), ("lengths", size[1], "mm")):
        assert 0.5 < chosen[fam] / drawn < 2.0, (fam, chosen, size)
        vals = [true[n] for n, u in zip(res.space.free_names, res.space.free_units) if u == unit and n in det]
        spread = math.sqrt(np.mean(np.square(vals))) * (180 / math.pi if unit == "rad" else 1.0)
        assert 0.5 < chosen[fam] / spread < 2.0, (fam, chosen, spread)
    assert res.prior.angle_deg == pytest.approx(chosen["angles"]) and res.prior.length_mm == pytest.approx(
        chosen["lengths"])


def test_warm_call_compiles_nothing(fits):
    """The rounds of the evidence prior (≥ 2 solves under different prior σ) run one compiled
    program: a warm call on new data of the same shapes compiles nothing."""
    ex = jaxcal.simulate_experiment(jax.random.key(7), None, n_samples=150, noise_std=0.05,
                                    measurement=jaxcal.Position(), angle_std_deg=0.3, length_std_mm=1.0, coverage=0.5)
    events = collections.Counter()

    def listener(event, duration, **kw):
        if event == "/jax/core/compile/backend_compile_duration":
            events["n"] += 1

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm", prior="evidence", loss="huber")
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert res.prior.evidence.rounds >= 2
    assert events["n"] == 0, f"{events['n']} programs compiled by a warm calibrate(prior='evidence')"


def test_evidence_spec_parses_and_a_sweep_refuses_it():
    """'evidence' is the default prior to be scaled; 'evidence:SPEC' any other; a sweep (one fixed
    prior for every trial) refuses it with a message naming what to give instead."""
    p = jaxcal.Prior.parse("evidence")
    assert p.scale_by == "evidence" and (p.angle_deg, p.length_mm) == (0.5, 2.0)
    q = jaxcal.Prior.parse("evidence:angle_deg=1,d_1=10")
    assert q.scale_by == "evidence" and q.angle_deg == 1.0 and q.overrides == (("d_1", 10.0),)
    with pytest.raises(ValueError, match="'none' has none"):
        jaxcal.Prior.parse("evidence:none")
    with pytest.raises(ValueError, match="give the sweep a fixed prior"):
        jaxcal.sweep(["lm"], 2, n_samples=50, prior="evidence")


def test_a_family_the_data_do_not_see_keeps_its_scale():
    """Lengths the data do not see (zero Jacobian columns): the evidence is flat in their scale,
    which stays as requested with an infinite uncertainty; the angles' scale is still chosen."""
    rng = np.random.default_rng(5)
    N, n = 80, 4
    J = np.concatenate([300.0 * rng.standard_normal((N, n)), np.zeros((N, n))], axis=1)
    y = J[:, :n] @ (math.radians(0.2) * rng.standard_normal(n)) + 0.1 * rng.standard_normal(N)
    base = np.r_[np.full(n, math.radians(0.5)), np.full(n, 2.0)]
    info = np.diag(1 / base**2)
    A, d, rss, x = _map_gram(J, y, info, 0.1)
    ev, _ = evidence_scales(A, d, rss, N, x, info, ["angles"] * n + ["lengths"] * n, noise_used=0.1)
    assert ev.factors[1] == 1.0 and math.isinf(ev.log_std[1]) and ev.effective[1] == pytest.approx(0.0, abs=1e-9)
    assert 0.1 < ev.factors[0] < 1.0 and math.isfinite(ev.log_std[0])
