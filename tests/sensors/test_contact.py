"""Contact measurement models without a tracker (issue 23): plane contact and fixed points."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcal
import jaxcal.cli
from jaxcal import FixedPoint, PlaneContact, simulate_contact, statistical_floor
from jaxcal._calibration._io import load_result_dict
from jaxcal._core._params import Deviations, ParameterSpace, layout_for
from jaxcal._datasets._dataset import relabel
from jaxcal._sensors._contact import DistanceBar, default_setup, initial_contact, unobservable_directions
from jaxcal._simulation._simulate_sensors import simulate_distance
from jaxcal._simulation._truth import simulated_truth

SIGMA = 0.05


def _cli_at_floor(robot, kind, tmp_path, seed=3, radius_mm=None, calibrate_args=()):
    """`jaxcal simulate` + `jaxcal calibrate` (defaults: prior, Huber, extras from the data) → the
    test RMSE on 3000 fresh poses of the same true robot over the floor. ``radius_mm``: point data
    as spheres of that radius (``--radius-mm``)."""
    path, out = tmp_path / f"{kind}.csv", tmp_path / f"{kind}.json"
    sphere = [] if radius_mm is None else ["--radius-mm", str(radius_mm)]
    assert jaxcal.cli.main(["simulate", "--measurement", kind, "--samples", "300", "--noise-std", str(SIGMA),
                            "--seed", str(seed), "--out", str(path), *sphere]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = jaxcal.cli.main(["calibrate", str(path), "--robot", "hsr_jr680", "--measurement", kind,
                              "--test-fraction", "0", "--out", str(out), *calibrate_args])
    assert rc == 0
    res = jaxcal.load_result(out)
    if kind == "distance":
        truth = simulated_truth(jax.random.key(seed), robot, DistanceBar(robot.dof))  # the file's set-up
        big = simulate_distance(jax.random.key(1000 + seed), robot, n_samples=3000, noise_std=SIGMA,
                                true_deviations=truth, test_fraction=0.0).train
    else:
        m = default_setup(kind, robot)
        if radius_mm is not None:
            m = FixedPoint(m.labels, np.asarray(m.centres), radii_mm=radius_mm)
        truth = simulated_truth(jax.random.key(seed), robot, m)
        big = simulate_contact(jax.random.key(1000 + seed), robot, m, n_samples=3000, noise_std=SIGMA,
                               true_deviations=truth, test_fraction=0.0).train
        big = relabel(big, res.measurement.labels)
    rank = res.identifiability["rank"]
    floor = statistical_floor(SIGMA, rank, 300, res.measurement.size).test
    return res, res.evaluate(big).rmse / floor, truth


def test_plane_cli_three_planes_at_floor(paper_robot, tmp_path):
    res, ratio, truth = _cli_at_floor(paper_robot, "plane", tmp_path)
    print("plane: test RMSE / floor", ratio)
    assert abs(ratio - 1) < 0.03, ratio
    # the planes' extras are free (kept before robot parameters) and the tool point is close to the truth
    assert {"plane_d@table", "plane_u@wall_a", "tool_y"} <= set(res.space.free_names)
    tool = np.asarray(paper_robot.tool) + np.asarray(res.deviations.tool)
    assert np.max(np.abs(tool - (np.asarray(paper_robot.tool) + np.asarray(truth.tool)))) < 5.0


def test_point_cli_pivot_at_floor(paper_robot, tmp_path):
    res, ratio, _ = _cli_at_floor(paper_robot, "point", tmp_path)
    print("point: test RMSE / floor", ratio)
    assert abs(ratio - 1) < 0.03, ratio


@pytest.mark.parametrize("estimate", [pytest.param(False, marks=pytest.mark.slow), True])
def test_sphere_cli_at_floor(paper_robot, tmp_path, estimate):
    """A ball on the flange touching two fixed spheres, via the CLI: the radius from the file's
    '# radius_mm:' line (known), or unknown (--estimate radius with a nominal of 0 mm: started by a
    sphere fit to the data)."""
    res, ratio, _ = _cli_at_floor(paper_robot, "point", tmp_path, radius_mm=30.0,
                                  calibrate_args=["--estimate", "radius", "--radius-mm", "0"] if estimate else [])
    print("sphere: test RMSE / floor", ratio, "radius estimated" if estimate else "")
    assert res.measurement.sphere and res.measurement.size == 1
    assert res.measurement.estimate_radius == estimate
    if estimate:
        assert {"radius@p1", "radius@p2"} <= set(res.space.free_names)
        c, r = res.measurement.points(res.deviations)
        assert np.allclose(np.asarray(res.measurement.radii), 0.0)
        assert np.allclose(np.asarray(r), 30.0, atol=0.5)  # nominal 0: found by the data
    else:
        assert np.allclose(np.asarray(res.measurement.radii), 30.0)
    assert abs(ratio - 1) < 0.03, ratio


def test_one_plane_report_names_what_it_cannot_see(paper_robot):
    """One horizontal plane: rotation about its normal (θ_1) is invisible and d_1 is the plane's
    offset; the words name the in-plane translations and the turn about the normal. Three planes with
    independent normals: nothing left unseen."""
    m0 = default_setup("plane", paper_robot)
    one = PlaneContact(("table",), [[0.0, 0.0, 1.0]], [float(m0.offsets[0])])
    ex = simulate_contact(jax.random.key(5), paper_robot, one, n_samples=120, noise_std=SIGMA, test_fraction=0.0)
    space = ParameterSpace.for_robot(paper_robot, measurement=one, tool=True)
    rep = jaxcal.identifiability(paper_robot, one, ex.train.q, space, ex.true_deviations)
    assert "theta_1" in rep.unidentifiable
    assert "d_1" in rep.unidentifiable and any(n == "plane_d@table" for _, n in rep.dependencies["d_1"])
    words = unobservable_directions(np.asarray(one.normals))
    assert len(words) == 2 and "translation along the plane" in words[0] and "rotation about the plane normal" in words[1]
    assert "intersection line" in unobservable_directions([[0, 0, 1], [1, 0, 0]])[0]
    assert unobservable_directions(np.asarray(m0.normals)) == []


@pytest.mark.parametrize("kind", ["plane", "point", "sphere-unknown", "sphere-known"])
def test_contact_data_cannot_see_the_length_scale(paper_robot, kind):
    """Scaling every length of the set-up (DH a_i, d_i, tool, plane offsets / point centres / unknown
    radii) by the same factor keeps every contact: that direction is in the Jacobian's null space.
    A known sphere radius is a length reference and sees it."""
    p = default_setup("point", paper_robot)
    m = {"plane": default_setup("plane", paper_robot), "point": p,
         "sphere-unknown": FixedPoint(p.labels, np.asarray(p.centres), radii_mm=30.0, estimate_radius=True),
         "sphere-known": FixedPoint(p.labels, np.asarray(p.centres), radii_mm=30.0)}[kind]
    ex = simulate_contact(jax.random.key(0), paper_robot, m, n_samples=90, noise_std=0.0, test_fraction=0.0,
                          true_deviations=Deviations.zeros(layout_for(paper_robot, m)))
    space = ParameterSpace.for_robot(paper_robot, measurement=m, tool=True)
    pr = jaxcal.Problem(paper_robot, m, ex.train.q, ex.train.y, space)
    J = np.asarray(pr.jacobian(pr.x0()))
    nominal = {**{f"a_{i + 1}": v for i, v in enumerate(np.asarray(paper_robot.a))},
               **{f"d_{i + 1}": v for i, v in enumerate(np.asarray(paper_robot.d))},
               **{f"tool_{c}": v for c, v in zip("xyz", np.asarray(paper_robot.tool))}}
    if kind == "plane":
        nominal.update({f"plane_d@{s}": v for s, v in zip(m.labels, np.asarray(m.offsets))})
    else:
        nominal.update({f"point_{c}@{s}": v for s, row in zip(m.labels, np.asarray(m.centres)) for c, v in zip("xyz", row)})
        nominal.update({f"radius@{s}": v for s, v in zip(m.labels, np.asarray(m.radii))})
    v = np.array([nominal.get(n, 0.0) for n in space.free_names])  # d(scale): every length × (1 + ε)
    rel = np.linalg.norm(J @ v) / (np.linalg.norm(J, axis=0) @ np.abs(v))
    if kind == "sphere-known":
        assert rel > 1e-3, rel
    else:
        assert rel < 1e-12, rel


def test_closed_form_starts_recover_planes_points_and_tool(paper_robot):
    """Noise-free data on the nominal robot: SVD plane fit + linear tool solve, and the linear pivot
    solve, give the true planes / centres and tool point."""
    m = default_setup("plane", paper_robot)
    layout_truth = jaxcal.Deviations({"tool": jnp.array([3.0, -2.0, 1.5])},
                                     jaxcal._core._params.layout_for(paper_robot, m))
    ex = simulate_contact(jax.random.key(7), paper_robot, m, n_samples=90, noise_std=0.0, test_fraction=0.0,
                          true_deviations=layout_truth)
    cm = PlaneContact.from_dataset(ex.train)
    est = initial_contact(paper_robot, cm, ex.train, estimate=("plane", "tool"))
    assert est.rmse_after < 1e-6
    np.testing.assert_allclose(np.asarray(est.deviations.tool), [3.0, -2.0, 1.5], atol=1e-6)
    n, d = cm.planes(est.deviations)
    np.testing.assert_allclose(np.asarray(n), np.asarray(m.normals), atol=1e-9)
    np.testing.assert_allclose(np.asarray(d), np.asarray(m.offsets), atol=1e-6)
    p = default_setup("point", paper_robot)
    truth = jaxcal.Deviations({"tool": jnp.array([3.0, -2.0, 1.5])}, jaxcal._core._params.layout_for(paper_robot, p))
    # 90 rows like the plane data here and the length-scale test's data: the same simulation programs
    ex = simulate_contact(jax.random.key(8), paper_robot, p, n_samples=90, noise_std=0.0, test_fraction=0.0,
                          true_deviations=truth)
    cp = FixedPoint.from_dataset(ex.train)
    est = initial_contact(paper_robot, cp, ex.train, estimate=("point", "tool"))
    np.testing.assert_allclose(np.asarray(est.deviations.tool), [3.0, -2.0, 1.5], atol=1e-6)
    c, _ = cp.points(est.deviations)
    np.testing.assert_allclose(np.asarray(c), np.asarray(p.centres), atol=1e-6)


def test_csv_round_trip_and_relabel(paper_robot, tmp_path):
    m = default_setup("plane", paper_robot)
    # 24 rows, like the hidden plane rows of test_evaluate_expects_the_floor...: the same simulation programs
    ex = simulate_contact(jax.random.key(9), paper_robot, m, n_samples=24, noise_std=SIGMA, test_fraction=0.0)
    path = tmp_path / "p.csv"
    ex.train.to_csv(path)
    text = path.read_text()
    assert any(line.endswith(",plane") for line in text.splitlines())
    back = jaxcal.load_csv(path)
    assert back.kind == "plane" and back.meta["plane_labels"] == "table,wall_a,wall_b"
    np.testing.assert_array_equal(np.asarray(back.y), np.asarray(ex.train.y))
    other = relabel(back, ("wall_b", "table", "wall_a"))
    # each residual as one compiled program (op by op, each operation compiled a program of its own)
    r0 = jax.jit(lambda dev, q, y: m.residual(paper_robot, dev, q, y))(ex.true_deviations, back.q, back.y)
    m2 = PlaneContact(("wall_b", "table", "wall_a"), np.asarray(m.normals)[[2, 0, 1]], np.asarray(m.offsets)[[2, 0, 1]])
    r2 = jax.jit(lambda dev, q, y: m2.residual(paper_robot, dev, q, y))(ex.true_deviations.replace(), other.q, other.y)
    np.testing.assert_allclose(np.asarray(r2), np.asarray(r0), atol=1e-9)


def test_distance_cli_at_floor_and_blind_to_the_base(paper_robot, tmp_path):
    """Bar data: at the floor; θ_1 and d_1 (the base frame) have no effect on any distance."""
    res, ratio, truth = _cli_at_floor(paper_robot, "distance", tmp_path)
    print("distance: test RMSE / floor", ratio)
    assert abs(ratio - 1) < 0.03, ratio
    # evaluate on hidden bar rows: the tool was estimated (part of the robot, kept), nothing to register;
    # the expectation counts each row's own second pose and length
    # 300 rows, like the calibration data: the same simulation programs (60 rows compiled their own)
    hidden = simulate_distance(jax.random.key(4), paper_robot, n_samples=300, noise_std=SIGMA, test_fraction=0.0,
                               true_deviations=truth).train
    ev = jaxcal.evaluate_result(res, hidden)
    assert ev.extras == "none" and ev.kept == ("tool",) and "no sensor extras were estimated" not in ev.message
    assert "tool from the result" in ev.table() and "nothing estimated" not in ev.table()
    assert not ev.worse_than_expected and ev.expected_rmse == pytest.approx(ev.after.rmse, rel=0.25)
    deps = res.identifiability["dependencies"]
    assert {"theta_1", "d_1"} <= set(res.identifiability["unidentifiable"])
    assert deps.get("theta_1") in ([], None, {}) and deps.get("d_1") in ([], None, {})
    std = load_result_dict(tmp_path / "distance.json")["uncertainty"]["std"]
    assert all(v is not None and np.isfinite(v) for v in std.values())  # a round-off column made every σ inf


@pytest.mark.slow  # default-run time (issue 25: keep it near 10 min on 2 cores)
def test_sphere_start_and_robust_fit_with_an_outlier(paper_robot):
    """A flange ball on two spheres of unknown radius: the algebraic start + Gauss–Newton finds
    centres and radii; one gross outlier row (a wrong label) does not move a Huber fit away from
    the floor, while plain least squares is pulled off."""
    p = default_setup("point", paper_robot)
    m = FixedPoint(p.labels, np.asarray(p.centres), [30.0, 45.0])
    ex = simulate_contact(jax.random.key(11), paper_robot, m, n_samples=200, noise_std=SIGMA, test_fraction=0.0)
    cm = FixedPoint(m.labels, radii_mm=[0.0, 0.0], estimate_radius=True)
    est = initial_contact(paper_robot, cm, ex.train, estimate=("point",))
    c, r = cm.points(est.deviations)
    np.testing.assert_allclose(np.asarray(r), [30.0, 45.0], atol=2.0)
    np.testing.assert_allclose(np.asarray(c), np.asarray(m.centres), atol=3.0)
    y = np.asarray(ex.train.y).copy()
    y[0] = 1.0 - y[0]  # one row names the wrong sphere: a gross outlier (~400 mm)
    bad = jaxcal.Dataset(ex.train.q, y, "point", ex.train.metadata)
    big = simulate_contact(jax.random.key(12), paper_robot, m, n_samples=2000, noise_std=SIGMA,
                           true_deviations=ex.true_deviations, test_fraction=0.0).train
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        hub = jaxcal.calibrate(paper_robot, cm, bad, "lm", extras=["tool"], prior="default", loss="huber")
        lin = jaxcal.calibrate(paper_robot, cm, bad, "lm", extras=["tool"], prior="default", loss="linear")
    floor = statistical_floor(SIGMA, hub.identifiability.rank, 199, 1).test
    assert hub.evaluate(big).rmse < 1.1 * floor
    assert lin.evaluate(big).rmse > 2 * floor
    assert np.all(np.isfinite(hub.uncertainty.std[[i for i, n in enumerate(hub.space.free_names) if "@" in n]]))


def test_evaluate_expects_the_floor_and_flags_a_remounted_probe(paper_robot, tmp_path, capsys):
    """`evaluate` of a plane-contact calibration on hidden rows: with the result's planes the RMSE
    it expects is near the measured one (each row counted on its own plane: with every row on the
    first plane it expected ~20× too much), and a probe remounted 2 mm longer is flagged by the
    library and by `jaxcal evaluate` (a warning naming the ratio, exit status 3)."""
    m = default_setup("plane", paper_robot)
    ex = simulate_contact(jax.random.key(3), paper_robot, m, n_samples=90, noise_std=SIGMA, test_fraction=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = jaxcal.calibrate(paper_robot, PlaneContact.from_dataset(ex.train), ex.train, "lm", extras=["tool"],
                               objective="measured")
    truth = ex.true_deviations
    hidden = simulate_contact(jax.random.key(4), paper_robot, m, n_samples=24, noise_std=SIGMA, test_fraction=0.0,
                              true_deviations=truth).train
    same = jaxcal.evaluate_result(res, hidden, extras="result")
    print(f"same set-up: measured {same.after.rmse:.4f} mm, expected {same.expected_rmse:.4f} mm")
    # 24 rows: their RMSE scatters by ~15 % (1 sd); the old expectation was ~20× the measured one
    assert not same.worse_than_expected and 1 / 1.6 < same.expected_rmse / same.after.rmse < 1.6
    assert same.kept == ("tool",) and "tool from the result" in same.table()
    remounted = truth.replace(tool=truth.values["tool"] + jnp.array([0.0, 0.0, 2.0]))
    new = simulate_contact(jax.random.key(5), paper_robot, m, n_samples=24, noise_std=SIGMA, test_fraction=0.0,
                           true_deviations=remounted).train
    ev = jaxcal.evaluate_result(res, new)  # the planes registered again: the tool is part of the robot
    print(f"probe 2 mm longer: measured {ev.after.rmse:.4f} mm, expected {ev.expected_rmse:.4f} mm")
    assert ev.extras == "registered" and ev.worse_than_expected and ev.after.rmse > 5 * ev.expected_rmse
    jaxcal.save_result(res, tmp_path / "r.json")
    new.to_csv(tmp_path / "new.csv")
    capsys.readouterr()
    assert jaxcal.cli.main(["evaluate", str(tmp_path / "r.json"), str(tmp_path / "new.csv")]) == 3
    err = capsys.readouterr().err
    assert "worse than the calibration predicts" in err and "exit status 3" in err


def test_evaluate_expects_the_floor_on_spheres_and_flags_a_remounted_probe(paper_robot):
    """`evaluate` of a sphere-contact calibration (a flange ball on two spheres of unknown radius,
    300 rows): the RMSE it expects on fresh rows of the same true set-up, with the result's spheres and
    with the spheres registered again, within 15 % of a Monte Carlo of fresh data sets (6 sets of 24
    rows from one simulation: 0.94 and 0.92 of it here; with every row counted on the first sphere, as
    before the rows' own labels were used, the result's spheres expected 6.6×), and a probe remounted
    2 mm longer still flagged (5×).
    (With 90 training rows under the measured-data defaults the expectation came out 19 % low over 6
    training seeds, with σ̂ under the Huber loss 0.039-0.053 mm for σ = 0.05, below the training RMSE in
    4 of 6; with a linear loss and the prior 0.98 / 1.04 of the Monte Carlo; planes at 90 rows: 3 %.)"""
    p = default_setup("point", paper_robot)
    m = FixedPoint(p.labels, np.asarray(p.centres), radii_mm=30.0)
    ex = simulate_contact(jax.random.key(3), paper_robot, m, n_samples=300, noise_std=SIGMA, test_fraction=0.0)
    fit_model = FixedPoint(m.labels, np.asarray(m.centres), radii_mm=30.0, estimate_radius=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = jaxcal.calibrate(paper_robot, fit_model, ex.train, "lm", extras=["tool"], objective="measured")
    truth = ex.true_deviations
    fresh = simulate_contact(jax.random.key(4), paper_robot, m, n_samples=144, noise_std=SIGMA, test_fraction=0.0,
                             true_deviations=truth).train
    for extras in ("result", "register"):
        evs = [jaxcal.evaluate_result(res, fresh.subset(np.arange(k, 144, 6)), extras=extras) for k in range(6)]
        measured = float(np.sqrt(np.mean([e.after.rmse ** 2 for e in evs])))
        expected = float(np.mean([e.expected_rmse for e in evs]))
        print(f"spheres, extras {extras}: Monte Carlo {measured:.4f} mm, expected {expected:.4f} mm")
        assert abs(expected / measured - 1) < 0.15, (extras, expected, measured)
    assert evs[0].registered == ("point@p1", "radius@p1", "point@p2", "radius@p2")
    remounted = truth.replace(tool=truth.values["tool"] + jnp.array([0.0, 0.0, 2.0]))
    new = simulate_contact(jax.random.key(5), paper_robot, m, n_samples=24, noise_std=SIGMA, test_fraction=0.0,
                           true_deviations=remounted).train
    ev = jaxcal.evaluate_result(res, new)  # the spheres registered again: the tool is part of the robot
    print(f"spheres, probe 2 mm longer: measured {ev.after.rmse:.4f} mm, expected {ev.expected_rmse:.4f} mm")
    assert ev.extras == "registered" and ev.worse_than_expected and ev.after.rmse > 5 * ev.expected_rmse
