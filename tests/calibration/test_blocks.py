"""Several data blocks in one fit, per-block σ by variance components, known relations (issue 34)."""

import dataclasses
import warnings

import jax
import numpy as np
import pytest

import jaxcal
from jaxcal import (
    Block,
    DistanceBar,
    FixedPoint,
    KnownDistance,
    block_result,
    calibrate_blocks,
    combined_floor,
    evaluate_result,
)
from jaxcal._calibration._blocks import block_information, free_scale_direction, length_scale_direction, scale_shares
from jaxcal._core._params import Deviations, ParameterSpace, layout_for
from jaxcal._sensors._blocks import combine
from jaxcal._sensors._contact import default_setup
from jaxcal._simulation._simulate_sensors import simulate_contact, simulate_distance

SIGMA_PLANE, SIGMA_BAR = 0.05, 0.02


def _dh_only(robot, dev):
    layout = layout_for(robot)
    return Deviations({g: v for g, v in dev.values.items() if g in layout.group_names}, layout)


def _plane_and_bar(robot, seed, n, truth=None):
    planes = default_setup("plane", robot)
    ex = simulate_contact(jax.random.key(seed), robot, planes, n_samples=n, noise_std=SIGMA_PLANE, test_fraction=0.0,
                          true_deviations=truth)
    bar = simulate_distance(jax.random.key(100 + seed), robot, n_samples=n, noise_std=SIGMA_BAR, test_fraction=0.0,
                            true_deviations=_dh_only(robot, ex.true_deviations))
    return planes, ex.train, bar.train, ex.true_deviations


def _fit(robot, planes, plane_data, bar_data, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return calibrate_blocks(robot, [Block("plane", planes, plane_data, extras="tool"),
                                        Block("bar", DistanceBar(robot.dof), bar_data)], **kw)


def _stacked(pd, bd):
    """The combined rows ``(q, y)`` of plane data ``pd`` and bar data ``bd`` (plane labels padded)."""
    return np.concatenate([pd.q, bd.q]), np.concatenate([np.pad(np.asarray(pd.y)[:, None], ((0, 0), (0, 6))), bd.y])


def test_plane_and_distance_bar_at_the_combined_floor_with_sigma_estimated(paper_robot):
    """Plane contact + a distance bar sharing the robot and the probe: σ of each block estimated by
    variance components (within 5 % of the truth on 3 seeds), and on fresh data of the same true
    set-up the whitened RMS (each block over its true σ) at the combined problem's floor (3 %)."""
    n = 800
    for seed in range(3):
        planes, pd, bd, truth = _plane_and_bar(paper_robot, seed, n)
        res = _fit(paper_robot, planes, pd, bd)
        est = {s.name: s for s in res.blocks}
        print(seed, [s.line() for s in res.blocks], res.variance_rounds, res.block_report)
        assert abs(est["plane"].sigma_hat / SIGMA_PLANE - 1) < 0.05
        assert abs(est["bar"].sigma_hat / SIGMA_BAR - 1) < 0.05
        # who sees what: a plane's offset only the plane rows; the bar rows never the base rotation θ_1
        assert est["plane"].information["plane_d@table"] == pytest.approx(1.0)
        assert est["bar"].information["plane_d@table"] == pytest.approx(0.0)
        assert est["bar"].information.get("theta_1", 0.0) < 1e-9
        assert any(line.startswith("plane alone determines: ") and "plane_d@table" in line for line in res.block_report)
        # the length scale, which plane contact cannot see, is set by the bar rows: a direction of
        # several lengths that the bar alone determines
        scale = [terms for share, terms in est["bar"].directions if any(n[:2] in ("a_", "d_") for _, n in terms)]
        assert scale, res.block_report
        assert any(line.startswith("bar alone determines the direction") for line in res.block_report)
        # in words: the length scale is set by the bar (its share of the information along every length
        # times 1 + ε); the plane rows alone give it only their own residuals' worth (J·v = r): unseen
        assert est["bar"].scale_seen and est["bar"].scale_share > 0.99 and est["plane"].scale_share < 0.01
        line = [s for s in res.block_report if s.startswith("length scale: ")]
        assert line and line[0].startswith("length scale: set by bar ("), res.block_report
        if seed == 0:
            # the direction: every length at its absolute value (held ones, d_1 and d_6 here, moved onto
            # the free parameters that stand in for them); along it each plane residual changes by
            # itself (J·v = r), so the plane rows' information along it is their own RSS
            r, every = block_information(res, res.measurement, *_stacked(pd, bd), every=True)
            full = ParameterSpace.from_names(res.space.layout, res.space.layout.names)
            v_all = length_scale_direction(paper_robot, res.measurement, res.deviations, full)
            assert v_all[full.free_names.index("a_2")] == pytest.approx(float(paper_robot.a[1] + res.deviations.a[1]))
            assert v_all[full.free_names.index("theta_2")] == 0.0
            v = free_scale_direction(v_all, every, res.space.free)
            idx = res.space.free_index
            grams = every[:, idx][:, :, idx]
            rss_plane = float(np.sum(r[: pd.q.shape[0]] ** 2))
            assert abs(v @ grams[0] @ v / rss_plane - 1) < 0.01, (v @ grams[0] @ v, rss_plane)
            assert not scale_shares(grams[:1], v, rss_plane)[1]  # the plane block's information alone
            assert scale_shares(grams, v, float(np.sum(r**2)))[1]
        # and within 2 % of the noise these rows really carry (the RMS residual of the true set-up)
        model = res.measurement
        layout = res.space.layout
        t = Deviations({g: v for g, v in truth.values.items() if g in layout.group_names}, layout)
        q, y = _stacked(pd, bd)
        realised = [float(np.sqrt(np.mean(np.asarray(r) ** 2))) for r in model.block_residuals(paper_robot, t, q, y)]
        assert abs(est["plane"].sigma_hat / realised[0] - 1) < 0.02 and abs(est["bar"].sigma_hat / realised[1] - 1) < 0.02
        assert not est["plane"].sigma_given and est["plane"].kind == "plane" and est["bar"].unit == "mm"
        # the redundancies share the residual degrees of freedom: Σ r_b = N − rank J (p, or one less
        # where the Jacobian is numerically rank deficient: d_2/d_3 of the parallel axes 2 and 3)
        total = sum(s.redundancy for s in res.blocks)
        assert 2 * n - res.space.n_free - 1e-6 <= total <= 2 * n - res.space.n_free + 1 + 1e-6, total
        if seed == 0:  # 2 × n fresh rows per sensor, drawn at the training shapes (programs compiled once)
            r = []
            for fresh_seed in (50, 51):
                _, tp, tb, _ = _plane_and_bar(paper_robot, fresh_seed, n, truth=truth)
                model, q, y = combine(paper_robot, [Block("plane", planes, tp, SIGMA_PLANE),
                                              Block("bar", DistanceBar(paper_robot.dof), tb, SIGMA_BAR)])
                r.append(np.asarray(model.residual(paper_robot, res.deviations, q, y)))
            floor = combined_floor(res.identifiability.rank, 2 * n).test
            ratio = float(np.sqrt(np.mean(np.concatenate(r) ** 2))) / floor
            print("whitened test RMS / combined floor", ratio)
            assert abs(ratio - 1) < 0.03, ratio


SIGMA_BALL, SOCKETS_MM = 0.02, 50.0


def _plates(rng, mid, n):
    """``n`` plate placements: two socket centres 50 mm apart, the plate somewhere in the middle of the
    workspace and turned about the vertical."""
    out = []
    for _ in range(n):
        c = mid + rng.uniform(-150, 150, 3) * [1, 1, 0.5]
        t = rng.uniform(0, np.pi)
        u = np.array([np.cos(t), np.sin(t), rng.uniform(-0.1, 0.1)])
        u *= SOCKETS_MM / 2 / np.linalg.norm(u)
        out += [c - u, c + u]
    return np.asarray(out)


def _register(robot, res, model, data):
    """The held-out sockets registered with the calibrated robot fixed (pivot: each centre the mean of its
    rows' tool points) → (centres [K, 3], per-entry RMS of p − c over the rows)."""
    from jaxcal._models._kinematics import tool_point_soa

    dev = Deviations({g: res.deviations.values[g] for g in layout_for(robot).group_names}, layout_for(robot))
    p = np.stack([np.asarray(v) for v in tool_point_soa(robot, dev, data.q)], -1)
    lab = np.asarray(data.y).astype(int)
    c = np.stack([p[lab == k].mean(0) for k in range(len(model.labels))])
    return c, float(np.sqrt(np.mean((p - c[lab]) ** 2)))


@pytest.fixture(scope="module")
def sockets(paper_robot):
    """Ball-in-socket data: the robot's links 1.5 % longer than nominal, a ball 80 mm off the flange,
    four training plate placements (labels a0, b0 … a3, b3: 320 rows) and two held-out ones
    (a4, b4, a5, b5: 160 rows), σ = 0.02 mm per axis."""
    from jaxcal._simulation._simulate import draw_deviations

    rng = np.random.default_rng(7)
    mid = np.asarray(default_setup("point", paper_robot).centres).mean(0)
    truth = draw_deviations(jax.random.key(3), paper_robot, angle_std_deg=0.05, length_std_mm=0.2)
    scale = 0.015
    truth = truth.replace(a=np.asarray(truth.a) + scale * np.asarray(paper_robot.a),
                          d=np.asarray(truth.d) + scale * np.asarray(paper_robot.d), tool=np.array([3.0, -2.0, 80.0]))
    train_labels = tuple(f"{s}{k}" for k in range(4) for s in "ab")
    test_labels = tuple(f"{s}{k}" for k in range(4, 6) for s in "ab")
    centres = _plates(rng, mid, 6)
    assert np.allclose(np.linalg.norm(centres[1::2] - centres[::2], axis=1), SOCKETS_MM)
    sims = []
    for labels, c, n, seed in ((train_labels, centres[:8], 320, 11), (test_labels, centres[8:], 160, 12)):
        m = FixedPoint(labels, c)
        layout = layout_for(paper_robot, m)
        t = Deviations({g: v for g, v in truth.values.items() if g in layout.group_names}, layout)
        sims.append((m, simulate_contact(jax.random.key(seed), paper_robot, m, n_samples=n, noise_std=SIGMA_BALL,
                                         test_fraction=0.0, true_deviations=t).train))
    return sims


def test_ball_in_socket_known_distance_sets_the_scale(paper_robot, sockets):
    """A ball on the flange put many times into two sockets 50.00 mm apart, four plate placements;
    the robot's links 1.5 % longer than nominal (a length scale pivot points cannot see). With the
    known distances, two held-out placements' socket distances come out within 0.05 mm and their
    consistency at the floor; without them the scale error shows (≈ 0.75 mm short)."""
    (m_train, train), (m_test, test) = sockets
    train_labels, test_labels = m_train.labels, m_test.labels
    fit_model = FixedPoint(train_labels)  # centres unknown: started from the data
    rel = [KnownDistance(f"a{k}", f"b{k}", SOCKETS_MM) for k in range(4)]
    out = {}
    for name, relations in (("with", rel), ("without", ())):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            # the measured-data defaults (prior toward the nominal lengths + Huber), as the CLI: without
            # the relation the prior, not the data, holds the scale at nominal
            res = calibrate_blocks(paper_robot, [Block("sockets", fit_model, train, extras="tool")], relations,
                                   objective="measured")
        c, rms = _register(paper_robot, res, m_test, test)
        err = np.linalg.norm(c[1::2] - c[::2], axis=1) - SOCKETS_MM
        if name == "with":  # the library's evaluate registers the held-out file's own labels by name
            ev = evaluate_result(block_result(res, "sockets"), test)
            assert set(ev.registered) == {f"point@{s}" for s in test_labels}
            got = np.stack([np.asarray(ev.deviations_after.values[f"point@{s}"]) for s in test_labels])
            np.testing.assert_allclose(got, c, atol=2e-3)  # least squares vs the rows' mean: both the pivot
        n_test, K = test.q.shape[0], len(test_labels)
        floor = SIGMA_BALL * np.sqrt(1 - K / n_test)  # per entry, the centres registered
        out[name] = (err, rms / floor, res)
        print(name, "held-out socket distance error (mm)", err, "consistency / floor", rms / floor,
              [s.line() for s in res.blocks])
    err, ratio, res = out["with"]
    assert res.uncertainty is not None  # the robust (Huber) consistency draws whole copies of the blocks' rows
    assert np.max(np.abs(err)) <= 0.05, err
    assert abs(ratio - 1) < 0.05, ratio
    sock = {s.name: s for s in res.blocks}["sockets"]
    # who sees what: the 4 relation rows alone set the length scale, which the 960 pivot residuals
    # cannot see: without them the data lose a direction of the lengths
    rel_stats = {s.name: s for s in res.blocks}["relations"]
    print(res.block_report)
    assert rel_stats.rank_without == rel_stats.rank - 1
    assert rel_stats.directions and rel_stats.directions[0][0] > 0.999
    assert any(n[:2] in ("a_", "d_") for _, n in rel_stats.directions[0][1]), rel_stats.directions
    assert "without relations: 1 direction not identifiable" in " ".join(res.block_report)
    assert abs(sock.sigma_hat / SIGMA_BALL - 1) < 0.1
    err0, _, _ = out["without"]
    assert np.all((err0 < -0.5) & (err0 > -1.0)), err0  # the nominal scale: the sockets come out ~1.5 % short


def test_combined_model_whitens_renames_and_names_errors(paper_robot):
    """The combined residual is each block's own residual over its σ (padded rows and columns left
    out by observed()); two trackers get their own frames, the tool is shared unless a block says
    own_tool; a relation naming a point no block has, or a label defined two ways, is refused."""
    from jaxcal import Position
    from jaxcal._simulation._simulate import simulate_experiment

    ex = simulate_experiment(jax.random.key(0), paper_robot, n_samples=12, noise_std=0.1, measurement=Position())
    pts = FixedPoint(("s1", "s2"), np.zeros((2, 3)))
    lab = np.arange(12) % 2.0
    blocks = [Block("t1", Position(), ex.train, 0.1), Block("t2", Position(), ex.train, 0.3, own_tool=True),
              Block("pivot", pts, (np.asarray(ex.train.q), lab[: ex.train.q.shape[0]]), 0.05)]
    model, q, y = combine(paper_robot, blocks, [KnownDistance("s1", "s2", 50.0, 0.01)])
    names = set(layout_for(paper_robot, model).names)
    assert {"base_rx@t1", "base_z@t2", "tool_x@t2", "point_x@s1", "tool_x"} <= names
    assert "tool_x@t1" not in names and "tool_x@pivot" not in names
    dev = Deviations.zeros(layout_for(paper_robot, model))
    r = np.asarray(model.residual(paper_robot, dev, q, y))
    n = ex.train.q.shape[0]
    own = np.asarray(Position().residual(paper_robot, None, ex.train.q, ex.train.y))
    assert np.allclose(r[:n], own / 0.1) and np.allclose(r[n:2 * n], own / 0.3)
    obs = model.observed(y)
    assert obs[:3 * n].all() and obs[-1].tolist() == [True, False, False]  # a pivot row: 3 entries; a relation: 1
    assert np.isclose(r[-1, 0], (0.0 - 50.0) / 0.01)  # both points at the origin: distance 0
    # padded to a bucket: the padding rows repeat row 0 and are cut off again
    padded = model.pad_rows(q.shape[0], q.shape[0] + 5)
    qp, yp = np.concatenate([q, np.repeat(q[:1], 5, 0)]), np.concatenate([y, np.repeat(y[:1], 5, 0)])
    rp = np.asarray(padded.residual(paper_robot, dev, qp, yp))
    assert np.allclose(rp[: q.shape[0]], r) and np.allclose(rp[q.shape[0]:], r[:1])
    with pytest.raises(ValueError, match="names point 'nope', which no block has"):
        combine(paper_robot, blocks, [KnownDistance("s1", "nope", 50.0)])
    moved = FixedPoint(("s1",), np.ones((1, 3)))
    with pytest.raises(ValueError, match="point 's1' is in block 'pivot' and block 'other' with different nominal"):
        combine(paper_robot, [*blocks, Block("other", moved, (np.asarray(ex.train.q), np.zeros(n)))])
    sphere = FixedPoint(("s1",), np.zeros((1, 3)), radii_mm=10.0, estimate_radius=True)
    with pytest.raises(ValueError, match="defined differently|block names must differ"):
        combine(paper_robot, [*blocks, Block("t1", sphere, (np.asarray(ex.train.q), np.zeros(n)))])


def test_relations_file(tmp_path):
    from jaxcal import PlaneAngle, PlaneDistance, PointOnPlane, load_relations

    path = tmp_path / "relations.txt"
    path.write_text("# plate\ndistance a0 b0 50.00 0.005\nplane_distance top, bottom, 25\n"
                    "plane_angle wall_a wall_b 90 0.01  # a cube\npoint_on_plane p1 table\n")
    rel = load_relations(path)
    assert rel == [KnownDistance("a0", "b0", 50.0, 0.005), PlaneDistance("top", "bottom", 25.0),
                   PlaneAngle("wall_a", "wall_b", 90.0, 0.01), PointOnPlane("p1", "table")]
    assert np.isclose(rel[2].target, np.pi / 2) and np.isclose(rel[2].std, np.radians(0.01))
    path.write_text("diameter a0 b0 50\n")
    with pytest.raises(ValueError, match="line 1: expected one of distance"):
        load_relations(path)
    path.write_text("distance a0 b0 -5\n")
    with pytest.raises(ValueError, match="finite number > 0"):
        load_relations(path)
    # their values on a known geometry (closed forms): a 25 mm block with outward faces, two walls at
    # 90°, a point on a table
    from jaxcal import PlaneContact
    from jaxcal._sensors._blocks import Relations

    planes = PlaneContact(("top", "bottom", "wall_a", "wall_b", "table"),
                          [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [25.0, 0.0, 0.0, 0.0, 3.0])
    pts = FixedPoint(("a0", "b0", "p1"), [[0, 0, 0], [30, 40, 0], [1, 2, 3]])
    with pytest.raises(ValueError, match="names plane 'nope'"):
        Relations([PlaneDistance("top", "nope", 1.0)], [planes, pts])
    values = np.asarray(Relations(rel, [planes, pts]).values(None))
    assert np.allclose(values, [50.0, 25.0, np.pi / 2, 0.0])


def test_cli_combine_with_relations_and_evaluate_new_labels(paper_robot, sockets, tmp_path, capsys):
    """`jaxcal calibrate sockets.csv --combine --relations rel.txt --out-dir DIR`, then `jaxcal evaluate`
    on a file with new point labels (two new plate placements): they are registered on its rows, and
    their registered sockets are 50 mm apart (the relation set the scale)."""
    import json

    import jaxcal.cli

    (_, train), (_, test) = sockets
    train.to_csv(tmp_path / "sockets.csv")
    test.to_csv(tmp_path / "held_out.csv")
    (tmp_path / "rel.txt").write_text("".join(f"distance a{k} b{k} 50.00 0.005\n" for k in range(4)))
    out = tmp_path / "fit"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = jaxcal.cli.main(["calibrate", str(tmp_path / "sockets.csv"), "--robot", "hsr_jr680", "--combine",
                              "--relations", str(tmp_path / "rel.txt"), "--out-dir", str(out), "--estimate", "tool"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "sockets (point)" in text and "relations (relations): 4 rows" in text
    summary = json.loads((out / "combined.json").read_text())
    assert [b["name"] for b in summary["blocks"]] == ["sockets", "relations"]
    # one JSON for the combined result: every block's stats and result, the relations, read back
    saved = jaxcal.load_combined_result(out / "combined.json")
    assert saved.relations == tuple(KnownDistance(f"a{k}", f"b{k}", 50.0, 0.005) for k in range(4))
    assert [s.name for s in saved.blocks] == ["sockets", "relations"] and set(saved.results) == {"sockets"}
    sock = saved.blocks[0]
    assert sock.unit == "mm" and sock.n_residuals == 960 and saved.sigma["sockets"] == sock.sigma
    assert saved.blocks[1].rank_without == saved.blocks[1].rank - 1 and saved.blocks[1].directions
    alone = jaxcal.load_result(out / "sockets.json")
    assert np.allclose(np.asarray(saved.results["sockets"].predict(test.q)), np.asarray(alone.predict(test.q)))
    assert saved.results["sockets"].uncertainty is not None
    assert any("relations alone determines the direction" in line for line in saved.block_report)
    # the length scale in words, and its shares read back from the file
    assert any(line.startswith("length scale: set by relations (") for line in saved.block_report), saved.block_report
    assert saved.blocks[1].scale_share > 0.99 and saved.blocks[0].scale_seen is True
    with pytest.raises(ValueError, match="not a jaxcal combined result"):
        jaxcal.load_combined_result(out / "sockets.json")
    rc = jaxcal.cli.main(["evaluate", str(out / "sockets.json"), str(tmp_path / "held_out.csv"),
                          "--out", str(tmp_path / "ev.json")])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "new point labels" in text and "a4, b4, a5, b5" in text
    ev = json.loads((tmp_path / "ev.json").read_text())
    # the expected RMSE with the points registered again: only the robot's uncertainty the new centres
    # cannot absorb (it said 2.19 mm against 0.035 mm measured before)
    assert abs(ev["expected_rmse_mm"] / ev["metrics_mm"]["after"]["rmse"] - 1) < 0.15, ev["expected_rmse_mm"]
    dev = ev["deviations_after"]
    c = {s: np.array([dev[f"point_{x}@{s}"] for x in "xyz"]) for s in ("a4", "b4", "a5", "b5")}
    for k in (4, 5):  # nominal centres are zero for new labels: the deviations are the centres
        assert abs(np.linalg.norm(c[f"a{k}"] - c[f"b{k}"]) - SOCKETS_MM) < 0.05


SIGMA_TRACKER, SIGMA_PX = 0.05, 0.3
SEEDS = (0, 1, 2)


def _camera_pair(robot, other: str, seed: int):
    """An eye-in-hand camera (30 views, hand-eye and target unknown, σ = 0.3 px) and ``other`` on one
    true robot: ``"tracker"`` (500 tool points, its own frame, σ = 0.05 mm) or ``"plane"`` (three
    planes, 600 probe contacts, σ = 0.05 mm): per-block σ estimated; on seed 0 also fresh rows of both
    (the same true set-up) → ``(result, whitened test RMS / combined floor or None)``."""
    from jaxcal import Camera, Position
    from jaxcal._simulation._simulate import simulate_experiment
    from jaxcal._simulation._simulate_sensors import simulate_camera

    fresh = seed == 0

    def plane_rows(key, truth=None):  # one simulation shape for training and fresh rows (compiled once)
        return simulate_contact(key, robot, model, n_samples=600, noise_std=SIGMA_TRACKER, test_fraction=0.0,
                                true_deviations=truth)

    def views(key, truth):
        return simulate_camera(key, robot, n_views=30, noise_px=SIGMA_PX, true_deviations=truth)

    if other == "plane":
        model = default_setup("plane", robot)
        ex = plane_rows(jax.random.key(10 + seed))
        truth, extras = ex.true_deviations, "tool"
    else:
        model, extras = Position(), "tool,base"
        truth = None
    q_c, y_c, cam, truth = views(jax.random.key(seed), truth)
    if other == "tracker":
        dh = _dh_only(robot, truth).replace(tool=np.array([20.0, -10.0, 90.0]))
        ex = simulate_experiment(jax.random.key(20 + seed), robot, n_samples=1000, noise_std=SIGMA_TRACKER,
                                 measurement=Position(), true_deviations=dh, test_fraction=0.5)
    nominal = Camera(cam.points, cam.intrinsics, cam.mount, image_size=cam.image_size)  # hand-eye, target unknown
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate_blocks(robot, [Block(other, model, ex.train, extras=extras),
                                       Block("camera", nominal, (q_c, y_c))])
    ratio = None
    if fresh:  # 30 views and rows of the other sensor not trained on (the same true set-up), with the true σ
        test = plane_rows(jax.random.key(110), ex.true_deviations).train if other == "plane" else ex.test
        q_t, y_t, _, _ = views(jax.random.key(100), truth)
        comb, q, y = combine(robot, [Block(other, model, test, SIGMA_TRACKER),
                                     Block("camera", nominal, (q_t, y_t), SIGMA_PX)])
        r = np.asarray(comb.residual(robot, res.deviations, q, y))
        n_train = sum(s.n_residuals for s in res.blocks)
        obs = comb.observed(y)
        r = r if obs is None else r[obs]
        ratio = float(np.sqrt(np.mean(r**2))) / combined_floor(res.identifiability.rank, n_train).test
    print(other, seed, [s.line() for s in res.blocks], res.variance_rounds, "test RMS / floor", ratio)
    return res, ratio


@pytest.fixture(scope="module")
def tracker_and_camera(paper_robot):
    return [_camera_pair(paper_robot, "tracker", seed) for seed in SEEDS]


@pytest.fixture(scope="module")
def camera_and_plane(paper_robot):
    return [_camera_pair(paper_robot, "plane", seed) for seed in SEEDS]


def _check_camera_pair(fits, other):
    """σ̂ of both blocks within 5 % of the truth on 3 seeds, in the blocks' own units (mm, px), and
    the whitened RMS on fresh rows of both (each block over its true σ) at the combined floor (3 %)."""
    for res, _ in fits:
        est = {s.name: s for s in res.blocks}
        assert est["camera"].unit == "px" and est[other].unit == "mm"
        assert abs(est[other].sigma_hat / SIGMA_TRACKER - 1) < 0.05, est[other].sigma_hat
        assert abs(est["camera"].sigma_hat / SIGMA_PX - 1) < 0.05, est["camera"].sigma_hat
    ratio = fits[0][1]
    assert abs(ratio - 1) < 0.03, ratio


def test_tracker_and_camera_at_the_combined_floor(tracker_and_camera):
    """A laser tracker (tool point, its own frame) and an eye-in-hand camera (hand-eye and target
    unknown) on one robot."""
    _check_camera_pair(tracker_and_camera, "tracker")


def test_camera_and_plane_at_the_combined_floor(camera_and_plane):
    """An eye-in-hand camera and plane contact (a probe touching three planes) on one robot: the
    camera sees the length scale that the planes cannot."""
    _check_camera_pair(camera_and_plane, "plane")


def test_known_plane_distance_lets_plane_data_see_the_scale(paper_robot):
    """Plane contact alone cannot see the length scale (one null direction of the Jacobian); a known
    distance between two parallel planes (a step of 25 mm), or a point on a plane at a known offset
    with a known socket distance, adds exactly that direction: the rank rises by one."""
    from types import SimpleNamespace

    from jaxcal import PlaneContact, PlaneDistance, identifiability
    from jaxcal._calibration._blocks import BlockStats, who_sees_what

    base = default_setup("plane", paper_robot)
    n = np.asarray(base.normals)
    d = np.asarray(base.offsets)
    planes = PlaneContact((*base.labels, "step"), np.concatenate([n, n[:1]]), np.concatenate([d, d[:1] + 25.0]))
    ex = simulate_contact(jax.random.key(4), paper_robot, planes, n_samples=160, noise_std=0.0, test_fraction=0.0)
    ranks, seen = [], []
    for relations in ((), [PlaneDistance("table", "step", 25.0)]):
        # the null direction needs exact contacts (off a plane, scaling changes the residual)
        model, q, y = combine(paper_robot, [Block("planes", planes, ex.train, 0.05)], relations)
        layout = layout_for(paper_robot, model)
        truth = Deviations({g: v for g, v in ex.true_deviations.values.items() if g in layout.group_names}, layout)
        space = ParameterSpace.for_robot(paper_robot, measurement=model, tool=True)
        ranks.append(identifiability(paper_robot, model, q, space, truth).rank)
        # the length-scale check of the block report on the same rows: the scale direction (every
        # free length at its absolute value) is the Jacobian's null direction of the planes, seen
        # by the relation alone
        result = SimpleNamespace(robot=paper_robot, deviations=truth, space=space)
        r, grams = block_information(result, model, q, y)
        v = length_scale_direction(paper_robot, model, truth, space)
        assert v[space.free_names.index("plane_d@step")] == pytest.approx(float(planes.offsets[3]))
        shares, ok = scale_shares(grams, v, float(np.sum(r**2)))
        seen.append(ok)
        if not relations:
            pr = jaxcal.Problem(paper_robot, model, q, y, space, truth)
            J = np.asarray(pr.jacobian(pr.x0()))
            assert np.linalg.norm(J @ v) < 1e-9 * np.linalg.norm(J, axis=0) @ np.abs(v)
            stats = [BlockStats("planes", "plane", "mm", 1, 1, 1.0, True, 1.0, 1.0, 1.0, 1.0,
                                scale_share=float(shares[0]), scale_seen=ok)]
            assert "length scale: not seen by any block" in " ".join(who_sees_what(stats))
        else:
            assert shares[1] > 0.999, shares  # the relation rows
    print("rank without / with the plane distance", ranks, "scale seen", seen)
    assert ranks[1] == ranks[0] + 1
    assert seen == [False, True]


def test_block_directions_names_the_block_that_alone_sees_a_direction():
    """A linear toy: block A sees p3 and the difference p1 − p2, block B only the sum p1 + p2 (as a
    tracker tells a plane's offset and d_1 apart): B alone determines (p1 + p2)/√2, and without B
    the rank drops by one; A's p3 is a one-parameter direction (left to the information shares)."""
    from jaxcal._calibration._blocks import block_directions, who_sees_what

    rng = np.random.default_rng(0)
    a = rng.normal(size=(50, 1)) * [[1.0, -1.0, 0.0]] + rng.normal(size=(50, 1)) * [[0.0, 0.0, 1.0]]
    b = rng.normal(size=(20, 1)) * [[2.0, 2.0, 0.0]]
    grams = np.stack([a.T @ a, b.T @ b])
    rank, without, dirs = block_directions(grams, ("p1", "p2", "p3"))
    assert rank == 3 and without == [1, 2]  # without A: p3 and p1 − p2 unseen; without B: p1 + p2
    assert len(dirs[1]) == 1 and dirs[1][0][0] == pytest.approx(1.0)
    assert sorted(n for _, n in dirs[1][0][1]) == ["p1", "p2"]
    assert np.allclose([c for c, _ in dirs[1][0][1]], [np.sqrt(0.5)] * 2)
    assert len(dirs[0]) == 1 and {n for _, n in dirs[0][0][1]} == {"p1", "p2"}  # the difference: A alone
    from jaxcal._calibration._blocks import BlockStats

    stats = [BlockStats(n, "plane", "mm", 1, 1, 1.0, True, 1.0, 1.0, 1.0, 1.0, information={}, directions=dirs[i],
                        rank_without=without[i], rank=rank) for i, n in enumerate(("A", "B"))]
    lines = who_sees_what(stats)
    assert "B alone determines the direction (+0.71·p1 +0.71·p2) (100.0% of its information)" in lines
    assert "without B: 1 direction not identifiable (rank 2 of 3)" in lines


def test_scale_shares_closed_form():
    """The blocks' shares of the information along the length scale ``v`` against their closed forms
    ``vᵀG_b v / vᵀG v``; the column scaling cancels; a total below the residuals' own information
    (``J·v = r`` for data blind to the scale) or below ``rtol`` of the largest eigenvalue is unseen;
    the report's line names the block, or says nobody sees it."""
    import json

    from jaxcal._calibration._blocks import BlockStats, _stats_from_dict, _stats_to_dict, who_sees_what
    from jaxcal._core._json import to_jsonable

    a = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])  # block A sees p1 and p2 (lengths), not p3 (an angle)
    b = np.array([[3.0, 3.0, 3.0]])
    grams = np.stack([a.T @ a, b.T @ b])
    v = np.array([2.0, 1.0, 0.0])  # the lengths' absolute values, 0 for the angle
    shares, seen = scale_shares(grams, v)
    # vᵀG_A v = 2² + (2·1)² = 8, vᵀG_B v = (3·2 + 3·1)² = 81
    assert np.allclose(shares, [8 / 89, 81 / 89]) and seen
    assert np.allclose(scale_shares(grams * 1e6, v)[0], shares)  # units cancel
    assert not scale_shares(grams, v, rss=1.0)[1]  # 89 < 100 × the residuals' own
    assert not scale_shares(np.stack([a.T @ a]), np.array([0.0, 0.0, 1.0]))[1]  # nobody sees p3
    mk = [BlockStats(n, "plane", "mm", 1, 1, 1.0, True, 1.0, 1.0, 1.0, 1.0, scale_share=float(x), scale_seen=seen)
          for n, x in zip(("A", "B"), shares)]
    assert "length scale: set by B (91 % of the information along it)" in who_sees_what(mk)
    mk = [dataclasses.replace(s, scale_share=x) for s, x in zip(mk, (0.6, 0.4))]
    assert "length scale: set by A (60 %) and B (40 %) (their shares of the information along it)" in who_sees_what(mk)
    old = [dataclasses.replace(s, scale_share=float("nan"), scale_seen=None) for s in mk]  # a file without them
    assert not any(line.startswith("length scale") for line in who_sees_what(old))
    # saved with the combined result's JSON and read back; a file written before them reads as unknown
    back = _stats_from_dict(json.loads(json.dumps(to_jsonable(_stats_to_dict(mk[0])))))
    assert back.scale_share == 0.6 and back.scale_seen is True
    d = {k: v for k, v in to_jsonable(_stats_to_dict(mk[0])).items() if not k.startswith("scale_")}
    back = _stats_from_dict(d)
    assert np.isnan(back.scale_share) and back.scale_seen is None



def test_own_entries_of_narrow_blocks_equal_the_padded_rows(paper_robot, monkeypatch):
    """A combined model's rows are padded to the widest block (a tracker's 3 entries, a wire's 1);
    the residual vector and the Jacobian hold each row's own entries only
    (``Combined.residual_entries``: 3 100 of 6 300 here). Against the same quantities with the padding
    kept in (the entries switched off, a fresh trace): the residual put back into rows is the model's
    own, and what the solves and the uncertainty read — the robust objective's ``JᵀJ``, ``Jᵀr`` and
    ``‖r‖²``, the Gram matrices, the robust weights' residual sum, the sample errors and the column
    scales — agree to round-off."""
    from jaxcal import CableLength, Position
    from jaxcal._fit._diagnostics import gram_from_jacobian
    from jaxcal._fit._objective import Objective
    from jaxcal._fit._problem import Problem, value_and_jacfwd
    from jaxcal._sensors._blocks import Combined
    from jaxcal._simulation._simulate import default_anchor, simulate_experiment
    from jaxcal.methods import ScaledProblem

    # the simulations at the shapes other tests draw (the paper's draw-wire experiment, the tracker
    # of the camera pairs): their programs are compiled once in a test run
    wire = simulate_experiment(jax.random.key(8), paper_robot)
    track = simulate_experiment(jax.random.key(7), paper_robot, n_samples=1000, noise_std=0.05, measurement=Position(),
                                true_deviations=_dh_only(paper_robot, wire.true_deviations), test_fraction=0.5)
    model, q, y = combine(paper_robot, [Block("tracker", Position(), track.train, 0.05, extras="tool,base"),
                                  Block("wire", CableLength(default_anchor(paper_robot)), wire.train, 0.05)])
    space = ParameterSpace.for_robot(paper_robot, measurement=model)
    problem = Problem(paper_robot, model, q, y, space)
    assert problem.n_entries == 500 * 3 + 1600 and problem.n_residuals == 2100 * 3
    np.testing.assert_array_equal(problem.entry_rows()[[0, 1499, 1500, 3099]], [0, 499, 500, 2099])
    x = jax.random.normal(jax.random.key(3), (space.n_free,)) * 1e-3  # off the start: residuals of all sizes
    objective = Objective.build(space, None, 0.05, loss="huber", loss_scale=2.0)

    def pieces(problem, x):
        scaled = ScaledProblem.build(problem, objective=objective)
        z = scaled.z(x)
        r, J = value_and_jacfwd(problem.residual, x, problem.q)  # one derivative of the kinematics
        ro, Jo = scaled.objective_from_data(z, r, J * scaled.scale)
        blocks = problem.measurement.residual(problem.robot, problem.deviations(x), problem.q, problem.y)
        return (problem.to_blocks(r), blocks), (Jo.T @ Jo, Jo.T @ ro, ro @ ro, scaled.scale,
                                                problem.sample_errors_from_residual(r),
                                                *gram_from_jacobian(problem, r, J, "huber", 2.0))

    (back, blocks), own = jax.jit(lambda p, x: pieces(p, x))(problem, x)
    np.testing.assert_allclose(np.asarray(back), np.asarray(blocks), rtol=1e-12, atol=1e-12)  # the wire's rows: 1 entry
    assert not np.any(np.asarray(back)[500:, 1:])
    monkeypatch.setattr(Combined, "residual_entries", lambda self, n: None)
    assert Problem(paper_robot, model, q, y, space).n_entries == 6300
    padded = jax.jit(lambda p, x: pieces(p, x))(problem, x)[1]
    for a, b in zip(own, padded):
        if b is None:  # a piece only some models have (a pose's per-component information)
            assert a is None
            continue
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-10, atol=1e-12 * float(np.max(np.abs(b))))
