"""The prior's scale chosen by the evidence (``prior="evidence"``) against the fixed 0.5° / 2 mm prior (issue 54).

1. **Simulated data with known deviations** (``jaxcal.simulate_experiment``: HSR-JR680, tracker
   positions, σ = 0.1 mm, half the joint ranges, 200 training and ~400 held-out poses), the
   deviations drawn at four sizes from 0.05° / 0.2 mm to 1° / 5 mm, several seeds: the chosen σ
   over the drawn σ (per family), the held-out RMSE over the statistical floor
   (``jaxcal.statistical_floor`` with the data-identifiable parameter count), and the std of the
   posterior z-scores ``(x̂ − x_true)/σ_post`` over every free parameter (pooled over the seeds;
   1 for a posterior that is neither over- nor under-confident) — for the evidence prior and the
   fixed default prior, both with the Huber loss.
2. **Real data**: FIGAROH's TIAGo files (``tests/data/figaroh_tiago`` Qualisys, 35 postures, 3
   markers, 5 contiguous folds; ``tests/data/figaroh_tiago_vicon`` the 7 base-referenced Vicon
   sessions, 3 posture folds held out of every session at once), with ``bench_figaroh``'s loaders
   and fits (the TIAGo URDF: ``--urdf``, ``$JAXCAL_TIAGO_URDF`` or the figaroh-examples mirror):
   pooled held-out RMSE of the evidence prior, today's fixed prior (both + Huber) and a plain and a
   Huber ``scipy.optimize.least_squares`` (``method="trf"``, the exact Jacobian) of the
   data-identifiable free parameters (QR with column pivoting at the start, no prior: what plain
   least squares can determine) from the same closed-form start on the same training rows; the
   Huber ``f_scale`` is ``1.345·σ̂`` per residual entry, σ̂ the MAD scale of the plain fit's residuals.
   **Public sets** (read from where the flags say, not kept here): the ABB IRB 120 points of Wu et
   al. (T-ASE 2015; ``--irb120``): 6 contiguous folds of its 36 configurations, and its two test
   sessions predicted by the fits on all 36 (each test point registered at q = 0 from its own
   measurement); the Franka Panda ball-in-socket data of MUKCa (MIT, kept in
   ``tests/data/mukca_panda``): leave one plate placement out, the other placements fitted with
   their sockets' known 50.1 mm spacing (``KnownDistance``), the held-out placement scored by its
   rows' agreement on each socket's centre and its sockets' spacing; ``--only-public`` runs and
   writes this section alone.
3. **Warm ``calibrate()`` time** of the evidence prior and the default prior on one simulated set
   (same process, interleaved, median and quartiles), the solves each runs, and the XLA programs
   compiled (or loaded from the persistent cache) by the first call of each and by the warm calls.

Run: ``python benchmarks/bench_evidence.py [--seeds 4] [--urdf tiago_no_hand.urdf] [--irb120 DIR]``. Writes
``benchmarks/results/evidence_cpu.md`` (or ``--out``). Record the load average: on a shared
machine the times move with it, the accuracies and counts do not.
"""

from __future__ import annotations

import argparse
import collections
import math
import os
import pathlib
import subprocess
import sys
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

sys.path.insert(0, str(pathlib.Path(__file__).parent))
import bench_figaroh as bf  # noqa: E402
from _common import machine, write_results  # noqa: E402

import jaxcal  # noqa: E402
from jaxcal._calibration._calibrate import resolve_space  # noqa: E402
from jaxcal._core._metrics import robust_scale  # noqa: E402
from jaxcal._sensors._initial_extras import initial_extras  # noqa: E402

SIZES = ((0.05, 0.2), (0.2, 1.0), (0.5, 2.0), (1.0, 5.0))
NOISE = 0.1
PRIORS = {"evidence": "evidence", "fixed 0.5°/2 mm": "default"}


def _quiet_calibrate(*a, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return jaxcal.calibrate(*a, **kw)


def _load() -> float:
    return os.getloadavg()[0]


# -- 1. simulated --------------------------------------------------------------------------------


def simulated(seeds: int) -> list[str]:
    rows = []
    for ang, ln in SIZES:
        acc = {name: collections.defaultdict(list) for name in PRIORS}
        for seed in range(seeds):
            ex = jaxcal.simulate_experiment(jax.random.key(100 + seed), None, n_samples=600, test_fraction=0.667,
                                            noise_std=NOISE, measurement=jaxcal.Position(), angle_std_deg=ang,
                                            length_std_mm=ln, coverage=0.5)
            true = ex.true_deviations.named()
            for name, prior in PRIORS.items():
                r = _quiet_calibrate(ex.robot, ex.measurement, ex.train, "lm", prior=prior, loss="huber")
                a = acc[name]
                floor = jaxcal.statistical_floor(NOISE, r.identifiability.rank, ex.train.n, 3).test
                a["ratio"].append(r.evaluate(ex.test).rmse / floor)
                sd = np.asarray(r.uncertainty.std)
                z = (np.asarray(r.x) - np.asarray([true[n] for n in r.space.free_names])) / sd
                a["z"].extend(z[np.isfinite(z)].tolist())
                # the realised spread: RMS of the drawn deviations of each family's free parameters
                spread = {u: math.sqrt(np.mean([true[n] ** 2 for n, v in zip(r.space.free_names, r.space.free_units)
                                                if v == u])) for u in ("rad", "mm")}
                spread["rad"] = math.degrees(spread["rad"])
                got = ({"angles": 0.5, "lengths": 2.0} if r.prior.evidence is None
                       else dict(zip(r.prior.evidence.families, r.prior.evidence.std)))
                a["angles"].append(got["angles"] / ang)
                a["lengths"].append(got["lengths"] / ln)
                a["angles_real"].append(got["angles"] / spread["rad"])
                a["lengths_real"].append(got["lengths"] / spread["mm"])
        for name, a in acc.items():
            rng = lambda v: f"{np.mean(v):.2f} ({min(v):.2f}–{max(v):.2f})"  # noqa: E731
            rows.append(f"| {ang:g}° / {ln:g} mm | {name} | {rng(a['angles'])} | {rng(a['lengths'])} | "
                        f"{rng(a['angles_real'])} | {rng(a['lengths_real'])} | "
                        f"{np.mean(a['ratio']):.3f} ({max(a['ratio']):.3f}) | {np.std(a['z']):.2f} |")
        print("\n".join(rows[-2:]), flush=True)
    return ["| drawn σ | prior | prior σ ÷ drawn σ, angles: mean (range) | lengths | prior σ ÷ realised spread, "
            "angles | lengths | held-out RMSE ÷ floor: mean (worst) | std of z-scores |",
            "|---|---|---:|---:|---:|---:|---:|---:|", *rows]


# -- 2. real data: TIAGo -------------------------------------------------------------------------


def _scipy_fit(robot, m, q, y, start, extras, loss: str):
    """``(deviations, space)``: ``scipy.optimize.least_squares`` of the data-identifiable free
    parameters (no prior) from ``start``; ``loss`` ``"linear"`` or ``"huber"``."""
    from scipy.optimize import least_squares

    q, y = jnp.asarray(q), jnp.asarray(y)
    space, _ = resolve_space(robot, m, q, None, start=start, extras=extras)
    problem = jaxcal.Problem(robot, m, q, y, space, start)
    fun = jax.jit(lambda x: problem.residual(x))
    jac = jax.jit(jax.jacfwd(lambda x: problem.residual(x)))
    x0 = np.asarray(space.to_vector_numpy(start), np.float64)
    f = lambda x: np.asarray(fun(jnp.asarray(x)), np.float64)  # noqa: E731
    J = lambda x: np.asarray(jac(jnp.asarray(x)), np.float64)  # noqa: E731
    sol = least_squares(f, x0, jac=J, method="trf", x_scale="jac", max_nfev=500)
    if loss == "huber":
        s = robust_scale(f(sol.x))
        sol = least_squares(f, sol.x, jac=J, method="trf", x_scale="jac", loss="huber", f_scale=1.345 * s,
                            max_nfev=500)
    return problem.deviations(jnp.asarray(sol.x)), space


def contiguous_folds(robot, m, q, y, folds: int, tag: str, gross_row: int | None = None):
    """``(out, scales)``: the pooled held-out RMSE of each fit over ``folds`` contiguous blocks of
    ``(q, y)`` (3-D marker errors, the measurement frame estimated: ``extras=["base"]``), as a
    tuple: over every held-out row, and (``gross_row`` given) without that row; and the σ the
    evidence chose on each fold's training rows."""
    n = q.shape[0]
    out = {}
    for name, prior in PRIORS.items():
        res = bf.held_out(robot, m, q, y, folds, prior=prior)
        out[name] = _pooled(np.concatenate([f["after_test_errors"] for f in res]),
                            np.concatenate([f["block"] for f in res]), gross_row)
        print(f"{tag} {name}: " + " / ".join(f"{v:.3f}" for v in out[name]), flush=True)
    scales = []
    for loss in ("linear", "huber"):
        errs, rows = [], []
        for b in np.array_split(np.arange(n), folds):
            tr = np.setdiff1d(np.arange(n), b)
            start = initial_extras(robot, m, (jnp.asarray(q[tr]), jnp.asarray(y[tr]))).deviations
            if loss == "linear":  # the scales the evidence chose on this fold (bench_figaroh.fit's calibration)
                scales.append(_chosen(_quiet_calibrate(robot, m, (jnp.asarray(q[tr]), jnp.asarray(y[tr])), "lm",
                                                       extras=["base"], prior="evidence", loss="huber", start=start)))
            dev, _ = _scipy_fit(robot, m, q[tr], y[tr], start, ("base",), loss)
            errs.append(bf.sample_errors(robot, m, dev, q[b], y[b]))
            rows.append(b)
        name = f"scipy least_squares ({'plain' if loss == 'linear' else 'Huber'})"
        out[name] = _pooled(np.concatenate(errs), np.concatenate(rows), gross_row)
        print(f"{tag} {name}: " + " / ".join(f"{v:.3f}" for v in out[name]), flush=True)
    return out, scales


def _pooled(e, rows, gross_row) -> tuple[float, ...]:
    return (bf.rms(e),) if gross_row is None else (bf.rms(e), bf.rms(e[rows != gross_row]))


def qualisys(text, folds: int = 5) -> dict:
    """Pooled held-out RMSE (with / without the gross row) of each fit on the Qualisys file."""
    q, y, _ = bf.load_figaroh_markers()
    return contiguous_folds(bf.tiago_chain(text), jaxcal.Markers(np.zeros((y.shape[1], 3))), q, y, folds, "qualisys",
                            gross_row=bf.OUTLIER_ROW)


def vicon(text, sessions, folds: int = 3) -> dict:
    """Pooled held-out RMSE of contiguous posture blocks held out of every Vicon session at once."""
    from jaxcal._calibration._evaluate import _errors
    from jaxcal._experiments._holdout import _rms

    chain = jaxcal.load_urdf(text, base=bf.BASE, tip=bf.VICON_TIP, name="TIAGo (tiago_no_hand.urdf)")
    data = bf.load_figaroh_vicon(sessions=sessions)
    out = {}
    for name, prior in PRIORS.items():
        out[name] = (bf.posture_blocks(chain, data, prior, folds)[1],)
        print(f"vicon {name}: {out[name][0]:.3f}", flush=True)
    sess = list(dict.fromkeys(lab[0] for lab in data.labels))
    per = data.n // len(sess)
    m = jaxcal.SessionMarkers.from_dataset(data)
    scales = []
    for loss in ("linear", "huber"):
        errs = []
        for b in np.array_split(np.arange(per), folds):
            test = np.concatenate([i * per + b for i in range(len(sess))])
            train = np.setdiff1d(np.arange(data.n), test)
            mt = m.take(train)
            start = jaxcal.initial_sessions(chain, mt, data.subset(train)).deviations
            if loss == "linear":  # the scales the evidence chose on this fold (posture_blocks' calibration)
                scales.append(_chosen(_quiet_calibrate(chain, mt, data.subset(train), "lm", prior="evidence",
                                                       loss="huber", start=start)))
            dev, _ = _scipy_fit(chain, mt, data.q[train], data.y[train], start, (), loss)
            errs.append(_errors(chain, m.take(test), dev, data.q[test], data.y[test]))
        name = f"scipy least_squares ({'plain' if loss == 'linear' else 'Huber'})"
        out[name] = (_rms(np.concatenate(errs)),)
        print(f"vicon {name}: {out[name][0]:.3f}", flush=True)
    return out, scales


# -- 2b. real data: public calibration sets (not in the repository) ------------------------------

IRB120_REPO = "https://github.com/drliaowu/Minimal_Robot_Calibration_Using_Position"
IRB120_COMMIT = "376cb83006b7ae4ae3328761c406e22e78c4be06"
IRB120_GIT = pathlib.Path("/work/.mirror/drliaowu+Minimal_Robot_Calibration_Using_Position/repo")
IRB120_DIR = "MinimalPositionCalibration"
# The test points measured at the zero configuration (mm, measurement frame): typed in the
# repository's Experiment.m (TestPoint_Meas, TestPoint_Meas2), not in a data file.
IRB120_HOME = {"TestPosition": (-82.538708, 502.156798, 652.749355),
               "TestPosition2": (-82.389469, 502.253113, 654.004118)}


def load_irb120(path=None) -> dict | None:
    """The ABB IRB 120 data of Wu, Yang, Chen & Ren, *A minimal POE-based model for robotic kinematic
    calibration with only position measurements*, IEEE T-ASE 12(2) 758–763, 2015, §IV, as published
    with its MATLAB code (``IRB120_REPO`` at ``IRB120_COMMIT``, folder ``MinimalPositionCalibration``;
    the repository states no licence, so the files stay out of this one).

    ``path``: that folder (the ``.mat`` files), else ``$JAXCAL_IRB120_DATA``, else the git mirror;
    ``None`` if none is found. Returns ``{"q": [36, 6] rad, "y": [36, 3, 3] mm`` (three points on the
    end effector per configuration, measurement frame), ``"tests": [(name, q [n, 6] rad, y [n, 3] mm,
    home [3] mm)]}``: the two test sessions (10 and 30 configurations), each of one point whose
    position at the zero configuration was measured on its own (``home``)."""
    import io

    import scipy.io

    def reader():
        for p in (path, os.environ.get("JAXCAL_IRB120_DATA")):
            if p and pathlib.Path(p).is_dir():
                return lambda name: (pathlib.Path(p) / f"{name}.mat").read_bytes()
        if IRB120_GIT.exists():
            return lambda name: subprocess.run(["git", "--git-dir", str(IRB120_GIT), "show",
                                                f"{IRB120_COMMIT}:{IRB120_DIR}/{name}.mat"],
                                               capture_output=True, check=True).stdout
        return None

    read = reader()
    if read is None:
        return None

    def mat(name):
        return next(v for k, v in scipy.io.loadmat(io.BytesIO(read(name))).items() if not k.startswith("__"))

    q = np.deg2rad(mat("CaliJointAngles"))
    y = mat("CaliPosition").reshape(q.shape[0], 3, 3)  # rows: point 1, 2, 3 of configuration 1, then 2, ...
    tests = [(name, np.deg2rad(mat(qname)), mat(name), np.asarray(home))
             for (name, home), qname in zip(IRB120_HOME.items(), ("TestJointAngles", "TestJointAngles2"))]
    return {"q": q, "y": y, "tests": tests}


def _registered_errors(robot, dev, q, y, home) -> np.ndarray:
    """3-D errors (mm) at ``q`` of a point on the end effector known only by its measured position
    ``home`` at the zero configuration: its flange coordinates from the fit (``dev``) at q = 0."""
    pose = jaxcal.Pose()
    t0 = np.asarray(pose.predict(robot, dev, jnp.zeros((1, robot.dof))))[0]
    p = t0[:3, :3].T @ (home - t0[:3, 3])
    t = np.asarray(pose.predict(robot, dev, jnp.asarray(q)))
    return np.linalg.norm(t[:, :3, :3] @ p + t[:, :3, 3] - y, axis=1)


def irb120(data, folds: int = 6) -> dict:
    """The ABB IRB 120 rows: contiguous folds of the 36 calibration configurations, and the two test
    sessions predicted by the fits on all 36."""
    robot = jaxcal.robots.abb_irb120(tool_mm=(0.0, 0.0, 0.0))
    m = jaxcal.Markers(np.zeros((3, 3)))
    q, y = data["q"], data["y"]
    cv = contiguous_folds(robot, m, q, y, folds, "irb120")
    start = initial_extras(robot, m, (jnp.asarray(q), jnp.asarray(y))).deviations
    fits = {}
    for name, prior in PRIORS.items():
        res = _quiet_calibrate(robot, m, (jnp.asarray(q), jnp.asarray(y)), "lm", extras=["base"], prior=prior,
                               loss="huber", start=start)
        fits[name] = res.deviations
        if prior == "evidence":
            scales = [_chosen(res)]
    for loss in ("linear", "huber"):
        fits[f"scipy least_squares ({'plain' if loss == 'linear' else 'Huber'})"] = _scipy_fit(
            robot, m, q, y, start, ("base",), loss)[0]
    sessions = {name: tuple(bf.rms(_registered_errors(robot, dev, qt, yt, home)) for _, qt, yt, home in data["tests"])
                for name, dev in fits.items()}
    for name, v in sessions.items():
        print(f"irb120 test sessions {name}: " + " / ".join(f"{x:.3f}" for x in v), flush=True)
    return cv, (sessions, scales)


# -- 2c. real data: MUKCa ball-in-socket (kept in tests/data/mukca_panda, MIT) -------------------

MUKCA_REPO = "https://github.com/platonics-delft/kinematics_calibration"
MUKCA_COMMIT = "05a05ab4cbbe328c8f5bfcc76479c752ed07b82e"
MUKCA_DIR = pathlib.Path(__file__).resolve().parents[1] / "tests" / "data" / "mukca_panda"
MUKCA_SPACING_MM = 50.1  # the two sockets' distance by caliper (50 mm as drawn)
MUKCA_SPACING_STD_MM = 0.1  # a caliper reading of a 3-D printed plate: ±0.1 mm (see public_section)


def load_mukca(path=None) -> dict:
    """The Franka Panda ``panda_2`` ball-in-socket data of MUKCa (Franzese, Spahn, Ramirez et al.,
    ``MUKCA_REPO`` at ``MUKCA_COMMIT``, MIT; copied in ``tests/data/mukca_panda``, see its
    SOURCE.md): ``{"urdf": text, "placements": {name: (q_socket0 [n0, 7], q_socket1 [n1, 7]) rad}}``."""
    d = pathlib.Path(path) if path else MUKCA_DIR
    places = sorted(p.name for p in (d / "panda_2").iterdir() if p.is_dir())
    return {"urdf": (d / "urdf" / "panda.urdf").read_text(),
            "placements": {p: tuple(np.loadtxt(d / "panda_2" / p / f"hole_{k}.csv", delimiter=",", ndmin=2)
                                    for k in (0, 1)) for p in places}}


def _socket_block(placements: dict, sigma=None):
    """``(block, relations)``: one :class:`jaxcal.FixedPoint` block, a label per placement × socket
    (``<placement>_0``, ``<placement>_1``), the shared ball (``tool``) estimated, and the known
    spacing of each placement's two sockets."""
    labels = [f"{p}_{k}" for p in placements for k in (0, 1)]
    q = np.concatenate([qk for pair in placements.values() for qk in pair])
    y = np.concatenate([np.full(qk.shape[0], float(i)) for i, qk in enumerate(qk for pair in placements.values()
                                                                              for qk in pair)])
    block = jaxcal.Block("sockets", jaxcal.FixedPoint(labels), (q, y), sigma=sigma, extras="tool")
    rel = [jaxcal.KnownDistance(f"{p}_0", f"{p}_1", MUKCA_SPACING_MM, std_mm=MUKCA_SPACING_STD_MM)
           for p in placements]
    return block, rel


def _ball_scores(robot, dev, pair) -> tuple[np.ndarray, float]:
    """Held-out placement scores of a fit ``dev`` (robot fixed): each socket's centre is the mean of
    its rows' predicted ball centres (the least-squares centre of ``p(q_i) − c``); returns the rows'
    3-D distances to their socket's centre (mm) and the centres' distance (mm)."""
    from jaxcal._models._kinematics import tool_point_soa

    ps = [np.stack([np.asarray(a) for a in tool_point_soa(robot, dev, jnp.asarray(qk))], -1) for qk in pair]
    cs = [p.mean(0) for p in ps]
    return (np.concatenate([np.linalg.norm(p - c, axis=1) for p, c in zip(ps, cs)]),
            float(np.linalg.norm(cs[0] - cs[1])))


def _scipy_blocks(robot, placements, start, loss: str):
    """scipy ``least_squares`` of the combined residual (the ball-in-socket rows over σ_b and the
    known spacings over their σ) of the data-identifiable parameters from ``start``; σ_b from a
    first plain fit with σ_b = 1 mm (its point residuals' RMS, N − p degrees of freedom)."""
    from jaxcal._sensors._blocks import combine

    sigma = 1.0
    for rnd in range(2):
        block, rel = _socket_block(placements, sigma=sigma)
        model, q, y = combine(robot, [block], rel)
        dev, space = _scipy_fit(robot, model, q, y, start, ("tool",), "linear" if rnd == 0 else loss)
        if rnd == 0:
            r = np.asarray(model.block_residuals(robot, dev, jnp.asarray(q), jnp.asarray(y))[0])
            r = r[: block.arrays()[0].shape[0]]
            sigma = float(np.sqrt(np.sum(r ** 2) / (r.size - len(space.free_names))))
    return dev


def mukca(data) -> tuple:
    """Leave one plate placement out: fit on the others (a label per placement × socket, the ball
    on the flange estimated, the known spacing per training placement), score the held-out one."""
    robot = jaxcal.load_urdf(data["urdf"], tip="ball_link", name="Franka Panda (MUKCa urdf/panda.urdf)")
    places = data["placements"]
    names = [*PRIORS, "scipy least_squares (plain)", "scipy least_squares (Huber)"]
    dists = {n: [] for n in names}
    gaps = {n: [] for n in names}
    scales = []
    nominal = [_ball_scores(robot, None, pair) for pair in places.values()]
    for held, pair in places.items():
        train = {p: v for p, v in places.items() if p != held}
        block, rel = _socket_block(train)
        fits = {}
        for name, prior in PRIORS.items():
            res = _quiet_calibrate_blocks(robot, [block], rel, prior=prior)
            fits[name] = res.deviations
            if prior == "evidence":
                scales.append(_chosen(res))
                start = res.start
        for loss in ("linear", "huber"):
            fits[f"scipy least_squares ({'plain' if loss == 'linear' else 'Huber'})"] = _scipy_blocks(
                robot, train, start, loss)
        for name, dev in fits.items():
            d, spacing = _ball_scores(robot, dev, pair)
            dists[name].append(d)
            gaps[name].append(spacing - MUKCA_SPACING_MM)
        print(f"mukca {held}: " + "; ".join(f"{n} {bf.rms(dists[n][-1]):.3f} / {gaps[n][-1]:+.3f}" for n in names),
              flush=True)
    out = {n: (bf.rms(np.concatenate(dists[n])), bf.rms(np.asarray(gaps[n])), float(np.max(np.abs(gaps[n]))))
           for n in names}
    per_fold = {n: gaps[n] for n in names}
    nom = (bf.rms(np.concatenate([d for d, _ in nominal])), bf.rms(np.asarray([s - MUKCA_SPACING_MM
                                                                               for _, s in nominal])))
    return (out, scales), per_fold, nom, list(places)


def _quiet_calibrate_blocks(*a, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return jaxcal.calibrate_blocks(*a, "lm", loss="huber", **kw)


def _chosen(res) -> str:
    """``"0.47° / 3.2 mm"``: the σ the evidence chose in a fit."""
    got = dict(zip(res.prior.evidence.families, res.prior.evidence.std))
    return f"{got['angles']:.2g}° / {got['lengths']:.2g} mm"


def real_table(sets: dict) -> list[str]:
    names = list(next(iter(sets.values()))[0][0])
    lines = ["| data | held out | " + " | ".join(f"{n} / mm" for n in names)
             + " | evidence ÷ fixed | evidence ÷ better scipy |", "|---|---|" + "---:|" * (len(names) + 2)]
    for data_name, ((res, _), parts) in sets.items():
        for i, part in enumerate(parts):
            v = {n: res[n][i] for n in names}
            best_scipy = min(v[n] for n in names if n.startswith("scipy"))
            lines.append(f"| {data_name} | {part} | " + " | ".join(f"{v[n]:.3f}" for n in names)
                         + f" | {v['evidence'] / v['fixed 0.5°/2 mm']:.3f} | {v['evidence'] / best_scipy:.3f} |")
    lines += ["", "The σ (angles / lengths) the evidence chose on each fold's training rows:", "",
              "| data | folds |", "|---|---|"]
    lines += [f"| {data_name} | {'; '.join(scales)} |" for data_name, ((_, scales), _) in sets.items()]
    return lines


# -- 3. warm calibrate time and programs ---------------------------------------------------------


def timing(repeats: int) -> list[str]:
    ex = jaxcal.simulate_experiment(jax.random.key(5), None, n_samples=250, test_fraction=0.2, noise_std=NOISE,
                                    measurement=jaxcal.Position(), angle_std_deg=0.3, length_std_mm=1.0, coverage=0.5)
    events = collections.Counter()

    def on_duration(name, duration, **kw):
        if name == "/jax/core/compile/backend_compile_duration":
            events["programs"] += 1

    def on_event(name, **kw):
        if name == "/jax/compilation_cache/cache_hits":
            events["programs"] += 1

    jax.monitoring.register_event_duration_secs_listener(on_duration)
    jax.monitoring.register_event_listener(on_event)
    first, times, rounds = {}, {name: [] for name in PRIORS}, {}
    load0 = _load()
    for name, prior in reversed(PRIORS.items()):  # the default first: the programs a session has today
        before = events["programs"]
        r = _quiet_calibrate(ex.robot, ex.measurement, ex.train, "lm", prior=prior, loss="huber")
        first[name] = events["programs"] - before
        rounds[name] = r.diagnostics.rounds
    warm_before = events["programs"]
    for _ in range(repeats):
        for name, prior in PRIORS.items():
            t = time.perf_counter()
            _quiet_calibrate(ex.robot, ex.measurement, ex.train, "lm", prior=prior, loss="huber")
            times[name].append(time.perf_counter() - t)
    warm = events["programs"] - warm_before
    load1 = _load()
    lines = [f"Simulated HSR-JR680 tracker set (200 training poses, 24 candidate parameters), LM + Huber; {repeats} "
             f"warm calls of each, interleaved; load average {load0:.2f} at the start, {load1:.2f} at the end. "
             f"XLA programs compiled or loaded by all {2 * repeats} warm calls: **{warm}**.", "",
             "| prior | warm calibrate() median / ms (quartiles) | solves (rounds) | XLA programs of its first call |",
             "|---|---:|---:|---:|"]
    for name in PRIORS:
        t = np.asarray(times[name]) * 1e3
        lines.append(f"| {name} | {np.median(t):.1f} ({np.percentile(t, 25):.1f}–{np.percentile(t, 75):.1f}) | "
                     f"{rounds[name]} | {first[name]} |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--urdf", help="TIAGo URDF (default: $JAXCAL_TIAGO_URDF or the figaroh-examples mirror)")
    ap.add_argument("--irb120", help="the MinimalPositionCalibration folder of " + IRB120_REPO + " (default: "
                    "$JAXCAL_IRB120_DATA or the mirror)")
    ap.add_argument("--only-public", action="store_true",
                    help="only the public data sets' section (the results file is then that section alone)")
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "evidence_cpu.md"))
    args = ap.parse_args()
    t0, load0 = time.perf_counter(), _load()
    if args.only_public:
        lines = public_section(args)
        lines[2:2] = [f"`python benchmarks/bench_evidence.py --only-public`; {machine()}; load average {load0:.2f} "
                      f"at the start, {_load():.2f} at the end (a shared machine); {time.perf_counter() - t0:.0f} s.",
                      ""]
        write_results(args.out, lines)
        return
    timing_lines = timing(args.repeats)
    print("\n".join(timing_lines), flush=True)
    sim = simulated(args.seeds)
    text = bf.tiago_urdf_text(args.urdf)
    real = None
    if text is not None:
        real = {"TIAGo Qualisys (35 postures, 5 contiguous folds)": (qualisys(text), ("held out",
                                                                                      "without the gross row")),
                "TIAGo Vicon, the rigid marker (3 gripper3 sessions × 21 postures, 3 posture folds)": (
                    vicon(text, [s for s in bf.VICON_BASE_SESSIONS if s.startswith("gripper3")]), ("held out",)),
                "TIAGo Vicon, all 7 base sessions (gripper1/2 not rigid: no model fits them)": (
                    vicon(text, bf.VICON_BASE_SESSIONS), ("held out",))}
    lines = [
        "# The prior's scale chosen by the evidence vs the fixed prior",
        "",
        f"`python benchmarks/bench_evidence.py --seeds {args.seeds}`; {machine()}; load average {load0:.2f} at the "
        f"start, {_load():.2f} at the end (a shared machine); {time.perf_counter() - t0:.0f} s.",
        "",
        "## Simulated data with known deviations",
        "",
        f"`jaxcal.simulate_experiment`: HSR-JR680, tracker positions (σ = {NOISE} mm), half the joint ranges, 200 "
        f"training and ~400 held-out poses; deviations drawn with σ (angles / lengths) as in the first column; seeds "
        f"100–{99 + args.seeds}; LM + Huber. Chosen ÷ drawn σ for the fixed prior: its 0.5° / 2 mm over the drawn σ. "
        "Floor: `jaxcal.statistical_floor(σ, rank, 200, 3).test` (rank: the data-identifiable parameters). z-scores: "
        "`(x̂ − x_true)/σ_post` over all free parameters, pooled over the seeds.",
        "",
        *sim,
        "",
        "## Real data: FIGAROH's TIAGo files",
        "",
    ]
    if real is None:
        lines.append("Not run: the TIAGo URDF was not found (`--urdf`, `$JAXCAL_TIAGO_URDF` or the mirror).")
    else:
        lines += ["Pooled held-out RMSE (mm) of the 3-D marker errors. Qualisys: `bench_figaroh.held_out` (5 "
                  "contiguous folds; the file's gross row 10 in one of them, the RMSE also without it); Vicon: "
                  "`bench_figaroh.posture_blocks` (contiguous posture blocks held out of every session at once, "
                  "frames and placements trained; the gripper3 marker is the one rigid with the flange, "
                  "`figaroh_cpu.md`). scipy: `least_squares(method=\"trf\")` with the exact Jacobian of "
                  "the data-identifiable parameters (no prior), from the same closed-form start; Huber "
                  "`f_scale = 1.345·σ̂` per residual entry.", "", *real_table(real)]
    lines += ["", *public_section(args)]
    lines += ["", "## Warm `calibrate()` time and XLA programs", "", *timing_lines]
    write_results(args.out, lines)


def public_section(args) -> list[str]:
    """The section on public calibration data sets (read from where ``--irb120`` etc. say)."""
    lines = ["## Real data: public calibration sets", "", *mukca_section(), ""]
    data = load_irb120(args.irb120)
    if data is None:
        return lines + [f"Not run: the ABB IRB 120 data were not found (`--irb120`, `$JAXCAL_IRB120_DATA`; get them "
                        f"from {IRB120_REPO}, folder `{IRB120_DIR}`)."]
    cv, sessions = irb120(data)
    n_test = " and ".join(str(t[1].shape[0]) for t in data["tests"])
    sets = {"ABB IRB 120, 3 points × 36 configurations, 6 contiguous folds": (cv, ("held out",)),
            "ABB IRB 120, fitted on all 36 configurations": (sessions, tuple(
                f"test session {i + 1} ({t[1].shape[0]} configurations, another point)"
                for i, t in enumerate(data["tests"])))}
    return lines + [
        f"**ABB IRB 120** (Wu, Yang, Chen & Ren, IEEE T-ASE 12(2), 2015, §IV; the data published with their MATLAB "
        f"code, {IRB120_REPO} at `{IRB120_COMMIT[:10]}`, folder `{IRB120_DIR}`: no licence stated, so read from "
        "`--irb120`, not kept here). Three points on the end effector measured in 36 configurations (a 3-D "
        "coordinate measuring device's frame, mm; joint angles from the controller, °), and two test sessions "
        f"({n_test} configurations) of one further point each, whose position at the zero configuration was "
        "measured on its own. Model: `jaxcal.robots.abb_irb120` (product-specification DH), the 3 points' flange "
        "coordinates and the measurement frame estimated (`Markers`, `extras=[\"base\"]`), LM + Huber; the "
        "nominal model with the closed-form frame and points is 5.3 mm RMS off on the 36 configurations. Held out: "
        "6 contiguous blocks of 6 configurations (pooled 3-D errors); and the test sessions, each test point's "
        "flange coordinates taken from its zero-configuration measurement through the fit being tested (the "
        "paper's protocol, nothing fitted on the test rows). scipy as above.",
        "",
        *real_table(sets)]



def mukca_section() -> list[str]:
    """The MUKCa ball-in-socket rows (placement-held-out folds)."""
    data = load_mukca()
    cv, per_fold, nominal, places = mukca(data)
    n = sum(a.shape[0] + b.shape[0] for a, b in data["placements"].values())
    k = len(places)
    sets = {f"Franka Panda ball in socket (MUKCa panda_2), {k} placements, leave one placement out": (cv, (
        "held-out rows' ball centres about their socket's centre (RMS)",
        f"held-out socket spacing − {MUKCA_SPACING_MM:g} mm (RMS over the {k} folds)",
        "the same, the worst fold's absolute value"))}
    signed = "; ".join(f"{name}: " + ", ".join(f"{g:+.2f}" for g in gaps) + f" (mean {np.mean(gaps):+.3f})"
                       for name, gaps in per_fold.items())
    return [
        f"**Franka Panda, ball in socket** (MUKCa: Franzese, Spahn, Ramirez et al., {MUKCA_REPO} at "
        f"`{MUKCA_COMMIT[:10]}`, MIT; the `panda_2` data and `urdf/panda.urdf` copied to `tests/data/mukca_panda`, "
        f"see its SOURCE.md). A ball on the flange seated in one of two sockets of a 3-D printed plate, "
        f"{MUKCA_SPACING_MM:g} mm apart by caliper (50 mm as drawn), the plate at {k} placements ({', '.join(places)}); "
        f"{n} rows of joint angles only. Model: `jaxcal.load_urdf(urdf/panda.urdf, tip=\"ball_link\")`, one "
        "`FixedPoint` block (a label per placement × socket, the ball's flange coordinates estimated: "
        "`extras=\"tool\"`, σ by variance components) and one `KnownDistance` per training placement, "
        f"{MUKCA_SPACING_MM:g} ± {MUKCA_SPACING_STD_MM:g} mm (σ: a caliper reading of a printed plate, and the 0.1 mm "
        "between the drawing and the reading; tighter would claim more than was measured, looser lets the "
        "fit shrink the robot as it does without the relation), `jaxcal.calibrate_blocks(..., \"lm\", "
        "loss=\"huber\")`. Each fold fits on the other placements and scores the held-out one with the robot "
        "(and ball) fixed: each socket's centre is the mean of its rows' predicted ball centres (the least-squares "
        "centre of `p(q_i) − c`, nothing else fitted), (a) the RMS 3-D distance of the held-out rows to their "
        f"socket's centre, (b) the two centres' distance − {MUKCA_SPACING_MM:g} mm. scipy: `least_squares` of the "
        "same combined residual (rows over σ_b, relations over their σ) of the data-identifiable parameters "
        "from the same start (the evidence fit's closed-form start), σ_b from a first plain fit at σ_b = 1 mm "
        "(its point residuals' RMS with N − p degrees of freedom), then the plain or Huber fit at that σ_b. The "
        f"nominal robot: {nominal[0]:.3f} mm (a), {nominal[1]:.3f} mm (b, RMS over the placements).",
        "",
        *real_table(sets),
        "",
        f"Held-out spacing − {MUKCA_SPACING_MM:g} mm per fold ({', '.join(places)}), mm: {signed}."]


if __name__ == "__main__":
    main()
