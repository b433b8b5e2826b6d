"""FIGAROH's published TIAGo motion-capture calibration data, end to end from the URDF.

Data: ``tests/data/figaroh_tiago/qualysis_base_hand_calibration.csv`` (FIGAROH, Apache-2.0;
source and commit in ``SOURCE.md``): 35 static postures of TIAGo's prismatic torso + 7-joint arm,
positions of markers on the hand measured by a Qualisys system (4 marker columns, of which the 4th
repeats the 3rd in every row: 3 distinct markers). The file has no session column: it is one
recording. "Held out" below means contiguous blocks of postures in recording order (5 folds of 7),
each calibrated on the other 28 and evaluated on the block.

Robot: the TIAGo URDF of FIGAROH's examples (``examples/tiago/urdf/tiago_no_hand.urdf``; CC BY-NC-ND,
so not shipped: ``--urdf``, ``$JAXCAL_TIAGO_URDF`` or a git mirror of figaroh-examples), chain
``base_footprint`` → ``wrist_ft_tool_link`` as FIGAROH's ``tiago_config.yaml`` (``universe`` is the
root, base_footprint). Model: :class:`jaxcal.SerialChain` per-joint errors (offset, dx..drz), the
mocap frame (``base`` extras, 6) and the marker positions on the hand (``marker_k``, 3 each) unknown,
started in closed form (Kabsch on marker centroids + alternating least squares) on the training
postures; LM with jaxcal's default prior toward the URDF (0.5°, 2 mm; none on the extras) and the
Huber loss (the data hold one ~60 mm gross outlier: data row 10, the row figaroh-examples' copy of
the file lacks).

"before" = the nominal URDF with the mocap frame and the marker layout fitted to the training
postures (without them a marker RMSE means nothing: the mocap frame is ~0.5 m from the robot's).
RMSE = root mean square over postures and markers of the 3-D marker distance error (mm). Held-out
RMSEs are given with and without the outlier row.

Two set-ups: ``3 markers`` (all distinct markers: jaxcal's ``Markers`` model) and ``1 marker``
(FIGAROH's ``tiago_config.yaml``: ``markers: [arm_7_joint, xyz]``, only columns x1,y1,z1).

Run: ``python benchmarks/bench_figaroh.py [--urdf tiago_no_hand.urdf]`` (about 2–4 min on 2 CPU cores).
Writes ``benchmarks/results/figaroh_cpu.md`` (or ``--out``).
"""

from __future__ import annotations

import argparse
import csv
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
from _common import machine  # noqa: E402

import jaxcal  # noqa: E402
from jaxcal._sensors._initial_extras import initial_extras  # noqa: E402

HERE = pathlib.Path(__file__).parent
DATA = HERE.parent / "tests" / "data" / "figaroh_tiago" / "qualysis_base_hand_calibration.csv"
FIGAROH_GIT = pathlib.Path("/work/.mirror/thanhndv212+figaroh-examples/repo")
URDF_PATH = "examples/tiago/urdf/tiago_no_hand.urdf"
BASE, TIP = "base_footprint", "wrist_ft_tool_link"
JOINTS = ("torso_lift_joint",) + tuple(f"arm_{k}_joint" for k in range(1, 8))
#: the gross outlier of the file (0-based; data row 10, file line 11: the row figaroh-examples' copy lacks)
OUTLIER_ROW = 9


def load_figaroh_markers(path=DATA, *, drop_duplicates: bool = True):
    """``(q [n, 8], y [n, N, 3], joint_names)`` from a FIGAROH mocap CSV.

    ``x1,y1,z1,…`` marker positions (m) become mm; ``torso_lift_joint`` (prismatic, m) becomes mm,
    the arm joints stay in rad. Marker columns that repeat an earlier marker in every row are
    dropped (``drop_duplicates``).
    """
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header = [h.strip() for h in rows[0]]
    a = np.asarray(rows[1:], dtype=np.float64)
    n_markers = sum(1 for h in header if h.startswith("x") and h[1:].isdigit())
    cols = [header.index(f"{c}{k}") for k in range(1, n_markers + 1) for c in "xyz"]
    y = a[:, cols].reshape(a.shape[0], n_markers, 3) * 1000.0
    if drop_duplicates:
        keep = [k for k in range(n_markers) if not any(np.array_equal(y[:, k], y[:, j]) for j in range(k))]
        y = y[:, keep]
    names = [h for h in header if h.endswith("_joint")]
    q = a[:, [header.index(h) for h in names]]
    q[:, names.index("torso_lift_joint")] *= 1000.0  # m -> mm
    return q, y, names


VICON = HERE.parent / "tests" / "data" / "figaroh_tiago_vicon"
#: the base-referenced Vicon sessions: marker placement gripperK, positions relative to base marker J
VICON_BASE_SESSIONS = ("gripper1_base1", "gripper1_base2", "gripper2_base1", "gripper2_base2", "gripper3_base1",
                       "gripper3_base2", "gripper3_base3")
#: the shoulder-referenced ones (frame on torso_lift_link: chain torso_lift_link -> tip, no torso joint)
VICON_SHOULDER_SESSIONS = ("gripper1_shoulder", "gripper2_shoulder", "gripper3_shoulder", "gripper3_shoulder2",
                           "gripper3_shoulder3", "gripper3_shoulder4")


def load_figaroh_vicon(family: str = "relative_encoder", sessions=VICON_BASE_SESSIONS, *, torso: bool = True):
    """A labelled marker :class:`jaxcal.Dataset` of FIGAROH's TIAGo Vicon sessions
    (``tests/data/figaroh_tiago_vicon/<family>/vicon_calibration_fc10_<session>.csv``).

    Each file is one (marker placement, reference frame) combination of the same 21 postures:
    ``gripperK_baseJ`` -> session ``gripperK_baseJ``, frame ``baseJ``, placement ``gripperK``
    (``..._shoulder`` -> frame ``shoulder1``). Marker ``x1,y1,z1`` (m) -> mm; ``torso_lift_joint`` (m) -> mm
    (dropped with ``torso=False``), arm joints rad.
    """
    qs, ys, labels = [], [], []
    for s in sessions:
        placement, frame = s.split("_", 1)
        frame = "shoulder1" if frame == "shoulder" else frame
        with open(VICON / family / f"vicon_calibration_fc10_{s}.csv", newline="") as f:
            rows = list(csv.reader(f))
        header = [h.strip() for h in rows[0]]
        a = np.asarray(rows[1:], dtype=np.float64)
        y = a[:, [header.index(c) for c in ("x1", "y1", "z1")]][:, None, :] * 1000.0
        names = list(JOINTS if torso else JOINTS[1:])
        q = a[:, [header.index(h) for h in names]]
        if torso:
            q[:, 0] *= 1000.0
        qs.append(q)
        ys.append(y)
        labels += [(s, frame, placement)] * q.shape[0]
    meta = {"source": f"FIGAROH Vicon sessions ({family}), tests/data/figaroh_tiago_vicon/SOURCE.md"}
    if torso:
        meta["mm_joints"] = "1"
    return jaxcal.Dataset(np.concatenate(qs), np.concatenate(ys), "markers", meta, labels)


def tiago_urdf_text(path=None):
    """The TIAGo URDF text: ``path``, ``$JAXCAL_TIAGO_URDF`` or the figaroh-examples mirror; else ``None``."""
    for p in (path, os.environ.get("JAXCAL_TIAGO_URDF")):
        if p and pathlib.Path(p).exists():
            return pathlib.Path(p).read_text()
    if FIGAROH_GIT.exists():
        try:
            return subprocess.run(["git", "--git-dir", str(FIGAROH_GIT), "show", f"HEAD:{URDF_PATH}"],
                                  capture_output=True, text=True, check=True).stdout
        except (subprocess.CalledProcessError, OSError):
            return None
    return None


def tiago_chain(text):
    return jaxcal.load_urdf(text, base=BASE, tip=TIP, name="TIAGo (tiago_no_hand.urdf)")


def sample_errors(robot, m, dev, q, y) -> np.ndarray:
    """Per-posture RMS-over-markers distance errors (mm)."""
    return np.asarray(m.sample_error(m.residual(robot, dev, jnp.asarray(q), jnp.asarray(y))), np.float64)


def rms(e) -> float:
    e = np.asarray(e, np.float64)
    return float(np.sqrt(np.mean(e * e))) if e.size else float("nan")


def fit(robot, m, q, y, *, prior="default", loss="huber"):
    """``(nominal start, result)``: closed-form frame + layout on ``(q, y)``, then LM."""
    start = initial_extras(robot, m, (jnp.asarray(q), jnp.asarray(y))).deviations
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = jaxcal.calibrate(robot, m, (jnp.asarray(q), jnp.asarray(y)), "lm", extras=["base"], prior=prior,
                               loss=loss, start=start)
    return start, res


def held_out(robot, m, q, y, folds: int, which=None, **kw):
    """Per contiguous block (``which``: indices of the blocks to run, default all): train/held-out
    RMSE before (nominal + closed-form extras) and after."""
    n = q.shape[0]
    blocks = np.array_split(np.arange(n), folds)
    out = []
    for b in (blocks if which is None else [blocks[i] for i in which]):
        tr = np.setdiff1d(np.arange(n), b)
        start, res = fit(robot, m, q[tr], y[tr], **kw)
        clean = b[b != OUTLIER_ROW]
        tr_clean = tr[tr != OUTLIER_ROW]
        out.append(dict(
            before_train_clean=rms(sample_errors(robot, m, start, q[tr_clean], y[tr_clean])),
            after_train_clean=rms(sample_errors(robot, m, res.deviations, q[tr_clean], y[tr_clean])),
            rows=f"{b[0] + 1}-{b[-1] + 1}",
            before_train=rms(sample_errors(robot, m, start, q[tr], y[tr])),
            after_train=rms(sample_errors(robot, m, res.deviations, q[tr], y[tr])),
            before_test=rms(sample_errors(robot, m, start, q[b], y[b])),
            after_test=rms(sample_errors(robot, m, res.deviations, q[b], y[b])),
            before_test_clean=rms(sample_errors(robot, m, start, q[clean], y[clean])),
            after_test_clean=rms(sample_errors(robot, m, res.deviations, q[clean], y[clean])),
            after_test_errors=sample_errors(robot, m, res.deviations, q[b], y[b]),
            before_test_errors=sample_errors(robot, m, start, q[b], y[b]),
            clean=clean, block=b, p=res.space.n_free, status=res.status.name.lower(),
        ))
    return out


def pooled(folds, key):
    """RMSE over every held-out posture (each predicted by the fit that did not see it)."""
    e = np.concatenate([f[f"{key}_test_errors"] for f in folds])
    rows = np.concatenate([f["block"] for f in folds])
    return rms(e), rms(e[rows != OUTLIER_ROW])


# -- FIGAROH's Vicon sessions (tests/data/figaroh_tiago_vicon): several markers/frames, jointly --------------
VICON_MARK = "<!-- vicon sessions: written by bench_figaroh.py (--vicon-only rewrites from here) -->"
VICON_TIP = "wrist_ft_tool_link"


def figaroh_vicon_results():
    """FIGAROH's published Vicon results: ``{"gripperK_baseJ": (names, values, cost)}`` (m, rad)."""
    out = {}
    for j in (1, 2):
        text = (VICON / f"gripper_base{j}_vicon_results").read_text()
        for block in [b for b in text.split("\n\n") if b.strip()]:
            lines = [ln.strip() for ln in block.strip().splitlines() if ln.strip()]
            head = lines[0].replace(" ", "")  # "gripper1base1", "gripper2base1"
            k = head[len("gripper")]
            names, vals, cost = [], [], float("nan")
            for ln in lines[1:]:
                if ln.startswith("minimized cost function"):
                    cost = float(ln.split(":")[1])
                elif ln[0].isdigit():
                    _, name, v = ln.split()
                    names.append(name)
                    vals.append(float(v))
            out[f"gripper{k}_base{j}"] = (names, np.asarray(vals), cost)
    return out


def figaroh_cost_to_rmse(names, vals, cost, n_samples=21, coeff=0.01):
    """FIGAROH's scipy ``cost = ½‖r‖²`` with ``r = [PEE_measured − PEE_model (m), √coeff·var[6:-3]]``
    (``tiago_utils/robot_tools.py`` ``cost_function``) → 3-D marker RMS distance (mm), with and without
    the regularisation term subtracted (upper bound: all of the cost is marker error)."""
    reg = 0.5 * coeff * float(np.sum(vals[6:-3] ** 2))
    upper = math.sqrt(2 * cost / n_samples) * 1000.0
    pos = max(cost - reg, 0.0)
    return math.sqrt(2 * pos / n_samples) * 1000.0, upper, reg


def _session_rows(data, sessions):
    return np.flatnonzero([lab[0] in sessions for lab in data.labels])


def _session_rms(robot, data, dev):
    """Per-session RMSE (mm) of ``dev`` on the labelled ``data``."""
    from jaxcal._calibration._evaluate import _errors
    from jaxcal._experiments._holdout import _rms

    m = jaxcal.SessionMarkers.from_dataset(data)
    e = _errors(robot, m, dev, data.q, data.y)
    return {s: _rms(e[[lab[0] == s for lab in data.labels]]) for s in dict.fromkeys(lab[0] for lab in data.labels)}


def _fit_sessions(robot, data, prior, loss="huber", **kw):
    m = jaxcal.SessionMarkers.from_dataset(data)
    start = jaxcal.initial_sessions(robot, m, data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = jaxcal.calibrate(robot, m, data, "lm", prior=prior, loss=loss, start=start.deviations, **kw)
    return start, res


def _free_compiled() -> None:
    """Drop compiled programs between stages: a long run of differently shaped fits otherwise exhausts
    LLVM's mapped code memory ("LLVM ERROR: Unable to allocate section memory" seen on the 2-core CPU)."""
    from jaxcal._calibration import _programs

    _programs._COMPILED.clear()
    jax.clear_caches()


def _largest(res, k=8):
    vals = [(n, v, u) for n, v, u in zip(res.space.free_names, np.asarray(res.x, np.float64), res.space.free_units)
            if "@" not in n]
    vals = [(n, math.degrees(v) if u == "rad" else v, "°" if u == "rad" else "mm") for n, v, u in vals]
    vals.sort(key=lambda t: -abs(t[1]) / (1.0 if t[2] == "°" else 4.0))  # 1° ~ 4 mm at the hand
    return ", ".join(f"{n} {v:+.2f}{'' if u == '°' else ' '}{u}" for n, v, u in vals[:k])


def posture_blocks(robot, data, prior, folds=3):
    """Hold out contiguous blocks of postures from EVERY session at once (the frames and placements stay
    trained): the honest generalisation test of data whose sessions share their postures."""
    from jaxcal._calibration._evaluate import _errors
    from jaxcal._experiments._holdout import _rms

    sess = list(dict.fromkeys(lab[0] for lab in data.labels))
    per = data.n // len(sess)
    blocks = np.array_split(np.arange(per), folds)
    eb, ea, rows_out = [], [], []
    m = jaxcal.SessionMarkers.from_dataset(data)
    for b in blocks:
        test = np.concatenate([i * per + b for i in range(len(sess))])
        train = np.setdiff1d(np.arange(data.n), test)
        mt = m.take(train)
        start = jaxcal.initial_sessions(robot, mt, data.subset(train)).deviations
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = jaxcal.calibrate(robot, mt, data.subset(train), "lm", prior=prior, loss="huber", start=start)
        me = m.take(test)
        eb.append(_errors(robot, me, start, data.q[test], data.y[test]))
        ea.append(_errors(robot, me, res.deviations, data.q[test], data.y[test]))
        rows_out.append(f"{b[0] + 1}-{b[-1] + 1}: {_rms(eb[-1]):.2f} → {_rms(ea[-1]):.2f}")
    return _rms(np.concatenate(eb)), _rms(np.concatenate(ea)), rows_out


def vicon_section(text, prior, prior_name) -> list[str]:
    from jaxcal._experiments._holdout import _rms

    t0 = time.perf_counter()
    chain = jaxcal.load_urdf(text, base=BASE, tip=VICON_TIP, name="TIAGo (tiago_no_hand.urdf)")
    data = load_figaroh_vicon()
    sessions = list(VICON_BASE_SESSIONS)
    rigid = [s for s in sessions if s.startswith("gripper3")]
    y = np.asarray(data.y)[:, 0]
    by = {s: y[_session_rows(data, [s])] for s in sessions}
    d12 = np.linalg.norm(by["gripper1_base1"] - by["gripper2_base1"], axis=1)
    d23 = np.linalg.norm(by["gripper2_base1"] - by["gripper3_base1"], axis=1)
    d13 = np.linalg.norm(by["gripper1_base1"] - by["gripper3_base1"], axis=1)
    L = [VICON_MARK, "", "# FIGAROH's TIAGo Vicon sessions, calibrated jointly (jaxcal.SessionMarkers)", "",
         f"Machine: {machine()}. Script: `benchmarks/bench_figaroh.py` (`--vicon-only` reruns this part).", "",
         "Data: `tests/data/figaroh_tiago_vicon/relative_encoder/` (FIGAROH figaroh-plus @ ab91261, Apache-2.0; "
         "SOURCE.md), the 7 base-referenced files `vicon_calibration_fc10_gripperK_baseJ.csv`: session = file, "
         "frame label = `baseJ` (positions relative to reference marker J on the base), placement label = "
         "`gripperK` (marker K on the gripper). One marker per row, 21 postures per file. Robot: "
         f"`tiago_no_hand.urdf`, chain `{BASE}` → `{VICON_TIP}` (8 joints; FIGAROH's Vicon config ends at "
         "`gripper_tool_link` of `tiago_48_schunk.urdf`: a fixed transform that the free marker positions absorb). "
         "Unknowns: per-joint errors (identifiable subset by QR), one sensor frame per frame label (6), one marker "
         f"position per placement label (3). LM, prior `{prior_name}` "
         f"({prior.describe() if prior is not None else 'none'}), Huber loss — the settings of the Qualisys "
         "benchmark above. 'before' = nominal URDF with frames and markers in closed form "
         "(`jaxcal.initial_sessions`). RMSE = RMS 3-D marker distance error (mm).", "",
         "**What these files are.** Every file holds the *same* 21 postures (identical joint columns): they are one "
         "recording seen through three markers and three references, not independent recording sessions. base1 and "
         "base2 differ by a constant 412 mm translation (same axes). Markers gripper1 and gripper2 keep a constant "
         f"distance to each other ({d12.min():.1f}–{d12.max():.1f} mm) but their distance to gripper3 takes two values "
         f"(gripper2–gripper3 {d23.min():.0f}–{d23.max():.0f} mm, gripper1–gripper3 {d13.min():.0f}–{d13.max():.0f} "
         "mm): gripper1/2 do not move rigidly with the flange and gripper3 (they are on a part that moves between "
         "postures — presumably a gripper finger). No rigid-marker model fits them; FIGAROH's own cost for them is "
         "10× that of gripper3 (below).", ""]
    # 1. per session alone (closed form) and the joint fits
    alone, alone_after = {}, {}
    for s in sessions:
        sub = data.subset(_session_rows(data, [s]))
        st, rs = _fit_sessions(chain, sub, prior)
        alone[s], alone_after[s] = st.rmse_after, _session_rms(chain, sub, rs.deviations)[s]
    print("per-session fits done", flush=True)
    _free_compiled()
    start_all, res_all = _fit_sessions(chain, data, prior)
    b_all, a_all = _session_rms(chain, data, start_all.deviations), _session_rms(chain, data, res_all.deviations)
    d3 = data.subset(_session_rows(data, rigid))
    start3, res3 = _fit_sessions(chain, d3, prior)
    b3, a3 = _session_rms(chain, d3, start3.deviations), _session_rms(chain, d3, res3.deviations)
    print("joint fits done", flush=True)
    _free_compiled()
    fig = figaroh_vicon_results()
    L += ["## Per session: before / after, and FIGAROH's published fits", "",
          f"Joint fits: all 7 sessions ({data.n} rows, {res_all.space.n_free} free parameters, status "
          f"{res_all.status.name.lower()}) and the 3 gripper3 sessions ({d3.n} rows, {res3.space.n_free} free, "
          f"{res3.status.name.lower()}). FIGAROH fits each file alone (21 postures, 32 parameters: 6 for "
          "base_footprint→torso incl. the mocap frame, 23 arm parameters, 3 marker); its RMSE is derived from the "
          "published cost (see below).", "",
          "| session | before (alone) | after (alone) | before (joint start) | after: all 7 jointly | "
          "after: gripper3 jointly | FIGAROH cost | FIGAROH RMSE (cost = marker error only) |",
          "|---|---|---|---|---|---|---|---|"]
    for s in sessions:
        f = fig.get(s)
        fr = figaroh_cost_to_rmse(*f) if f else None
        L.append(f"| {s} | {alone[s]:.2f} | {alone_after[s]:.2f} | {b_all[s]:.2f} | {a_all[s]:.2f} | "
                 + (f"{a3[s]:.2f}" if s in a3 else "–") + " | "
                 + (f"{f[2]:.4g} | {fr[1]:.1f} |" if f else "– | – |"))
    e_all = np.asarray(list(b_all.values())), np.asarray(list(a_all.values()))
    L += ["", f"All 7 jointly: {_rms(e_all[0]):.2f} → {_rms(e_all[1]):.2f} mm (RMS over sessions); gripper3 jointly: "
          f"{_rms(np.asarray(list(b3.values()))):.2f} → {_rms(np.asarray(list(a3.values()))):.2f} mm.", ""]
    # 2. leave one session out
    L += ["## Leave one session out", "",
          "`jaxcal.leave_one_session_out`: calibrate on the other sessions, predict the held-out one. A frame or "
          "placement label seen in training is predicted with its trained value; a new one is *registered* on the "
          "held-out rows with the robot fixed (closed form + LM on those 3–6 parameters only), for 'before' (nominal "
          "robot) and 'after' alike. Because all sessions share their postures, this tests transfer between "
          "markers/references, not to new postures (next section).", ""]
    loso = {}
    for label, d in (("all 7 sessions", data), ("gripper3 sessions", d3)):
        out, pb, pa = jaxcal.leave_one_session_out(chain, d, prior=prior, loss="huber")
        loso[label] = (pb, pa)
        L += [f"### {label}", "", "| held-out session | frame seen | placement seen | registered on held-out | "
              "train before → after | held-out before | held-out after |", "|---|---|---|---|---|---|---|"]
        for h in out:
            L.append(f"| {h.session} | {'yes' if h.frame_seen else 'no'} | {'yes' if h.placement_seen else 'no'} | "
                     f"{', '.join(h.registered) or '–'} | {h.train_before_rmse:.2f} → {h.train_after_rmse:.2f} | "
                     f"{h.before_rmse:.2f} | {h.after_rmse:.2f} |")
        L += ["", f"Pooled over the held-out sessions ({label}): **{pb:.2f} → {pa:.2f} mm**.", ""]
        print(f"LOSO {label} done", flush=True)
        _free_compiled()
    # 3. held-out postures
    pb, pa, rows_out = posture_blocks(chain, d3, prior)
    strong = "angle_deg=0.1,length_mm=0.5"
    sb, sa, srows = posture_blocks(chain, d3, jaxcal.Prior.parse(strong))
    L += ["## Held-out postures (all gripper3 sessions at once)", "",
          "3 contiguous blocks of 7 postures, each held out of every gripper3 session (frames and marker trained on "
          f"the other 14 postures): pooled held-out RMSE **{pb:.2f} → {pa:.2f} mm** (per block: "
          f"{'; '.join(rows_out)}). With a 5× stronger prior (`{strong}`): {sb:.2f} → {sa:.2f} mm "
          f"({'; '.join(srows)}). The training fit reaches ~4 mm: 14 distinct postures (×3 coordinates) are too few "
          "for ~40 robot parameters, as with the Qualisys file above.", ""]
    print("posture blocks done", flush=True)
    _free_compiled()
    # 4. plausibility
    d = res3.diagnostics
    L += ["## Plausibility of jaxcal's parameters (gripper3 joint fit)", "",
          f"Largest robot deviations (1° counted as 4 mm): {_largest(res3)}. Condition number "
          f"{d.condition_number:.3g}; implausible (beyond ±5°/±20 mm): "
          f"{', '.join(n for n, _, _ in d.implausible) or 'none'}; diagnostics: "
          + (" / ".join(d.warnings) if d.warnings else "no warnings") + ".", "",
          f"All-7 fit: {_largest(res_all, 6)}; implausible: "
          f"{', '.join(n for n, _, _ in res_all.diagnostics.implausible) or 'none'}.", ""]
    # 5. FIGAROH's numbers
    L += ["## FIGAROH's published numbers", "",
          "Source: `gripper_base{1,2}_vicon_results` (copied to the fixture). Cost = scipy's `½‖r‖²` with "
          "`r = [PEE_measured − PEE_model (m), √0.01·var[6:-3]]` (`examples/tiago/tiago_utils/robot_tools.py`, "
          "`cost_function`, coeff_regularize 0.01 from the Vicon config); 21 postures × 3 coordinates assumed "
          "(FIGAROH drops rows beyond `outlier_eps` = 0.05 m and re-fits; the results do not say whether any were "
          "dropped, nor which code version printed them). If the cost is marker error only, RMSE = √(2·cost/21)·1000 mm "
          "(3-D distance). Subtracting the regularisation term computed from the published values cannot be right for "
          "every file: for gripper2_base2 the term (0.0357) exceeds the whole cost (0.0319) — so the printed cost most "
          "likely holds no regularisation, and the first RMSE column is the one to compare. Dropped outlier rows would "
          "make the true RMSE larger (fewer rows for the same cost).", "",
          "| file | cost | reg. term from the values | RMSE if cost = marker error (mm) | RMSE with reg. subtracted "
          "(mm) | first 6 (base_footprint→torso + mocap frame) | "
          "arm parameters beyond 0.1 m / 0.1 rad (of 23) | largest |", "|---|---|---|---|---|---|---|---|"]
    for s, (names, vals, cost) in fig.items():
        r, up, reg = figaroh_cost_to_rmse(names, vals, cost)
        arm = vals[6:-3]
        big = int(np.sum(np.abs(arm) > 0.1))
        i = int(np.argmax(np.abs(arm)))
        L.append(f"| {s} | {cost:.4g} | {reg:.4g} | {up:.1f} | {r:.1f} | "
                 f"{', '.join(f'{v:+.3f}' for v in vals[:6])} | {big} | {names[6 + i]} = {arm[i]:+.3f} |")
    L += ["", "Reading: FIGAROH's gripper1/gripper2 fits put 0.3–0.7 m translations and 0.3–2.4 rad rotations on arm "
          "joints (e.g. d_px_arm_3 ±0.6 m, d_phiy_arm_6 −2.36 rad): not plausible geometric errors of a TIAGo arm — "
          "the fit bends the model to a marker that is not rigid with the flange. Its gripper3 fits keep the arm "
          "parameters within ~0.04 m / 0.08 rad and the first six carry the mocap frame (≈0.2 m, −0.31 m: the "
          "reference marker's offset), which is plausible; but they stop at 17.8 mm with `optimality` 0.036 "
          "(10⁴× the gripper1/2 runs): not converged — jaxcal's fit of the same single file reaches the 'after "
          "(alone)' column.", ""]
    print("FIGAROH part done", flush=True)
    _free_compiled()
    # 6. encoder families (shoulder reference, chain from torso_lift_link)
    sh_sessions = [s for s in VICON_SHOULDER_SESSIONS if s.startswith("gripper3")]
    arm = jaxcal.load_urdf(text, base="torso_lift_link", tip=VICON_TIP, name="TIAGo arm")
    fam_rows = []
    for fam in ("relative_encoder", "absolute_encoder"):
        ds = load_figaroh_vicon(fam, sh_sessions, torso=False)
        st, rs = _fit_sessions(arm, ds, prior)
        bb, aa = _session_rms(arm, ds, st.deviations), _session_rms(arm, ds, rs.deviations)
        pb_, pa_, _ = posture_blocks(arm, ds, prior)
        _free_compiled()
        fam_rows.append(f"| {fam} | {_rms(np.asarray(list(bb.values()))):.2f} → {_rms(np.asarray(list(aa.values()))):.2f}"
                        f" | {pb_:.2f} → {pa_:.2f} | {rs.space.n_free} |")
    L += ["## Relative vs absolute encoders", "",
          "`absolute_encoder` files have `torso_lift_joint = 0` in every row (no reading) while the shoulder markers "
          "move 329 mm vertically, so they cannot drive the `base_footprint` chain; FIGAROH's `_abs` config starts "
          "the chain at `torso_lift_link`. Same here: the 4 shoulder-referenced gripper3 sessions "
          f"(`{', '.join(sh_sessions)}`; frames `shoulder1..4` on the torso), chain `torso_lift_link` → "
          f"`{VICON_TIP}` (7 arm joints), each family fitted jointly (same settings):", "",
          "| family | all rows: before → after | held-out postures (3 blocks): before → after | p |",
          "|---|---|---|---|", *fam_rows, "",
          "The main result uses `relative_encoder` (FIGAROH's Vicon config and its published results use it, and only "
          "it has the torso reading the base-referenced sessions need).", ""]
    L += [f"Wall time of this section {time.perf_counter() - t0:.0f} s (compilation included).", ""]
    return L


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--urdf", help="TIAGo URDF (default: $JAXCAL_TIAGO_URDF or the figaroh-examples mirror)")
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--prior", default="default", help="prior spec as for the CLI (default: jaxcal's default)")
    ap.add_argument("--write-csv", metavar="PATH",
                    help="only write the data as a jaxcal marker CSV (q1_mm torso, q2..q8_rad, marker_k_*_mm) "
                         "for `jaxcal calibrate PATH --robot tiago_no_hand.urdf --base base_footprint "
                         "--tip wrist_ft_tool_link --measurement markers`, and exit")
    ap.add_argument("--out", default=str(HERE / "results" / "figaroh_cpu.md"))
    ap.add_argument("--vicon-only", action="store_true",
                    help="only (re)write the Vicon-sessions part of --out (everything after its marker line)")
    ap.add_argument("--qualisys-only", action="store_true",
                    help="only the Qualisys-file part (e.g. with another --prior and --out; ~1 min)")
    args = ap.parse_args()
    if args.write_csv:
        q, y, _ = load_figaroh_markers()
        jaxcal.Dataset(q, y, "markers", {"mm_joints": "1", "source": "FIGAROH qualysis_base_hand_calibration.csv "
                                         "(tests/data/figaroh_tiago/SOURCE.md)"}).to_csv(args.write_csv,
                                                                                       angle_unit="rad")
        print(f"wrote {args.write_csv}")
        return
    text = tiago_urdf_text(args.urdf)
    if text is None:
        sys.exit("TIAGo URDF not found: pass --urdf or set JAXCAL_TIAGO_URDF (figaroh-examples, "
                 f"{URDF_PATH})")
    t0 = time.perf_counter()
    prior = jaxcal.Prior.parse(args.prior)
    out = pathlib.Path(args.out)
    if args.vicon_only:
        old = out.read_text() if out.exists() else ""
        head = old.split(VICON_MARK)[0].rstrip("\n") + "\n\n" if old else ""
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(head + "\n".join(vicon_section(text, prior, args.prior)) + "\n")
        print(f"wrote {out}")
        return
    chain = tiago_chain(text)
    q, y, names = load_figaroh_markers()
    assert tuple(names) == JOINTS == tuple(chain.joint_names), (names, chain.joint_names)
    setups = {"3 markers": (jaxcal.Markers(np.zeros((y.shape[1], 3))), y),
              "1 marker (FIGAROH's set-up)": (jaxcal.Markers(np.zeros((1, 3))), y[:, :1])}
    lines = [
        "# FIGAROH's TIAGo motion-capture data, calibrated by jaxcal from the URDF",
        "",
        f"Machine: {machine()}. Script: `benchmarks/bench_figaroh.py`.",
        "",
        f"Data: FIGAROH `qualysis_base_hand_calibration.csv` ({q.shape[0]} postures, {y.shape[1]} distinct markers; "
        "tests/data/figaroh_tiago/SOURCE.md). Robot: `tiago_no_hand.urdf`, chain "
        f"`{BASE}` → `{TIP}`, {chain.dof} joints (torso prismatic + 7 revolute). Unknowns: per-joint "
        "errors (offset, dx, dy, dz, drx, dry, drz; identifiable subset by QR), mocap frame (6), marker "
        f"positions on the hand (3 per marker). LM, prior `{args.prior}` "
        f"({prior.describe() if prior is not None else 'none'}; the default is 0.5°, 2 mm toward the URDF, none "
        "on the extras), Huber loss. 'before' = nominal URDF with the mocap frame and marker layout fitted in "
        "closed form to the same training postures. RMSE = RMS 3-D marker distance error over postures and "
        "markers (mm).",
        "",
        f"Held out: {args.folds} contiguous blocks in recording order (the file has no session column: one "
        f"recording), each fitted on the rest. Data row {OUTLIER_ROW + 1} is a gross outlier "
        "(~60 mm after calibration; the figaroh-examples copy of the file drops it): held-out RMSEs are "
        "given with / without it.",
        "",
    ]
    summary = []
    for label, (m, yy) in setups.items():
        start, res = fit(chain, m, q, yy, prior=prior)
        e0 = sample_errors(chain, m, start, q, yy)
        e1 = sample_errors(chain, m, res.deviations, q, yy)
        folds = held_out(chain, m, q, yy, args.folds, prior=prior)
        b_all, b_clean = pooled(folds, "before")
        a_all, a_clean = pooled(folds, "after")
        summary.append((label, rms(e0), rms(e1), float(np.mean([f["before_train_clean"] for f in folds])),
                        float(np.mean([f["after_train_clean"] for f in folds])), b_all, b_clean, a_all, a_clean,
                        res.space.n_free, rms(np.delete(e0, OUTLIER_ROW)), rms(np.delete(e1, OUTLIER_ROW))))
        lines += [f"## {label}", "",
                  f"All {q.shape[0]} postures: before {rms(e0):.2f} mm → after {rms(e1):.2f} mm "
                  f"(without row {OUTLIER_ROW + 1}: {rms(np.delete(e0, OUTLIER_ROW)):.2f} → "
                  f"{rms(np.delete(e1, OUTLIER_ROW)):.2f} mm); {res.space.n_free} free parameters, "
                  f"status {res.status.name.lower()}, {res.n_iterations} iterations, "
                  f"{res.diagnostics.rounds} rounds (robust scale / prior noise re-estimated); flagged outlier rows "
                  f"(0-based): {list(res.diagnostics.outliers_after)}.",
                  "",
                  "| held-out rows | p | train before | train after | train before / after (no outlier) | "
                  "held-out before | held-out after | held-out before / after (no outlier) |",
                  "|---|---|---|---|---|---|---|---|"]
        for f in folds:
            lines.append(f"| {f['rows']} | {f['p']} | {f['before_train']:.2f} | {f['after_train']:.2f} | "
                         f"{f['before_train_clean']:.2f} / {f['after_train_clean']:.2f} | "
                         f"{f['before_test']:.2f} | {f['after_test']:.2f} | "
                         f"{f['before_test_clean']:.2f} / {f['after_test_clean']:.2f} |")
        lines += ["", f"Pooled held-out RMSE: before {b_all:.2f} → after {a_all:.2f} mm "
                      f"(without row {OUTLIER_ROW + 1}: {b_clean:.2f} → {a_clean:.2f} mm).", ""]
        unc = res.uncertainty
        if unc is not None:
            lines += ["Calibrated parameters (all postures), value ± posterior σ:", "",
                      "| parameter | value | σ | unit |", "|---|---|---|---|"]
            vals = dict(zip(res.space.free_names, np.asarray(res.x, np.float64)))
            for n, s, u in zip(unc.names, unc.std, unc.units):
                v = vals[n]
                if u == "rad":
                    v, s, u = np.degrees(v), np.degrees(s), "deg"
                lines.append(f"| {n} | {v:+.3f} | {s:.3f} | {u} |")
            lines.append("")
        print("\n".join(lines[-12:]), flush=True)
    lines += [
        "## Summary and FIGAROH's numbers", "",
        "RMSE in mm. 'all' = fitted and evaluated on all 35 postures; 'train (folds)' = mean over the folds of "
        f"the training RMSE without row {OUTLIER_ROW + 1}; 'held-out' = pooled over the folds.",
        "",
        f"| set-up | p | all: before → after | all without row {OUTLIER_ROW + 1} | train (folds, no row "
        f"{OUTLIER_ROW + 1}) | held-out | held-out without row {OUTLIER_ROW + 1} |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in summary:
        lines.append(f"| {s[0]} | {s[9]} | {s[1]:.2f} → {s[2]:.2f} | {s[10]:.2f} → {s[11]:.2f} | "
                     f"{s[3]:.2f} → {s[4]:.2f} | {s[5]:.2f} → {s[7]:.2f} | {s[6]:.2f} → {s[8]:.2f} |")
    lines += [
        "",
        "FIGAROH publishes no before/after RMSE for this file (figaroh-examples and figaroh-plus READMEs give "
        "only generic claims; `geometric_calibration.ipynb` is stored without outputs). The nearest published "
        "numbers are Nguyen et al., *Improving Operational Accuracy of a Mobile Manipulator by Modeling Geometric "
        "and Non-Geometric Parameters* (2024; thanhndv212.github.io/tiago-calibration-webpage): TIAGo, "
        "stereophotogrammetric data, geometric calibration + suspension + joint non-linearity models, "
        "end-effector pose accuracy improved by 60 % vs the nominal model to RMSE **5.7 mm** (position) and "
        "2.7° (orientation) — probably other recordings (FIGAROH's Vicon sessions), not this file, and with "
        "non-geometric models jaxcal does not fit here.",
        "",
        f"Total wall time {time.perf_counter() - t0:.0f} s (compilation included).",
        "",
        "Prior strength, the command line on this file and why one Vicon session alone fits worse: "
        "`figaroh_notes.md` (kept by hand; this script does not rewrite it).",
        "",
        *([] if args.qualisys_only else vicon_section(text, prior, args.prior)),
    ]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
