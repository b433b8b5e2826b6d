"""The simulated experiment: reproducibility, noise level, error scale, filters, vmap."""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcal
from jaxcal import Problem, compute_metrics, simulate_experiment

# Compile time: simulate_experiment compiles one program (~9 s on 2 CPU cores) per robot,
# measurement model, dtype and sample count; its float settings (noise, deviations, filters) are
# arguments of that program, but a typed key (jax.random.key) and a raw one (PRNGKey) are not.
# The tests below share sample counts (and typed keys) where the count itself is not what they
# check, with the counts test_padded_simulation_has_the_unpadded_rows simulates anyway (260 and
# 511), so those programs compile once: N_SMALL (draw-wire: noiseless, vmap, bad
# arguments), N_ROBOTS (positions, every robot), N_SENSORS (every sensor; ≥ 500, that test is
# statistical).
N_SMALL = 260
N_ROBOTS = 260
N_SENSORS = 511


@eqx.filter_jit
def _residual(measurement, robot, deviations, q, y):
    """``measurement.residual`` as one compiled program (op by op, each operation compiles alone)."""
    return measurement.residual(robot, deviations, q, y)


@eqx.filter_jit
def _problem_residual(problem):
    return problem.residual(problem.x0())


@eqx.filter_jit
def _problem_sample_errors(problem):
    return problem.sample_errors(problem.x0())


def test_same_key_bit_identical(experiment):
    again = simulate_experiment(jax.random.PRNGKey(0))
    for a, b in [(experiment.train.q, again.train.q), (experiment.train.y, again.train.y),
                 (experiment.test.y, again.test.y), (experiment.true_deviations.ravel(), again.true_deviations.ravel())]:
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    other = simulate_experiment(jax.random.PRNGKey(1))
    assert not np.array_equal(np.asarray(other.train.y), np.asarray(experiment.train.y))


def test_sizes_limits_and_filters(experiment):
    ex = experiment
    assert (ex.train.n, ex.test.n) == (1600, 400)
    q = np.concatenate([np.asarray(ex.train.q), np.asarray(ex.test.q)])
    assert np.all(q >= np.asarray(ex.robot.q_min)) and np.all(q <= np.asarray(ex.robot.q_max))
    assert np.unique(q, axis=0).shape[0] == 2000  # no duplicated or filler poses
    p = np.asarray(eqx.filter_jit(jaxcal.fk_position)(ex.robot, jnp.asarray(q), ex.true_deviations))
    assert p[:, 2].min() >= 0.0
    # joints spread over their ranges: each joint covers most of its range
    span = (q.max(0) - q.min(0)) / (np.asarray(ex.robot.q_max) - np.asarray(ex.robot.q_min))
    assert span.min() > 0.9


def test_noise_level_is_documented_sigma():
    sigma = 0.25
    ex = simulate_experiment(jax.random.PRNGKey(3), n_samples=4000, noise_std=sigma)
    prob = Problem(ex.robot, ex.measurement, ex.train.q, ex.train.y, base=ex.true_deviations)
    r = np.asarray(_problem_residual(prob))
    # sample std of 3200 Gaussian draws: relative standard error 1/sqrt(2·3200) = 1.25 %
    assert abs(r.std() / sigma - 1) < 0.05
    assert abs(r.mean()) < 4 * sigma / np.sqrt(r.size)


@pytest.mark.parametrize("kind", ["position", "pose", "markers"])
def test_noise_of_every_simulated_sensor(kind):
    """σ on every position entry of the readings (for poses the position only; the orientation is
    exact), at the documented level. Marker readings were once taken for poses: their noise was
    written out of bounds and dropped, silently (noise-free data for σ = 0.5)."""
    sigma = 0.5
    meas = {"position": jaxcal.Position(), "pose": jaxcal.Pose(),
            "markers": jaxcal.Markers(np.array([[50.0, 0, 0], [0, 50.0, 0], [0, 0, 80.0]]))}[kind]
    ex = simulate_experiment(jax.random.key(5), n_samples=N_SENSORS, noise_std=sigma, measurement=meas)
    r = np.asarray(_residual(ex.measurement, ex.robot, ex.true_deviations, ex.train.q, ex.train.y))
    if kind == "pose":
        assert np.max(np.abs(r[:, 3:])) < 1e-9
        r = r[:, :3]
    assert abs(r.std() / sigma - 1) < 0.06, r.std()  # ≥ 1 227 draws: relative standard error ≤ 2 %


def test_other_sensors_are_refused():
    with pytest.raises(TypeError, match="simulate_contact"):
        simulate_experiment(jax.random.key(0), n_samples=20, measurement=jaxcal.PlaneContact(
            ("table",), [[0.0, 0.0, 1.0]], [0.0]))


def test_noiseless_truth_fits_exactly():
    ex = simulate_experiment(jax.random.key(4), n_samples=N_SMALL, noise_std=0.0)
    prob = Problem(ex.robot, ex.measurement, ex.test.q, ex.test.y, base=ex.true_deviations)
    assert np.abs(np.asarray(_problem_residual(prob))).max() < 1e-9


def test_before_calibration_error_in_paper_range():
    # paper Table III: BC RMSE 4.56 mm; the default deviations give 3–6 mm on average
    rmses = []
    for s in range(8):
        ex = simulate_experiment(jax.random.PRNGKey(s))
        prob = Problem(ex.robot, ex.measurement, ex.test.q, ex.test.y)
        rmses.append(float(compute_metrics(_problem_sample_errors(prob)).rmse))
    assert 3.0 <= np.mean(rmses) <= 6.0


def test_vmap_over_keys_equals_sequential():
    """Under ``vmap`` the deviations are drawn inside the simulation's program; a direct call
    draws them in a program of their own (it compiles faster): the same bits either way."""
    keys = jax.random.split(jax.random.key(7), 3)
    batched = jax.vmap(lambda k: simulate_experiment(k, n_samples=N_SMALL))(keys)
    for i in range(3):
        one = simulate_experiment(keys[i], n_samples=N_SMALL)
        for name, v in one.true_deviations.values.items():
            np.testing.assert_array_equal(np.asarray(batched.true_deviations.values[name][i]), np.asarray(v))
        np.testing.assert_array_equal(np.asarray(batched.train.y[i]), np.asarray(one.train.y))
        np.testing.assert_array_equal(np.asarray(batched.test.q[i]), np.asarray(one.test.q))


def test_position_experiment_every_robot(robot):
    ex = simulate_experiment(jax.random.key(0), robot, n_samples=N_ROBOTS, measurement=jaxcal.Position())
    assert ex.train.y.shape == (208, 3) and ex.train.kind == "position"  # N_ROBOTS − round(0.2·N_ROBOTS)


def test_bad_arguments():
    with pytest.raises(ValueError, match="noise_std"):
        simulate_experiment(jax.random.PRNGKey(0), noise_std=-1.0)
    with pytest.raises(ValueError, match="test_fraction"):
        simulate_experiment(jax.random.PRNGKey(0), test_fraction=1.5)
    with pytest.raises(ValueError, match="too few joint configurations"):
        simulate_experiment(jax.random.key(0), n_samples=N_SMALL, wire_range_mm=(10.0, 20.0))


def test_float32_warns():
    with jax.enable_x64(False):
        with pytest.warns(jaxcal.PrecisionWarning, match="float32"):
            ex = simulate_experiment(jax.random.PRNGKey(0), n_samples=50)
    assert ex.train.q.dtype == jnp.float32


# ---------------------------------------------------------------------------------------------
# padded to a shape bucket (jaxcal.sweep over many sample counts)


def test_masked_permutation_is_jax_permutation():
    """The real part of ``masked_permutation`` is ``jax.random.permutation`` itself, around the
    one-to-two-rounds threshold (1 625 / 1 626) too; the padding stays last. If JAX changes its
    permutation, this fails (and padded sweeps would draw other splits than unpadded ones)."""
    from jaxcal._simulation._simulate import masked_permutation, permutation_rounds

    assert [permutation_rounds(n) for n in (1, 2, 1625, 1626, 10**6)] == [0, 1, 1, 2, 2]

    # one compiled program per n (op by op, every operation compiled per shape: 171 programs);
    # n_real and n_rounds stay traced, as in simulate_padded
    @functools.partial(jax.jit, static_argnums=(1, 2))
    def permutations(key, n, caps, n_real, n_rounds):
        return jax.random.permutation(key, n), [masked_permutation(key, cap, n_real, n_rounds) for cap in caps]

    for n in (2, 7, 300, 1625, 1626, 2000):
        key = jax.random.key(n)
        caps = (n, n + 1, 3 * n // 2 + 5)
        want, got = permutations(key, n, caps, jnp.asarray(n), jnp.asarray(permutation_rounds(n)))
        for cap, p in zip(caps, got):
            p = np.asarray(p)
            np.testing.assert_array_equal(p[:n], np.asarray(want), err_msg=f"n={n}, cap={cap}")
            np.testing.assert_array_equal(p[n:], np.arange(n, cap))


@pytest.mark.parametrize("kind", ["cable", "position"])
def test_padded_simulation_has_the_unpadded_rows(kind):
    """``simulate_padded`` of n samples in a larger bucket: its real rows are exactly
    ``simulate_experiment(n_samples=n)``'s (same key), in order; the filler has weight 0."""
    from jaxcal._experiments._sweep_trials import _CONFIG_FIELDS, _simulation_options
    from jaxcal._simulation import _simulate as S
    from jaxcal.robots import hsr_jr680

    robot = hsr_jr680()
    meas = jaxcal.CableLength(S.default_anchor(robot)) if kind == "cable" else jaxcal.Position()
    opts = _simulation_options(robot, 512, 0.5, 0.2, {"tool_std_mm": 1.0})
    cfg = S._Config(*(opts[f] for f in _CONFIG_FIELDS))
    run = jax.jit(S.simulate_padded, static_argnums=(5,))
    for n in (260, 511):
        key = jax.random.key(n)
        ex = simulate_experiment(key, robot, n_samples=n, measurement=meas, tool_std_mm=1.0)
        n_test = int(round(0.2 * n))
        ps = run(key, robot, meas, None, 0.5, cfg, n, n_test, S.permutation_rounds(n))
        assert ps.q_train.shape[0] == 512 - 102 and ps.q_test.shape[0] == 102
        for a, b in ((ps.q_train, ex.train.q), (ps.q_test, ex.test.q)):  # the same draws and split
            np.testing.assert_array_equal(np.asarray(a)[: b.shape[0]], np.asarray(b))
        for a, b in ((ps.y_train, ex.train.y), (ps.y_test, ex.test.y)):  # other shapes: XLA may round 1 ulp apart
            np.testing.assert_allclose(np.asarray(a)[: b.shape[0]], np.asarray(b), rtol=1e-14, atol=0)
        np.testing.assert_array_equal(ps.w_train, np.arange(410) < n - n_test)
        np.testing.assert_array_equal(ps.w_test, np.arange(102) < n_test)
        np.testing.assert_array_equal(ps.true_deviations.ravel(), ex.true_deviations.ravel())
