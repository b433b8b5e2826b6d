"""The solver layer: calibrate(), the statistical floor, Cramér–Rao recovery, vmap, errors."""

import json
import os
import threading
import time
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import optimistix as optx
import pytest

import jaxcal
from jaxcal import (
    CalibrationError,
    CalibrationWarning,
    Calibrator,
    Deviations,
    Problem,
    Status,
    calibrate,
    iterations_to_converge,
    simulate_experiment,
    statistical_floor,
)
from jaxcal.methods import LevenbergMarquardt, ScaledProblem, make_method
from jaxcal.methods._least_squares import residual_with_jacfwd

GRADIENT_METHODS = ["adam", "adamw", "adamod", "adamodw"]


def assert_lm_at_floor_and_cramer_rao(ex, n_test_extra=20000, seed=11):
    """LM on ex.train; test RMSE on a large fresh test set vs the statistical floor, and the
    estimate vs the noiseless fit within 3 Cramér–Rao standard deviations."""
    res = calibrate(ex.robot, ex.measurement, ex.train, "lm")
    assert res.status == Status.CONVERGED, res.message
    space = res.space
    # a large fresh test set from the same true robot: the RMSE estimate is then within ~0.5 %
    big = simulate_experiment(jax.random.PRNGKey(seed), ex.robot, n_samples=n_test_extra, test_fraction=0.5,
                              measurement=ex.measurement, true_deviations=ex.true_deviations,
                              noise_std=float(ex.noise_std))
    test_rmse = res.evaluate(big.test).rmse
    floor = statistical_floor(float(ex.noise_std), space.n_free, ex.train.n).test
    assert abs(test_rmse / floor - 1) < 0.02, (test_rmse, floor)
    # the truth restricted to the identifiable subset: LM on noiseless data at the same poses.
    # The left-out parameters are absorbed to first order only (e.g. a5 acts like −θ5/L, L ≈ 200 mm), leaving a
    # ~1e-3 mm remainder, negligible against σ.
    # compiled, not op by op (each eager operation is a program of its own)
    y_clean = eqx.filter_jit(lambda m, r, d, q: m.predict(r, d, q))(ex.measurement, ex.robot, ex.true_deviations,
                                                                     ex.train.q)
    ref = calibrate(ex.robot, ex.measurement, (ex.train.q, y_clean), "lm", space=space)
    assert ref.train_metrics.rmse < 0.01 * float(ex.noise_std), "identifiable subset must represent the true robot"
    J = np.asarray(eqx.filter_jit(lambda p, x: p.jacobian(x))(
        Problem(ex.robot, ex.measurement, ex.train.q, ex.train.y, space), jnp.asarray(ref.x)))
    cov = float(ex.noise_std) ** 2 * np.linalg.inv(J.T @ J)
    err = res.x - ref.x
    z = err / np.sqrt(np.diag(cov))
    assert np.all(np.abs(z) < 3.0), dict(zip(space.free_names, np.round(z, 2)))
    maha = float(err @ np.linalg.solve(cov, err))
    assert maha < 45.3  # chi-square(19) 99.9 % quantile is 43.8; (p varies by robot)
    return test_rmse, floor


def test_lm_reaches_floor_and_cramer_rao(experiment):
    assert_lm_at_floor_and_cramer_rao(experiment)


@pytest.mark.slow  # ~1 min each on 2 cores (compilation); run with -m slow
@pytest.mark.parametrize("name", ["puma560", "ur5", "abb_irb120"])
def test_lm_floor_other_robots(name):
    robot = jaxcal.robots.get_robot(name)
    ex = simulate_experiment(jax.random.PRNGKey(2), robot)
    assert_lm_at_floor_and_cramer_rao(ex)


def test_gauss_newton_matches_lm(experiment):
    ex = experiment
    lm = calibrate(ex.robot, ex.measurement, ex.train, "lm")
    gn = calibrate(ex.robot, ex.measurement, ex.train, "gn")
    np.testing.assert_allclose(gn.x, lm.x, rtol=0, atol=1e-6 * np.abs(lm.x).max())


def test_lm_cholesky_step_equals_qr_step(experiment):
    ex = experiment
    space = jaxcal.identifiability(ex.robot, ex.measurement, ex.train.q).space
    sp = ScaledProblem.build(Problem(ex.robot, ex.measurement, ex.train.q, ex.train.y, space))
    fn = lambda z, args: (sp.residual(z), None)  # noqa: E731
    z = jnp.zeros(space.n_free)
    f_struct = jax.ShapeDtypeStruct((sp.problem.n_residuals,), jnp.float64)
    ys = {}
    for ls in ("cholesky", "qr"):
        solver = LevenbergMarquardt(linear_solver=ls).solver()

        @jax.jit
        def three_steps(z):
            st = solver.init(fn, z, None, {}, f_struct, None, frozenset())
            y = z
            for _ in range(3):  # first step only evaluates; later ones solve the damped system
                y, st, _ = solver.step(fn, y, None, {}, st, frozenset())
            return y

        ys[ls] = np.asarray(three_steps(z))
    assert np.abs(ys["qr"]).max() > 0.1  # the steps moved
    np.testing.assert_allclose(ys["cholesky"], ys["qr"], rtol=1e-9, atol=1e-9)


def test_residual_with_jacfwd_has_the_exact_derivatives(experiment):
    """The custom-JVP residual handed to optimistix (Jacobian materialised by jacfwd in its JVP
    rule) has the values, JVPs, Jacobians and (through transposition) VJPs of the plain one, also
    under vmap over problems."""
    ex = experiment
    sp = ScaledProblem.build(Problem(ex.robot, ex.measurement, ex.train.q[:300], ex.train.y[:300]))
    f = residual_with_jacfwd(sp)
    z = 0.01 * jax.random.normal(jax.random.key(0), (sp.n_free,))
    t = jax.random.normal(jax.random.key(1), (sp.n_free,))
    np.testing.assert_array_equal(f(z), sp.residual(z))
    # the derivative checks compiled (one program each, the problem an argument), not op by op:
    # evaluated eagerly, every operation of the transformed residuals was a program of its own
    jvps = eqx.filter_jit(lambda sp, z, t: (jax.jvp(residual_with_jacfwd(sp), (z,), (t,)),
                                            jax.jvp(sp.residual, (z,), (t,))))
    (r1, d1), (r2, d2) = jvps(sp, z, t)
    # the JVP rule evaluates the residual inside a shared_joint_trig block: cos(q + θ) by angle
    # addition, equal to the direct form to round-off
    np.testing.assert_allclose(r1, r2, rtol=1e-13, atol=1e-10)
    np.testing.assert_allclose(d1, d2, rtol=1e-10, atol=1e-10)
    jac_f, jac = eqx.filter_jit(lambda sp, z: (jax.jacfwd(residual_with_jacfwd(sp))(z), sp.jacobian(z)))(sp, z)
    np.testing.assert_allclose(jac_f, jac, rtol=1e-10, atol=1e-10)
    w = jax.random.normal(jax.random.key(2), r1.shape)
    vjp_f, vjp = eqx.filter_jit(lambda sp, z, w: (jax.vjp(residual_with_jacfwd(sp), z)[1](w)[0],
                                                  jax.vjp(sp.residual, z)[1](w)[0]))(sp, z, w)
    np.testing.assert_allclose(vjp_f, vjp, rtol=1e-9, atol=1e-9)
    two = jax.tree.map(lambda a: jnp.stack([a, a]), sp)
    batched = eqx.filter_jit(jax.vmap(lambda p, z, t: jax.jvp(residual_with_jacfwd(p), (z,), (t,))[1],
                                      in_axes=(0, 0, None)))(two, jnp.stack([z, 2 * z]), t)
    np.testing.assert_allclose(batched[1], jvps(sp, 2 * z, t)[1][1], rtol=1e-10, atol=1e-10)


def test_lm_started_at_its_optimum_stops_at_once(experiment):
    """From (round-off away from) the optimum every LM proposal is a round-off-level change: the
    round-off-aware trust region accepts it and the solve terminates in ≤ 3 steps (the plain
    ratio test rejected at random and took up to 15 steps on these starts)."""
    ex = experiment
    space = jaxcal.identifiability(ex.robot, ex.measurement, ex.train.q).space
    prob = Problem(ex.robot, ex.measurement, ex.train.q, ex.train.y, space)
    lm = make_method("lm")
    run = jax.jit(lambda sp: lm.run(sp, None))
    sp = ScaledProblem.build(prob)
    first = run(sp)
    x = sp.x(first.z)
    best = float(first.history[first.n_iterations])
    for s in range(6):
        again = run(ScaledProblem.build(prob, x_start=x + 1e-9 * s))
        assert int(again.status) == int(Status.CONVERGED)
        assert int(again.n_iterations) <= 3, (s, int(again.n_iterations))
        assert abs(float(again.history[again.n_iterations]) - best) < 1e-12


def test_start_jacobian_from_identifiability_gives_the_same_fit(experiment):
    """calibrate() hands the identifiability program's Jacobian (cable data: it does not depend
    on the readings) to an unmasked solve (GN here) as its start Jacobian: the fit equals the one
    whose program computes its own to round-off, and a Jacobian of the wrong shape is refused."""
    ex = experiment
    res = calibrate(ex.robot, ex.measurement, ex.train, "gn")
    q, y = jnp.asarray(ex.train.q), jnp.asarray(ex.train.y)
    cal = Calibrator(ex.robot, ex.measurement, make_method("gn"), res.start, res.space)
    own = jax.jit(lambda q, y: cal(q, y, None))(q, y)
    np.testing.assert_allclose(res.x, own.x, rtol=0, atol=1e-10)
    assert res.n_iterations == int(own.n_iterations)
    prob = Problem(ex.robot, ex.measurement, q, y, res.space)
    J = prob.jacobian(prob.x0())
    sp = ScaledProblem.build(prob, jacobian=J)
    np.testing.assert_array_equal(sp.scale, ScaledProblem.build(prob).scale)
    with pytest.raises(ValueError, match="start Jacobian has shape"):
        ScaledProblem.build(prob, jacobian=J[:, :-1])
    assert ex.measurement.jacobian_free_of_data and jaxcal.Position().jacobian_free_of_data
    assert not jaxcal.Pose().jacobian_free_of_data


def assert_same_fit(got, ref, *, x=1e-9, rmse=1e-10, noise=1e-9, std=1e-7):
    """Two calibrations are the same fit to round-off: free set, parameters (``x``: tolerance
    relative to the largest), iterations, status, training RMSE, σ̂ and posterior σ (relative)."""
    assert got.space.free_names == ref.space.free_names
    np.testing.assert_allclose(got.x, ref.x, rtol=0, atol=x * max(1.0, np.abs(ref.x).max()))
    assert got.n_iterations == ref.n_iterations and got.status == ref.status
    np.testing.assert_allclose(got.train_metrics.rmse, ref.train_metrics.rmse, rtol=rmse)
    np.testing.assert_allclose(got.uncertainty.noise_std, ref.uncertainty.noise_std, rtol=noise)
    np.testing.assert_allclose(got.uncertainty.std, ref.uncertainty.std, rtol=std)


def _drive(steps):
    """Run the solves a ``_calibration_steps`` generator asks for, one by one (as ``calibrate``)."""
    from jaxcal._calibration import _programs

    launched = None
    while True:
        try:
            cal, q, y, k = steps.send(launched)
        except StopIteration as done:
            return done.value
        launched = _programs._Launched(*_programs._launch(cal, q, y, k))


def test_masked_solve_takes_the_start_jacobian_at_run_time(experiment):
    """calibrate()'s masked LM solve carries a start Jacobian with a run-time flag: the
    identifiability program's (cable data: free of the readings) where the free set was just
    selected, zeros standing in where it is not (a given space) — one compiled program for both,
    and each fit equals the one whose solve computes its own start Jacobian (the generator without
    the shared Jacobian) to round-off: parameters, iterations, RMSE, σ̂ and posterior σ."""
    from jaxcal._calibration import _calibrate as cal_mod
    from jaxcal._calibration import _programs
    from jaxcal._calibration._selection import candidate_space
    from jaxcal._fit._identifiability import identify_with_residuals, start_jacobian

    ex = experiment
    res = calibrate(ex.robot, ex.measurement, ex.train, "lm")  # selected here: the Jacobian is given
    before = set(_programs._COMPILED._d)
    given = calibrate(ex.robot, ex.measurement, ex.train, "lm", space=res.space)  # not selected: zeros
    assert set(_programs._COMPILED._d) == before, "the given and the computed start Jacobian share one program"
    own = _drive(cal_mod._calibration_steps(ex.robot, ex.measurement, ex.train, "lm"))
    for r in (res, given):
        assert_same_fit(r, own, x=1e-10, rmse=1e-12, noise=1e-10, std=1e-8)
    # the program behind start_jacobian (a re-selection refit's start) is the identifiability's
    cand = candidate_space(ex.robot, ex.measurement, ())
    _, resid, J = identify_with_residuals(ex.robot, ex.measurement, ex.train.q, cand, res.start, ex.train.y)
    resid2, J2 = start_jacobian(ex.robot, ex.measurement, ex.train.q, cand, res.start, ex.train.y)
    np.testing.assert_array_equal(resid, resid2)
    np.testing.assert_array_equal(np.asarray(J), np.asarray(J2))
    with pytest.raises(ValueError, match="depends on the readings"):
        start_jacobian(ex.robot, jaxcal.Pose(), ex.train.q, cand, res.start, ex.train.y)
    # ScaledProblem refuses a flag without a Jacobian or outside a method that scales itself
    prob = Problem(ex.robot, ex.measurement, jnp.asarray(ex.train.q), jnp.asarray(ex.train.y), res.space)
    with pytest.raises(ValueError, match="jacobian_given needs"):
        ScaledProblem.build(prob, jacobian_given=jnp.asarray(True), defer_scale=True)
    with pytest.raises(ValueError, match="jacobian_given needs"):
        ScaledProblem.build(prob, jacobian=prob.jacobian(prob.x0()), jacobian_given=jnp.asarray(True))


@pytest.mark.slow
def test_lm_qr_whole_solve_agrees(experiment):
    ex = experiment
    a = calibrate(ex.robot, ex.measurement, ex.train, "lm", linear_solver="qr")
    b = calibrate(ex.robot, ex.measurement, ex.train, "lm")
    np.testing.assert_allclose(a.train_metrics.rmse, b.train_metrics.rmse, rtol=1e-9)


def test_free_set_is_data(experiment, monkeypatch):
    """LM runs with the free set as a run-time mask over one program space: fits with different
    free sets (identifiable subset, MAP over all candidates with a Huber loss, fix=, extras)
    share one compiled solve, and each equals the solve compiled for its free set alone
    (``JAXCAL_FREE_MASK=off``) to round-off: parameters, iterations, RMSE, σ̂ and posterior σ."""
    from jaxcal._calibration import _programs

    ex = experiment
    # the whole training set, as the other tests of this module calibrate: its identifiability and
    # plain-LM programs are compiled once for the module (a 300-sample subset compiled its own)
    data = ex.train
    settings = [dict(), dict(fix="d_4,a_2"), dict(objective="measured"), dict(objective="measured", fix="theta")]
    before = set(_programs._COMPILED._d)
    masked = [calibrate(ex.robot, ex.measurement, data, "lm", **kw) for kw in settings]
    new = [k for k in _programs._COMPILED._d if k not in before]
    assert len(new) <= 2, len(new)  # one program per objective kind (plain; prior + Huber), not per free set
    assert masked[0].space.n_free != masked[1].space.n_free != masked[2].space.n_free
    monkeypatch.setenv("JAXCAL_FREE_MASK", "off")
    for kw, m in zip(settings, masked):
        assert_same_fit(m, calibrate(ex.robot, ex.measurement, data, "lm", **kw))
    # only maskable methods take a mask
    with pytest.raises(ValueError, match="cannot run with a free-parameter mask"):
        Calibrator(ex.robot, ex.measurement, make_method("gn"), masked[0].start, masked[0].space,
                   free=jnp.ones(masked[0].space.n_free))


def test_first_solve_compiles_ahead_once(experiment, monkeypatch):
    """calibrate() starts compiling its first solve on a background thread before the closed-form
    extras and the identifiability (the program is known before the free set: a run-time mask):
    the solve it then runs is that program — one new compiled solve, none left pending — and the
    fit is the one compiled the usual way."""
    from jaxcal._calibration import _calibrate as cal_mod
    from jaxcal._calibration import _programs

    ex = experiment
    built = []  # the thread each solve program is built in
    build = _programs._build_solve

    def slow_build(*a):  # a build of at least 0.3 s, finished before the solve is launched (below)
        built.append(threading.current_thread().name)
        time.sleep(0.3)
        return build(*a)

    launch = cal_mod._launch

    def late_launch(*a):
        time.sleep(0.6)
        return launch(*a)

    monkeypatch.setattr(_programs, "_build_solve", slow_build)
    monkeypatch.setattr(cal_mod, "_launch", late_launch)
    before = set(_programs._COMPILED._d)
    res = calibrate(ex.robot, ex.measurement, ex.train, "lm", loss="cauchy")  # an objective kind of its own
    assert len(set(_programs._COMPILED._d) - before) == 1 and not _programs._AHEAD
    ahead = (os.cpu_count() or 1) >= 2 and os.environ.get("JAXCAL_COMPILE_AHEAD", "on") != "off"
    assert len(built) == 1 and built[0].startswith("jaxcal-compile") == ahead, built
    # the compile time reported is the build's, also where the call waited for none of it
    assert res.compile_time_s >= 0.3, res.compile_time_s
    monkeypatch.setenv("JAXCAL_COMPILE_AHEAD", "off")
    monkeypatch.setenv("JAXCAL_FREE_MASK", "off")  # a program of its own, compiled in this thread
    ref = calibrate(ex.robot, ex.measurement, ex.train, "lm", loss="cauchy")
    # equal far inside the solver's own tolerance: the second round starts with the trust region the
    # first ended with, near Gauss–Newton, where the two programs' round-off (24 masked vs 19 columns)
    # leaves ~3e-9 relative; both fits are ~3e-7 from the optimum converged to rtol = atol = 1e-12
    np.testing.assert_allclose(res.x, ref.x, rtol=0, atol=1e-8 * max(1.0, np.abs(ref.x).max()))
    assert res.n_iterations == ref.n_iterations


@pytest.mark.parametrize("name", GRADIENT_METHODS)
def test_gradient_methods_noiseless(name):
    ex = simulate_experiment(jax.random.PRNGKey(5), n_samples=400, noise_std=0.0)
    res = calibrate(ex.robot, ex.measurement, ex.train, name, steps=3000)
    assert res.status == Status.COMPLETED
    assert res.train_metrics.rmse < 0.01 * res.history[0], (res.train_metrics.rmse, res.history[0])
    assert np.all(np.isfinite(res.history))


def test_vmap_over_keys_and_data_equals_sequential():
    keys = jax.random.split(jax.random.PRNGKey(3), 3)
    # the experiment fixture's sample count: identifiability() below then runs the program that
    # test_lm_cholesky_step_equals_qr_step compiled for that shape
    exs = jax.vmap(lambda k: simulate_experiment(k))(keys)
    robot, meas = jaxcal.robots.hsr_jr680(), exs.measurement
    meas = jaxcal.CableLength(exs.measurement.anchor[0])
    space = jaxcal.identifiability(robot, meas, exs.train.q[0]).space
    for method in (make_method("lm"), make_method("adamodw", steps=50, batch_size=64)):
        cal = Calibrator(robot, meas, method, Deviations.zeros(6), space)
        run = lambda q, y, k: cal(q, y, k)  # noqa: E731
        batched = jax.jit(jax.vmap(run))(exs.train.q, exs.train.y, keys)
        for i in range(3):
            one = jax.jit(run)(exs.train.q[i], exs.train.y[i], keys[i])
            if method.name == "lm":
                # batched and unbatched linear algebra round differently, and LM's accept/reject
                # decisions at round-off level amplify that up to the solver tolerance (1e-5 on
                # the scaled parameters): equal to well within it, and the same fit
                np.testing.assert_allclose(np.asarray(batched.x[i]), np.asarray(one.x), rtol=1e-5, atol=1e-9)
                np.testing.assert_allclose(float(batched.train_metrics.rmse[i]), float(one.train_metrics.rmse),
                                           rtol=1e-9)
            else:
                np.testing.assert_allclose(np.asarray(batched.x[i]), np.asarray(one.x), rtol=1e-10, atol=1e-12)
                np.testing.assert_allclose(np.asarray(batched.history[i]), np.asarray(one.history), rtol=1e-10)
                assert int(batched.n_iterations[i]) == int(one.n_iterations)


def test_minibatch_reproducible_from_key(experiment):
    ex = experiment
    a = calibrate(ex.robot, ex.measurement, ex.train, "adam", steps=100, batch_size=128, key=jax.random.key(1))
    b = calibrate(ex.robot, ex.measurement, ex.train, "adam", steps=100, batch_size=128, key=jax.random.key(1))
    c = calibrate(ex.robot, ex.measurement, ex.train, "adam", steps=100, batch_size=128, key=jax.random.key(2))
    np.testing.assert_array_equal(a.x, b.x)
    assert not np.array_equal(a.x, c.x)
    assert a.train_metrics.rmse < 0.5 * a.history[0]


def test_user_optax_chain(experiment):
    ex = experiment
    tx = optax.chain(optax.clip_by_global_norm(1.0), jaxcal.optim.adamodw(0.1, b3=0.9, weight_decay=1e-4))
    res = calibrate(ex.robot, ex.measurement, ex.train, tx, steps=300)
    assert res.method == "optax" and res.status == Status.COMPLETED
    assert res.train_metrics.rmse < 0.2 * res.history[0]


def test_divergence_is_reported_never_silent(experiment):
    ex = experiment
    tx = optax.sgd(1e6)
    with pytest.warns(CalibrationWarning, match="diverged"):
        res = calibrate(ex.robot, ex.measurement, ex.train, tx, steps=50)
    assert res.status == Status.DIVERGED and np.all(np.isfinite(res.x))
    assert res.n_iterations < 50
    with pytest.raises(CalibrationError, match="diverged"):
        calibrate(ex.robot, ex.measurement, ex.train, tx, steps=50, throw=True)


def test_iterations_to_converge_definition():
    h = jnp.asarray([10.0, 5.0, 1.02, 1.5, 1.009, 1.0, 1.0, 1.0])
    assert int(iterations_to_converge(h, 5)) == 4  # 1.5 at index 3 breaks the earlier run
    assert int(iterations_to_converge(h, 2)) == 2
    assert int(iterations_to_converge(jnp.asarray([3.0, 1.0, 1.0]), 2)) == 1
    assert int(iterations_to_converge(jnp.asarray([3.0, 3.0]), 0)) == 0


def test_result_api(experiment, tmp_path):
    ex = experiment
    res = calibrate(ex.robot, ex.measurement, ex.train, "lm")
    assert res.identifiability.rank == 19 and res.space.n_free == 19
    m = res.evaluate(ex.test)
    assert 0 < m.mean <= m.rmse <= m.max
    tab = res.dh_table()
    diff = tab - ex.robot.dh_table_deg()
    diff[:, [0, 3]] = (diff[:, [0, 3]] + 180.0) % 360.0 - 180.0  # angles are wrapped to (-180°, 180°]
    assert tab.shape == (6, 4) and np.abs(diff).max() < 5 and np.all(np.abs(tab[:, [0, 3]]) <= 180.0)
    d = res.to_dict()
    json.dumps(d)
    assert d["status"] == "converged" and len(d["free_parameters"]) == 19
    assert res.wall_time_s > 0 and res.compile_time_s > 0
    assert "lm" in repr(res)


@pytest.mark.slow
def test_all_parameters_rank_deficient_stays_finite(experiment):
    ex = experiment
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        full = calibrate(ex.robot, ex.measurement, ex.train, "lm", space="all", max_steps=30)
    assert np.all(np.isfinite(full.x)) and full.space.n_free == 24


def test_float32_runs_and_warns(experiment):
    ex = experiment
    q32, y32 = ex.train.q.astype(jnp.float32), ex.train.y.astype(jnp.float32)
    with pytest.warns(jaxcal.PrecisionWarning):
        res = calibrate(ex.robot, ex.measurement, (q32, y32), "lm")
    assert res.x.dtype == np.float32
    ref = calibrate(ex.robot, ex.measurement, ex.train, "lm")
    assert abs(res.train_metrics.rmse / ref.train_metrics.rmse - 1) < 0.01
    # float32: the same identifiable subset (dtype-aware rank threshold) and LM/GN stop at their
    # (float32-raised) tolerance instead of a solver failure or the step budget
    assert res.space.free_names == ref.space.free_names and res.status == Status.CONVERGED
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", jaxcal.PrecisionWarning)  # warned once per process
        gn = calibrate(ex.robot, ex.measurement, (q32, y32), "gn")
    assert gn.status == Status.CONVERGED and abs(gn.train_metrics.rmse / ref.train_metrics.rmse - 1) < 0.01


def test_bad_input(experiment):
    ex = experiment
    r, m = ex.robot, ex.measurement
    with pytest.raises(ValueError, match="unknown method 'newton'; available: .*adamodw.*lm"):
        calibrate(r, m, ex.train, "newton")
    with pytest.raises(TypeError, match=r"unknown setting\(s\) \['learning_rate'\] for method 'lm'; its settings: atol"):
        calibrate(r, m, ex.train, "lm", learning_rate=0.1)
    with pytest.raises(TypeError, match="unknown setting"):
        calibrate(r, m, ex.train, "adam", max_steps=3)
    with pytest.raises(ValueError, match="'cable' measurements but the measurement model is 'position'"):
        calibrate(r, jaxcal.Position(), ex.train)
    with pytest.raises(ValueError, match="too few samples: 10 sample"):
        calibrate(r, m, ex.train.subset(slice(0, 10)), space="all")
    with pytest.raises(ValueError, match="NaN/inf"):
        calibrate(r, m, (ex.train.q, ex.train.y.at[3].set(jnp.nan)))
    with pytest.raises(ValueError, match="look like degrees"):
        calibrate(r, m, (jnp.rad2deg(ex.train.q), ex.train.y))
    with pytest.raises(ValueError, match="robot 'hsr_jr680' has 6 joints"):
        calibrate(r, m, (ex.train.q[:, :5], ex.train.y))
    with pytest.raises(ValueError, match="steps must be >= 1"):
        calibrate(r, m, ex.train, "adam", steps=0)
    with pytest.raises(ValueError, match="linear_solver must be"):
        calibrate(r, m, ex.train, "lm", linear_solver="svd")
    with pytest.warns(UserWarning, match="outside robot 'hsr_jr680'"):
        calibrate(r, m, (ex.train.q.at[0, 1].set(3.0), ex.train.y))


def test_optimistix_least_squares_agrees(experiment):
    """Our step-by-step loop matches optimistix.least_squares on the same scaled problem."""
    ex = experiment
    space = jaxcal.identifiability(ex.robot, ex.measurement, ex.train.q).space
    sp = ScaledProblem.build(Problem(ex.robot, ex.measurement, ex.train.q, ex.train.y, space))
    solver = LevenbergMarquardt().solver()
    sol = optx.least_squares(lambda z, a: sp.residual(z), solver, jnp.zeros(space.n_free), max_steps=100)
    ours = LevenbergMarquardt().run(sp, None)
    np.testing.assert_allclose(np.asarray(ours.z), np.asarray(sol.value), rtol=1e-12, atol=1e-12)
    assert int(ours.n_iterations) == int(sol.stats["num_steps"])
