"""Identifiability: rank and dependent parameters of the paper's set-up, with derivations."""

import math

import jax
import numpy as np
import pytest

import jaxcal
from jaxcal import ParameterSpace, identifiability, simulate_experiment
from jaxcal._core._params import group_kind


def test_default_experiment_rank_19_of_24(experiment):
    ex = experiment
    rep = identifiability(ex.robot, ex.measurement, ex.train.q)
    # 24 − α6, θ6 (no effect: the wire attaches on the 6th axis) − 1 (d2, d3 act as a sum:
    # axes 2 ∥ 3) − 2 (a5 acts like −θ5/L and α5 like L·d5, L the distance from joint 5 to the
    # tool point on the 5th link's z axis)
    assert rep.rank == 19 and len(rep.names) == 24
    assert len(rep.identifiable) == 19 and rep.space.n_free == 19
    # the documented rule (KEEP_PREFERENCE): θ, d, a, α; lower joint first
    assert rep.unidentifiable == ("alpha_5", "alpha_6", "a_5", "d_3", "theta_6")
    (coef, other), = rep.dependencies["d_3"]
    assert other == "d_2" and coef == pytest.approx(1.0, abs=1e-9)
    (coef, other), = rep.dependencies["a_5"]
    assert other == "theta_5" and coef == pytest.approx(-1 / float(ex.robot.d[5] + ex.robot.tool[2]), rel=0.05)
    text = str(rep)
    assert "rank 19 of 24" in text and "has no effect" in text
    assert "mm/mm·d_2" in text and "rad/mm·theta_5" in text and "mm/rad·d_5" in text
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
    rep = identifiability(ex.robot, ex.measurement, ex.train.q.astype(np.float32))
    assert rep.rank == 19 and rep.rtol == 1e-4  # dtype-aware default threshold
    assert rep.unidentifiable == identifiability(ex.robot, ex.measurement, ex.train.q).unidentifiable


def test_dependent_choice_is_deterministic(experiment):
    """Which of a dependent group is kept follows KEEP_PREFERENCE, not the data or round-off:
    the same on other poses, another seed and a permuted sample order."""
    ex = experiment
    ref = identifiability(ex.robot, ex.measurement, ex.train.q).unidentifiable
    other = simulate_experiment(jax.random.PRNGKey(7), n_samples=300)
    assert identifiability(ex.robot, ex.measurement, other.train.q).unidentifiable == ref
    perm = np.random.default_rng(1).permutation(ex.train.q.shape[0])
    assert identifiability(ex.robot, ex.measurement, ex.train.q[perm]).unidentifiable == ref
    robot = ex.robot.with_hayati(2).with_tool((60.0, 40.0, 120.0))
    space = ParameterSpace.for_robot(robot, anchor=True, tool=True, cable_offset=True)
    rep = identifiability(robot, ex.measurement, ex.train.q, space)
    # the robot's parameters give way to the sensor extras (they have a nominal value to stay at;
    # the extras' size is unknown): a tool offset along x acts like Δa_6, along z like Δd_6, a
    # shift of the anchor along z_0 like Δd_1, a turn about z_0 like Δθ_1
    assert set(rep.unidentifiable) == {"alpha_6", "a_6", "d_1", "d_3", "d_6", "theta_1", "theta_6"}
    assert {"anchor_x", "anchor_y", "anchor_z", "tool_x", "tool_y", "tool_z", "cable_offset"} <= set(rep.identifiable)
    (coef, other), = rep.dependencies["a_6"]
    assert other == "tool_x" and coef == pytest.approx(1.0, abs=1e-6)


def test_prior_frees_every_candidate_it_covers(experiment):
    """Under a prior (maximum a posteriori) nothing the prior covers is held; of the extras
    without a prior only those the data see are free, and a pair of them that act alike keeps
    the first in KEEP_PREFERENCE order."""
    ex = experiment
    robot = ex.robot.with_hayati(2).with_tool((60.0, 40.0, 120.0))
    space = ParameterSpace.for_robot(robot, anchor=True, tool=True, cable_offset=True)
    rep = identifiability(robot, ex.measurement, ex.train.q, space, prior="default")
    assert rep.space.n_free == 32 and rep.held == () and rep.rank == 25
    assert set(rep.prior_covered) == {n for n in space.free_names if group_kind(n) != "extra"}
    text = str(rep)
    assert "estimated under the prior" in text and "held at their start value" not in text
    # a prior on nothing but the DH lengths: θ1 (no prior) and anchor_y act alike; anchor_y comes
    # first, θ1 is held; the d's are free under their prior whatever the data see
    only_lengths = jaxcal.Prior(angle_deg=math.inf)
    rep = identifiability(robot, ex.measurement, ex.train.q, space, prior=only_lengths)
    assert set(rep.held) == {"alpha_6", "theta_1", "theta_6"}
    assert {"d_1", "d_3", "d_6", "a_6", "anchor_y"} <= set(rep.space.free_names)
    # the MAP information matrix JᵀJ/σ² + diag(1/s²) of the free set is positive definite
    from jaxcal._fit._problem import Problem

    J = np.asarray(Problem(robot, ex.measurement, ex.train.q, ex.train.y, rep.space).jacobian(
        np.zeros(rep.space.n_free)))
    s = only_lengths.std(rep.space)
    H = J.T @ J / 0.5**2 + np.diag(np.where(np.isfinite(s), 1 / s**2, 0.0))
    assert np.linalg.eigvalsh(H / np.outer(np.sqrt(np.diag(H)), np.sqrt(np.diag(H)))).min() > 1e-8


def test_every_robot_position_rank(robot):
    q = jaxcal.simulate_experiment(jax.random.PRNGKey(0), robot, n_samples=200, measurement=jaxcal.Position()).train.q
    rep = identifiability(robot, jaxcal.Position(), q)
    assert 0 < rep.rank < 24 and rep.rank == len(rep.identifiable)
    assert np.all(np.diff(rep.singular_values) <= 1e-12)


def test_identify_with_residuals_shares_the_program(experiment):
    """The residuals and the Jacobian that come with the report (what calibrate() scans first
    and starts the solve from) equal the separately computed ones; the report is unchanged."""
    from jaxcal._fit._identifiability import identify_with_residuals
    from jaxcal._fit._problem import Problem, signed_residuals

    ex = experiment
    rep, resid, J = identify_with_residuals(ex.robot, ex.measurement, ex.train.q, y=ex.train.y)
    assert rep.identifiable == identifiability(ex.robot, ex.measurement, ex.train.q).identifiable
    prob = Problem(ex.robot, ex.measurement, ex.train.q, ex.train.y)
    np.testing.assert_allclose(resid, signed_residuals(prob, prob.x0()), rtol=0, atol=1e-9)
    # the program runs on the rows padded to their shape bucket: the Jacobian's padding rows are zero
    J_real = prob.jacobian(prob.x0())
    np.testing.assert_allclose(np.asarray(J)[: J_real.shape[0]], J_real, rtol=1e-12, atol=1e-9)
    assert J.shape[0] == jaxcal.bucket_size(ex.train.n) and not np.any(np.asarray(J)[J_real.shape[0]:])
    assert identify_with_residuals(ex.robot, ex.measurement, ex.train.q)[1:] == (None, None)
    # pose data: the Jacobian depends on the readings, so none is handed on; residuals still are
    pose = jaxcal.Pose()
    y = pose.predict(ex.robot, None, ex.train.q[:50])
    _, resid, J = identify_with_residuals(ex.robot, pose, ex.train.q[:50], y=y)
    assert J is None and resid.shape == (50, 6) and np.abs(resid).max() < 1e-9


@pytest.mark.parametrize("shape,rank", [((1600, 24), 24), ((400, 12), 9), ((5, 8), 5)])
def test_pivoted_qr_matches_scipy(shape, rank):
    """The host pivoted QR (unpivoted QR of the tall matrix, then Businger–Golub pivoting of its
    triangular factor) picks LAPACK geqp3's columns and |R|, also for rank-deficient and wide
    matrices."""
    scipy_linalg = pytest.importorskip("scipy.linalg")
    from jaxcal._fit._identifiability import pivoted_qr

    rng = np.random.default_rng(sum(shape))
    n, p = shape
    A = rng.normal(size=(n, min(rank, p))) @ rng.normal(size=(min(rank, p), p)) * rng.uniform(0.1, 10, p)
    R, piv = pivoted_qr(A)
    _, R_ref, piv_ref = scipy_linalg.qr(A, mode="economic", pivoting=True)
    k = min(rank, n, p)  # beyond the rank the pivots are round-off ties
    np.testing.assert_array_equal(piv[:k], piv_ref[:k])
    # rows of the leading k pivots, columns in A's order (the trailing pivots' order may differ)
    R_orig, R_ref_orig = np.zeros((k, p)), np.zeros((k, p))
    R_orig[:, piv], R_ref_orig[:, piv_ref] = R[:k], R_ref[:k]
    np.testing.assert_allclose(np.abs(R_orig), np.abs(R_ref_orig), rtol=1e-9, atol=1e-9 * np.abs(R_ref).max())
    np.testing.assert_allclose(np.triu(R), R)
    # A[:, piv] = Q R with orthonormal Q: the Gram matrices agree
    np.testing.assert_allclose(R.T @ R, A[:, piv].T @ A[:, piv], rtol=1e-9, atol=1e-9 * np.abs(A).max() ** 2 * n)
