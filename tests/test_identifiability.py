"""Identifiability: rank and dependent parameters of the paper's set-up, with derivations."""

import jax
import numpy as np
import pytest

import jaxcal
from jaxcal import ParameterSpace, identifiability, simulate_experiment


@pytest.fixture(scope="module")
def experiment():
    return simulate_experiment(jax.random.PRNGKey(0))


def test_default_experiment_rank_19_of_24(experiment):
    ex = experiment
    rep = identifiability(ex.robot, ex.measurement, ex.train.q)
    # 24 − α6, θ6 (no effect: the wire attaches on the 6th axis) − 1 (d2, d3 act as a sum:
    # axes 2 ∥ 3) − 2 (a5 ≈ d6·θ5 and d5 ≈ d6·α5 with the tool point on the 5th link's z axis)
    assert rep.rank == 19 and len(rep.names) == 24
    assert len(rep.identifiable) == 19 and rep.space.n_free == 19
    assert {"d_2", "d_3"} & set(rep.unidentifiable)
    assert {"alpha_6", "theta_6"} <= set(rep.unidentifiable)
    dep = "d_2" if "d_2" in rep.unidentifiable else "d_3"
    (coef, other), = rep.dependencies[dep]
    assert other in ("d_2", "d_3") and coef == pytest.approx(1.0, abs=1e-9)
    text = str(rep)
    assert "rank 19 of 24" in text and "has no effect" in text
    assert rep.to_dict()["rank"] == 19


def test_extras_and_hayati_rank_25_of_32(experiment):
    ex = experiment
    robot = ex.robot.with_hayati(2).with_tool((60.0, 40.0, 120.0))
    space = ParameterSpace.for_robot(robot, anchor=True, tool=True, cable_offset=True)
    rep = identifiability(robot, ex.measurement, ex.train.q, space)
    # 32 free = 24 DH + β2 + anchor (3) + tool (3) + cable offset. Lost: d2/d3 sum (1);
    # anchor vs joint 1: rotating the anchor about z0 ≡ θ1, moving it along z0 ≡ d1 (2);
    # joint 6 + tool: the 7 numbers θ6, d6, a6, α6, tool xyz only set one point that turns
    # with q6 about z5 (radius, height, phase: 3) (4). 32 − 7 = 25.
    assert rep.rank == 25 and len(rep.names) == 32


def test_float32_and_errors(experiment):
    ex = experiment
    with pytest.raises(ValueError, match="no free parameters"):
        identifiability(ex.robot, ex.measurement, ex.train.q, ParameterSpace(6, np.zeros(43, bool)))
    rep = identifiability(ex.robot, ex.measurement, ex.train.q.astype(np.float32), rtol=1e-5)
    assert rep.rank == 19


def test_every_robot_position_rank(robot):
    q = jaxcal.simulate_experiment(jax.random.PRNGKey(0), robot, n_samples=200, measurement=jaxcal.Position()).train.q
    rep = identifiability(robot, jaxcal.Position(), q)
    assert 0 < rep.rank < 24 and rep.rank == len(rep.identifiable)
    assert np.all(np.diff(rep.singular_values) <= 1e-12)
