"""The ``jaxcal`` argument parser: every command's options and help text.
"""

from __future__ import annotations

import argparse

from .._sensors._kind import kind_names, plannable_kind_names, simulated_kind_names
from ._calibrate import _cmd_calibrate
from ._evaluate import _cmd_evaluate
from ._export import _cmd_export
from ._fleet_prior import _cmd_drift, _cmd_fleet_prior
from ._plan import _cmd_plan
from ._report import _cmd_report
from ._reproduce import _cmd_reproduce
from ._simulate import _cmd_simulate

__all__ = ["build_parser"]


_DATA_FORMAT = """\
data file (CSV): optional '# key: value' comment lines, then a header row, then one row per
sample. Columns: q1_deg … qN_deg joint angles in degrees (or q1_rad … in radians), then the
measurement: length_mm (draw-wire length, --measurement cable) or x_mm,y_mm,z_mm (tool point
in the robot base frame, --measurement position). Contact data without a tracker: a text column
`plane` naming the plane the probe touched (--measurement plane), or `point` naming the fixed
point the tool tip was put on (--measurement point); no value columns. Spheres (a ball on the
flange touching a fixed sphere; residual: distance to the centre minus the radius): point data
with --radius-mm R (the sphere's plus the ball's radius, mm; or a '# radius_mm: R' line in the
file, which `jaxcal simulate --measurement point --radius-mm R` writes); with
--estimate radius the radius is unknown (estimated per point, started by a sphere fit to the
data; R, if given, is the nominal value the estimate starts from). A distance bar
(--measurement distance): q1a_deg … qNa_deg, q1b_deg … qNb_deg (two poses per row) and
distance_mm (the bar's length between their tool points). Rows with empty/NaN values are
rejected, not dropped (except a missing marker or camera corner, below). `jaxcal simulate --out data.csv` writes an example (it also records the anchor
as '# anchor_mm: x,y,z', which calibrate uses when --anchor is not given).

camera data (--measurement camera): one row per image, q1_deg … qN_deg then u_1_px,v_1_px,
u_2_px,v_2_px, … the pixel coordinates of target point k (OpenCV convention: origin at the
top-left pixel's centre, u right, v down). Leave both cells of a point empty where it was not
detected: it is masked (zero weight), counted and reported, not dropped. The target layout
(--target: checkerboard:COLSxROWS:SQUARE_MM or a CSV file x_mm,y_mm,z_mm, one row per point k)
and the calibrated camera (--camera fx,fy,cx,cy,k1,k2,p1,p2,k3, OpenCV's intrinsics, px) may
instead come from the data file's '# target: …', '# camera_intrinsics: …', '# mount: …' lines
(`jaxcal simulate --measurement camera` writes them). Errors are reported in px: RMS over an
image's detected corners of the 2-D reprojection distance.

marker data (--measurement markers): q1_deg … qN_deg then marker_1_x_mm, marker_1_y_mm,
marker_1_z_mm, marker_2_x_mm, … the positions of N markers on the end effector in the
motion-capture frame (mm); the frame and the markers' positions on the flange are estimated.
Several recording sessions in one file: text columns `session` and/or `frame`, `placement`;
sessions with the same frame label share one sensor frame, with the same placement label one
set of marker positions; the robot's errors are shared by all. A session with fewer markers (a
one-point session beside three-marker ones) leaves the other markers' cells empty (x, y and z
together; one coordinate alone is an error): those readings are masked (zero weight), counted
and reported, not dropped, and its placement has positions only for the markers it has.
Statistics (RMSE, σ̂, outlier scale) count only real readings: an error is the RMS over a row's
markers of the 3-D distance. `jaxcal evaluate` of such a result on a new file registers that
file's frames and placements (any marker counts) with the robot fixed."""


_ROBOT_FORMAT = """\
robot: a preset name (DH tables: hsr_jr680, puma560, ur5, abb_irb120; kinematic trees, whose tips
--tip A[,B...] selects: dual_arm_ma1400, icub) or a DH table file (CSV): optional
'# name: NAME', '# tool_mm: x,y,z' (tool point in the flange frame, mm) and '# convention:
standard|modified' lines, a header row alpha_deg,a_mm,d_mm,theta_deg[,q_min_deg,q_max_deg] and
one row per joint (standard DH, the default: A_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i);
modified (Craig) DH: A_i = Rx(alpha_i) Tx(a_i) Rz(theta_i + q_i) Tz(d_i), row i holding Craig's
alpha_(i-1), a_(i-1); joint limits default to ±180°), or a URDF
file (.urdf) with --base LINK and --tip LINK naming the serial chain to calibrate (lengths in the
URDF are metres; jaxcal reports mm; prismatic joint columns are in mm)."""


def build_parser() -> argparse.ArgumentParser:
    fmt = argparse.RawDescriptionHelpFormatter
    p = argparse.ArgumentParser(
        prog="jaxcal", formatter_class=fmt,
        description="Kinematic calibration of industrial robots in JAX (AdaModW paper reproduction). "
                    "Lengths in mm, angles in degrees on the command line and in files.",
    )
    p.add_argument("--no-cache", action="store_true",
                   help="do not use the persistent compilation cache (default: $JAXCAL_CACHE_DIR or "
                        "~/.cache/jaxcal/jax; a second run skips most of the ~10-20 s compilation per method)")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    _add_reproduce(sub, fmt)
    _add_calibrate(sub, fmt)
    _add_simulate(sub, fmt)
    _add_report(sub, fmt)
    _add_evaluate(sub, fmt)
    _add_export(sub, fmt)
    _add_plan(sub, fmt)
    _add_fleet_prior(sub, fmt)
    _add_drift(sub, fmt)
    return p


def _add_reproduce(sub, fmt) -> None:
    """The ``jaxcal reproduce`` sub-command's arguments."""
    r = sub.add_parser(
        "reproduce", formatter_class=fmt, help="reproduce the paper's Tables III–V and Figs. 2–4 (seed sweep)",
        description="Simulate the paper's experiment (HSR-JR680, draw-wire sensor, σ = --noise-std mm) once per seed, "
                    "calibrate with each method on 80 % of the samples, evaluate on the other 20 %, and print "
                    "Table III (accuracy: mean ± std over seeds, with the statistical floor and the true model), "
                    "Table IV (iterations and time) and Table V (AdaModW's DH table, trial 0).",
        epilog="writes into --out: table3_accuracy/table4_convergence/table5_dh .txt/.md/.csv, summary.json, "
               "report.md, fig2_accuracy/fig3_training/fig4_positioning .png/.pdf, and sweep/ (one .npz per chunk; "
               "rerunning with the same settings resumes). Default methods: the paper's M1–M8 = ga ekf bso lm "
               "iwoa rbfnn adam adamodw. --quick: 3 seeds, 400 samples, lm and adamodw only (M4 and M8; each "
               "method costs ~10-20 s of compilation on a 2-core CPU); all eight at that scale: --quick --methods "
               "ga ekf bso lm iwoa rbfnn adam adamodw (~3 min on 2 cores).",
    )
    r.add_argument("--seeds", type=int, default=None, help="number of seeded trials (default 20; --quick: 3)")
    r.add_argument("--methods", nargs="+", metavar="M", help="methods to compare (default: the paper's M1–M8)")
    r.add_argument("--samples", type=int, default=None, help="samples per simulated experiment (default 2000; --quick: 400)")
    r.add_argument("--noise-std", type=float, default=0.5, help="sensor noise σ in mm (default 0.5)")
    r.add_argument("--seed", type=int, default=0, help="base random seed (default 0)")
    r.add_argument("--out", default="jaxcal-reproduce", help="output directory (default ./jaxcal-reproduce)")
    r.add_argument("--quick", action="store_true", help="small, fast settings (a smoke run)")
    r.add_argument("--chunk-size", type=int, default=None, help="max trials per device per compiled chunk (default 16 on CPU, 1024 on a GPU)")
    r.add_argument("--batching", choices=("auto", "vmap", "map"), default="auto",
                   help="how a device runs its trials: vmap (vectorised; GPUs, several devices), map (lax.map, one "
                        "after the other), auto (map on one CPU device, else vmap)")
    r.add_argument("--no-figures", action="store_true", help="skip the figures (no matplotlib needed)")
    r.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    r.set_defaults(func=_cmd_reproduce)

def _add_calibrate(sub, fmt) -> None:
    """The ``jaxcal calibrate`` sub-command's arguments."""
    c = sub.add_parser(
        "calibrate", formatter_class=fmt, help="calibrate a robot from a CSV data file",
        description="Calibrate the robot's parameters from measured data (under the default prior: every DH "
                    "deviation and the estimated extras the data see, maximum a posteriori; with --prior none: the "
                    "identifiable subset, found by QR with column pivoting; either way judged again with the extras "
                    "where the fit put them): split off --test-fraction of the samples (at random, --seed) or "
                    "validate on a separate --test file, calibrate on the rest, print RMSE/MEAN/MAX (mm) before and "
                    "after on both parts and the calibrated DH table, and write a JSON result (--out) that "
                    "jaxcal.load_result, `jaxcal evaluate` and `jaxcal report --html` read back. 'before' is the "
                    "nominal robot with the sensor extras estimated from the data (closed-form start); 'raw nominal' "
                    "the guessed extras. Objective: the measured-data defaults (jaxcal.MEASURED_DEFAULTS: default "
                    "prior + Huber loss) unless --prior/--loss say otherwise; printed in the output.",
        epilog=_DATA_FORMAT + "\n\n" + _ROBOT_FORMAT + "\n\nexit status: 0 ok, 1 calibration failed, diverged, "
               "stopped at its step budget, implausible or not credible (see --accept-implausible), 2 bad input.",
    )
    c.add_argument("data", nargs="+",
                   help="CSV data file (format below); several files: one unit each of the same robot model, "
                        "calibrated together (jaxcal.calibrate_many: the solves as one compiled program) — give "
                        "--out-dir; with --combine: several sensors of ONE robot in one fit")
    c.add_argument("--robot", required=True, help="preset name, DH table CSV file or URDF file (format below)")
    c.add_argument("--base", metavar="LINK", help="URDF robot: the chain's base link (default: the root link)")
    c.add_argument("--tip", metavar="LINK[,LINK...]",
                   help="URDF robot: the chain's tip link (the flange; the tool point is given in its frame); "
                        "several links, comma-separated: a kinematic tree with those tips (two arms, a head), the "
                        "first the default tip; a tree preset (dual_arm_ma1400, icub): the tips to keep, the first "
                        "the default (one tip: its chain)")
    c.add_argument("--measurement", choices=kind_names(), default=None,
                   help="the sensor (default: the data file's '# kind:' line, else the kind its columns show; a "
                        "--measurement that contradicts the file's '# kind:' line is an error). "
                        "cable: draw-wire length from a fixed anchor (mm); position: tool point x,y,z (mm) in the "
                        "sensor frame (identity = robot base unless --estimate base); pose: x,y,z (mm) and a "
                        "rotation vector rx,ry,rz (deg) of the flange orientation; markers: N markers on the "
                        "flange seen by a motion-capture system or tracker, columns marker_k_x_mm, marker_k_y_mm, "
                        "marker_k_z_mm (sensor frame); the sensor frame and the marker positions are estimated; "
                        "camera: a calibrated camera sees a known target, columns u_k_px, v_k_px (see below); the "
                        "hand-eye transform and the target pose are estimated; "
                        "plane: the tool tip touched the plane named in a text column `plane` (residual: signed "
                        "distance, mm); point: the tool tip was put on the fixed point named in a text column "
                        "`point` (pivoting; residual: 3-D distance, mm); for plane/point the planes/points and the "
                        "tool point are estimated (closed form from the data, then the joint fit); distance: two poses "
                        "per row (columns q1a_deg … qNa_deg, q1b_deg … qNb_deg) whose tool points are distance_mm "
                        "apart (a bar or ballbar; residual: distance error, mm); it never sees the base frame")
    c.add_argument("--target", metavar="SPEC",
                   help="camera: the target layout, checkerboard:COLSxROWS:SQUARE_MM (inner corners, row by row) or "
                        "a CSV file with x_mm,y_mm,z_mm per point (default: the file's '# target:' line)")
    c.add_argument("--camera", metavar="FX,FY,CX,CY,K1,K2,P1,P2,K3",
                   help="camera: OpenCV intrinsics (px) and distortion (default: the file's '# camera_intrinsics:')")
    c.add_argument("--mount", choices=("eye-in-hand", "eye-to-hand", "tip-to-tip", "eye_in_hand", "eye_to_hand",
                                       "tip_to_tip"),
                   help="camera: on the flange with the target fixed (eye-in-hand, default) or fixed with the target "
                        "on the flange (eye-to-hand), or on one tip of a kinematic tree seeing the target on another "
                        "(tip-to-tip: the file's '# tip:' and '# target_tip:' lines name them); default: the file's "
                        "'# mount:' line (tip-to-tip for a file with a '# target_tip:' line)")
    c.add_argument("--radius-mm", type=float, metavar="R",
                   help="point data: a ball on the flange touches fixed spheres; R = sphere radius + ball radius "
                        "(mm, known; with --estimate radius only the start). Default: the file's '# radius_mm:' "
                        "line; without either, points (pivoting)")
    c.add_argument("--markers", type=int, metavar="N",
                   help="number of markers per sample (--measurement markers; default: as many as the file has)")
    c.add_argument("--anchor", metavar="X,Y,Z", help="draw-wire anchor in the base frame, mm (cable only)")
    c.add_argument("--estimate", metavar="LIST",
                   help="also estimate extras: comma list of anchor (wire exit point), offset (cable zero offset), "
                        "tool (tool point in the flange frame), base (position sensor's frame relative to the robot "
                        "base, 6 parameters), intrinsics (camera: fx, fy, cx, cy, k1, k2, p1, p2, k3; off by "
                        "default), radius (point data as spheres: the radius, per point). Anchor, offset and base "
                        "start from the data in closed form, so a "
                        "rough --anchor guess is fine. Without --anchor (and no anchor_mm line in the file) the "
                        "anchor and offset are estimated.")
    c.add_argument("--free", metavar="LIST",
                   help="parameters to fit instead of all DH deviations (groups dh, alpha, a, d, theta, beta, anchor, "
                        "offset, tool, base, extras, or names such as d_6); e.g. --free anchor,offset fits only the "
                        "sensor extras with the DH table fixed (a sensible first step on real data)")
    c.add_argument("--compliance", metavar="FILE",
                   help="also fit joint compliance (rad/(N·m)) under gravity: Δq_i = c_i·τ_i(q), τ from a nominal "
                        "mass model FILE (JSON or CSV, see jaxcal.MassModel.load) or 'default' (the preset's "
                        "assumed masses; hsr_jr680 only) at every joint that carries a gravity torque")
    c.add_argument("--harmonics", metavar="JOINTS", nargs="?", const="all",
                   help="also fit harmonic transmission errors Δq_i = h1s sin q + h1c cos q + h2s sin 2q + h2c cos 2q "
                        "(rad): at all joints, or a comma list of 1-based joints; ':1' after it keeps only the "
                        "once-per-revolution terms (e.g. --harmonics 2,3:1)")
    c.add_argument("--fix", metavar="LIST",
                   help="parameters to keep at nominal (same names/groups), e.g. --fix d_6 or --fix theta")
    c.add_argument("--prior", default="default", metavar="SPEC",
                   help="Gaussian prior toward the nominal robot (MAP): 'default' (σ 0.5° on angles, 2 mm on DH "
                        "lengths, none on extras; the default), 'evidence' (the same prior with its scale, one σ on "
                        "angles and one on lengths, chosen from the data by type-II maximum likelihood; "
                        "'evidence:SPEC' chooses the scale of any SPEC below, one factor on a learned covariance), "
                        "'none' (plain least squares), or key=value pairs: "
                        "angle_deg=0.5,length_mm=2,extras_mm=500,noise_std=0.3 or a parameter name, e.g. d_1=10; "
                        "or a .json file: a robot model's prior learned from its fleet (`jaxcal fleet-prior --out "
                        "MODEL.prior.json`), or the unit's previous RESULT.json (mean = its estimate, covariance = "
                        "its posterior; then `jaxcal drift` tells what moved)")
    c.add_argument("--loss", default=None, choices=("linear", "huber", "cauchy"),
                   help="huber (the default: with the default prior, the measured-data defaults "
                        "jaxcal.MEASURED_DEFAULTS), cauchy (robust losses against gross outliers) or linear (plain "
                        "least squares)")
    c.add_argument("--exclude-outliers", action="store_true",
                   help="refit without the training rows flagged as outliers (see --outlier-rate) after the first "
                        "fit; they are listed")
    c.add_argument("--outlier-rate", type=float, default=0.01, metavar="P",
                   help="false-alarm probability of the outlier warning per data file (default 0.01): each file's "
                        "rows are judged in their own robust σ̂ (1.4826·MAD), with the threshold that a file of clean "
                        "Gaussian rows crosses with probability P (about 4.4 σ̂ for 800 one-reading rows, 5.1 σ̂ for "
                        "800 positions); the warning names the file and its data rows, and nothing is dropped")
    c.add_argument("--exclude-rows", metavar="ROWS", help="data rows to leave out (1-based, e.g. 3,17,40-45)")
    c.add_argument("--max-angle-deg", type=float, default=5.0,
                   help="plausibility bound on DH angle deviations (default 5°)")
    c.add_argument("--max-length-mm", type=float, default=20.0,
                   help="plausibility bound on DH length deviations (default 20 mm)")
    c.add_argument("--accept-implausible", action="store_true",
                   help="exit 0 even when a deviation exceeds the plausibility bounds or the result as a whole "
                        "fails its checks (residual σ̂ beyond 1 %% of the robot's reach or 10× the file's "
                        "noise_std_mm, a fit worse than its start, extras far from their closed-form start; "
                        "default: exit 1, naming the likely cause: readings in metres, radians under q*_deg, "
                        "another robot's model)")
    c.add_argument("--method", default="lm", help="calibration method: lm (default), gn, adam, adamw, adamod, adamodw, ga, ekf, bso, iwoa, "
                        "rbfnn (an unknown name lists the registered ones), or stages joined by '>', e.g. "
                        "'ga>lm' (quote it in a shell): each stage starts where the last ended")
    c.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="method hyperparameter, e.g. --set steps=1000 --set learning_rate=0.05 (repeatable); "
                        "for stages STAGE.NAME=VALUE, e.g. --set ga.generations=100 --set lm.max_steps=50")
    c.add_argument("--test-fraction", type=float, default=None, help="held-out fraction in [0, 1) (default 0.2)")
    c.add_argument("--test", metavar="TEST.csv",
                   help="validate on this separate data file instead of a random split (all of DATA trains); the "
                        "sensor extras (anchor, frame, markers) are registered again on it, for the nominal and the "
                        "calibrated robot alike, unless --keep-extras")
    c.add_argument("--keep-extras", action="store_true",
                   help="with --test: the test file shares the training data's sensor set-up; take the extras from "
                        "the calibration instead of registering them again")
    c.add_argument("--seed", type=int, default=0, help="seed of the split and the method (default 0)")
    c.add_argument("--out", metavar="RESULT.json", help="write the result as JSON")
    c.add_argument("--out-dir", metavar="DIR",
                   help="several data files (a fleet): write DIR/<file name>.json per unit and the summary table "
                        "DIR/summary.md and DIR/summary.csv (unit, samples, status, train RMSE/MAX, σ̂, floor, "
                        "out-of-tolerance flag); exit status 1 when a unit failed or is out of tolerance. "
                        "Cable, position and pose data; no --test/--exclude-*")
    c.add_argument("--combine", action="store_true",
                   help="several data files of ONE robot (each file its own sensor, kind from its '# kind:' line or "
                        "columns): one fit sharing the robot's parameters, each file a block with its own extras "
                        "and noise σ (estimated); writes DIR/<file name>.json per block and DIR/combined.json "
                        "(give --out-dir). Without it, several files are a fleet of units")
    c.add_argument("--relations", metavar="FILE",
                   help="with --combine: known relations between the files' point/plane labels, one per line "
                        "(distance A B L_mm [std_mm]; plane_distance; plane_angle; point_on_plane; see the how-to "
                        "'Several sensors in one fit')")
    c.add_argument("--tolerance-mm", type=float, metavar="MM",
                   help="with several files: flag units whose train RMSE exceeds MM in the summary")
    c.add_argument("--noise-std", type=float, metavar="MM",
                   help="with several files: the sensor's noise σ per reading (mm), for the summary's "
                        "statistical-floor column (train RMSE / floor ≈ 1 for a good fit)")
    c.add_argument("--verbose", action="store_true", help="print where the time went (imports, data, fit, output)")
    c.set_defaults(func=_cmd_calibrate)

_SIMULATE_FORMAT = """\
what it writes (CSV, read by `calibrate`): '# key: value' lines (source, robot, seed, noise σ, the
set-up), a header row, then one row per sample: q1_deg … qN_deg (q<j>_mm at a prismatic joint),
then per --measurement:
  cable     length_mm; the known anchor as '# anchor_mm: x,y,z' (--unknown-anchor: '# true_anchor_mm:'
            and '# true_cable_offset_mm:' lines instead, which calibrate does not read)
  position  x_mm,y_mm,z_mm (the tool point in the robot base frame)
  pose      x_mm,y_mm,z_mm,rx_deg,ry_deg,rz_deg (the tool point and a rotation vector)
  camera    u_1_px,v_1_px … u_54_px,v_54_px (one row per image, the checkerboard's corners; both cells
            empty where a corner is undetected, --missing-corners) and '# target:',
            '# camera_intrinsics:', '# mount:' lines ('# tip:', '# target_tip:' with --mount tip-to-tip)
  plane     a text column `plane` (three planes), no value columns
  point     a text column `point` (two fixed points; --radius-mm: spheres, a '# radius_mm: R' line)
  distance  q1a_deg … qNa_deg, q1b_deg … qNb_deg, distance_mm (bar lengths 150 and 300 mm)
One recording session per file. It makes no marker (motion-capture) data: `jaxcal calibrate --help`
describes every format calibrate reads, marker data and several sessions in one file included."""


def _add_simulate(sub, fmt) -> None:
    """The ``jaxcal simulate`` sub-command's arguments."""
    s = sub.add_parser(
        "simulate", formatter_class=fmt, help="write a simulated data set (CSV) to try `calibrate` on",
        description="Simulate the paper's experiment: a 'true' robot = nominal + random DH deviations (~0.2°, "
                    "~0.6 mm), joint angles uniform within the limits, readings with Gaussian noise σ (mm; px "
                    "for a camera).",
        epilog=_SIMULATE_FORMAT + "\n\n" + _ROBOT_FORMAT,
    )
    s.add_argument("--out", help="CSV file to write")
    s.add_argument("--out-dir", metavar="DIR",
                   help="with --like DIR/combined.json: the folder for one new file per block, each under the name "
                        "of the file the block was calibrated on")
    s.add_argument("--samples", type=int, default=None,
                   help="number of samples (default 2000; with --like the row count of the file the result was "
                        "calibrated on: a new day of the same measurement program)")
    s.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    s.add_argument("--noise-std", type=float, default=None,
                   help="sensor noise σ in mm (default 0.5; --like: the first file's)")
    s.add_argument("--orientation-noise-deg", type=float, default=None, metavar="DEG",
                   help="pose: noise σ per axis of the orientation readings, deg (a rotation about the tool "
                        "frame's axes; default 0: exact orientations, noise on the position only; --like: the "
                        "first file's)")
    s.add_argument("--robot", default=None, help="preset name, DH table CSV or URDF file (default hsr_jr680)")
    s.add_argument("--base", metavar="LINK", help="URDF robot: the chain's base link")
    s.add_argument("--tip", metavar="LINK[,LINK...]",
                   help="URDF robot: the chain's tip link; several, comma-separated: a kinematic tree; a tree "
                        "preset (dual_arm_ma1400, icub): the tips to keep, the first the default (one tip: its "
                        "chain)")
    s.add_argument("--measurement", choices=simulated_kind_names(), default=None,
                   help="sensor: cable (draw-wire length), position (x,y,z), pose (x,y,z + rotation vector; default "
                        "cable); camera (--samples images of a 9×6 checkerboard, 20 mm squares, 1280×1024 px, "
                        "f = 1000 px, only poses that see the whole target; --noise-std in px); plane: a probe "
                        "touching three planes (a `plane` label column); point: the tool tip pivoting on two fixed "
                        "points (a `point` label column); distance: pose pairs 150 or 300 mm apart (a bar with two "
                        "nests); self_contact: a robot with two tips (--robot FILE.urdf --tip A,B, or a tree "
                        "preset: its first two tips) touching itself, a 30 mm ball on each tip (contact distance "
                        "60 mm; --noise-std: the contact's "
                        "scatter, mm)")
    s.add_argument("--mount", choices=("eye-in-hand", "eye-to-hand", "tip-to-tip"), default=None,
                   help="camera: on the flange (eye-in-hand, default) or fixed, the target on the flange; tip-to-tip "
                        "(self-observation, a robot with two tips --tip A,B): the camera on A sees the target on B")
    s.add_argument("--radius-mm", type=float, metavar="R",
                   help="point: a ball touching two fixed spheres instead of a pivoting tip, R = sphere + ball radius "
                        "(mm; written as '# radius_mm: R')")
    s.add_argument("--missing-corners", type=float, default=None, metavar="FRACTION",
                   help="camera: fraction of corners left undetected at random (empty cells; default 0; written "
                        "as '# missing_corners: F')")
    s.add_argument("--anchor", metavar="X,Y,Z",
                   help="draw-wire anchor, mm (default (reach/2, 0, 0)); written as '# anchor_mm:', the known "
                        "anchor calibrate uses")
    s.add_argument("--unknown-anchor", action="store_true",
                   help="cable: a set-up as a real cell has it: the anchor drawn around the default one (σ 50 mm per "
                        "axis) and a zero offset of the wire (σ 20 mm), from --seed; the file has no anchor_mm line, "
                        "so calibrate estimates both from the data (the truth is in its '# true_anchor_mm:' and "
                        "'# true_cable_offset_mm:' lines, which calibrate does not read)")
    s.add_argument("--like", metavar="RESULT.json",
                   help="a new file of the robot and set-up a calibration result was made from (a 'new day' of the "
                        "same robot: same true deviations, anchor and offset; new poses and noise from --seed). The "
                        "result's data file must be one `jaxcal simulate` wrote (its '# seed:' line names the true "
                        "robot, its other lines the set-up), of any kind it writes. A combined result "
                        "(DIR/combined.json, with --out-dir NEW): one new file per block, same names")
    s.set_defaults(func=_cmd_simulate)

def _add_report(sub, fmt) -> None:
    """The ``jaxcal report`` sub-command's arguments."""
    rp = sub.add_parser(
        "report", formatter_class=fmt, help="an HTML page for a calibration or evaluation; tables and figures of a sweep",
        description="jaxcal report RESULT.json --html PAGE.html (or EVAL.json from `jaxcal evaluate --out`): one "
                    "self-contained HTML page (figures inline, no network) with the summary (data, model, method, "
                    "objective, status, warnings), the before/after tables, a residual histogram, residuals against "
                    "each joint, the error over the workspace, the parameter table with σ and a correlation heat "
                    "map, the identifiability report and the outlier rows.\n\n"
                    "jaxcal report SWEEP_DIR: print Tables III–V and write the tables and figures again from the "
                    "chunks a sweep wrote (`jaxcal reproduce --out DIR` keeps them in DIR/sweep).",
    )
    rp.add_argument("sweep_dir", metavar="SOURCE",
                    help="RESULT.json / EVAL.json (with --html), or the reproduce --out directory or its sweep/ "
                         "subdirectory")
    rp.add_argument("--html", metavar="PAGE.html", help="write the HTML page of a result or evaluation file")
    rp.add_argument("--out", help="where to write (default: next to the sweep)")
    rp.add_argument("--partial", action="store_true", help="use the trials finished so far of an interrupted sweep")
    rp.add_argument("--no-figures", action="store_true", help="skip the figures")
    rp.set_defaults(func=_cmd_report)

def _add_evaluate(sub, fmt) -> None:
    """The ``jaxcal evaluate`` sub-command's arguments."""
    ev = sub.add_parser(
        "evaluate", formatter_class=fmt, help="check a saved calibration on new measurements (before/after)",
        description="Check a calibration (`jaxcal calibrate --out RESULT.json`) on new measurements DATA.csv (e.g. "
                    "the next day's): RMSE/MEAN/MAX (mm; px for a camera) of the nominal robot ('before') and the "
                    "calibrated robot ('after'), each with the sensor extras (draw-wire anchor and cable offset, "
                    "tracker / mocap frame, marker positions, contact planes / points, a camera's hand-eye transform "
                    "and target pose) registered again on the new rows with the robot fixed (closed form, then a fit "
                    "of the extras only) — a new day's set-up — or, with --keep-extras, the calibrated robot with the "
                    "result's extras. A tool point and a camera's intrinsics belong to the robot / the camera: taken "
                    "from the result for both. The raw nominal line uses the guessed extras (none for a camera "
                    "without a guessed hand-eye and target). Also prints the RMSE the calibration expects of itself "
                    "on these rows and warns when the rows fit far worse. Prints which "
                    "extras were registered, warns about the rows that are outliers after calibration (in their own robust "
                    "σ̂, at a 1 % false-alarm rate for the file: --outlier-rate; named by 1-based data row), "
                    "and writes per-row errors to --out (EVAL.json: metrics_mm.before/after with rmse, mean, max).",
        epilog=_DATA_FORMAT + "\n\nThe data file's kind comes from the result (cable, position, pose, markers, camera, "
               "plane, point, distance; a block result of `calibrate --combine` is its block's kind). A plane/point "
               "file may name planes/points the result does not have (another table, a new plate placement): they "
               "are registered on its rows with the robot fixed.\n\n"
               "exit status: 0 the calibrated robot predicts the new data at least as well as the nominal one "
               "and about as well as the calibration expects of itself, 1 worse than the nominal robot, 2 bad "
               "input, 3 better than nominal but more than 1.5× worse than the calibration predicts (its σ̂ and "
               "parameter uncertainty at these poses): the set-up changed since (a remounted tool or probe, a "
               "moved camera with --keep-extras) or the rows lie outside the calibrated workspace.",
    )
    ev.add_argument("result", help="RESULT.json written by `jaxcal calibrate --out`")
    ev.add_argument("data", help="CSV data file with new measurements (same robot and sensor kind)")
    ev.add_argument("--out", metavar="EVAL.json", help="write the evaluation (metrics, per-row errors) as JSON; "
                                                       "`jaxcal report EVAL.json --html page.html` shows it")
    ev.add_argument("--keep-extras", action="store_true",
                    help="the new data share the calibration's sensor set-up: take the extras from the result "
                         "instead of registering them again")
    ev.add_argument("--outlier-rate", type=float, default=0.01, metavar="P",
                    help="false-alarm probability of the outlier warning for the file (default 0.01): its rows are "
                         "judged in their own robust σ̂ (1.4826·MAD), with the threshold that clean Gaussian rows "
                         "cross with probability P")
    ev.set_defaults(func=_cmd_evaluate)

def _add_export(sub, fmt) -> None:
    """The ``jaxcal export`` sub-command's arguments."""
    e = sub.add_parser(
        "export", formatter_class=fmt, help="write a calibrated model (URDF, DH table) from a result file",
        description="Write the calibrated model of a `jaxcal calibrate --out RESULT.json` as URDF: for a robot "
                    "loaded from a URDF, the same file with the moving joints' <origin>s between base and tip "
                    "corrected (joint offsets folded in, listed in a comment); for a DH robot, a URDF chain "
                    "base_link -> link_i -> flange with the calibrated DH table in a comment. The calibrated tool "
                    "point becomes a fixed link 'jaxcal_tool_point'. --dh-out writes the calibrated DH table "
                    "(the CSV format --robot reads) where the model is a DH table.",
    )
    e.add_argument("result", help="RESULT.json written by `jaxcal calibrate --out`")
    e.add_argument("--out", metavar="FILE.urdf", help="URDF file to write")
    e.add_argument("--dh-out", metavar="FILE.csv", help="calibrated DH table (DH robots only)")
    e.set_defaults(func=_cmd_export)

def _add_plan(sub, fmt) -> None:
    """The ``jaxcal plan`` sub-command's arguments."""
    pl = sub.add_parser(
        "plan", formatter_class=fmt, help="choose the poses to measure and predict the accuracy (before measuring)",
        description="Measurement planning: draw candidate poses within the joint limits and the sensor's range "
                    "(or read them), select --poses of them (greedy D/A/E/I-optimal selection with rank-m updates, "
                    "then a DETMAX exchange), print the observability indices O1-O5 and the predicted test RMSE "
                    "and per-parameter σ (linearised covariance σ²(JᵀJ)⁻¹; no measurement needed), and write the "
                    "poses as a data file with empty reading columns. With --with FILE (data of other sensors in "
                    "hand): the poses that add most to that data in one combined fit (`jaxcal calibrate --combine`), "
                    "and the prediction of every block.",
        epilog="O1 = (σ1⋯σp)^(1/p)/√N (Borm & Menq 1991, D-optimality), O2 = σp/σ1 (inverse condition number, "
               "Driels & Pathre 1990), O3 = σp (Nahvi et al. 1994), O4 = σp²/σ1 (noise amplification, Nahvi & "
               "Hollerbach 1996), O5 = 1/Σ(1/σi) (Sun & Hollerbach 2008), of the column-scaled identification "
               "Jacobian on the identifiable parameters.\n\n" + _ROBOT_FORMAT,
    )
    pl.add_argument("--robot", default="hsr_jr680", help="preset name, DH table CSV or URDF file (default hsr_jr680)")
    pl.add_argument("--base", metavar="LINK", help="URDF robot: the chain's base link")
    pl.add_argument("--tip", metavar="LINK", help="URDF robot: the chain's tip link; a tree preset: the tip(s) to keep")
    pl.add_argument("--measurement", choices=plannable_kind_names(), default="cable",
                    help="sensor: cable (draw-wire length), position (tracker x,y,z) or pose (default cable); "
                         "without a tracker (the set-ups of `jaxcal simulate`): plane (three planes; candidates "
                         "touch them), point (two pivot points, or spheres with --radius-mm; candidates touch them), "
                         "distance (a bar of 150 and 300 mm; candidates are pose pairs that far apart), camera "
                         "(eye-in-hand or --mount eye-to-hand, a 9×6 checkerboard, 1280×1024 px; candidates see the "
                         "whole target; --noise-std in px). Candidates are made on the nominal robot by random joint "
                         "angles moved onto the contact by minimum-norm Newton steps (no inverse kinematics)")
    pl.add_argument("--mount", choices=("eye-in-hand", "eye-to-hand"), default="eye-in-hand",
                    help="camera: on the flange (default) or fixed, the target on the flange")
    pl.add_argument("--radius-mm", type=float, metavar="R", help="point: spheres of radius R (sphere + ball, mm)")
    pl.add_argument("--anchor", metavar="X,Y,Z", help="draw-wire anchor, mm (default (reach/2, 0, 0))")
    pl.add_argument("--poses", type=int, required=True, help="number of poses to select")
    pl.add_argument("--candidates", metavar="FILE|N",
                    help="number of random candidate poses (default 20000; 2000 for plane/point/distance/camera) or "
                         "a CSV file with q1_deg…qN_deg columns (plane/point: a data file with its label column; "
                         "distance: q1a_deg…, q1b_deg…, distance_mm)")
    pl.add_argument("--criterion", choices=("D", "A", "E", "I"), default="D",
                    help="D: max det (default); A: min trace of the covariance (scaled units); E: max smallest "
                         "eigenvalue (greedy to first order); I: min the average prediction variance over the "
                         "candidate workspace (the predicted test error)")
    pl.add_argument("--no-exchange", action="store_true", help="greedy selection only (no DETMAX exchange)")
    pl.add_argument("--noise-std", type=float, default=0.5, help="sensor noise σ in mm, px for a camera (default 0.5)")
    pl.add_argument("--wire-range", metavar="LO,HI", help="draw-wire length window, mm (default 0.05–1.2 × reach)")
    pl.add_argument("--box", metavar="X0,Y0,Z0,X1,Y1,Z1", help="workspace box for the tool point, mm (base frame)")
    pl.add_argument("--tracker", metavar="X,Y,Z", help="tracker position, mm: keep poses inside its line-of-sight cone")
    pl.add_argument("--tracker-axis", default="0,0,1", metavar="X,Y,Z",
                    help="the cone's axis (default 0,0,1; a leading minus needs the = form: --tracker-axis=-1,0,0)")
    pl.add_argument("--cone-deg", type=float, default=60.0, help="the cone's half angle, degrees (default 60)")
    pl.add_argument("--seed", type=int, default=0, help="seed of the candidates and the random comparison (default 0)")
    pl.add_argument("--out", required=True, metavar="POSES.csv", help="CSV file to write the selected poses to")
    pl.add_argument("--plot", metavar="FILE.png", help="also draw predicted test RMSE vs number of poses (selected vs random)")
    pl.add_argument("--with", dest="with_files", action="append", metavar="FILE",
                    help="plan a combined set-up: a data file of another sensor already in hand (or planned), its "
                         "kind from the file as `jaxcal calibrate` reads it; repeatable. The poses are chosen on the "
                         "combined information of all blocks (each block's rows over its σ, the robot shared, each "
                         "block's own extras), and the prediction covers every block")
    pl.add_argument("--with-sigma", type=float, action="append", metavar="SIGMA",
                    help="noise σ of the --with files, one per file in order (mm; px for a camera; default: the "
                         "file's noise_std_mm / noise_std_px line, as `jaxcal simulate` and `jaxcal plan` write it)")
    pl.set_defaults(func=_cmd_plan)


def _add_fleet_prior(sub, fmt) -> None:
    """The ``jaxcal fleet-prior`` sub-command's arguments."""
    f = sub.add_parser(
        "fleet-prior", formatter_class=fmt, help="learn a robot model's prior from calibrated units (result files)",
        description="Learn the prior of a robot model from calibrated units of it (empirical Bayes): the "
                    "population mean deviation of the robot's parameters (the shared systematic error) and their "
                    "covariance around it (each unit's estimation noise taken out, correlations shrunk when the "
                    "units are few), plus the mean's own uncertainty from the number of units. Sensor extras "
                    "(anchor, tool point, sensor frame) stay out: they belong to one unit's set-up. Prints the "
                    "population (mean ± σ, spread ± σ, degrees for angles) and writes the prior file, used as "
                    "`jaxcal calibrate DATA.csv --prior MODEL.prior.json` (a new unit then needs far fewer poses).",
        epilog="the units must be result files of one robot model (`jaxcal calibrate --out`), calibrated under a "
               "prior (the default), at least 3 of them.",
    )
    f.add_argument("results", nargs="+", help="RESULT.json files of calibrated units of one robot model")
    f.add_argument("--out", required=True, metavar="MODEL.prior.json", help="prior file to write")
    f.add_argument("--noise-std", type=float, default=None,
                   help="sensor noise σ in mm the prior is weighed against (default: estimated from each new fit)")
    f.set_defaults(func=_cmd_fleet_prior)


def _add_drift(sub, fmt) -> None:
    """The ``jaxcal drift`` sub-command's arguments."""
    d = sub.add_parser(
        "drift", formatter_class=fmt, help="which robot parameters of a unit moved between two calibrations",
        description="Compare two calibrations of one unit (result files, e.g. months apart): for every robot "
                    "parameter both fitted, the change and its σ from the two posterior σ, and whether it moved "
                    "beyond its uncertainty (|z| above a Bonferroni threshold: a unit that did not change reports "
                    "a move with probability at most --alpha). Angles in degrees, lengths in mm. Exits with "
                    "status 1 if a parameter moved. Calibrate the new data independently (the default prior, "
                    "not --prior PREVIOUS.json, which pulls toward the previous estimate).",
    )
    d.add_argument("previous", help="the earlier RESULT.json")
    d.add_argument("current", help="the later RESULT.json")
    d.add_argument("--since", metavar="LABEL",
                   help="how to name the earlier calibration (default: its file's date and name)")
    d.add_argument("--alpha", type=float, default=0.01,
                   help="family-wise false-alarm probability (default 0.01)")
    d.add_argument("--json", metavar="FILE.json", help="also write the report as JSON")
    d.set_defaults(func=_cmd_drift)
