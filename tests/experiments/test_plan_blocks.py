"""Planning a combined set-up: the poses of one sensor chosen on the combined whitened information
of every block (plane contact planned with a distance bar in hand). Checked against the combined
model's own Jacobian, the rank plane contact lacks (the length scale), random candidates, and
simulated fits (slow)."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcal
from jaxcal import Block, DistanceBar, PlaneAngle, plan_blocks, predicted_accuracy_blocks
from jaxcal._experiments import _plan
from jaxcal._fit._problem import Problem
from jaxcal._sensors._blocks import combine
from jaxcal._sensors._contact import default_setup

SIGMA_PLANE, SIGMA_BAR = 0.05, 0.02


@pytest.fixture(scope="module")
def setup(paper_robot):
    """150 plane-contact candidates and 40 bar pose pairs (the shapes of test_plan_sensors.py); 40
    plane poses planned with the bar data in hand."""
    planes, bar = default_setup("plane", paper_robot), DistanceBar(paper_robot.dof)
    cand = _plan.candidate_poses(jax.random.key(3), paper_robot, planes, 150)
    bars = _plan.candidate_poses(jax.random.key(1), paper_robot, bar, 40)
    plan = plan_blocks(paper_robot, Block("plane", planes, cand, sigma=SIGMA_PLANE, extras="tool"), 40,
                       fixed=[Block("bar", bar, bars, sigma=SIGMA_BAR)])
    return planes, bar, cand, bars, plan


def _scaled_rank(G, rtol=1e-12):
    d = np.sqrt(np.diag(G))
    ev = np.linalg.eigvalsh(G / np.outer(d, d))
    return int(np.sum(ev > rtol * ev[-1]))


def test_combined_information_is_the_sum_of_the_whitened_blocks(paper_robot, setup):
    """The plan's information equals JᵀJ of the Combined model's own whitened residual (what
    calibrate_blocks fits) at the bar rows and the selected plane rows; the plane rows alone miss
    one direction of it (the length scale), which the bar supplies: every σ finite."""
    planes, bar, cand, bars, plan = setup
    sel = plan.selection
    assert sel.n == 40 and np.array_equal(np.asarray(sel.data.y), np.asarray(cand.y)[sel.index])
    model, q, y = combine(paper_robot, [Block("bar", bar, bars, SIGMA_BAR),
                                  Block("plane", planes, sel.data, SIGMA_PLANE, extras="tool")])
    assert model.size == 1  # one residual column each: no padding to mask
    J = np.asarray(_plan._jac(Problem(paper_robot, model, jnp.asarray(q), jnp.asarray(y), plan.space)))  # one program
    J = J.reshape(q.shape[0], -1)
    G = plan.prediction.information
    assert np.allclose(J.T @ J, G, rtol=1e-9, atol=1e-9 * np.abs(G).max())
    p = plan.space.n_free
    assert plan.prediction.rank == p and _scaled_rank(J.T @ J) == p
    assert _scaled_rank(J[40:].T @ J[40:]) == p - 1  # the plane rows alone: the length scale unseen
    assert np.all(np.isfinite(plan.prediction.param_std))
    # planned alone, plane contact identifies one parameter fewer (same candidates, nominal contacts)
    alone = predicted_accuracy_blocks(paper_robot, [Block("plane", planes, cand, sigma=SIGMA_PLANE, extras="tool")])
    assert len(alone.names) == p - 1
    # the prediction's σ: Σ = G⁻¹ (no prior)
    assert np.allclose(plan.prediction.covariance @ G, np.eye(p), atol=1e-6)


def test_plan_beats_random_candidates_on_the_combined_criterion(setup):
    """The jointly planned plane poses beat 5 random sets of 40 candidates on the combined
    D-criterion and on the predicted plane test RMSE, and the criterion is that of its selection."""
    *_, plan = setup
    assert plan.criterion_of(plan.selection.index) == pytest.approx(plan.criterion_value, rel=1e-12)
    assert plan.criterion_value > plan.fixed_value
    rng = np.random.default_rng(0)
    rand = [rng.choice(150, 40, replace=False) for _ in range(5)]
    values = [plan.criterion_of(i) for i in rand]
    assert plan.criterion_value > max(values), (plan.criterion_value, values)
    best = plan.prediction.block("plane").test_rmse
    assert best < min(plan.prediction_of(i).block("plane").test_rmse for i in rand)
    print(plan.table())


def test_budget_split_and_relations(paper_robot, setup):
    """Two planned blocks share one budget (the criterion picks the split); a relation's whitened row
    adds its rank-one information to the plane block's."""
    planes, bar, cand, bars, plan = setup
    split = plan_blocks(paper_robot, [Block("plane", planes, cand, sigma=SIGMA_PLANE, extras="tool"),
                                Block("bar", bar, bars, sigma=SIGMA_BAR)], 40, exchange=False)
    assert sum(split.split.values()) == 40 and min(split.split.values()) > 0, split.split
    idx = {k: s.index for k, s in split.selections.items()}
    assert split.criterion_of(idx) == pytest.approx(split.criterion_value, rel=1e-12)
    rng = np.random.default_rng(1)
    assert split.criterion_value > max(split.criterion_of({"plane": rng.choice(150, 20, replace=False),
                                                           "bar": rng.choice(40, 20, replace=False)})
                                       for _ in range(3))
    # a known angle between the table and a wall (their nominal one, 0.01°)
    n = np.asarray(planes.normals, np.float64)
    angle = float(np.degrees(np.arccos(np.clip(n[0] @ n[1], -1, 1))))
    blk = Block("plane", planes, cand, sigma=SIGMA_PLANE, extras="tool")
    without = predicted_accuracy_blocks(paper_robot, [blk])
    with_rel = predicted_accuracy_blocks(paper_robot, [blk],
                                         [PlaneAngle(planes.labels[0], planes.labels[1], angle, 0.01)])
    assert with_rel.names == without.names
    extra = with_rel.information - without.information
    ev = np.linalg.eigvalsh(extra)
    assert ev[-1] > 0 and np.all(np.abs(ev[:-1]) < 1e-9 * ev[-1])  # one whitened row: rank one
    assert np.all(with_rel.param_std <= without.param_std * (1 + 1e-9))


@pytest.mark.slow
def test_predicted_test_rmse_matches_simulated_fits(paper_robot, setup):
    """The combined prediction of each block's test RMSE against calibrate_blocks on 6 simulated true
    set-ups (the planned plane poses and the bar pairs moved onto the true robot's contacts / bar
    lengths plus noise, σ given), evaluated on fresh readings at the test poses (all 150 plane
    candidates, the 40 bar pairs). Measured: bar 0.02349 predicted vs 0.02361 mm simulated, plane
    0.05521 vs 0.05502 mm."""
    from jaxcal._core._params import Deviations, layout_for
    from jaxcal._simulation._simulate_sensors import _newton_step, _pair_step, _true_deviations

    planes, bar, cand, bars, plan = setup
    sel = plan.selection

    def on_plane(dev, data, key):
        q, k = jnp.asarray(data.q), jnp.asarray(np.round(np.asarray(data.y)).astype(int))
        target = SIGMA_PLANE * jax.random.normal(key, (q.shape[0], 1), q.dtype)
        for _ in range(31):
            q, err = _newton_step(paper_robot, dev, planes, q, k, target)
        assert float(jnp.max(err)) < 1e-8
        return np.asarray(q), np.asarray(data.y)

    def on_bar(dev, key):
        y = np.asarray(bars.y)
        qa, qb, L = jnp.asarray(bars.q), jnp.asarray(y[:, :paper_robot.dof]), y[:, paper_robot.dof]
        target = jnp.asarray(L + SIGMA_BAR * np.asarray(jax.random.normal(key, L.shape, qa.dtype)))[:, None]
        for _ in range(31):
            qb, err = _pair_step(paper_robot, dev, qa, qb, target)
        assert float(jnp.max(err)) < 1e-8
        return np.asarray(qa), np.concatenate([np.asarray(qb), L[:, None]], 1)

    rmse = {"bar": [], "plane": []}
    for s in range(6):
        ks = jax.random.split(jax.random.key(1000 + s), 5)
        truth = _true_deviations(ks[0], paper_robot, layout_for(paper_robot, planes), None, None, None, 2.0,
                                 jnp.float64)
        bl = layout_for(paper_robot, bar)
        tb = Deviations({g: truth.values[g] for g in bl.group_names}, bl)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = jaxcal.calibrate_blocks(paper_robot, [Block("bar", bar, on_bar(tb, ks[2]), sigma=SIGMA_BAR),
                                                  Block("plane", planes, on_plane(truth, sel.data, ks[1]),
                                                        sigma=SIGMA_PLANE, extras="tool")])
        model, q, y = combine(paper_robot, [Block("bar", bar, on_bar(tb, ks[4]), SIGMA_BAR),
                                      Block("plane", planes, on_plane(truth, cand, ks[3]), SIGMA_PLANE)])
        for name, r in zip(("bar", "plane"), model.block_residuals(paper_robot, res.deviations, q, y)):
            rmse[name].append(float(np.sqrt(np.mean(np.asarray(r) ** 2))))
    for name, vals in rmse.items():
        simulated = float(np.sqrt(np.mean(np.square(vals))))
        predicted = plan.prediction.block(name).test_rmse
        print(name, "predicted", predicted, "simulated", simulated, vals)
        assert abs(simulated / predicted - 1) < 0.15


def test_cli_plan_with_a_file_in_hand(paper_robot, setup, tmp_path, capsys):
    """`jaxcal plan --measurement plane --with bar.csv`: the combined table, a poses file that reads
    back as plane data touching the planes, and clear errors."""
    from jaxcal.cli import main

    planes, bar, cand, bars, plan = setup
    bar_file = tmp_path / "bar.csv"
    jaxcal.Dataset(bars.q, bars.y, "distance", {"noise_std_mm": str(SIGMA_BAR)}).to_csv(bar_file)
    out = tmp_path / "plane.csv"
    args = ["--no-cache", "plan", "--measurement", "plane", "--poses", "40", "--candidates", "150",  # the fixture's shapes
            "--noise-std", str(SIGMA_PLANE), "--with", str(bar_file), "--out", str(out)]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "combined information" in text and "predicted test RMSE bar / mm" in text and "| selected |" in text
    assert "--combine" in text
    data = jaxcal.load_csv(out, kind="plane")
    assert data.n == 40 and data.meta["planned_with"] == "bar.csv"
    pts = np.asarray(jaxcal.fk_pose(paper_robot, jnp.asarray(data.q), tool=True))[:, :3, 3]
    k = np.round(np.asarray(data.y)).astype(int)
    n, d = np.asarray(planes.normals), np.asarray(planes.offsets)
    assert np.max(np.abs(np.einsum("ij,ij->i", pts, n[k]) - d[k])) < 1e-6
    assert main([*args[:-2], "--with-sigma", "1", "--with-sigma", "2", "--out", str(out)]) == 2
    assert "one σ per --with file" in capsys.readouterr().err
