"""Forward kinematics: against an independent NumPy 4×4 implementation, closed-form poses,
Hayati β, modified DH, jacfwd Jacobians vs finite differences, dtypes and bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import central_differences, numpy_dh_fk

import jaxcal
from jaxcal import Deviations, DHRobot, fk_pose, fk_position
from jaxcal.robots import hsr_jr680, ur5


def _random_q(robot, n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(np.asarray(robot.q_min), np.asarray(robot.q_max), size=(n, robot.dof))


def _random_dev(robot, seed=1, scale=1.0):
    rng = np.random.default_rng(seed)
    f = lambda *s: jnp.asarray(scale * rng.normal(size=s))  # noqa: E731
    dof = robot.dof
    return Deviations.from_dh(1e-2 * f(dof), f(dof), f(dof), 1e-2 * f(dof), 1e-2 * f(dof), f(3), f(3), f())


def _ref(robot, q, dev=None, tool=True):
    g = {k: np.asarray(getattr(robot, k)) for k in ("alpha", "a", "d", "theta", "beta")}
    t = np.asarray(robot.tool)
    if dev is not None:
        g = {k: v + np.asarray(getattr(dev, k)) for k, v in g.items()}
        t = t + np.asarray(dev.tool)
    return numpy_dh_fk(g["alpha"], g["a"], g["d"], g["theta"], g["beta"], q, robot.convention,
                       robot.beta_joints, t if tool else None)


def test_fk_matches_numpy_reference(robot):
    q = _random_q(robot, 64)
    for dev in (None, _random_dev(robot)):
        T = np.asarray(fk_pose(robot, jnp.asarray(q), dev))
        np.testing.assert_allclose(T, _ref(robot, q, dev, tool=False), rtol=0, atol=1e-9)
        p = np.asarray(fk_position(robot, jnp.asarray(q), dev))
        np.testing.assert_allclose(p, _ref(robot, q, dev)[:, :3, 3], rtol=0, atol=1e-9)
        Tt = np.asarray(fk_pose(robot, jnp.asarray(q), dev, tool=True))
        np.testing.assert_allclose(Tt[:, :3, 3], p, rtol=0, atol=1e-9)
        flange = np.asarray(fk_position(robot, jnp.asarray(q), dev, tool=False))
        np.testing.assert_allclose(flange, T[:, :3, 3], rtol=0, atol=1e-9)


def test_zero_angles_hand_computed():
    # HSR-JR680 (Table I), q = 0, worked by hand: shoulder (250, 0, 653.5), +900 up the upper
    # arm, +205 up (a3 = -205 along -z), forearm d4 = 1030.2 toward -x, flange d6 = 200.6 up.
    p = fk_position(hsr_jr680(), jnp.zeros(6), tool=False)
    np.testing.assert_allclose(np.asarray(p), [250 - 1030.2, 0.0, 653.5 + 900 + 205 + 200.6], atol=1e-9)
    # UR5 at q = 0: (a2 + a3, -(d4 + d6), d1 - d5), the well-known zero pose.
    p = fk_position(ur5(tool_mm=(0, 0, 0)), jnp.zeros(6), tool=False)
    np.testing.assert_allclose(np.asarray(p), [-817.25, -191.45, 89.159 - 94.65], atol=1e-9)


def test_single_configuration_and_jit(robot):
    q = jnp.asarray(_random_q(robot, 5))
    batched = fk_position(robot, q)
    single = fk_position(robot, q[2])
    assert single.shape == (3,)
    np.testing.assert_allclose(np.asarray(single), np.asarray(batched[2]), atol=1e-12)
    jitted = jax.jit(fk_position)(robot, q)
    np.testing.assert_allclose(np.asarray(jitted), np.asarray(batched), atol=1e-12)


def test_host_kinematics_equal_the_functions_with_their_defaults(robot):
    """``fk_position_jit`` / ``fk_pose_jit`` (host callers: rows padded to a bucket, NumPy out)
    give what ``fk_position`` / ``fk_pose`` give, with the same default for ``tool`` (the tool
    point for a position, the flange for a pose), for a fit's committed deviations as for fresh ones."""
    from jaxcal._models._kinematics import fk_pose_jit, fk_position_jit

    q = jnp.asarray(_random_q(robot, 7))
    dev = Deviations.zeros(robot.dof).replace(tool=jnp.asarray([1.0, -2.0, 3.0]), d=jnp.full(robot.dof, 0.5))
    committed = jax.tree_util.tree_map(lambda a: jax.device_put(a, jax.devices()[0]), dev)
    for d in (dev, committed):
        np.testing.assert_allclose(fk_position_jit(robot, q, d), np.asarray(fk_position(robot, q, d)), atol=1e-9)
        np.testing.assert_allclose(fk_pose_jit(robot, q, d), np.asarray(fk_pose(robot, q, d)), atol=1e-9)
    np.testing.assert_allclose(fk_position_jit(robot, q, dev, tool=False),
                               np.asarray(fk_position(robot, q, dev, tool=False)), atol=1e-9)


def test_rotation_is_orthonormal(robot):
    T = np.asarray(fk_pose(robot, jnp.asarray(_random_q(robot, 20)), _random_dev(robot)))
    R = T[:, :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_array_equal(T[:, 3], np.broadcast_to([0, 0, 0, 1.0], (20, 4)))


def test_hayati_beta_zero_equals_dh():
    base = hsr_jr680()
    hay = base.with_hayati(2, 3)
    q = jnp.asarray(_random_q(base, 50))
    dev = _random_dev(base)
    dev_no_beta = dev.replace(beta=jnp.zeros(6))
    np.testing.assert_array_equal(np.asarray(fk_pose(hay, q, dev_no_beta)), np.asarray(fk_pose(base, q, dev_no_beta)))


def test_hayati_beta_nonzero_matches_reference():
    hay = hsr_jr680().with_hayati(2)
    q = _random_q(hay, 30)
    dev = _random_dev(hay)
    np.testing.assert_allclose(np.asarray(fk_pose(hay, jnp.asarray(q), dev)), _ref(hay, q, dev, tool=False), atol=1e-9)
    # positions come from a separate recursion (a point carried from the flange inward)
    np.testing.assert_allclose(np.asarray(fk_position(hay, jnp.asarray(q), dev)), _ref(hay, q, dev)[:, :3, 3], atol=1e-9)
    np.testing.assert_allclose(np.asarray(fk_position(hay, jnp.asarray(q), dev, tool=False)),
                               _ref(hay, q, dev, tool=False)[:, :3, 3], atol=1e-9)
    # beta at a joint without Hayati is ignored
    plain = hsr_jr680()
    np.testing.assert_allclose(np.asarray(fk_pose(plain, jnp.asarray(q), dev)), _ref(plain, q, dev, tool=False), atol=1e-9)
    assert np.abs(_ref(hay, q, dev) - _ref(plain, q, dev)).max() > 1e-3


def test_modified_dh_matches_reference():
    # PUMA 560 in Craig's modified DH (Craig, Introduction to Robotics, 3rd ed., Fig. 3.18)
    r = DHRobot.from_degrees(
        alpha_deg=[0, -90, 0, -90, 90, -90], a_mm=[0, 0, 431.8, 20.3, 0, 0],
        d_mm=[0, 0, 149.09, 433.07, 0, 0], theta_deg=[0] * 6, convention="modified",
        beta_joints=(3,), tool_mm=(10, 20, 30), name="puma_craig",
    )
    q = _random_q(r, 40)
    dev = _random_dev(r)
    np.testing.assert_allclose(np.asarray(fk_pose(r, jnp.asarray(q), dev)), _ref(r, q, dev, tool=False), atol=1e-9)
    np.testing.assert_allclose(np.asarray(fk_position(r, jnp.asarray(q), dev)), _ref(r, q, dev)[:, :3, 3], atol=1e-9)
    np.testing.assert_allclose(np.asarray(fk_position(r, jnp.asarray(q), dev, tool=False)),
                               _ref(r, q, dev, tool=False)[:, :3, 3], atol=1e-9)


@pytest.mark.parametrize("model", ["cable", "position", "pose"])
def test_jacfwd_matches_central_differences(robot, model):
    q = jnp.asarray(_random_q(robot, 40))
    meas = {
        "cable": jaxcal.CableLength(jnp.asarray([800.0, 100.0, -50.0])),
        "position": jaxcal.Position(),
        "pose": jaxcal.Pose(),
    }[model]
    y = meas.predict(robot, None, q)
    space = jaxcal.ParameterSpace.for_robot(robot.with_hayati(2), anchor=model == "cable", tool=True,
                                            cable_offset=model == "cable")
    prob = jaxcal.Problem(robot.with_hayati(2), meas, q, y, space)
    x0 = jnp.asarray(np.random.default_rng(3).normal(size=space.n_free) * 1e-2)
    J = np.asarray(prob.jacobian(x0))
    h = 1e-6
    fd = central_differences(prob.residual, x0, h)
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-5 * max(1.0, np.abs(fd).max()))


def test_float32_follows_joint_angle_dtype(robot):
    q64 = jnp.asarray(_random_q(robot, 100))
    p64 = fk_position(robot, q64)
    p32 = fk_position(robot, q64.astype(jnp.float32))
    assert p32.dtype == jnp.float32 and p64.dtype == jnp.float64
    # float32 resolution on metre-scale positions: ~1e-4 mm per operation
    assert np.abs(np.asarray(p32, np.float64) - np.asarray(p64)).max() < 5e-2


@pytest.mark.parametrize("shape", [(10, 5), (10, 7), (2, 3, 6), ()])
def test_wrong_joint_angle_shape_raises(shape):
    with pytest.raises(ValueError, match=r"joint angles must have shape \[n, 6\]"):
        fk_position(hsr_jr680(), jnp.zeros(shape))


def test_robot_construction_errors():
    with pytest.raises(ValueError, match="a_mm has 2 entries but the robot has 3 joints"):
        DHRobot.from_degrees(alpha_deg=[0, 0, 0], a_mm=[1, 2], d_mm=[0, 0, 0], theta_deg=[0, 0, 0])
    with pytest.raises(ValueError, match="NaN"):
        DHRobot.from_degrees(alpha_deg=[0, np.nan], a_mm=[1, 2], d_mm=[0, 0], theta_deg=[0, 0])
    with pytest.raises(ValueError, match="q_min < q_max"):
        DHRobot.from_degrees(alpha_deg=[0], a_mm=[1], d_mm=[0], theta_deg=[0], q_min_deg=[10], q_max_deg=[5])
    with pytest.raises(ValueError, match="convention"):
        DHRobot.from_degrees(alpha_deg=[0], a_mm=[1], d_mm=[0], theta_deg=[0], convention="craig")
    with pytest.raises(ValueError, match="1-based"):
        DHRobot.from_degrees(alpha_deg=[0], a_mm=[1], d_mm=[0], theta_deg=[0], beta_joints=(0,))
    with pytest.raises(ValueError, match="unknown robot"):
        jaxcal.robots.get_robot("kuka_kr1000")


def test_table_i_stored_exactly():
    tab = hsr_jr680().dh_table_deg()
    np.testing.assert_allclose(tab[:, 0], [-90, 0, -90, 90, -90, 0], atol=1e-12)
    np.testing.assert_array_equal(tab[:, 1], [250, 900, -205, 0, 0, 0])
    np.testing.assert_array_equal(tab[:, 2], [653.5, 0, 0, 1030.2, 0, 200.6])
    np.testing.assert_allclose(tab[:, 3], [0, -90, 180, 0, 90, 0], atol=1e-12)


def _eqns_nested(jaxpr, depth=0):
    """(depth, eqn) for every equation, descending into sub-jaxprs (loop bodies, cond branches)."""
    for e in jaxpr.eqns:
        yield depth, e
        for v in e.params.values():
            for sub in v if isinstance(v, (tuple, list)) else (v,):
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    yield from _eqns_nested(inner, depth + 1)


def test_shared_joint_trig_same_values_and_computed_once(robot):
    """``shared_joint_trig``: kernels at the block's joint angles give the same residuals and
    Jacobians as without it, and an LM calibration computes ``cos`` of the data once, outside its
    loop (inside, each residual and Jacobian recomputed it)."""
    from jaxcal._models._kinematics import shared_joint_trig

    q = jnp.asarray(_random_q(robot, 50))
    meas = jaxcal.CableLength(jnp.asarray([800.0, 100.0, -50.0]))
    dev = _random_dev(robot, scale=0.1)
    y = meas.predict(robot, dev, q)
    prob = jaxcal.Problem(robot, meas, q, y)
    x = jnp.asarray(np.random.default_rng(2).normal(size=prob.space.n_free) * 1e-2)

    def both(p):
        with shared_joint_trig(p.q):
            inside = (p.residual(x), p.jacobian(x))
        return inside, (p.residual(x), p.jacobian(x))

    (r_in, J_in), (r_out, J_out) = jax.jit(both)(prob)
    np.testing.assert_allclose(np.asarray(r_in), np.asarray(r_out), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(np.asarray(J_in), np.asarray(J_out), rtol=1e-12, atol=1e-9)

    cal = jaxcal.Calibrator(robot, meas, jaxcal.methods.make_method("lm"), Deviations.zeros(robot.dof),
                            prob.space)
    jaxpr = jax.make_jaxpr(cal)(q, y, jax.random.key(0)).jaxpr
    cos_data = [d for d, e in _eqns_nested(jaxpr) if e.primitive.name == "cos" and q.shape[0] in e.outvars[0].aval.shape]
    assert cos_data == [0], cos_data  # once, at the top level of the program
