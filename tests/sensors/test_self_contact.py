"""Self-contact: two tips of a kinematic tree touch (`jaxcal.SelfContact`): the reading is the
distance of the two tool points, a fit of a two-armed robot from contact alone reaches the
statistical floor, and what contact cannot see is named."""

from __future__ import annotations

import pathlib

import jax
import numpy as np
import pytest

import jaxcal
from jaxcal import Dataset, SelfContact, statistical_floor
from jaxcal._datasets._dataset import mm_joints_metadata
from jaxcal._models._kinematics import fk_pose
from jaxcal._models._urdf import load_urdf
from jaxcal._simulation._simulate import draw_deviations

HUMANOID = pathlib.Path(__file__).resolve().parents[1] / "data" / "urdf" / "humanoid_tree.urdf"
TIPS = ("left_tool", "right_tool")
SIGMA = 0.1  # mm: the contact's scatter


@pytest.fixture(scope="module")
def contact():
    jaxcal.enable_x64()
    tree = load_urdf(HUMANOID, tips=list(TIPS))
    truth = draw_deviations(jax.random.key(1), tree, angle_std_deg=0.2, length_std_mm=0.5)
    q, y = jaxcal.simulate_self_contact(jax.random.key(2), tree, TIPS, n_samples=600, noise_std=SIGMA,
                                        true_deviations=truth)
    data = Dataset(q, y, "self_contact", {"tips": ",".join(TIPS), **mm_joints_metadata(tree)})
    return tree, truth, data


def test_reading_is_the_distance_of_the_two_tool_points(contact):
    tree, truth, data = contact
    model = SelfContact(TIPS)
    q = data.q[:50]
    # the tips' tool points through the frame kernel (fk_pose), not the point kernel predict uses
    pa, pb = (np.asarray(fk_pose(tree, q, truth, tip=t, tool=True))[:, :3, 3] for t in TIPS)
    np.testing.assert_allclose(np.asarray(model.predict(tree, truth, q)), np.linalg.norm(pa - pb, axis=1),
                               rtol=0, atol=1e-9)
    # at contact on the true robot: the gap scatters by the contact's σ around the known distance
    r = np.asarray(model.residual(tree, truth, data.q, data.y))[:, 0]
    assert abs(r.mean()) < 4 * SIGMA / np.sqrt(r.size) and 0.85 < r.std() / SIGMA < 1.15


def test_two_arms_from_contact_alone_at_the_floor(contact, tmp_path):
    tree, truth, data = contact
    train, test = data.subset(np.arange(300)), data.subset(np.arange(300, 600))
    setup = jaxcal.measurement_for(train, tree)
    assert setup.measurement == SelfContact(TIPS)
    res = jaxcal.calibrate(tree, setup.measurement, train, "lm")
    rank = res.identifiability.rank
    floor = statistical_floor(SIGMA, rank, train.n, 1).test
    ratio = res.evaluate(test).rmse / floor
    assert abs(ratio - 1) < 0.12, ratio
    # contact sees the arms relative to each other: a shift of the shared base joint's origin, which
    # moves both tips together, is not determined by the data
    assert "dx_1" not in res.space.free_names and len(res.space.free_names) == rank
    # the result file keeps the tree and the model
    path = tmp_path / "contact.json"
    jaxcal.save_result(res, path)
    back = jaxcal.load_result(path)
    assert back.measurement == res.measurement and back.robot.tip_names() == TIPS
    np.testing.assert_allclose(back.evaluate(test).rmse, res.evaluate(test).rmse, rtol=1e-9)


def test_tips_are_checked(contact):
    tree, _, data = contact
    with pytest.raises(ValueError, match="two different tips"):
        SelfContact(("left_tool",))
    with pytest.raises(ValueError, match="two different tips"):
        SelfContact("left_tool,left_tool")
    with pytest.raises(ValueError, match=r"tip\(s\) \['head_camera'\] are not tips of robot"):
        SelfContact(("left_tool", "head_camera")).check_robot(tree)
    with pytest.raises(ValueError, match=r"are not tips of robot 'hsr_jr680'; its tips: \[\]"):
        jaxcal.measurement_for(data.subset(np.arange(5)), jaxcal.robots.hsr_jr680())
    no_line = Dataset(data.q[:5], data.y[:5], "self_contact", mm_joints_metadata(tree))
    with pytest.raises(ValueError, match="'# tips: A,B' line"):
        jaxcal.measurement_for(no_line, tree)
    with pytest.raises(ValueError, match="--estimate base does not apply to self-contact data"):
        jaxcal.measurement_for(data.subset(np.arange(5)), tree, estimate="base")
