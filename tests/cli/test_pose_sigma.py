"""Pose data with a σ per component (issue 53): position σ (mm) and orientation σ (rad) estimated
from the data by variance components, the residual whitened with them, so that no noise mix breaks
the fit or ``jaxcal evaluate``'s "has the set-up changed" alarm (exit 3).

Before, one fixed weight of 1000 mm/rad and one σ̂ for the 6 entries: exact orientations (the
simulator's default) gave "residual σ̂ 0.1200 mm" beside a 0.78 mm train RMSE and exit 3 on new data
of the same set-up; 0.3 mm / 0.002° exit 3; 0.05 mm / 0.05° (a mocap rigid body) failed in
calibrate ("step budget exhausted", σ̂ 0.0000 mm). Each mix here, over a preset, a DH table file and
a URDF chain: the σ̂ of each component near the simulated σ, the held-out RMSE at the statistical
floor, and evaluate on a new day of the same set-up exits 0 with expected/measured in 0.8–1.25.
"""

import json
import math

import numpy as np
import pytest
from test_robot_types import _run, robot_type_args

import jaxcal

#: (position σ mm, orientation σ deg per axis): the simulator's default (exact orientations), a
#: precise orientation sensor beside a worse position, a mocap rigid body
MIXES = [(0.5, 0.0), (0.3, 0.002), (0.05, 0.05)]
SAMPLES = 150


@pytest.fixture(scope="module", params=["preset", "dh_file", "urdf"])
def robot_args(request, tmp_path_factory):
    """``--robot ...`` of each robot type (tests/cli/test_robot_types.py's)."""
    return robot_type_args(request.param, tmp_path_factory.mktemp(request.param))


@pytest.mark.parametrize("pos_mm,rot_deg", MIXES, ids=[f"{p}mm-{r}deg" for p, r in MIXES])
def test_pose_mix_calibrates_at_floor_and_evaluates_as_expected(robot_args, pos_mm, rot_deg, tmp_path, capsys):
    sim = ["simulate", *robot_args, "--measurement", "pose", "--samples", str(SAMPLES), "--seed", "1",
           "--noise-std", str(pos_mm)]
    if rot_deg:
        sim += ["--orientation-noise-deg", str(rot_deg)]
    assert _run([*sim, "--out", str(tmp_path / "a.csv")], capsys)[0] == 0
    code, out = _run(["calibrate", str(tmp_path / "a.csv"), *robot_args, "--measurement", "pose",
                      "--test-fraction", "0", "--out", str(tmp_path / "a.json")], capsys)
    assert code == 0, out.out + out.err
    assert "residual σ̂ per component: position" in out.out
    raw = json.loads((tmp_path / "a.json").read_text())
    comp = raw["uncertainty"]["noise_std_components"]
    assert raw["measurement"]["orientation_scale_estimated"] is True
    # σ̂ per component near the simulated σ (360 entries each: ~4 % sampling scatter)
    assert 0.85 < comp["position_mm"] / pos_mm < 1.15, comp
    if rot_deg:
        assert 0.85 < comp["orientation_deg"] / rot_deg < 1.15, comp
        w = raw["measurement"]["orientation_scale"]
        assert 0.8 < w / (pos_mm / math.radians(rot_deg)) < 1.25, w
    else:  # exact orientations: far below any sensor's, the weight at the end of its range
        assert comp["orientation_deg"] < 1e-3, comp
    # a new day of the same set-up: evaluate exits 0 and its expectation matches the measured RMSE
    assert _run(["simulate", "--like", str(tmp_path / "a.json"), "--seed", "2", "--out", str(tmp_path / "b.csv")],
                capsys)[0] == 0
    assert f"orientation_noise_std_deg: {rot_deg}" in (tmp_path / "b.csv").read_text() or not rot_deg
    code, out = _run(["evaluate", str(tmp_path / "a.json"), str(tmp_path / "b.csv"), "--out",
                      str(tmp_path / "e.json")], capsys)
    assert code == 0, out.out + out.err
    ev = json.loads((tmp_path / "e.json").read_text())
    measured, expected = ev["metrics_mm"]["after"]["rmse"], ev["expected_rmse_mm"]
    assert 0.8 < expected / measured < 1.25, (expected, measured)
    # at the statistical floor: the held-out position error is no worse than positions alone would
    # leave (every free parameter from the 3 position entries per row; the orientations only help)
    # and no better than the noise itself
    p = len(raw["uncertainty"]["std"])
    floor = jaxcal.statistical_floor(pos_mm, p, SAMPLES, 3)
    assert math.sqrt(3) * pos_mm * 0.9 < measured < floor.test * 1.1, (measured, floor)


def test_given_orientation_weight_stays(tmp_path):
    """A user's ``Pose(orientation_scale=...)`` is kept as given (no reweighting rounds); the
    default estimates it, from the same start and in the same compiled solve."""
    import jax

    from jaxcal._simulation._simulate import add_orientation_noise

    robot = jaxcal.robots.hsr_jr680()
    ex = jaxcal.simulate_experiment(jax.random.key(3), robot, n_samples=240, noise_std=0.2,
                                    measurement=jaxcal.Pose(), test_fraction=0.5)
    y = add_orientation_noise(ex.train.y, math.radians(0.01), 3)
    data = (np.asarray(ex.train.q), y)
    given = jaxcal.calibrate(robot, jaxcal.Pose(orientation_scale=1000.0), data)
    assert float(given.measurement.orientation_scale) == 1000.0 and given.measurement.orientation_scale_given
    est = jaxcal.calibrate(robot, jaxcal.Pose(), data)
    truth = 0.2 / math.radians(0.01)
    assert 0.8 < float(est.measurement.orientation_scale) / truth < 1.25
    # the saved result reads back with the weight the fit used, taken as given
    jaxcal.save_result(est, tmp_path / "r.json")
    back = jaxcal.load_result(tmp_path / "r.json")
    assert float(back.measurement.orientation_scale) == float(est.measurement.orientation_scale)
    assert back.uncertainty.component_std == pytest.approx(est.uncertainty.component_std)
