"""Self-contained calibration of the dual-arm preset (issue 51): the CTU-style table and the speed row.

Robot: ``jaxcal.robots.dual_arm_ma1400()`` (two MA1400 arms on one torso axis, two cameras on the
torso; 13 joints, tips ``left_tool``, ``right_tool``, ``left_camera``, ``right_camera``).

Truth: seeded random deviations of every robot parameter (:func:`jaxcal.draw_deviations`, 0.1°,
0.5 mm), the two tool points 1–2 mm off nominal, and each camera's true hand-eye / target pose as
:func:`jaxcal.simulate_camera` makes them (camera 27 mm off its tip's origin, the board 44 mm off
the hand's, facing each other at the view's home posture). Sensors (the blocks), with their noise:

* ``contact``: self-contact, the two tool points (58 mm balls) touching: ‖p_L − p_R‖ = 116 mm,
  contact scatter σ = 0.3 mm (:func:`jaxcal.simulate_self_contact`);
* ``planes``: the left hand touching three planes (a table, two walls; :func:`default_setup`),
  σ = 0.1 mm; the planes are estimated (their nominal is the truth);
* ``cam_l`` / ``cam_r``: each torso camera sees a 5×4 board (15 mm squares) on its own hand
  (``Camera(..., "tip_to_tip", tip=<camera>, target_tip=<hand>)``), f = 1000 px, 1280×1024,
  σ = 0.3 px; hand-eye and board pose estimated;
* ``trk_l`` / ``trk_r``: the reference: a tracker on each hand (``Position(tip=...)``), σ = 0.1 mm,
  its frame and the tool point estimated (two blocks: each its own tracker frame).

Each configuration is one :func:`jaxcal.calibrate_blocks` (LM, jaxcal's default prior toward nominal, every block's σ estimated
by variance components; under the prior every candidate is free, the rank is what the data determine). Columns:

* held-out whitened RMSE / floor: the held-out rows of the configuration's blocks (as many as the
  training rows), each block's residual over its true σ, against the combined floor
  ``sqrt(1 + p/(N − p − 1))`` (p = the rank, N the training residual entries); 1.00 is the floor,
  the acceptance is within 3 %;
* tool-point error: both hands' tool points (flange + tool offset) at 1 000 random joint
  postures within the limits, calibrated vs true, after the best rigid transform of the base
  frame (Kabsch) over both hands together ("one frame": no configuration here fixes where the
  robot stands: the planes, the tracker frames and the cameras are all estimated, and self-contact
  sees only the arms relative to each other) and after one rigid transform per hand ("per hand":
  what a sensor that sees one arm alone cannot place, e.g. a camera sees its arm relative to itself);
  RMS and max in mm, left / right;
* free / rank: the candidates the fit frees and the rank of the whitened Jacobian there (the
  identifiability report); "unseen" are the candidates it leaves at nominal.

Sequential against simultaneous: ``cameras → robot`` fits the cameras' extrinsics first with the
robot fixed at nominal (``fix="geometric"``), then the robot (and the other blocks' extras) with the
cameras' extrinsics fixed at the first stage's values, on the same blocks as ``all three``.

Speed row: ``all three`` (contact + planes + both cameras, ~10 000 residual entries), the Python
``jaxcal.calibrate_blocks`` timed cold in a fresh process (imports and compilation included) and
warm (a second call in that process), and one warm LM solve of the final problem's whitened
residual against ``scipy.optimize.least_squares(method="lm", jac="2-point")`` of the same residual
(a finite-difference Jacobian), both from the same start (the extras' closed-form start, robot at
nominal) on the same free set. scipy twice: on a plain NumPy transcription of the residual
(``benchmarks/_numpy_tree_residual.py``, vectorised over rows, float64: what the CTU toolbox gives
MATLAB's ``lsqnonlin``; checked equal to jaxcal's residual at the start and at the solution, the run
fails if it is not within 1e-9 relative), the issue's baseline; and on jaxcal's own jitted JAX
residual (the strongest scipy baseline there is, not what the toolbox does).

The command-line route of the same speed row: the four training blocks written as the data files a
user has (:func:`write_cli_files`: ``Dataset.to_csv``, each file its ``# kind:`` line and set-up
lines: self-contact ``# tips: left_tool,right_tool`` and ``contact_distance_mm``; planes the
``plane`` column, ``# plane_labels:`` and ``# tip: left_tool``; each camera ``# mount: tip_to_tip``,
``# tip: <side>_camera``, ``# target_tip: <side>_tool``, ``# target: checkerboard:5x4:15``,
``# camera_intrinsics:``, ``# image_size_px:``; every file its ``# noise_std_mm/px:`` line), then
``jaxcal calibrate contact.csv planes.csv cam_l.csv cam_r.csv --robot dual_arm_ma1400 --combine
--out-dir DIR --verbose`` timed as whole fresh processes (Python's start-up and imports included):
cold (``JAXCAL_CACHE_DIR`` a new empty folder), warm (the same command again with the cache that
run filled) and with no persistent cache (``JAXCAL_CACHE_DIR=off``). ``jaxcal simulate`` cannot
write these blocks as the bench sets them up (its camera is a 9×6 board at random postures, its
contact balls 30 mm, its true robot another one), so the files hold ``setup()``'s own rows. The
command runs the measured-data defaults (default prior, Huber loss; the Python row: default prior,
plain least squares) from the planes' closed-form start (the Python row starts them at the truth).
Its result is checked on the blocks' held-out rows (the block results of ``combined.json``,
whitened by the true σ, against the combined floor, as the table's column).

Run: ``python benchmarks/bench_multiarm.py`` (about 12 min on 2 busy CPU cores) or ``--quick``
(small sizes, a smoke run). Writes ``benchmarks/results/multiarm_cpu.md`` (or ``--out``).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from _common import machine, median_time  # noqa: E402
from _numpy_tree_residual import NumpyTreeResidual  # noqa: E402

import jaxcal  # noqa: E402
from jaxcal import Block, Camera, Position, SelfContact  # noqa: E402
from jaxcal._calibration._blocks import combined_floor  # noqa: E402
from jaxcal._core._params import Deviations, layout_for  # noqa: E402
from jaxcal._models._kinematics import fk_pose  # noqa: E402
from jaxcal._models._robot import sample_joint_angles  # noqa: E402
from jaxcal._sensors._blocks import combine  # noqa: E402
from jaxcal._sensors._camera import checkerboard  # noqa: E402
from jaxcal._sensors._contact import default_setup  # noqa: E402
from jaxcal._simulation._simulate import draw_deviations  # noqa: E402

HERE = pathlib.Path(__file__).parent
SIG = {"contact": 0.3, "planes": 0.1, "cam": 0.3, "trk": 0.1}
#: joint postures (deg) with each hand ~0.7 m in front of its torso camera (found by sampling)
HOME_DEG = [0.0, -87.4, -80.3, -70.0, -141.5, 44.6, 12.7, 53.8, -41.1, -58.1, 73.8, 176.7, -120.0]
INTRINSICS = [1000.0, 1000.0, 640.0, 512.0, -0.05, 0.02, 0.0005, -0.0003, 0.0]
CONFIGS = [  # (row name, blocks)
    ("self-contact", ("contact",)),
    ("planes", ("planes",)),
    ("cameras", ("cam_l", "cam_r")),
    ("self-contact + planes", ("contact", "planes")),
    ("self-contact + cameras", ("contact", "cam_l", "cam_r")),
    ("planes + cameras", ("planes", "cam_l", "cam_r")),
    ("all three", ("contact", "planes", "cam_l", "cam_r")),
    ("tracker on each hand (reference)", ("trk_l", "trk_r")),
]
ALL = CONFIGS[6][1]
#: jaxcal's default prior toward nominal (0.5°, 2 mm on the robot's parameters, none on the extras);
#: without it planes alone collapse (the left tool point pulled 554 mm to a degenerate exact fit)
PRIOR = "default"


def setup(sizes: dict, seed: int = 51):
    """``(tree, truth, {block: (train Block, test Block)})`` of the simulated dual-arm cell."""
    jaxcal.enable_x64()
    tree = jaxcal.robots.dual_arm_ma1400()
    key = jax.random.key(seed)
    planes = default_setup("plane", tree)  # the left hand (the default tip) touches them
    layout = layout_for(tree, Position(tip="right_tool")).extend(planes.extra_groups())
    drawn = draw_deviations(jax.random.fold_in(key, 0), tree, angle_std_deg=0.1, length_std_mm=0.5)
    vals = {g: v for g, v in drawn.values.items() if g in layout.group_names}
    vals |= {"tool": np.array([1.0, -2.0, 1.5]), "tool@right_tool": np.array([-1.5, 1.0, 2.0])}
    truth = Deviations(vals, layout)
    n_c, n_p, n_v, n_t = sizes["contact"], sizes["planes"], sizes["views"], sizes["tracker"]
    blocks = {}
    q, y = jaxcal.simulate_self_contact(jax.random.fold_in(key, 1), tree, ("left_tool", "right_tool"),
                                        n_samples=2 * n_c, distance_mm=116.0, noise_std=SIG["contact"],
                                        true_deviations=truth)
    touch = SelfContact(("left_tool", "right_tool"))
    blocks["contact"] = tuple(Block("contact", touch, (q[s], y[s]), sig)
                              for s, sig in ((slice(0, n_c), None), (slice(n_c, None), SIG["contact"])))
    ex = jaxcal.simulate_contact(jax.random.fold_in(key, 2), tree, planes, n_samples=2 * n_p, noise_std=SIG["planes"],
                                 true_deviations=truth, test_fraction=0.5)
    blocks["planes"] = (Block("planes", planes, ex.train, None, extras="tool"),
                        Block("planes", planes, ex.test, SIG["planes"], extras="tool"))
    home = np.deg2rad(HOME_DEG)
    for i, side in enumerate(("left", "right")):
        cam = Camera(checkerboard(5, 4, 15.0), INTRINSICS, "tip_to_tip", image_size=(1280, 1024),
                     tip=jaxcal.resolve_tip(tree, f"{side}_camera"), target_tip=jaxcal.resolve_tip(tree, f"{side}_tool"))
        arm = [n for n in tree.joint_names if n.startswith(side)]
        spread = np.array([20.0 if n == "torso_joint" else (8.0 if n in arm else 0.0) for n in tree.joint_names])
        q, uv, cam, _ = jaxcal.simulate_camera(jax.random.fold_in(key, 3 + i), tree, cam, n_views=2 * n_v,
                                               noise_px=SIG["cam"], home=home, joint_spread_deg=spread,
                                               true_deviations=truth)
        # the model a user has: nominal (identity) hand-eye and board pose, started in closed form
        cam = Camera(cam.points, INTRINSICS, "tip_to_tip", image_size=(1280, 1024), tip=cam.tip,
                     target_tip=cam.target_tip)
        name = f"cam_{side[0]}"
        blocks[name] = (Block(name, cam, (q[:n_v], uv[:n_v]), None),
                        Block(name, cam, (q[n_v:], uv[n_v:]), SIG["cam"]))
    for i, side in enumerate(("left", "right")):
        trk = Position(tip=jaxcal.resolve_tip(tree, f"{side}_tool"))
        ex = jaxcal.simulate_experiment(jax.random.fold_in(key, 5 + i), tree, n_samples=2 * n_t,
                                        noise_std=SIG["trk"], measurement=trk, true_deviations=truth,
                                        test_fraction=0.5)
        name = f"trk_{side[0]}"
        blocks[name] = (Block(name, trk, ex.train, None, extras="tool,base"),
                        Block(name, trk, ex.test, SIG["trk"], extras="tool,base"))
    return tree, truth, blocks


def fit(tree, blocks, names, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return jaxcal.calibrate_blocks(tree, [blocks[n][0] for n in names], prior=PRIOR, **kw)


def held_out_ratio(tree, res, blocks, names):
    """Held-out whitened RMS over the blocks' test rows (true σ) / the combined floor."""
    comb, q, y = combine(tree, [blocks[n][1] for n in names])
    r = np.asarray(comb.residual(tree, res.deviations, q, y))[comb.observed(y)]
    n_train = sum(s.n_residuals for s in res.blocks)
    return float(np.sqrt(np.mean(r**2))) / combined_floor(res.identifiability.rank, n_train).test


def _kabsch(a, b):
    """``b`` moved by the rigid transform that best maps it onto ``a``."""
    ca, cb = a.mean(0), b.mean(0)
    U, _, Vt = np.linalg.svd((b - cb).T @ (a - ca))
    d = np.sign(np.linalg.det(U @ Vt))
    R = (U @ np.diag([1.0, 1.0, d]) @ Vt).T
    return (b - cb) @ R.T + ca


def tool_points(tree, dev, q):
    return [np.asarray(fk_pose(tree, q, dev, tip=t, tool=True))[:, :3, 3] for t in ("left_tool", "right_tool")]


def tool_errors(tree, res, truth, q):
    """``{frame: [(rms, max) left, right]}`` of the tool points after the rigid alignments."""
    est, tru = tool_points(tree, res.deviations, q), tool_points(tree, truth, q)
    n = q.shape[0]
    both = _kabsch(np.concatenate(tru), np.concatenate(est))
    out = {"one": [], "hand": []}
    for k in range(2):
        e1 = np.linalg.norm(both[k * n:(k + 1) * n] - tru[k], axis=1)
        e2 = np.linalg.norm(_kabsch(tru[k], est[k]) - tru[k], axis=1)
        out["one"].append((float(np.sqrt(np.mean(e1**2))), float(e1.max())))
        out["hand"].append((float(np.sqrt(np.mean(e2**2))), float(e2.max())))
    return out


def sequential(tree, blocks, names, simultaneous):
    """Cameras' extrinsics first (robot fixed at nominal), then everything else with them fixed.
    Stage 2 starts where the simultaneous fit started (``simultaneous.start``: the robot nominal,
    every block's extras in closed form), the cameras' groups replaced by stage 1's values."""
    cams = [n for n in names if n.startswith("cam")]
    first = fit(tree, blocks, cams, fix="geometric")
    cam_groups = [g for g in first.deviations.layout.group_names if "@cam_" in g]
    start = simultaneous.start.replace(**{g: first.deviations.values[g] for g in cam_groups})
    return fit(tree, blocks, names, start=start, init="none", fix=cam_groups), first


def row(tree, truth, blocks, names, qe, res=None, label=None):
    t = time.perf_counter()
    res = fit(tree, blocks, names) if res is None else res
    wall = time.perf_counter() - t
    ratio = held_out_ratio(tree, res, blocks, names)
    err = tool_errors(tree, res, truth, qe)
    n_free, rank = len(res.space.free_names), res.identifiability.rank
    n_train = sum(s.n_residuals for s in res.blocks)
    return dict(res=res, label=label, blocks=names, ratio=ratio, err=err, free=n_free, rank=rank,
                unseen=len(res.identifiability.unidentifiable), n=n_train, wall=wall,
                sigma={k: float(v) for k, v in res.sigma.items()}, rounds=res.variance_rounds)


def fmt(r):
    e1, e2 = r["err"]["one"], r["err"]["hand"]
    pair = lambda e: f"{e[0][0]:.3f} / {e[1][0]:.3f} ({e[0][1]:.2f} / {e[1][1]:.2f})"  # noqa: E731
    return (f"| {r['label']} | {r['n']} | {r['ratio']:.3f} | {pair(e1)} | {pair(e2)} | {r['free']} / {r['rank']} | "
            f"{r['wall']:.1f} |")


HEADER = ["| blocks | training entries | held-out / floor | tool error, one frame: RMS L / R (max L / R) mm "
          "| per hand: RMS L / R (max L / R) mm | free / rank | fit s |",
          "|---|---|---|---|---|---|---|"]


def speed_child(sizes: dict) -> dict:
    """Run in a fresh process: cold and warm ``calibrate_blocks`` of every block, then LM vs scipy."""
    t0 = time.perf_counter()
    tree, truth, blocks = setup(sizes)
    t_setup = time.perf_counter() - t0
    t = time.perf_counter()
    res = fit(tree, blocks, ALL)
    cold = time.perf_counter() - t
    t = time.perf_counter()
    res2 = fit(tree, blocks, ALL)
    warm = time.perf_counter() - t
    out = dict(cold=cold, warm=warm, setup=t_setup, import_s=T_IMPORT, free=len(res.space.free_names),
               rank=res.identifiability.rank, n=sum(s.n_residuals for s in res.blocks), rounds=res.variance_rounds,
               same=bool(np.allclose(res.space.to_vector_numpy(res.deviations), res2.space.to_vector_numpy(res2.deviations))))
    out |= lm_vs_scipy(tree, blocks, res)
    out["cli"] = cli_speed(tree, blocks)
    return out


#: the target layout of the bench's cameras (``checkerboard(5, 4, 15.0)``) as a data file's ``# target:`` line
TARGET = "checkerboard:5x4:15"


def write_cli_files(tree, blocks, folder, part: int = 0) -> list[pathlib.Path]:
    """The blocks of :data:`ALL` (``part`` 0: training rows, 1: held-out rows) as the data files
    ``jaxcal calibrate --combine`` reads, one per block, named after the block (the CLI's block
    name is the file's stem). Returns the paths in :data:`ALL`'s order."""
    from jaxcal import Dataset
    from jaxcal._sensors._camera import load_target

    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    src = {"source": "benchmarks/bench_multiarm.py setup()", "robot": tree.name}
    paths = []
    for name in ALL:
        blk = blocks[name][part]
        m = blk.measurement
        if isinstance(m, SelfContact):
            q, y = blk.data
            d = Dataset(q, y, "self_contact", {**src, "noise_std_mm": SIG["contact"], "tips": ",".join(m.tips)})
        elif isinstance(m, Camera):
            q, uv = blk.data
            if not np.array_equal(np.asarray(load_target(TARGET)), np.asarray(m.points)):
                raise SystemExit(f"block {name}: its target is not {TARGET}")
            d = Dataset(q, uv, "camera", {**src, "noise_std_px": SIG["cam"], "target": TARGET,
                                          "camera_intrinsics": ",".join(repr(v) for v in INTRINSICS),
                                          "image_size_px": "1280,1024", "mount": "tip_to_tip",
                                          "tip": m.tip or tree.tip_names()[0],
                                          "target_tip": m.target_tip or tree.tip_names()[0]})
        else:  # plane contact: the labels and noise lines of simulate_contact's data, the tip named
            meta = {k: v for k, v in blk.data.metadata if k not in ("source", "robot")}
            d = Dataset(blk.data.q, blk.data.y, blk.data.kind,
                        {**src, **meta, "tip": getattr(m, "tip", None) or tree.tip_names()[0]})
        paths.append(folder / f"{name}.csv")
        d.to_csv(paths[-1])
    return paths


def _jaxcal_command() -> list[str]:
    """The ``jaxcal`` console script of this interpreter's environment (else ``python -m jaxcal.cli``)."""
    exe = shutil.which("jaxcal", path=str(pathlib.Path(sys.executable).parent))
    return [exe] if exe else [sys.executable, "-m", "jaxcal.cli"]


def cli_run(files, out_dir, cache: str) -> dict:
    """One ``jaxcal calibrate FILES --robot dual_arm_ma1400 --combine --out-dir OUT --verbose`` in a
    fresh process with ``JAXCAL_CACHE_DIR=cache``: its wall time and its ``--verbose`` times."""
    cmd = _jaxcal_command() + ["calibrate", *map(str, files), "--robot", "dual_arm_ma1400", "--combine",
                               "--out-dir", str(out_dir), "--verbose"]
    env = dict(os.environ, JAXCAL_CACHE_DIR=cache)
    n_before = _n_files(cache)
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
    if proc.returncode:
        raise SystemExit(f"`{' '.join(cmd[-10:])}` (JAXCAL_CACHE_DIR={cache}) exit {proc.returncode}:\n"
                         f"{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("times:")), "")
    nums = [float(v) for v in re.findall(r"(\d+\.\d+) s\b", line)]
    keys = ("startup", "data", "fit", "compile", "solve", "output", "total")
    status = next((ln for ln in proc.stdout.splitlines() if ln.startswith("status ")), "")
    return dict(wall=wall, cpu=cpu, **dict(zip(keys, nums)), status=status, new_cache_files=_n_files(cache) - n_before)


def _n_files(cache: str) -> int:
    """Files in a cache folder (0 for ``off`` or a folder not yet made)."""
    p = pathlib.Path(cache)
    return sum(1 for f in p.rglob("*") if f.is_file()) if p.is_dir() else 0


def cli_speed(tree, blocks) -> dict:
    """The command-line route of the speed row (module docstring): the training blocks written as
    data files, ``jaxcal calibrate --combine`` cold, warm and without a persistent cache, each a
    fresh process; the warm run's result on the held-out rows (whitened by the true σ) against the
    combined floor."""
    from jaxcal._core._exported import source_hash

    with tempfile.TemporaryDirectory(prefix="bench_multiarm_cli_") as tmp:
        tmp = pathlib.Path(tmp)
        files = write_cli_files(tree, blocks, tmp / "data")
        cache = str(tmp / "cache")
        before = source_hash.__wrapped__()  # the stored programs' key: jaxcal's sources
        runs = {"cold": cli_run(files, tmp / "fit", cache)}
        runs["warm"] = cli_run(files, tmp / "fit", cache)
        edited = source_hash.__wrapped__() != before  # an edit between the runs: the warm one is not warm
        runs["off"] = cli_run(files, tmp / "fit_off", "off")
        res = jaxcal.load_combined_result(tmp / "fit" / "combined.json")
        sq, n = 0.0, 0
        for name in ALL:
            br, test = res.results[name], blocks[name][1]
            q, y = (test.data.q, test.data.y) if hasattr(test.data, "q") else test.data
            r = np.asarray(br.measurement.residual(tree, br.deviations, jnp.asarray(q), jnp.asarray(y)))
            r = r[np.isfinite(r)] / test.sigma
            sq, n = sq + float(np.sum(r**2)), n + r.size
        rank = res.blocks[0].rank
        n_train = sum(b.n_residuals for b in res.blocks)
        ratio = float(np.sqrt(sq / n)) / combined_floor(rank, n_train).test
        print("CLI " + " | ".join(f"{k}: {v}" for k, v in runs.items()), flush=True)
        return dict(runs=runs, files=[p.name for p in files], n_train=n_train, rank=rank, n_free=len(res.free_names),
                    held_out_ratio=ratio, train_whitened=float(res.raw["train_metrics_whitened"]["rmse"]),
                    sigma={k: float(v) for k, v in res.sigma.items()}, rounds=int(res.raw["variance_rounds"]),
                    status=res.raw["status"], sources_edited=edited)


def lm_vs_scipy(tree, blocks, res, repeats: int = 3) -> dict:
    """jaxcal's LM against scipy ``least_squares(method="lm")`` with a 2-point finite-difference
    Jacobian on one problem: every block with σ given (the variance components of ``res``), no
    prior, the identifiable subset jaxcal frees, from the same start (the robot nominal, the
    extras in closed form). jaxcal: ``calibrate_blocks`` on that space, warm (one round: σ given;
    its identifiability check and diagnostics included), and its jitted LM solve alone; scipy:
    on the plain NumPy transcription of the residual (the CTU toolbox's way), and on the same
    jitted JAX residual (the strongest scipy baseline). Both residuals hold every row's own
    entries (``Combined.residual_entries``: no padding)."""
    from scipy.optimize import least_squares

    blks = [Block(b.name, b.measurement, b.data, res.sigma[b.name], b.extras) for b in (blocks[n][0] for n in ALL)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = jaxcal.calibrate_blocks(tree, blks)  # the free set (identifiable subset) and the start
        space, start = ref.space, ref.start
        kw = dict(space=space, start=start, init="none")
        jaxcal.calibrate_blocks(tree, blks, **kw)  # compile
        tj = []
        for _ in range(repeats):
            t = time.perf_counter()
            rj = jaxcal.calibrate_blocks(tree, blks, **kw)
            tj.append(time.perf_counter() - t)
    comb, q, y = combine(tree, blks)
    entries = comb.residual_entries(q.shape[0])
    qd, yd = jnp.asarray(q), jnp.asarray(y)

    @jax.jit
    def resid(x):
        r = comb.residual(tree, space.from_vector(x, start), qd, yd).reshape(-1)
        return r if entries is None else r[entries]

    # the pure LM solve (jaxcal.Calibrator, jitted), as benchmarks/bench_lm_scipy.py times it
    import equinox as eqx

    from jaxcal import Calibrator
    from jaxcal.methods import make_method

    cal = Calibrator(tree, comb, make_method("lm"), start, space)
    dyn, stat = eqx.partition(cal, eqx.is_array)
    run = jax.jit(lambda d, q, y, k: eqx.combine(d, stat)(q, y, k))
    key = jax.random.key(0)
    t_solve = median_time(run, dyn, qd, yd, key, repeats=5)
    out = run(dyn, qd, yd, key)
    x0 = space.to_vector_numpy(start)
    fun_jax = lambda x: np.asarray(resid(jnp.asarray(x)))  # noqa: E731
    fun_np = NumpyTreeResidual(tree, comb, q, y, space, start)

    def check(x, where):
        """The NumPy transcription against jaxcal's residual at ``x``: max |Δ| and |Δ| / max |r|."""
        r, rn = fun_jax(x), fun_np(x)
        if rn.shape != r.shape:
            raise SystemExit(f"NumPy transcription at {where}: {rn.shape[0]} entries, jaxcal's residual {r.shape[0]}")
        diff = float(np.max(np.abs(rn - r)))
        rel = diff / float(np.max(np.abs(r)))
        print(f"NumPy transcription vs comb.residual at {where}: max |diff| {diff:.3g} (relative {rel:.3g})",
              flush=True)
        if not rel <= 1e-9:
            raise SystemExit(f"the NumPy transcription differs from jaxcal's residual at {where}: max |diff| "
                             f"{diff:.3g}, relative {rel:.3g} > 1e-9")
        return rel

    rel_start = check(x0, "the start")
    rel_end = check(np.asarray(out.x), "jaxcal's solution")
    counted = {"n": 0}

    def counting(fun):
        def f(x):
            counted["n"] += 1
            return fun(x)
        return f

    t_eval_np = float(np.median([_timed(fun_np, x0) for _ in range(20)]))
    t_eval_jax = float(np.median([_timed(fun_jax, x0) for _ in range(20)]))
    runs = {}
    for name, fun in (("np", fun_np), ("jax", fun_jax)):
        ts = []
        for _ in range(max(1, repeats - 2)):
            counted["n"] = 0
            t = time.perf_counter()
            sol = least_squares(counting(fun), x0, method="lm", jac="2-point", x_scale="jac")
            ts.append(time.perf_counter() - t)
        runs[name] = (float(np.median(ts)), sol, counted["n"])
    rel_scipy = check(runs["np"][1].x, "scipy's solution")
    cost = lambda x: float(np.sum(fun_jax(x) ** 2))  # noqa: E731
    return dict(solve_s=t_solve, solve_steps=int(out.n_iterations), cost_solve=cost(np.asarray(out.x)),
                jax_s=float(np.median(tj)), jax_steps=int(rj.n_iterations),
                cost_jax=cost(space.to_vector_numpy(rj.deviations)), p=int(x0.size), m=int(fun_np(x0).size),
                cost_start=cost(x0), check_rel=max(rel_start, rel_end, rel_scipy),
                eval_np_s=t_eval_np, eval_jax_s=t_eval_jax,
                scipy_np_s=runs["np"][0], scipy_np_nfev=int(runs["np"][1].nfev), scipy_np_calls=runs["np"][2],
                cost_scipy_np=cost(runs["np"][1].x),
                scipy_s=runs["jax"][0], scipy_nfev=int(runs["jax"][1].nfev), scipy_calls=runs["jax"][2],
                cost_scipy=cost(runs["jax"][1].x))


def _timed(fun, x) -> float:
    t = time.perf_counter()
    fun(x)
    return time.perf_counter() - t


T_IMPORT = 0.0
ROWS_RES = {}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small sizes: a smoke run")
    ap.add_argument("--out", default=str(HERE / "results" / "multiarm_cpu.md"))
    ap.add_argument("--speed-child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--skip-speed", action="store_true", help="the table only")
    ap.add_argument("--speed-only", action="store_true", help="the speed row only, replacing that section of --out")
    args = ap.parse_args()
    sizes = (dict(contact=60, planes=60, views=20, tracker=60, poses=200) if args.quick
             else dict(contact=300, planes=300, views=120, tracker=300, poses=1000))
    if args.speed_child:
        print("SPEED " + json.dumps(speed_child(sizes)))
        return
    load0 = os.getloadavg()[0]
    t_all = time.perf_counter()
    if args.speed_only:
        speed = run_speed(args)
        text = pathlib.Path(args.out).read_text(encoding="utf-8")
        text = text.split("\n## Speed")[0].rstrip("\n") + "\n\n"
        lines = speed_lines(speed, (load0, os.getloadavg()[0]), args)
        pathlib.Path(args.out).write_text(text + "\n".join(lines) + "\n", encoding="utf-8")
        print("\n".join(lines))
        return
    tree, truth, blocks = setup(sizes)
    qe = np.asarray(sample_joint_angles(jax.random.key(1000), tree, sizes["poses"]))
    rows = []
    for label, names in CONFIGS:
        rows.append(row(tree, truth, blocks, names, qe, label=label))
        ROWS_RES[label] = rows[-1].pop("res")
        print(fmt(rows[-1]), flush=True)
    t = time.perf_counter()
    seq, first = sequential(tree, blocks, ALL, ROWS_RES["all three"])
    r = row(tree, truth, blocks, ALL, qe, res=seq, label="all three, sequential: cameras → robot")
    r.pop("res")
    r["wall"] = time.perf_counter() - t
    rows.append(r)
    print(fmt(r), flush=True)
    write(args, sizes, rows, None, time.perf_counter() - t_all, (load0, os.getloadavg()[0]))
    speed = None if args.skip_speed else run_speed(args)
    lines = write(args, sizes, rows, speed, time.perf_counter() - t_all, (load0, os.getloadavg()[0]))
    print("\n".join(lines))


def run_speed(args) -> dict:
    """The speed row in a fresh process (cold = its first ``calibrate_blocks``)."""
    cmd = [sys.executable, __file__, "--speed-child"] + (["--quick"] if args.quick else [])
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode:
        sys.exit(f"the speed run failed (exit {proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    out = proc.stdout
    print("\n".join(ln for ln in out.splitlines() if ln.startswith("NumPy transcription")))
    speed = json.loads(next(ln for ln in out.splitlines() if ln.startswith("SPEED "))[6:])
    print(speed)
    return speed


def write(args, sizes, rows, speed, total, load):
    run = "python benchmarks/bench_multiarm.py" + (" --quick" if args.quick else "")
    lines = ["# Self-contained calibration of the dual-arm robot (issue 51)", "",
             f"Machine: {machine()}. Run: `{run}` ({total:.0f} s in all), {time.strftime('%Y-%m-%d')}. "
             f"**Under load**: other sessions compiled JAX on the same 2 cores (load average {load[0]:.2f} at the "
             f"start, {load[1]:.2f} at the end); the times are upper bounds.", "",
             f"Sizes (training rows = held-out rows): self-contact {sizes['contact']}, planes {sizes['planes']}, "
             f"{sizes['views']} images per camera (20 board corners), tracker {sizes['tracker']} per hand; "
             f"tool-point error at {sizes['poses']} random postures. See the script's docstring for the set-up.", "",
             *HEADER, *(fmt(r) for r in rows), ""]
    if speed:
        lines += speed_lines(speed, load, args)
    pathlib.Path(args.out).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return lines



def speed_lines(speed, load, args):
    ratio = lambda a, b: f"{a / b:.1f}×"  # noqa: E731
    return ["## Speed: every block (all three)", "",
            f"{speed['n']} training residual entries, {speed['free']} free parameters (rank {speed['rank']}), "
            f"{speed['rounds']} variance-component rounds. Under load (load average {load[0]:.2f} → {load[1]:.2f} "
            f"while it ran): upper bounds. scipy runs twice, from jaxcal's start on jaxcal's free set: on a plain "
            f"NumPy transcription of the residual (`benchmarks/_numpy_tree_residual.py`, vectorised over rows: what "
            f"the CTU toolbox gives MATLAB's `lsqnonlin`; equal to jaxcal's residual within "
            f"{speed['check_rel']:.1g} relative at the start and at both solutions), the issue's baseline; and on "
            f"jaxcal's own jitted JAX residual (its compilation not timed), the strongest scipy baseline there is. "
            f"One residual evaluation: NumPy {1e3 * speed['eval_np_s']:.2f} ms, jitted JAX "
            f"{1e3 * speed['eval_jax_s']:.2f} ms.", "",
            "| what | time / s |", "|---|---|",
            f"| `calibrate_blocks` cold, fresh process (after `import jaxcal` and simulation) | {speed['cold']:.2f} |",
            f"| `calibrate_blocks` warm, same process | {speed['warm']:.2f} |",
            f"| `calibrate_blocks`, σ given, no prior, the identifiable {speed['p']} parameters, warm "
            f"({speed['jax_steps']} LM steps) | {speed['jax_s']:.3f} |",
            f"| jaxcal's LM solve alone (`jaxcal.Calibrator`, jitted, warm; {speed['solve_steps']} steps) "
            f"| {speed['solve_s']:.3f} |",
            f"| scipy `least_squares(method='lm', jac='2-point')`, **NumPy residual** ({speed['scipy_np_calls']} "
            f"residual calls, FD columns included; nfev {speed['scipy_np_nfev']} as scipy reports it) "
            f"| {speed['scipy_np_s']:.2f} |",
            f"| scipy `least_squares(method='lm', jac='2-point')`, jitted JAX residual ({speed['scipy_calls']} "
            f"residual calls; nfev {speed['scipy_nfev']}) | {speed['scipy_s']:.2f} |",
            f"| **ratio scipy (NumPy residual, FD) / jaxcal LM solve** | "
            f"**{ratio(speed['scipy_np_s'], speed['solve_s'])}** |",
            f"| ratio scipy (jitted JAX residual, FD) / jaxcal LM solve | {ratio(speed['scipy_s'], speed['solve_s'])} |",
            f"| ratio scipy (NumPy residual, FD) / jaxcal `calibrate_blocks` (with its checks) | "
            f"{ratio(speed['scipy_np_s'], speed['jax_s'])} |", "",
            f"Cost (sum of squared whitened residuals) at the start {speed['cost_start']:.4g}; at the end: jaxcal "
            f"{speed['cost_jax']:.2f} (the solve alone {speed['cost_solve']:.2f}), scipy on the NumPy residual "
            f"{speed['cost_scipy_np']:.2f}, on the JAX residual {speed['cost_scipy']:.2f} ({speed['p']} parameters, "
            f"{speed['m']} entries).", ""] + cli_lines(speed.get("cli"))


def cli_lines(cli) -> list[str]:
    """The command-line route's rows (:func:`cli_speed`)."""
    if not cli:
        return []
    files = " ".join(cli["files"])
    sig = ", ".join(f"{k} {v:.3g}" for k, v in cli["sigma"].items())
    rows = ["### The command line: `jaxcal calibrate --combine`", "",
            f"`jaxcal calibrate {files} --robot dual_arm_ma1400 --combine --out-dir DIR --verbose`, each run a "
            "fresh process, its whole wall time (Python's start-up and the imports included); the files are the "
            "speed row's training blocks as a user has them (the script's docstring: file forms, and what differs "
            f"from the Python row: the measured-data defaults, default prior and Huber loss). {cli['n_train']} "
            f"training entries, {cli['n_free']} free parameters (rank {cli['rank']}), {cli['rounds']} fits with "
            f"re-estimated σ, status {cli['status']}; whitened training RMSE {cli['train_whitened']:.3f}, held-out "
            f"rows of the four blocks (true σ) **{cli['held_out_ratio']:.3f}× the combined floor**; σ estimated: "
            f"{sig}. Under load (as above): upper bounds; the CPU time (user + system, all threads) is the "
            "command's own work, less disturbed by the load (on 2 idle cores the wall time is at least half of it). "
            "The other columns are the command's `--verbose` times.", "",
            "| `jaxcal calibrate --combine` | wall s | CPU s | start-up (imports) s | data s | fit s (compile / solve) "
            "| output s | cache files written |", "|---|---|---|---|---|---|---|---|"]
    what = {"cold": "cold: `JAXCAL_CACHE_DIR` an empty folder", "warm": "warm: the same cache again",
            "off": "no persistent cache (`JAXCAL_CACHE_DIR=off`)"}
    for k, label in what.items():
        r = cli["runs"][k]
        fit = (f"{r['fit']:.2f} ({r['compile']:.2f} / {r['solve']:.2f})" if "fit" in r else "–")
        rows.append(f"| {label} | **{r['wall']:.2f}** | {r['cpu']:.1f} | {r.get('startup', float('nan')):.2f} | "
                    f"{r.get('data', float('nan')):.2f} | {fit} | {r.get('output', float('nan')):.2f} | "
                    f"{r['new_cache_files']} |")
    warm = cli["runs"]["warm"]["new_cache_files"]
    if cli.get("sources_edited") or warm:
        rows += ["", f"**The warm row is not warm**: it wrote {warm} new cache files"
                 + (" (jaxcal's sources were edited between the cold and the warm run, which changes the stored "
                    "programs' keys)" if cli.get("sources_edited") else "") + "; run again."]
    return rows + [""]


if __name__ == "__main__":
    main()
