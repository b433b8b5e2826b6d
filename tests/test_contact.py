"""Contact measurement models without a tracker (issue 23): plane contact and fixed points."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcal
import jaxcal.cli
from jaxcal import FixedPoint, PlaneContact, simulate_contact, statistical_floor
from jaxcal._contact import default_setup, initial_contact, relabel, unobservable_directions
from jaxcal._params import ParameterSpace

SIGMA = 0.05


@pytest.fixture(scope="module")
def robot():
    return jaxcal.robots.hsr_jr680()


def _cli_at_floor(robot, kind, tmp_path, seed=3):
    """`jaxcal simulate` + `jaxcal calibrate` (defaults: prior, Huber, extras from the data) → the
    test RMSE on 3000 fresh poses of the same true robot over the floor."""
    path, out = tmp_path / f"{kind}.csv", tmp_path / f"{kind}.json"
    assert jaxcal.cli.main(["simulate", "--measurement", kind, "--samples", "300", "--noise-std", str(SIGMA),
                            "--seed", str(seed), "--out", str(path)]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = jaxcal.cli.main(["calibrate", str(path), "--robot", "hsr_jr680", "--measurement", kind,
                              "--test-fraction", "0", "--out", str(out)])
    assert rc == 0
    res = jaxcal.load_result(out)
    m = default_setup(kind, robot)
    truth = simulate_contact(jax.random.key(seed), robot, m, n_samples=300, noise_std=SIGMA).true_deviations
    big = simulate_contact(jax.random.key(1000 + seed), robot, m, n_samples=3000, noise_std=SIGMA,
                           true_deviations=truth, test_fraction=0.0).train
    big = relabel(big, res.measurement.labels)
    rank = res.identifiability["rank"]
    floor = statistical_floor(SIGMA, rank, 300, res.measurement.size).test
    return res, res.evaluate(big).rmse / floor, truth


def test_plane_cli_three_planes_at_floor(robot, tmp_path):
    res, ratio, truth = _cli_at_floor(robot, "plane", tmp_path)
    print("plane: test RMSE / floor", ratio)
    assert abs(ratio - 1) < 0.03, ratio
    # the planes' extras are free (kept before robot parameters) and the tool point is close to the truth
    assert {"plane_d@table", "plane_u@wall_a", "tool_y"} <= set(res.space.free_names)
    tool = np.asarray(robot.tool) + np.asarray(res.deviations.tool)
    assert np.max(np.abs(tool - (np.asarray(robot.tool) + np.asarray(truth.tool)))) < 5.0


def test_point_cli_pivot_at_floor(robot, tmp_path):
    res, ratio, _ = _cli_at_floor(robot, "point", tmp_path)
    print("point: test RMSE / floor", ratio)
    assert abs(ratio - 1) < 0.03, ratio
