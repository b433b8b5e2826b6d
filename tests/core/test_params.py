"""Calibration parameters as named groups: layouts, deviations, spaces, and a new
error model added as a group without touching the solver, identifiability or report layers."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcal
from jaxcal import Deviations, ParameterSpace
from jaxcal._core._params import GROUPS, Group, Layout, group_kind, group_of, layout_for
from jaxcal._models._kinematics import register_joint_correction


def test_dh_layout_keeps_the_historic_order_and_names():
    lay = Layout.dh(6)
    assert lay.size == 43 and lay.group_names == tuple(g for g, _ in GROUPS)
    assert lay.names[:2] == ("alpha_1", "alpha_2") and lay.names[-7:] == (
        "cable_offset", "base_rx", "base_ry", "base_rz", "base_x", "base_y", "base_z")
    assert lay.units[lay.names.index("theta_3")] == "rad" and lay.units[lay.names.index("d_2")] == "mm"
    assert layout_for(jaxcal.robots.hsr_jr680(), jaxcal.CableLength(jnp.zeros(3))) == lay
    assert ParameterSpace(6, np.ones(43, bool)) == ParameterSpace(lay, np.ones(43, bool))
    assert hash(Layout.dh(6)) == hash(lay)


def test_group_lookup_and_errors():
    assert group_of("base_rx") == "base_rotation" and group_of("d_3") == "d" and group_of("cable_offset") == "cable_offset"
    assert group_kind("anchor_y") == "extra" and group_kind("theta_1") == "geometric"
    with pytest.raises(ValueError, match="unknown parameter name"):
        group_of("nonsense_1")
    with pytest.raises(ValueError, match="shape"):
        Group("g", ("g_1",), ("mm",), "extra", (2,))
    with pytest.raises(ValueError, match="kind"):
        Group.scalar("g", "mm", kind="sensor")
    with pytest.raises(ValueError, match="appears twice"):
        Layout((Group.scalar("g", "mm"), Group.scalar("g", "mm")), 1)


def test_deviations_by_group():
    dev = Deviations({"theta": jnp.arange(6.0), "anchor": jnp.ones(3)}, 6)
    assert dev.alpha.shape == (6,) and float(dev.cable_offset) == 0.0
    np.testing.assert_array_equal(np.asarray(dev.theta), np.arange(6.0))
    assert dev.named()["theta_4"] == 3.0 and dev.named()["anchor_z"] == 1.0
    dev2 = dev.replace(cable_offset=2.5)
    assert float(dev2.cable_offset) == 2.5 and float(dev.cable_offset) == 0.0
    with pytest.raises(ValueError, match="unknown parameter groups"):
        Deviations({"thetta": jnp.zeros(6)}, 6)
    with pytest.raises(ValueError, match=r"group 'anchor' must have shape \[3\]"):
        Deviations({"anchor": jnp.zeros(2)}, 6)
    with pytest.raises(ValueError, match="unknown parameter group"):
        dev.replace(tool_point=jnp.zeros(3))
    with pytest.raises(AttributeError, match="no group 'compliance'"):
        _ = dev.compliance
    with pytest.raises(ValueError, match="flat vector of 43"):
        Deviations.unravel(jnp.zeros(42), 6)


# -- a new error model is a new group -------------------------------------------------------------
# A toy joint-space model: a constant bias per joint. It acts exactly like the DH θ offsets, so
# data made with θ errors must be explained by the bias when only the bias is free.
register_joint_correction("toy_bias", lambda robot, dev, q: jnp.broadcast_to(dev.toy_bias, q.shape).astype(q.dtype))


class _BiasedRobot(jaxcal.DHRobot):
    def error_groups(self):
        return super().error_groups() + (Group.per_joint("toy_bias", self.dof, "rad", kind="nongeometric"),)


def _biased(robot):
    return _BiasedRobot(robot.alpha, robot.a, robot.d, robot.theta, robot.beta, robot.q_min, robot.q_max,
                        robot.tool, convention=robot.convention, beta_joints=robot.beta_joints, name="biased")


def test_a_new_group_enters_kinematics_spaces_and_calibration():
    ex = jaxcal.simulate_experiment(jax.random.key(3), n_samples=300, noise_std=0.0)
    robot = _biased(ex.robot)
    lay = layout_for(robot, ex.measurement)
    assert lay.group_names[-1] == "toy_bias" and lay.size == 49 and lay.kinds[-1] == "nongeometric"
    shift = jnp.asarray([0.01, -0.02, 0.005, 0.0, 0.01, 0.0])
    q = ex.train.q
    # the bias moves the tool exactly as a θ offset does
    with_bias = jaxcal.fk_position(robot, q, Deviations({"toy_bias": shift}, lay))
    with_theta = jaxcal.fk_position(ex.robot, q, Deviations({"theta": shift}, 6))
    np.testing.assert_allclose(np.asarray(with_bias), np.asarray(with_theta), atol=1e-12)
    # calibrate frees the new group by name; LM recovers the θ-shifted truth through it
    y = ex.measurement.predict(ex.robot, Deviations({"theta": shift}, 6), q)
    res = jaxcal.calibrate(robot, ex.measurement, (q, y), "lm", free="toy_bias", prior=None)
    assert set(res.space.free_names) <= {f"toy_bias_{j}" for j in range(1, 7)}
    got = np.asarray(res.deviations.toy_bias)
    idx = [int(n.rsplit("_", 1)[1]) - 1 for n in res.space.free_names]
    np.testing.assert_allclose(got[idx], np.asarray(shift)[idx], atol=1e-9)
    assert float(res.train_metrics.rmse) < 1e-6
    # and the JSON names carry the group
    assert "toy_bias_1" in res.to_dict()["deviations"]


def test_prior_sigma_per_group():
    lay = Layout.dh(2).extend([Group.per_joint("stiff", 2, "rad/(N*m)", kind="nongeometric", prior_std=1e-6),
                               Group.per_joint("other", 2, "rad/(N*m)", kind="nongeometric"),
                               Group.vector("mark", ("mark_x", "mark_y", "mark_z"), "mm")])
    space = ParameterSpace.from_names(lay, ["theta_1", "d_2", "stiff_1", "other_2", "mark_y"])
    std = jaxcal.Prior().std(space)
    assert space.free_names[:3] == ("d_2", "theta_1", "stiff_1")  # layout order
    np.testing.assert_allclose(std[:3], [2.0, np.radians(0.5), 1e-6])
    assert np.isinf(std[3]) and np.isinf(std[4])  # no default for a unit without one; extras: none
    np.testing.assert_allclose(jaxcal.Prior().scaled(2.0).std(space)[:3], [1.0, np.radians(0.25), 5e-7])
    np.testing.assert_allclose(jaxcal.Prior(extras_mm=3.0).std(space)[4], 3.0)
