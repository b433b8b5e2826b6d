"""Measurement models and parameters: closed-form cable lengths, extras, residual signs, masks."""

import jax.numpy as jnp
import numpy as np
import pytest

import jaxcal
from jaxcal import CableLength, Deviations, DHRobot, ParameterSpace, Pose, Position


def _one_link():
    # one joint, a = 300, d = 400: at q = 0 the flange is at (300, 0, 400)
    return DHRobot.from_degrees(alpha_deg=[0], a_mm=[300], d_mm=[400], theta_deg=[0], name="link")


def test_cable_length_exact_3_4_5():
    r = _one_link()
    L = CableLength(jnp.zeros(3)).predict(r, None, jnp.zeros((1, 1)))
    assert float(L[0]) == 500.0
    # at q = 90°: point (0, 300, 400), anchor at (0, 300, 0): length 400 exactly up to cos(pi/2)
    L = CableLength(jnp.asarray([0.0, 300.0, 0.0])).predict(r, None, jnp.full((1, 1), np.pi / 2))
    np.testing.assert_allclose(np.asarray(L), [400.0], rtol=0, atol=1e-12)


def test_cable_extras_closed_form():
    r = _one_link()
    dev = Deviations.zeros(1)
    dev = dev.replace(anchor=jnp.asarray([0.0, 0.0, 100.0]), tool=jnp.asarray([0.0, 0.0, 200.0]),
                      cable_offset=jnp.asarray(-12.5))
    # anchor moves to (0,0,100), tool to flange + (0,0,200): point (300,0,600), offset -12.5
    L = CableLength(jnp.zeros(3)).predict(r, dev, jnp.zeros((1, 1)))
    np.testing.assert_allclose(np.asarray(L), [np.hypot(300.0, 500.0) - 12.5], rtol=1e-15)


def test_residual_is_prediction_minus_measured(robot):
    q = jnp.asarray(np.random.default_rng(0).uniform(-1, 1, size=(7, robot.dof)))
    for m in (CableLength(jnp.asarray([500.0, 0, 0])), Position(), Pose()):
        y = m.predict(robot, None, q)
        assert np.abs(np.asarray(jaxcal.residuals(m, robot, None, q, y))).max() < 1e-9
    y = CableLength(jnp.asarray([500.0, 0, 0])).predict(robot, None, q)
    r = jaxcal.residuals(CableLength(jnp.asarray([500.0, 0, 0])), robot, None, q, y - 2.0)
    np.testing.assert_allclose(np.asarray(r), 2.0, atol=1e-9)
    p = Position().predict(robot, None, q)
    np.testing.assert_allclose(np.asarray(p), np.asarray(jaxcal.fk_position(robot, q)), atol=1e-12)


def test_pose_residual_small_rotation():
    r = _one_link()
    q = jnp.zeros((1, 1))
    T = np.asarray(Pose().predict(r, None, q))
    eps = 1e-4
    Rz = np.array([[np.cos(eps), -np.sin(eps), 0], [np.sin(eps), np.cos(eps), 0], [0, 0, 1]])
    Tm = T.copy()
    Tm[0, :3, :3] = T[0, :3, :3] @ Rz.T  # measured rotated by -eps about z: prediction is +eps
    Tm[0, :3, 3] += [1.0, -2.0, 0.5]
    res = np.asarray(Pose(orientation_scale=1000.0).residual(r, None, q, jnp.asarray(Tm)))[0]
    np.testing.assert_allclose(res[:3], [-1.0, 2.0, -0.5], atol=1e-12)
    np.testing.assert_allclose(res[3:], [0, 0, 1000 * np.sin(eps)], atol=1e-12)


def test_measurement_shape_checks():
    with pytest.raises(ValueError, match="anchor must be a \\[3\\]"):
        CableLength(jnp.zeros(2))
    with pytest.raises(ValueError, match="shape \\[5\\]"):
        CableLength(jnp.zeros(3)).check_measurements(np.zeros((5, 1)), 5)
    with pytest.raises(ValueError, match="NaN/inf at samples \\[1\\]"):
        Position().check_measurements(np.array([[0, 0, 0], [np.nan, 0, 0.0]]), 2)


def test_deviations_ravel_roundtrip():
    parts = [jnp.arange(k, k + s, dtype=float) for k, s in
             [(0, 6), (10, 6), (20, 6), (30, 6), (40, 6), (50, 3), (60, 3), (70, 1), (80, 3), (90, 3)]]
    parts[7] = parts[7][0]
    dev = Deviations.from_dh(*parts)
    flat = dev.ravel()
    assert flat.shape == (43,)
    np.testing.assert_array_equal(np.asarray(flat[:6]), np.arange(6.0))  # DH layout order: alpha first
    np.testing.assert_array_equal(np.asarray(flat[37:]), [80, 81, 82, 90, 91, 92])
    back = Deviations.unravel(flat, 6)
    for g, _ in jaxcal._core._params.GROUPS:
        np.testing.assert_array_equal(np.asarray(getattr(back, g)), np.asarray(getattr(dev, g)))
    # a batch of deviations ravels/unravels along the last axis
    batch = Deviations.unravel(jnp.stack([flat, 2 * flat]), 6)
    assert batch.alpha.shape == (2, 6) and batch.cable_offset.shape == (2,)
    np.testing.assert_array_equal(np.asarray(batch.ravel()[1]), 2 * np.asarray(flat))


def test_parameter_space_maps(robot):
    space = ParameterSpace.for_robot(robot.with_hayati(2), anchor=True, cable_offset=True)
    assert space.n_free == 4 * robot.dof + 1 + 3 + 1
    assert "beta_2" in space.free_names and "beta_3" not in space.free_names
    assert space.free_names[:2] == ("alpha_1", "alpha_2")
    x = jnp.arange(1.0, space.n_free + 1.0)
    dev = space.from_vector(x)
    np.testing.assert_array_equal(np.asarray(space.to_vector(dev)), np.asarray(x))
    assert float(dev.tool.sum()) == 0.0 and float(dev.beta[2]) == 0.0
    assert space.units[space.names.index("alpha_1")] == "rad"
    sub = space.restrict(np.arange(space.n_free) % 2 == 0)
    assert sub.n_free == (space.n_free + 1) // 2
    assert ParameterSpace.from_names(robot.dof, ["d_2", "theta_1"]).free_names == ("d_2", "theta_1")
    assert hash(sub) == hash(space.restrict(np.arange(space.n_free) % 2 == 0))


def test_parameter_space_errors():
    with pytest.raises(ValueError, match="unknown parameter name 'd_9'"):
        ParameterSpace.from_names(6, ["d_9"])
    with pytest.raises(ValueError, match="expected 24 free parameters"):
        ParameterSpace.for_robot(jaxcal.robots.hsr_jr680()).from_vector(jnp.zeros(5))
    with pytest.raises(ValueError, match="free mask must have shape"):
        ParameterSpace(6, np.ones(3, bool))
