"""The ``jaxcal`` command line: reproduce the paper, calibrate a robot from a CSV file, simulate data.

Subcommands (``jaxcal SUBCOMMAND --help`` explains units and file formats):

* ``jaxcal reproduce``: the paper's comparison (Tables III–V, Figs. 2–4) as a seed sweep.
* ``jaxcal calibrate DATA.csv``: calibrate from measured data; prints before/after accuracy on
  held-out data and the calibrated DH table; writes a JSON result.
* ``jaxcal simulate --out data.csv``: a simulated draw-wire (or position) data set to try
  ``calibrate`` on.
* ``jaxcal report SWEEP_DIR``: tables and figures again from a finished (or interrupted) sweep.
* ``jaxcal export RESULT.json --out calibrated.urdf``: the calibrated model as URDF (and the
  calibrated DH table with ``--dh-out`` where the model is a DH table).
* ``jaxcal plan --poses N --out poses.csv``: which poses to measure, their observability indices and
  the predicted accuracy, before measuring.

Errors in the input (unknown robot or method, bad CSV, too few samples) print one line on
stderr and exit with status 2; a failed calibration exits with status 1.
"""

from __future__ import annotations

import argparse
import ast
import math
import pathlib
import sys
import time
import types
import warnings

_T0 = time.perf_counter()  # process start-up (as near as the CLI can tell)

__all__ = ["main", "build_parser"]

_EXIT_USAGE = 2
_EXIT_FAILED = 1

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
robot: a preset name (hsr_jr680, puma560, ur5, abb_irb120) or a DH table file (CSV): optional
'# name: NAME' and '# tool_mm: x,y,z' (tool point in the flange frame, mm) lines, a header
row alpha_deg,a_mm,d_mm,theta_deg[,q_min_deg,q_max_deg] and one row per joint (standard DH:
A_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i); joint limits default to ±180°), or a URDF
file (.urdf) with --base LINK and --tip LINK naming the serial chain to calibrate (lengths in the
URDF are metres; jaxcal reports mm; prismatic joint columns are in mm)."""


def _die(msg: str, code: int = _EXIT_USAGE) -> int:
    print(f"jaxcal: error: {msg}", file=sys.stderr)
    return code


class _Usage(Exception):
    """Bad command-line input: reported as one line, exit status 2."""


# -- helpers ----------------------------------------------------------------------------------------


def _floats(text: str, n: int, what: str) -> list[float]:
    parts = [p for p in text.replace(";", ",").split(",") if p.strip()]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise _Usage(f"{what} must be {n} comma-separated numbers, got {text!r}") from None
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise _Usage(f"{what} must be {n} finite comma-separated numbers, got {text!r}")
    return vals


def _hyper(items: list[str] | None) -> dict:
    out = {}
    for it in items or []:
        if "=" not in it:
            raise _Usage(f"--set expects NAME=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        try:
            out[k.strip()] = ast.literal_eval(v.strip())
        except (ValueError, SyntaxError):
            out[k.strip()] = v.strip()
    return out


def _robot(spec: str, base: str | None = None, tip: str | None = None):
    from . import robots
    from ._io import load_robot_csv

    p = pathlib.Path(spec)
    if p.suffix.lower() == ".urdf":
        from ._urdf import load_urdf

        if not p.exists():
            raise _Usage(f"robot file {spec!r} not found")
        return load_urdf(p, base=base, tip=tip)
    if base is not None or tip is not None:
        raise _Usage("--base/--tip apply to a URDF robot (--robot FILE.urdf) only")
    if spec in robots.PRESETS:
        return robots.get_robot(spec)
    if p.suffix.lower() in (".csv", ".txt") or p.exists():
        if not p.exists():
            raise _Usage(f"robot file {spec!r} not found")
        return load_robot_csv(p)
    raise _Usage(f"unknown robot {spec!r}; presets: {', '.join(robots.PRESETS)} (or a DH table CSV file)")


def _camera_measurement(args, data, path):
    """The :class:`~jaxcal.Camera` of ``jaxcal calibrate --measurement camera`` from ``--target``,
    ``--camera``, ``--mount`` (or the data file's ``# target:``, ``# camera_intrinsics:``,
    ``# mount:`` lines), hand-eye and target pose unknown (started from the data)."""
    from ._camera import Camera, load_target

    meta = data.meta
    target = args.target or meta.get("target")
    if not target:
        raise _Usage("--measurement camera needs the target layout: --target checkerboard:COLSxROWS:SQUARE_MM or "
                     "--target FILE.csv (x_mm,y_mm,z_mm per point), or a '# target: …' line in the data file")
    try:
        points = load_target(target, base_dir=pathlib.Path(path).parent)
    except (ValueError, OSError) as e:
        raise _Usage(f"--target: {e}") from None
    if points.shape[0] != data.y.shape[1]:
        raise _Usage(f"the target has {points.shape[0]} points but {path} has image columns for {data.y.shape[1]} "
                     "(u_k_px, v_k_px)")
    spec = args.camera or meta.get("camera_intrinsics")
    if not spec:
        raise _Usage("--measurement camera needs the camera's intrinsics: --camera fx,fy,cx,cy[,k1,k2,p1,p2[,k3]] "
                     "(px; OpenCV's camera matrix and distortion) or a '# camera_intrinsics: …' line")
    parts = [p for p in spec.replace(";", ",").split(",") if p.strip()]
    intr = _floats(spec, len(parts), "--camera") if len(parts) in (4, 8, 9) else None
    if intr is None:
        raise _Usage(f"--camera takes 4, 8 or 9 numbers fx,fy,cx,cy[,k1,k2,p1,p2[,k3]], got {spec!r}")
    mount = (args.mount or meta.get("mount") or "eye_in_hand").replace("-", "_").lower()
    size = meta.get("image_size_px")
    size = tuple(int(v) for v in _floats(size, 2, "the file's image_size_px")) if size else None
    try:
        return Camera(points, intr, mount, image_size=size, calibrate_intrinsics="intrinsics" in
                      {e.strip().lower() for e in (args.estimate or "").split(",")})
    except ValueError as e:
        raise _Usage(str(e)) from None


def _measurement(kind: str, anchor, robot, n_markers: int | None = None, data=None):
    from ._measurement import CableLength, Markers, Pose, Position
    from ._simulate import default_anchor

    if kind in ("plane", "point", "distance"):  # contact data (jaxcal._contact): planes/points from the data's labels
        if anchor is not None:
            raise _Usage("--anchor applies to --measurement cable only")
        from ._contact import contact_model

        return contact_model(kind, robot, data)

    if kind == "cable":
        import jax.numpy as jnp

        return CableLength(jnp.asarray(anchor) if anchor is not None else default_anchor(robot))
    if anchor is not None:
        raise _Usage("--anchor applies to --measurement cable only")
    if kind == "markers":
        # marker positions on the flange unknown: they start from the data (closed form) and are calibrated
        import numpy as np

        return Markers(np.zeros((int(n_markers), 3)))
    return Pose() if kind == "pose" else Position()


def _metrics_rows(pairs):
    return [[name, m.rmse, m.mean, m.max] for name, m in pairs]


# -- simulate ---------------------------------------------------------------------------------------


def _robot_and_sensor(args):
    """``(robot, measurement)`` from ``--robot/--base/--tip``, ``--measurement`` and ``--anchor``
    (``jaxcal simulate`` and ``jaxcal plan``)."""
    robot = _robot(args.robot, args.base, args.tip)
    anchor = _floats(args.anchor, 3, "--anchor") if args.anchor else None
    if args.measurement == "camera":  # jaxcal plan: the simulation's set-up as the nominal frames
        if anchor is not None:
            raise _Usage("--anchor applies to --measurement cable only")
        from ._camera import planning_camera

        return robot, planning_camera(robot, mount=args.mount.replace("-", "_"))
    measurement = _measurement(args.measurement, anchor, robot)
    radius = getattr(args, "radius_mm", None)
    if radius is not None:
        measurement = _sphere_model(args.measurement, measurement, radius, False)
    return robot, measurement


def _sphere_model(kind: str, measurement, radius_mm, estimate: bool):
    """``--radius-mm`` / ``--estimate radius``: the point model as spheres (jaxcal.FixedPoint with radii)."""
    if kind != "point":
        raise _Usage("--radius-mm and --estimate radius apply to --measurement point only")
    r = 0.0 if radius_mm is None else float(radius_mm)
    if not (math.isfinite(r) and r >= 0):
        raise _Usage(f"--radius-mm must be a finite number >= 0 (mm), got {radius_mm}")
    from ._contact import FixedPoint

    return FixedPoint(measurement.labels, measurement.centres, radii_mm=r, estimate_radius=estimate)


def _cmd_simulate(args) -> int:
    import jax

    from ._dataset import Dataset
    from ._simulate import simulate_experiment

    if args.measurement == "camera":
        return _simulate_camera(args)
    robot, measurement = _robot_and_sensor(args)
    if args.samples < 2:
        raise _Usage(f"--samples must be at least 2, got {args.samples}")
    if measurement.kind in ("plane", "point", "distance"):
        from ._contact import save_simulated_contact

        save_simulated_contact(args, robot, measurement)
        return 0
    ex = simulate_experiment(jax.random.key(args.seed), robot, n_samples=args.samples, noise_std=args.noise_std,
                             measurement=measurement, test_fraction=0.5)
    import jax.numpy as jnp

    q = jnp.concatenate([ex.train.q, ex.test.q])
    y = jnp.concatenate([ex.train.y, ex.test.y])
    from ._dataset import mm_joints_metadata

    meta = {"source": "jaxcal simulate", "robot": robot.name, "seed": args.seed, "noise_std_mm": args.noise_std,
            **mm_joints_metadata(robot)}
    if args.measurement == "cable":
        meta["anchor_mm"] = ",".join(f"{float(v):.6g}" for v in measurement.anchor)
    Dataset(q, y, measurement.kind, meta).to_csv(args.out)
    print(f"wrote {args.samples} {measurement.kind} samples of robot {robot.name} (σ = {args.noise_std} mm, "
          f"seed {args.seed}) to {args.out}")
    return 0


def _simulate_camera(args) -> int:
    """``jaxcal simulate --measurement camera``: :func:`jaxcal.simulate_camera` (a 9×6 checkerboard of
    20 mm squares, 1280×1024 px, f = 1000 px), written with the target, intrinsics and mount lines."""
    import jax
    import numpy as np

    from ._camera import Camera, checkerboard, simulate_camera
    from ._dataset import Dataset, mm_joints_metadata

    robot = _robot(args.robot, args.base, args.tip)
    if args.anchor:
        raise _Usage("--anchor applies to --measurement cable only")
    if args.samples < 3:
        raise _Usage(f"--samples (images) must be at least 3, got {args.samples}")
    if not 0.0 <= args.missing_corners < 1.0:
        raise _Usage(f"--missing-corners must be in [0, 1), got {args.missing_corners}")
    target = "checkerboard:9x6:20"
    intr = [1000.0, 1000.0, 640.0, 512.0, -0.05, 0.02, 0.0005, -0.0003, 0.0]
    cam = Camera(checkerboard(9, 6, 20.0), intr, args.mount.replace("-", "_"), image_size=(1280, 1024))
    try:
        q, y, cam, truth = simulate_camera(jax.random.key(args.seed), robot, cam, n_views=args.samples,
                                           noise_px=args.noise_std, missing=args.missing_corners)
    except ValueError as e:
        raise _Usage(str(e)) from None
    n_masked = int(np.isnan(np.asarray(y)).any(axis=-1).sum())
    meta = {"source": "jaxcal simulate", "robot": robot.name, "seed": args.seed, "noise_std_px": args.noise_std,
            "target": target, "camera_intrinsics": ",".join(repr(v) for v in intr), "mount": cam.mount,
            "image_size_px": "1280,1024", **mm_joints_metadata(robot)}
    Dataset(q, y, "camera", meta).to_csv(args.out)
    print(f"wrote {args.samples} camera images ({cam.mount}, {cam.n_points} target points, {n_masked} corner(s) "
          f"left undetected) of robot {robot.name} (σ = {args.noise_std} px, seed {args.seed}) to {args.out}")
    return 0


# -- calibrate --------------------------------------------------------------------------------------


def _seed_split(seed: int, n: int, test_fraction: float):
    """``(k_method, train_idx, test_idx)``: ``k_split, k_method = jax.random.split(jax.random.key(seed))``
    and the row indices (0-based, into the file's data rows) of :meth:`Dataset.split`'s train/test
    parts drawn with ``k_split``, as one compiled program (op by op it was five, each loaded from
    the compilation cache at every start)."""
    import numpy as np

    k_method, perm = _seed_split_program()(seed, n)
    perm = np.asarray(perm)
    n_test = int(round(n * test_fraction))
    return k_method, perm[n_test:], perm[:n_test]


def _seed_split_program():
    import functools

    import jax

    @functools.partial(jax.jit, static_argnums=1)
    def program(seed, n):
        k_split, k_method = jax.random.split(jax.random.key(seed))
        return k_method, jax.random.permutation(k_split, n)

    global _seed_split_program
    _seed_split_program = lambda: program  # noqa: E731  (built once, on first use: jax imported lazily)
    return program


def _rows(text: str | None) -> list[int]:
    if not text:
        return []
    out = []
    for part in text.replace(";", ",").split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if "-" in part:
                a, b = (int(v) for v in part.split("-", 1))
                out += list(range(a, b + 1))
            else:
                out.append(int(part))
        except ValueError:
            raise _Usage(f"--exclude-rows takes data row numbers (1-based) and ranges like 5-9, got {part!r}") from None
    return out


def _fmt_value(v: float, sd: float | None, unit: str) -> str:
    if sd is None:
        return f"{v:+.4f}"
    return f"{v:+.4f} ± {sd:.2g}" if sd < float("inf") else f"{v:+.4f} ± ∞"


def _print_dh_table(robot, res, sd) -> None:
    from ._diagnostics import wrap_angle_deg
    from ._metrics import format_table

    nominal = robot.dh_table_deg()
    cal = res.dh_table()
    by_prior = _set_by_prior(res)
    trows = []
    for j in range(robot.dof):
        cells = [str(j + 1)]
        for g, col in (("alpha", 0), ("a", 1), ("d", 2), ("theta", 3)):
            name = f"{g}_{j + 1}"
            delta = cal[j, col] - nominal[j, col]
            if col in (0, 3):
                delta = float(wrap_angle_deg(delta))
            if name in sd:
                mark = "†" if name in by_prior else ""
                cells.append(f"{cal[j, col]:.4f}{mark} ({_fmt_value(delta, sd[name][0], sd[name][1])})")
            else:
                cells.append(f"{cal[j, col]:.4f}* ({delta:+.4f})")
        trows.append(cells)
    print()
    print(format_table(trows, ["joint", "α/° (Δ ± σ)", "a/mm (Δ ± σ)", "d/mm (Δ ± σ)", "θ/° (Δ ± σ)"],
                       title="Calibrated DH table (Δ = calibrated − nominal, ± one posterior standard deviation; "
                             + _TABLE_MARKS))


#: the legend of the parameter tables' marks
_TABLE_MARKS = ("† set by the prior rather than the data (posterior σ above half the prior σ); "
                "* not calibrated: held at its start value (not identifiable without a prior, or fixed)")


def _set_by_prior(res) -> set:
    """Free parameters whose posterior σ is above ``Checks.weak_fraction`` of their prior σ."""
    if res.prior is None or res.diagnostics is None:
        return set()
    return set(res.diagnostics.weak_parameters)


def _print_chain_table(robot, res, sd) -> None:
    """Per-joint corrections of a generic chain: offset (°, or mm at prismatic joints), dx, dy, dz
    (mm), drx, dry, drz (°), and a last row with the tip transform's tip_dx … tip_drz; ± one
    posterior σ; * = not calibrated (not identifiable or fixed)."""
    from ._chain import GEOMETRIC_GROUPS, TIP_GROUPS, correction_entries
    from ._metrics import format_table

    free = set(res.space.free_names)
    value = {n: v for n, v, _ in correction_entries(robot, res.deviations)}

    by_prior = _set_by_prior(res)

    def cell(name):
        if name not in value:  # drz at a revolute joint: the joint offset
            return ""
        if name not in free:
            return f"{value[name]:+.4f}*"
        return _fmt_value(value[name], sd.get(name, (None,))[0], "") + ("†" if name in by_prior else "")

    rows = [[f"{j + 1} {robot.joint_names[j]}"] + [cell(f"{g}_{j + 1}") for g, _ in GEOMETRIC_GROUPS]
            for j in range(robot.dof)]
    rows.append([f"tip → {robot.tip}", ""] + [cell(n) for _, names, _ in TIP_GROUPS for n in names])
    print()
    print(format_table(rows, ["joint", "offset/° (mm)", "dx/mm", "dy/mm", "dz/mm", "drx/°", "dry/°", "drz/°"],
                       title=f"Calibrated joint corrections of {robot.name} ({robot.base} → {robot.tip}; ± one "
                             f"posterior standard deviation; {_TABLE_MARKS}; `jaxcal export` writes the corrected URDF)"))


def _nongeometric_robot(robot, compliance: str | None, harmonics: str | None):
    """``robot`` with the non-geometric error models of ``--compliance`` / ``--harmonics``."""
    try:
        if compliance:
            spec = compliance.strip()
            if spec.lower() != "default" and not pathlib.Path(spec).exists():
                raise _Usage(f"--compliance: mass model file {spec!r} not found (or 'default')")
            robot = robot.with_compliance(None if spec.lower() == "default" else spec)
        if harmonics:
            spec, orders = harmonics.strip().lower(), (1, 2)
            if ":" in spec:
                spec, o = spec.split(":", 1)
                orders = tuple(int(x) for x in o.split(",") if x.strip())
            joints = None if spec in ("", "all") else [int(j) for j in spec.split(",") if j.strip()]
            robot = robot.with_harmonics(joints, orders=orders)
    except (ValueError, OSError) as e:
        raise _Usage(f"--compliance/--harmonics: {e}") from None
    return robot


def _calibration_setup(args, method: str, data_file: str) -> types.SimpleNamespace:
    """What `jaxcal calibrate` builds from its arguments and one data file before fitting: the robot,
    the loaded data, the measurement model, the extras to estimate, the objective, the checks and the
    method's settings (raises :class:`_Usage` on bad input)."""
    from ._dataset import load_csv
    from ._diagnostics import Checks
    from ._evaluate import MEASURED_DEFAULTS
    from ._objective import LOSSES, Prior

    robot = _nongeometric_robot(_robot(args.robot, args.base, args.tip), args.compliance, args.harmonics)
    path = pathlib.Path(data_file)
    if not path.exists():
        raise _Usage(f"data file {data_file!r} not found")
    if args.markers is not None and args.measurement != "markers":
        raise _Usage("--markers applies to --measurement markers only")
    if args.markers is not None and args.markers < 1:
        raise _Usage(f"--markers must be at least 1, got {args.markers}")
    try:
        data = load_csv(path, kind=args.measurement, n_markers=args.markers)
    except ValueError as e:
        if args.measurement != "markers":
            raise
        raise _Usage(str(e)) from None
    if data.dof != robot.dof:
        raise _Usage(f"{path} has {data.dof} joint columns but robot {robot.name!r} has {robot.dof} joints")
    if data.labels and args.test:
        raise _Usage(f"{path} has session/frame/placement columns (several recording sessions): --test FILE takes "
                     "one-session files; hold a session out with jaxcal.holdout_session (Python) instead")
    anchor = _floats(args.anchor, 3, "--anchor") if args.anchor else None
    estimate = {e.strip().lower() for e in (args.estimate or "").split(",") if e.strip()}
    notes = []
    if args.measurement == "camera":
        if estimate - {"intrinsics"}:
            raise _Usage(f"--estimate for camera data takes intrinsics only (the hand-eye transform and the target "
                         f"pose are always estimated); got {sorted(estimate - {'intrinsics'})}")
        estimate = set()  # intrinsics: a group of the camera model (--estimate read again below)
    if args.measurement == "distance":
        if "base" in estimate:
            raise _Usage("--estimate base does not apply to distance data: distances never see the base frame")
        if "tool" not in estimate:
            estimate.add("tool")
            notes.append("distance data: the tool point is estimated (from its nominal value); distances never see "
                         "the robot's base frame (d_1, theta_1 and the base's position and orientation stay at "
                         "nominal or are set by the prior)")
    sphere = args.measurement == "point" and (args.radius_mm is not None or "radius" in estimate
                                              or "radius_mm" in data.meta)
    radius_mm = args.radius_mm
    if sphere and radius_mm is None and "radius_mm" in data.meta:
        radius_mm = _floats(data.meta["radius_mm"], 1, "the file's radius_mm")[0]
    estimate_radius = "radius" in estimate
    estimate.discard("radius")
    if (args.radius_mm is not None or estimate_radius) and args.measurement != "point":
        raise _Usage("--radius-mm and --estimate radius apply to --measurement point only")
    if sphere:
        notes.append("point data as spheres: residual = distance to the centre minus the radius, "
                     + ("radius unknown: estimated per point (sphere fit to the data, then the joint fit)"
                        if estimate_radius else f"radius {radius_mm:g} mm (known)"))
    if args.measurement in ("plane", "point"):
        if "base" in estimate:
            raise _Usage(f"--estimate base does not apply to {args.measurement} data: the {args.measurement}s are "
                         "in the robot base frame and carry any base-frame error")
        if "tool" not in estimate:
            estimate.add("tool")
            notes.append(f"{args.measurement} data: the {args.measurement}s and the tool point are estimated "
                         "(closed-form start from the data, then the joint fit); contact data have no length "
                         "reference, so the prior (or a --fix'ed length) sets the robot's scale")
    bad = estimate - {"anchor", "tool", "offset", "cable_offset", "base"}
    if bad:
        raise _Usage(f"--estimate takes anchor, offset, tool (cable) or base, tool (position); got {sorted(bad)}")
    if args.measurement != "cable" and estimate & {"anchor", "offset", "cable_offset"}:
        raise _Usage("--estimate anchor/offset apply to --measurement cable only")
    if args.measurement == "cable" and "base" in estimate:
        raise _Usage("--estimate base applies to --measurement position only")
    if anchor is None and args.measurement == "cable":
        if "anchor_mm" in data.meta:
            anchor = _floats(data.meta["anchor_mm"], 3, "the file's anchor_mm")
        else:
            # nothing known about the anchor: estimate it (and the cable offset) from the data
            estimate |= {"anchor", "offset"}
            notes.append("no --anchor given and none in the file: the anchor and the cable offset are estimated "
                         "from the data (multilateration on the nominal robot, then the joint fit)")
    if args.measurement == "markers":
        if "base" not in estimate and not data.labels:  # sessions: every session frame is always estimated
            estimate.add("base")
            notes.append("marker data: the motion-capture frame (base extras) and the marker positions on the flange "
                         "are estimated (closed-form Kabsch start from the data, then the joint fit)")
        if "tool" in estimate:
            raise _Usage("--estimate tool does not apply to marker data: the marker positions are the tool")
    if args.measurement == "camera":
        from ._camera import masked_corners

        measurement = _camera_measurement(args, data, path)
        n_mask, n_all, n_img = masked_corners(data.y)
        notes.append(f"camera ({measurement.mount}): hand-eye transform and target pose estimated (per-image PnP, "
                     f"Park–Martin hand-eye, then the joint fit){'; intrinsics estimated' if measurement.calibrate_intrinsics else ''}; "
                     f"{n_mask} of {n_all} corner readings not detected (empty cells) in {n_img} image(s): masked "
                     "(zero weight), not dropped")
    elif data.labels:  # marker data of several sessions: SessionMarkers (one frame / placement per label)
        from ._sessions import SessionMarkers, masked_markers

        measurement = SessionMarkers.from_dataset(data)
        n_miss, n_all, n_rows = masked_markers(data.y)
        places = ", ".join(f"{p} ({len(k)})" for p, k in zip(measurement.placements, measurement.markers))
        notes.append(f"{len(dict.fromkeys(s for s, _, _ in data.labels))} recording sessions: frames "
                     f"{', '.join(measurement.frames)}; placements (markers) {places}; shared robot errors"
                     + (f"; {n_miss} of {n_all} marker readings missing (empty cells) in {n_rows} row(s): masked "
                        "(zero weight), not dropped" if n_miss else ""))
    else:
        measurement = _measurement(args.measurement, anchor, robot,
                                   data.y.shape[1] if data.kind == "markers" else None, data=data)
        if sphere:
            measurement = _sphere_model("point", measurement, radius_mm, estimate_radius)
    if args.test and args.test_fraction is not None:
        raise _Usage("--test FILE and --test-fraction exclude each other (a separate test file replaces the random split)")
    test_fraction = 0.2 if args.test_fraction is None else args.test_fraction
    if args.test:
        test_fraction = 0.0
    if not (0.0 <= test_fraction < 1.0):
        raise _Usage(f"--test-fraction must be in [0, 1), got {test_fraction}")
    loss = MEASURED_DEFAULTS["loss"] if args.loss is None else args.loss
    if loss not in LOSSES:
        raise _Usage(f"--loss must be one of {', '.join(LOSSES)}, got {loss!r}")
    test_file = None
    if args.test:
        tpath = pathlib.Path(args.test)
        if not tpath.exists():
            raise _Usage(f"test file {args.test!r} not found")
        test_file = load_csv(tpath, kind=data.kind, n_markers=data.y.shape[1] if data.kind == "markers" else None)
        if test_file.dof != robot.dof:
            raise _Usage(f"{tpath} has {test_file.dof} joint columns but robot {robot.name!r} has {robot.dof} joints")
        if test_file.labels:
            raise _Usage(f"{tpath} has session/frame/placement columns; the command line takes one session per file")
        if test_file.kind in ("plane", "point"):
            from ._contact import relabel

            test_file = relabel(test_file, measurement.labels)
    try:
        prior = Prior.parse(args.prior)
    except ValueError as e:
        raise _Usage(f"--prior: {e}") from None
    checks = Checks(angle_deg=args.max_angle_deg, length_mm=args.max_length_mm)
    hyper = _hyper(args.set)
    from .methods import method_settings

    valid = method_settings(method)
    if valid is not None and set(hyper) - set(valid):
        raise _Usage(f"--set: unknown setting(s) {sorted(set(hyper) - set(valid))} for method {method}; "
                     f"its settings: {', '.join(valid)}")
    return types.SimpleNamespace(robot=robot, path=path, data=data, estimate=estimate, notes=notes,
                                 measurement=measurement, test_fraction=test_fraction, loss=loss,
                                 test_file=test_file, prior=prior, checks=checks, hyper=hyper)


def _same_tree(a, b) -> bool:
    """Two pytrees (measurement models) with the same structure and equal array leaves."""
    import jax
    import numpy as np

    (la, ta), (lb, tb) = jax.tree_util.tree_flatten(a), jax.tree_util.tree_flatten(b)
    return ta == tb and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))


#: measurement kinds `jaxcal calibrate` takes several files of (one sensor set-up per fleet)
FLEET_KINDS = ("cable", "position", "pose")


def _cmd_calibrate_fleet(args, method: str) -> int:
    """`jaxcal calibrate a.csv b.csv ... --out-dir DIR`: every file one unit of the same robot model,
    calibrated by :func:`jaxcal.calibrate_many` (the solves as one compiled program); one result
    JSON per unit and the summary table (``summary.md``, ``summary.csv``) in ``DIR``."""
    import numpy as np

    from ._calibrate import CalibrationWarning
    from ._fleet import calibrate_many
    from ._io import save_result
    from ._metrics import metrics_numpy

    for given, flag in ((args.out, "--out"), (args.test, "--test"), (args.exclude_rows, "--exclude-rows"),
                        (args.exclude_outliers, "--exclude-outliers")):
        if given:
            raise _Usage(f"{flag} applies to one data file; several files write one result each to --out-dir DIR")
    if not args.out_dir:
        raise _Usage("several data files: give --out-dir DIR (one RESULT.json per file and the summary table)")
    if args.measurement not in FLEET_KINDS:
        raise _Usage(f"several data files take --measurement {', '.join(FLEET_KINDS)}; calibrate "
                     f"{args.measurement} data one file at a time")
    setups = [_calibration_setup(args, method, f) for f in args.data]
    first = setups[0]
    for s in setups[1:]:
        if not _same_tree(s.measurement, first.measurement) or s.estimate != first.estimate:
            raise _Usage(f"{s.path} and {first.path} imply different sensor set-ups (the files' anchor_mm or "
                         "columns differ); give --anchor (or --estimate anchor,offset), or calibrate them separately")
    names = [s.path.stem for s in setups]
    if len(set(names)) != len(names):
        names = [str(s.path) for s in setups]
    trains, tests = [], []
    k_method = None
    for s in setups:
        k, train_idx, test_idx = _seed_split(args.seed, s.data.n, first.test_fraction)
        k_method = k if k_method is None else k_method  # one key for every unit (same seed)
        trains.append(s.data.subset(train_idx))
        tests.append(s.data.subset(test_idx))
    extras = sorted({"offset": "cable_offset"}.get(e, e) for e in first.estimate)
    robot, measurement = first.robot, first.measurement
    print(f"fleet: {len(setups)} units of robot {robot.name}, {measurement.kind} data, method {method}; "
          f"{first.test_fraction:g} of each file held out (seed {args.seed})")
    for n in first.notes:
        print(f"note: {n}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CalibrationWarning)
        try:
            fleet = calibrate_many(robot, measurement, trains, method, names=names, key=k_method, extras=extras,
                                   prior=first.prior, loss=first.loss, checks=first.checks, free=args.free,
                                   fix=args.fix or (), tolerance_mm=args.tolerance_mm, noise_std=args.noise_std,
                                   **first.hyper)
        except TypeError as e:
            raise _Usage(str(e)) from None
    for w in caught:
        if issubclass(w.category, CalibrationWarning):
            print(f"jaxcal: warning: {w.message}", file=sys.stderr)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    out = pathlib.Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for s, name, res, train, test in zip(setups, names, fleet.results, trains, tests):
        if res is None:
            continue
        metrics = {"train, after": res.train_metrics._asdict()}
        if test.n:
            metrics["test, after"] = metrics_numpy(np.asarray(res.sample_errors(test), np.float64))._asdict()
        settings = {"data": str(s.path), "n_samples": s.data.n, "n_train": train.n, "n_test": test.n,
                    "seed": args.seed, "test_fraction": first.test_fraction, "method": method, "estimate": extras,
                    "hyperparameters": first.hyper, "prior": args.prior, "loss": first.loss, "fleet": names}
        save_result(res, out / f"{pathlib.Path(name).stem}.json", settings=settings, metrics_mm=metrics)
    table = fleet.summary.table()
    print()
    print(table)
    (out / "summary.md").write_text(fleet.summary.table(markdown=True) + "\n", encoding="utf-8")
    fleet.summary.to_csv(out / "summary.csv")
    print(f"\nwrote {sum(r is not None for r in fleet.results)} result(s), summary.md and summary.csv to {out} "
          f"(compilation {fleet.compile_time_s:.1f} s, batched solves {fleet.solve_time_s:.2f} s)")
    if fleet.summary.flagged:
        print(f"jaxcal: {len(fleet.summary.flagged)} unit(s) failed or out of tolerance: "
              f"{', '.join(fleet.summary.flagged)}", file=sys.stderr)
        return _EXIT_FAILED
    return 0


def _cmd_calibrate(args) -> int:
    t_start = time.perf_counter()
    import numpy as np

    from ._calibrate import CalibrationWarning, calibrate
    from ._evaluate import (
        describe_objective,
        evaluate_result,
        joints_to_file_units,
        nominal_with_extras,
        sample_errors,
    )
    from ._io import save_result
    from ._metrics import format_table, metrics_numpy
    from ._params import Deviations, group_kind
    from .methods._stages import check_method_name

    try:
        method = check_method_name(args.method)  # a registry name, or stages such as ga>lm
    except ValueError as e:
        raise _Usage(str(e)) from None
    if len(args.data) > 1 or args.out_dir:
        return _cmd_calibrate_fleet(args, method)
    setup = _calibration_setup(args, method, args.data[0])
    robot, path, data, estimate, notes, measurement = (
        setup.robot, setup.path, setup.data, setup.estimate, setup.notes, setup.measurement)
    test_fraction, loss, test_file, prior, checks, hyper = (
        setup.test_fraction, setup.loss, setup.test_file, setup.prior, setup.checks, setup.hyper)
    excluded = sorted(set(_rows(args.exclude_rows)))
    if excluded and (excluded[0] < 1 or excluded[-1] > data.n):
        raise _Usage(f"--exclude-rows: data rows are numbered 1..{data.n}, got {excluded[0]}..{excluded[-1]}")
    kept_rows = np.setdiff1d(np.arange(data.n), np.asarray(excluded, int) - 1)
    if excluded:
        notes.append(f"excluded data rows (your choice): {', '.join(map(str, excluded))}")
    data = data.subset(kept_rows)
    k_method, train_idx, test_idx = _seed_split(args.seed, data.n, test_fraction)
    if test_file is not None:  # a separate test file: every row trains, in file order
        train_idx = np.arange(data.n)
    train, test = data.subset(train_idx), (data.subset(test_idx) if test_file is None else test_file)
    full = None
    if hasattr(measurement, "frame_index"):  # SessionMarkers: a model per row set (train, test)
        full = measurement.take(kept_rows)
        lonely = sorted({lab for i in test_idx for lab in data.labels[i][1:]}
                        - {lab for i in train_idx for lab in data.labels[i][1:]})
        if lonely:
            raise _Usage(f"frame/placement label(s) {lonely} have no training rows after the random split; give "
                         "them more rows, --test-fraction 0, or hold the session out in Python (jaxcal.holdout_session)")
        measurement = full.take(train_idx)
    if train.n < 2:
        raise _Usage(f"too few samples: {data.n} in the file, {train.n} for training")
    extras = sorted({"offset": "cable_offset"}.get(e, e) for e in estimate)
    file_row = lambda i: int(kept_rows[train_idx[i]]) + 1  # noqa: E731  (1-based data row of a training row)

    split = (f"{train.n} train / {test.n} test (seed {args.seed})" if test_file is None else
             f"all {train.n} for training; test: {test.n} samples from {args.test}")
    print(f"data: {data.n} {measurement.kind} samples from {path} → {split}; robot {robot.name}; method {method}")
    for n in notes:
        print(f"note: {n}")
    objective_line = describe_objective(prior, loss)
    print(objective_line)

    def run(train_set):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", CalibrationWarning)
            try:
                res = calibrate(robot, measurement, train_set, method, key=k_method, extras=extras, prior=prior,
                                loss=loss, checks=checks, free=args.free, fix=args.fix or (), **hyper)
            except TypeError as e:
                raise _Usage(str(e)) from None
        for w in caught:
            if not issubclass(w.category, CalibrationWarning):
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        return res

    t_loaded = time.perf_counter()
    res = run(train)
    t_fit = time.perf_counter()
    if args.exclude_outliers and res.diagnostics.outliers_after:
        drop = [file_row(i) for i in res.diagnostics.outliers_after]
        print(f"--exclude-outliers: refitting without data rows {', '.join(map(str, drop))}")
        keep = np.setdiff1d(np.arange(train.n), np.asarray(res.diagnostics.outliers_after))
        train_idx = train_idx[keep]
        train = data.subset(train_idx)
        if full is not None:
            measurement = full.take(train_idx)
        res = run(train)
    if res.identifiability is not None:
        print(res.identifiability)
    for line in res.diagnostics.reselection:
        print(line)
    if res.diagnostics.extras:
        print(res.diagnostics.extras)

    # "before" = the nominal robot with the sensor extras estimated from the data (closed-form start)
    dev_before = nominal_with_extras(res)
    zero = Deviations.zeros(res.space.layout, np.asarray(train.q).dtype)
    estimated = any(group_kind(n) == "extra" for n in res.space.free_names)
    per_row = {}

    def part(name, ds, rows_1based, ev=None, m=measurement):
        eb = ev.before_errors if ev is not None else sample_errors(robot, m, dev_before, ds)
        ea = (ev.after_errors if ev is not None else np.asarray(res.sample_errors(ds), np.float64) if m is measurement
              else sample_errors(robot, m, res.deviations, ds))
        per_row[name] = {"row": rows_1based, "q_deg": joints_to_file_units(robot, ds.q).tolist(),
                         "before_mm": eb.tolist(), "after_mm": ea.tolist()}
        out = []
        if estimated:
            out.append((f"{name}, raw nominal", metrics_numpy(sample_errors(robot, m, zero, ds))))
        return out + [(f"{name}, before", metrics_numpy(eb)),
                      (f"{name}, after", metrics_numpy(ea))]

    rows = part("train", train, [file_row(i) for i in range(train.n)])
    evaluation = None
    if test_file is not None:
        evaluation = evaluate_result(res, test_file, extras="result" if args.keep_extras else "auto")
        rows += part("test", test_file, list(range(1, test_file.n + 1)), evaluation)
    elif test.n:
        rows += part("test", test, [int(kept_rows[i]) + 1 for i in test_idx],
                     m=measurement if full is None else full.take(test_idx))
    print()
    unit = getattr(measurement, "unit", "mm")  # px for camera data
    print(format_table(_metrics_rows(rows), ["data", f"RMSE/{unit}", f"MEAN/{unit}", f"MAX/{unit}"],
                       title=f"Accuracy before/after calibration ({res.method}: {res.status.name.lower()}, "
                             f"{res.n_iterations} iterations, {res.wall_time_s:.3f} s + compile {res.compile_time_s:.1f} s)"))
    print("before = the nominal robot with the sensor extras estimated from the data (closed-form start)"
          + ("; raw nominal = the guessed extras, nothing estimated" if estimated else "")
          + ("" if evaluation is None else f"\ntest file: {evaluation.message}"))
    sd = res.uncertainty.std_display() if res.uncertainty is not None else {}
    if hasattr(robot, "dh_table_deg"):
        _print_dh_table(robot, res, sd)
    else:
        _print_chain_table(robot, res, sd)
    from ._params import group_kind

    # every estimated sensor/set-up unknown: anchor, tool, cable offset, sensor frame, marker positions
    extra_names = [n for n in res.space.free_names if group_kind(n) == "extra"]
    # asked for but held (no prior, and the data cannot tell them from another extra): at their start
    from ._calibrate import SELECT_GROUPS
    from ._params import group_of

    asked = {g for e in extras for g in SELECT_GROUPS.get(e, ())}
    frozen = [n for n in res.space.names if group_kind(n) == "extra" and group_of(n) in asked
              and n not in res.space.free_names]
    if extra_names or frozen:
        dev = {**res.deviations.named(), **dict(zip(res.space.free_names, np.asarray(res.x)))}
        units = dict(zip(res.space.names, res.space.units))
        parts = []
        for n in extra_names + frozen:
            unit = "°" if units[n] == "rad" else units[n]
            v = math.degrees(dev[n]) if units[n] == "rad" else dev[n]
            s_ = sd.get(n, (None,))[0]
            parts.append(f"{n} {_fmt_value(v, s_, unit)}{'*' if n in frozen else ''} {unit}")
        print("estimated extras (deviation from the nominal/guessed value, ± one posterior σ"
              + ("; * held at its start value: without a prior the data cannot tell it from another extra"
                 if frozen else "")
              + "): " + ", ".join(parts))

    ng_names = [n for n in res.space.free_names if group_kind(n) == "nongeometric"]
    if ng_names:
        dev = dict(zip(res.space.free_names, np.asarray(res.x)))
        units = dict(zip(res.space.names, res.space.units))
        parts = []
        for n in ng_names:
            s_ = sd.get(n, (None,))[0]
            if units[n] == "rad":
                parts.append(f"{n} {_fmt_value(math.degrees(dev[n]), s_, '°')}°")
            else:  # compliance: µrad/(N·m)
                parts.append(f"{n} {_fmt_value(dev[n] * 1e6, None if s_ is None else s_ * 1e6, '')} µrad/(N·m)")
        print("non-geometric errors (± one posterior σ): " + ", ".join(parts))
    if res.uncertainty is not None:
        print(f"residual σ̂ {res.uncertainty.noise_std:.4f} {unit}, effective parameters "
              f"{res.uncertainty.effective_parameters:.1f}; condition number {res.diagnostics.condition_number:.3g}"
              + (" (data and prior together)" if res.prior is not None else ""))
    diag = res.diagnostics
    if diag.outliers_after:
        listed = ", ".join(str(file_row(i)) for i in diag.outliers_after[:20])
        print(f"outliers after the fit (> {checks.outlier_k:g} robust σ = {diag.outlier_scale_mm:.3g} mm): data rows "
              f"{listed}{' …' if len(diag.outliers_after) > 20 else ''}"
              + ("" if args.exclude_outliers else
                 " (kept, down-weighted by the robust loss; --exclude-outliers drops them)" if args.loss != "linear" else
                 " (kept; --exclude-outliers or --loss huber to guard against them)"))
    for w in res.warnings:
        if diag.outliers_after and "outlier sample(s)" in w:
            w = (f"{len(diag.outliers_after)} outlier sample(s) at data rows "
                 f"{', '.join(str(file_row(i)) for i in diag.outliers_after[:20])} (see above)")
        print(f"jaxcal: warning: {w}", file=sys.stderr)
    if args.out:
        settings = {"data": str(path), "n_samples": data.n, "n_train": train.n, "n_test": test.n,
                    "seed": args.seed, "test_fraction": test_fraction, "test_file": args.test, "method": method,
                    "estimate": extras, "hyperparameters": hyper, "prior": args.prior, "loss": loss,
                    "objective": objective_line,
                    "excluded_rows": excluded, "compliance": args.compliance, "harmonics": args.harmonics,
                    "outlier_rows_after": [file_row(i) for i in diag.outliers_after]}
        info = {"test_extras": {"source": evaluation.extras, "registered": list(evaluation.registered),
                                "message": evaluation.message}} if evaluation is not None else {}
        save_result(res, args.out, settings=settings, metrics_mm={name: m._asdict() for name, m in rows},
                    rows=per_row, **info)
        print(f"\nwrote {args.out}")
    if args.verbose:
        t_end = time.perf_counter()
        print(f"\ntimes: reading and checking the data {t_loaded - t_start:.2f} s, "
              f"calibrate() {t_fit - t_loaded:.2f} s (compilation {res.compile_time_s:.2f} s, solve {res.wall_time_s:.3f} s, "
              f"the rest: initialisation, identifiability, diagnostics), output {t_end - t_fit:.2f} s; "
              f"total {t_end - _T0:.2f} s since jaxcal was imported (Python + JAX start-up come before: ~1 s)")
    if not res.ok:
        print(f"jaxcal: calibration failed: {res.message}", file=sys.stderr)
        return _EXIT_FAILED
    if not res.plausible and not args.accept_implausible:
        hint = ""
        if measurement.kind == "cable" and not {"anchor", "cable_offset"} <= set(extras):
            hint = ("; the anchor and cable offset were taken as known — if they are not exact, estimate them "
                    "(--estimate anchor,offset), or the robot's parameters absorb their error")
        elif measurement.kind in ("position", "pose") and "base" not in extras:
            hint = ("; the sensor frame was taken as known — if it is not exact, estimate it (--estimate base), "
                    "or the robot's parameters absorb its error")
        print("jaxcal: calibration implausible (see the warning above); exit status 1 — use "
              f"--accept-implausible to accept it, or a stronger --prior{hint}", file=sys.stderr)
        return _EXIT_FAILED
    return 0


# -- evaluate -----------------------------------------------------------------------------------------

#: ``"format"`` of the files ``jaxcal evaluate --out`` writes.
EVALUATION_FORMAT = "jaxcal-evaluation/1"


def _cmd_evaluate(args) -> int:
    """A saved calibration on new measurements: before/after, per-row errors, outliers (issue 24)."""
    import json

    from ._dataset import load_csv
    from ._evaluate import evaluate_result
    from ._io import load_result, load_result_dict, measurement_to_dict, robot_to_dict
    from ._json import to_jsonable

    src, path = pathlib.Path(args.result), pathlib.Path(args.data)
    if not src.exists():
        raise _Usage(f"result file {args.result!r} not found")
    if not path.exists():
        raise _Usage(f"data file {args.data!r} not found")
    raw = load_result_dict(src)
    res = load_result(src)
    m = res.measurement
    sessions = hasattr(m, "frame_index")  # a SessionMarkers result: the file's own sessions and marker count
    data = load_csv(path, kind=m.kind, n_markers=int(m.positions.shape[0]) if m.kind == "markers" and not sessions
                    else None)
    if data.dof != res.robot.dof:
        raise _Usage(f"{path} has {data.dof} joint columns but the calibrated robot {res.robot.name!r} has "
                     f"{res.robot.dof} joints")
    if data.labels and not sessions:
        raise _Usage(f"{path} has session/frame/placement columns; evaluate takes one session per file")
    if data.kind in ("plane", "point"):
        from ._contact import relabel

        data = relabel(data, m.labels)
    objective = raw.get("settings", {}).get("objective") or (
        f"objective: {raw.get('loss', 'linear')} loss; {raw.get('prior') or 'no prior'}")
    ev = evaluate_result(res, data, extras="result" if args.keep_extras else "auto", objective=objective)
    print(f"calibration: {src} ({res.robot.name}, {res.method}, {raw.get('status')}; {len(res.space.free_names)} "
          f"free parameters); new data: {data.n} {m.kind} samples from {path}")
    print(f"calibrated with the {objective}" if objective.startswith("measured") else f"calibrated with: {objective}")
    print(ev)
    if args.out:
        out = {"format": EVALUATION_FORMAT, "result": str(src), "data": str(path), "method": res.method,
               "status": raw.get("status"), "robot": robot_to_dict(res.robot), "measurement": measurement_to_dict(m),
               **ev.to_dict()}
        pathlib.Path(args.out).write_text(json.dumps(to_jsonable(out), indent=1, allow_nan=False) + "\n",
                                          encoding="utf-8")
        print(f"\nwrote {args.out}")
    if ev.worse:
        print(f"jaxcal: the calibrated robot predicts {path} worse than the nominal robot (RMSE {ev.after.rmse:.4g} "
              f"vs {ev.before.rmse:.4g} mm); exit status 1", file=sys.stderr)
        return _EXIT_FAILED
    return 0


# -- export -------------------------------------------------------------------------------------------


def _cmd_export(args) -> int:
    from ._io import load_result
    from ._robot import DHRobot
    from ._urdf import export_urdf

    if not args.out and not args.dh_out:
        raise _Usage("export: give --out FILE.urdf and/or --dh-out FILE.csv")
    src = pathlib.Path(args.result)
    if not src.exists():
        raise _Usage(f"result file {args.result!r} not found")
    res = load_result(src)
    if args.out:
        export_urdf(res.robot, res.deviations, args.out)
        print(f"wrote {args.out} (calibrated {res.robot.name}, {res.robot.dof} joints)")
    if args.dh_out:
        if not isinstance(res.robot, DHRobot):
            raise _Usage("--dh-out: this result's robot is a generic chain, not a DH table; use --out FILE.urdf")
        from ._io import save_robot_csv

        save_robot_csv(_calibrated_dh_robot(res.robot, res.deviations), args.dh_out)
        print(f"wrote {args.dh_out} (calibrated DH table)")
    return 0


def _calibrated_dh_robot(robot, dev):
    """The DH robot with the calibrated table (nominal + deviations) and tool point."""
    import jax.numpy as jnp

    from ._chain import _dev_get
    from ._robot import DHRobot

    vals = []
    for g in ("alpha", "a", "d", "theta", "beta"):
        v = jnp.asarray(getattr(robot, g))
        dv = _dev_get(dev, g)
        vals.append(v if dv is None else v + jnp.asarray(dv))
    tool = jnp.asarray(robot.tool)
    if _dev_get(dev, "tool") is not None:
        tool = tool + jnp.asarray(_dev_get(dev, "tool"))
    return DHRobot(*vals, robot.q_min, robot.q_max, tool, convention=robot.convention,
                   beta_joints=robot.beta_joints, name=robot.name)


# -- reproduce ----------------------------------------------------------------------------------------

#: ``--quick`` settings: few seeds and samples, two methods (LM and AdaModW: compilation, ~10-20 s
#: per method on 2 CPU cores, dominates a small run). The population methods keep their full
#: budgets (with 150 generations they ended "still improving"; a trial costs ~1 s at 400 samples).
QUICK = {
    "seeds": 3,
    "samples": 400,
    "methods": ("lm", "adamodw"),
    "hyperparameters": {
        "rbfnn": {"n_centres": 60},
    },
}
ALL_EIGHT = "ga ekf bso lm iwoa rbfnn adam adamodw"


def _staged_ok(name: str) -> bool:
    """Whether ``name`` is stages of registered methods (``ga>lm``)."""
    from .methods._stages import check_method_name, is_staged_name

    try:
        return is_staged_name(name) and bool(check_method_name(name))
    except ValueError:
        return False


def _cmd_reproduce(args) -> int:
    from ._sweep import PAPER_METHODS, sweep
    from .methods import METHODS

    quick = args.quick
    seeds = args.seeds if args.seeds is not None else (QUICK["seeds"] if quick else 20)
    samples = args.samples if args.samples is not None else (QUICK["samples"] if quick else 2000)
    # the defaults (the paper's M1-M8, or the quick pair) are all registered
    methods = [m.lower() for m in args.methods or (QUICK["methods"] if quick else PAPER_METHODS)]
    unknown = [m for m in methods if m not in METHODS and not _staged_ok(m)]
    if unknown:
        raise _Usage(f"unknown method(s) {unknown}; available: {', '.join(sorted(METHODS))}")
    if seeds < 1:
        raise _Usage(f"--seeds must be >= 1, got {seeds}")
    hyper = {m: h for m, h in QUICK["hyperparameters"].items() if m in methods} if quick else {}
    out = pathlib.Path(args.out)
    if quick and not args.methods and not args.quiet:
        print(f"jaxcal reproduce --quick: {' and '.join(methods)} only, {seeds} seeds × {samples} samples (a smoke "
              f"run). All eight methods at this scale: --quick --methods {ALL_EIGHT} (~3 min on 2 CPU cores, mostly "
              "compilation); the paper's scale: no --quick.")
    t0 = time.perf_counter()
    try:
        res = sweep(methods, seeds, seed=args.seed, n_samples=samples, noise_std=args.noise_std, hyperparameters=hyper,
                    chunk_size=args.chunk_size, batching=args.batching, out_dir=out / "sweep", progress=not args.quiet)
    except ValueError as e:
        if "other settings" not in str(e):
            raise
        raise _Usage(f"{out}/sweep holds chunks of a run with other settings (seeds, samples, methods, noise, ...); "
                     f"pass another --out DIR, or delete {out} to start over") from None
    t_sweep = time.perf_counter() - t0
    files = _write_outputs(res, out, figures=not args.no_figures)
    total = time.perf_counter() - t0
    print(f"\n{len(files)} files written to {out}/ (sweep {t_sweep:.1f} s, total {total:.1f} s; "
          f"chunks in {out / 'sweep'} resume an interrupted run)")
    return 0


def _write_outputs(res, out, *, figures: bool) -> dict:
    """Print Tables III-V, write them (and the figures) into ``out``; ``{name: path}``."""
    from .report import write_report

    _print_tables(res)
    files = write_report(res, out)
    if figures:
        files |= _figures(res, out)
    return files


def _figures(res, out) -> dict:
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        print("jaxcal: note: matplotlib is not installed; figures skipped (pip install 'jaxcal[plot]')",
              file=sys.stderr)
        return {}
    from .plots import save_figures

    return save_figures(res, out)


def _print_tables(res) -> None:
    from .report import accuracy_table, convergence_table, dh_table

    print()
    print(accuracy_table(res))
    print()
    print(convergence_table(res))
    print()
    print(dh_table(res))


def _cmd_report(args) -> int:
    from ._sweep import load_sweep

    src = pathlib.Path(args.sweep_dir)
    if src.suffix.lower() == ".json" or args.html:
        if not src.is_file():
            raise _Usage(f"{args.sweep_dir}: no such file (--html takes a RESULT.json or EVAL.json)")
        if not args.html:
            raise _Usage("a result or evaluation file needs --html PAGE.html (tables and figures for sweeps: "
                         "the sweep directory)")
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise _Usage("the HTML report needs matplotlib (pip install 'jaxcal[plot]')") from None
        from ._html import write_html

        out = write_html(src, args.html)
        print(f"wrote {out} (one self-contained page: figures inline, no network needed)")
        return 0
    if not (src / "sweep.json").exists() and (src / "sweep" / "sweep.json").exists():
        src = src / "sweep"
    if not (src / "sweep.json").exists():
        raise _Usage(f"{args.sweep_dir} holds no sweep (no sweep.json)")
    res = load_sweep(src, partial=args.partial)
    out = pathlib.Path(args.out) if args.out else src.parent
    files = _write_outputs(res, out, figures=not args.no_figures)
    print(f"\n{len(files)} files written to {out}/")
    return 0


# -- parser ---------------------------------------------------------------------------------------------


# -- plan -------------------------------------------------------------------------------------------


def _cmd_plan(args) -> int:
    """Which poses to measure: candidates, selection, indices, predicted accuracy (issue 12)."""
    import jax
    import numpy as np

    from . import _plan
    from ._dataset import mm_joints_metadata

    robot, measurement = _robot_and_sensor(args)
    if args.poses < 1:
        raise _Usage(f"--poses must be at least 1, got {args.poses}")
    if not (args.noise_std > 0 and math.isfinite(args.noise_std)):
        raise _Usage(f"--noise-std must be a finite number > 0 (mm), got {args.noise_std}")
    key = jax.random.key(args.seed)
    k_cand, k_test, k_perm = jax.random.split(key, 3)
    filters = {}
    if args.wire_range:
        filters["wire_range_mm"] = tuple(_floats(args.wire_range, 2, "--wire-range"))
    if args.box:
        b = _floats(args.box, 6, "--box")
        filters["box_mm"] = (b[:3], b[3:])
    if args.tracker:
        filters["tracker_mm"] = _floats(args.tracker, 3, "--tracker")
        filters["tracker_axis"] = _floats(args.tracker_axis, 3, "--tracker-axis")
        filters["cone_half_angle_deg"] = args.cone_deg
    sensor = args.measurement in ("plane", "point", "distance", "camera")
    unit = "px" if args.measurement == "camera" else "mm"
    if sensor and filters:
        raise _Usage(f"--wire-range/--box/--tracker do not apply to --measurement {args.measurement}: its candidates "
                     "are poses that touch the planes/points, bar pose pairs, or poses that see the target")
    spec = args.candidates or ("2000" if sensor else "20000")
    if spec.isdigit():
        cand = _plan.candidate_poses(k_cand, robot, measurement, int(spec), **filters)
        if not sensor:
            cand = np.asarray(cand)
        source = f"{int(spec)} random candidates within the joint limits and the sensor's range (seed {args.seed})"
    else:
        if not pathlib.Path(spec).exists():
            raise _Usage(f"--candidates: {spec!r} is neither a number nor an existing file")
        if args.measurement in ("plane", "point", "distance"):
            from ._dataset import load_csv

            cand = load_csv(spec, kind=args.measurement)  # labels / the bar's second pose are part of a candidate
            if args.measurement != "distance":
                from ._contact import contact_model, relabel

                measurement = contact_model(args.measurement, robot, cand) if args.radius_mm is None else \
                    _sphere_model("point", contact_model("point", robot, cand), args.radius_mm, False)
                cand = relabel(cand, measurement.labels)
        else:
            cand = _plan.load_joint_angles(spec, robot.dof)
        source = f"{len(cand.q) if hasattr(cand, 'q') else cand.shape[0]} candidates from {spec}"
    n_cand = len(cand.q) if hasattr(cand, "q") else cand.shape[0]
    if args.poses > n_cand:
        raise _Usage(f"--poses {args.poses} is more than the {n_cand} candidates")
    sel = _plan.select_poses(robot, measurement, cand, args.poses, criterion=args.criterion,
                             exchange=not args.no_exchange, noise_std=args.noise_std)
    q_test = _plan.candidate_poses(k_test, robot, measurement, 2000 if not sensor else 500, **filters)
    pred = _plan.predicted_accuracy(robot, measurement, sel.data if sel.data is not None else sel.q, args.noise_std,
                                    q_test=q_test)
    rnd_idx = np.asarray(jax.random.permutation(k_perm, n_cand))[: args.poses]
    rnd_cand = cand.subset(rnd_idx) if hasattr(cand, "q") else cand[rnd_idx]
    rnd = _plan.predicted_accuracy(robot, measurement, rnd_cand, args.noise_std, q_test=q_test)
    rnd_ind = _plan.indices_from_jacobian(
        _plan.planning_jacobian(robot, measurement, rnd_cand, sel.space), sel.scale)
    meta = [("source", "jaxcal plan"), ("robot", robot.name), ("planned_poses", args.poses),
            ("criterion", f"{args.criterion}-optimal ({sel.method})"), ("seed", args.seed),
            (f"predicted_test_rmse_{unit}", f"{pred.test_rmse:.4f}"), (f"noise_std_{unit}", args.noise_std)]
    if args.measurement == "cable":
        meta.append(("anchor_mm", ",".join(f"{float(v):.6g}" for v in measurement.anchor)))
    meta += list(mm_joints_metadata(robot).items())
    if sensor:
        _save_sensor_plan(args.out, robot, measurement, sel, meta)
    else:
        _plan.save_plan_csv(args.out, sel.q, measurement.kind, meta)
    print(f"{source}; {sel.n} selected ({args.criterion}-optimal, {sel.method}, {sel.seconds:.2f} s) "
          f"for {len(sel.space.free_names)} identifiable parameters")
    rows = [["selected", *[f"{v:.4g}" for v in (sel.indices.o1, sel.indices.o2, sel.indices.o3, sel.indices.o4,
                                                 sel.indices.o5)], f"{pred.test_rmse:.4f}"],
            ["random", *[f"{v:.4g}" for v in (rnd_ind.o1, rnd_ind.o2, rnd_ind.o3, rnd_ind.o4, rnd_ind.o5)],
             f"{rnd.test_rmse:.4f}"]]
    print(f"\n| poses | O1 (D) | O2 (1/cond) | O3 (σ_min) | O4 (noise ampl.) | O5 | predicted test RMSE / {unit} |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")
    print(f"\n(indices of the column-scaled Jacobian; {args.poses} random candidates for comparison; test RMSE over "
          f"{len(q_test.q) if hasattr(q_test, 'q') else q_test.shape[0]} random "
          f"{'candidate' if sensor else 'workspace'} poses, σ = {args.noise_std:g} {unit})\n")
    print(pred.table())
    print(f"\nwrote {sel.n} poses to {args.out}: {_PLAN_NEXT.get(args.measurement, 'fill in the readings')}, then "
          f"`jaxcal calibrate {args.out} --robot {args.robot} --measurement {args.measurement}`")
    if args.plot:
        top = min(cand.shape[0], max(4 * args.poses, 100))
        ns = sorted({int(round(v)) for v in np.geomspace(max(len(sel.space.free_names) + 2, 5), top, 12)})
        curve = _plan.accuracy_curve(robot, measurement, cand, ns, args.noise_std, q_test=q_test,
                                     criterion=args.criterion, key=k_perm)
        fig = curve.plot()
        fig.savefig(args.plot, dpi=120)
        print(f"wrote the predicted RMSE-vs-poses curve to {args.plot}")
    return 0


_PLAN_NEXT = {
    "plane": "touch the plane each row names and record the joint angles there (the planned ones are the nominal "
             "robot's)",
    "point": "put the tool tip on the point each row names (or the ball on the sphere) and record the joint angles "
             "there",
    "distance": "place the bar between each row's two poses (bar length: distance_mm) and record both poses' joint "
                "angles",
    "camera": "take an image at each pose and fill in the detected target points' u_k_px, v_k_px (empty where not "
              "detected)",
}


def _save_sensor_plan(path, robot, measurement, sel, meta) -> None:
    """The selected poses of a plane/point/distance/camera plan as a data file of its kind: contact
    rows with their label, bar rows with both poses and the bar length, camera rows with empty
    pixel columns and the set-up lines (target: the default 9×6 board of
    :func:`jaxcal._camera.planning_camera`, intrinsics, mount, image size)."""
    import numpy as np

    from ._dataset import Dataset

    meta = dict(meta)
    if measurement.kind == "camera":
        meta.update({"target": "checkerboard:9x6:20", "camera_intrinsics": ",".join(repr(float(v)) for v in measurement.intrinsics),
                     "mount": measurement.mount, "image_size_px": ",".join(str(v) for v in measurement.image_size)})
        y = np.full((sel.n, measurement.n_points, 2), np.nan)
        Dataset(sel.q, y, "camera", meta).to_csv(path)
        return
    data = sel.data
    if measurement.kind != "distance":
        meta[f"{measurement.kind}_labels"] = ",".join(measurement.labels)
        if getattr(measurement, "sphere", False):
            meta["radius_mm"] = f"{float(np.asarray(measurement.radii)[0]):g}"
    Dataset(data.q, data.y, measurement.kind, meta).to_csv(path)


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
               "stopped at its step budget, or implausible (see --accept-implausible), 2 bad input.",
    )
    c.add_argument("data", nargs="+",
                   help="CSV data file (format below); several files: one unit each of the same robot model, "
                        "calibrated together (jaxcal.calibrate_many: the solves as one compiled program) — give "
                        "--out-dir")
    c.add_argument("--robot", required=True, help="preset name, DH table CSV file or URDF file (format below)")
    c.add_argument("--base", metavar="LINK", help="URDF robot: the chain's base link (default: the root link)")
    c.add_argument("--tip", metavar="LINK", help="URDF robot: the chain's tip link (the flange; the tool point "
                                                 "is given in its frame)")
    c.add_argument("--measurement", choices=("cable", "position", "pose", "markers", "camera", "plane", "point",
                                             "distance"), default="cable",
                   help="cable: draw-wire length from a fixed anchor (mm); position: tool point x,y,z (mm) in the "
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
    c.add_argument("--mount", choices=("eye-in-hand", "eye-to-hand", "eye_in_hand", "eye_to_hand"),
                   help="camera: on the flange with the target fixed (eye-in-hand, default) or fixed with the target "
                        "on the flange (eye-to-hand); default: the file's '# mount:' line")
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
                        "lengths, none on extras; the default), 'none' (plain least squares), or key=value pairs: "
                        "angle_deg=0.5,length_mm=2,extras_mm=500,noise_std=0.3 or a parameter name, e.g. d_1=10")
    c.add_argument("--loss", default=None, choices=("linear", "huber", "cauchy"),
                   help="huber (the default: with the default prior, the measured-data defaults "
                        "jaxcal.MEASURED_DEFAULTS), cauchy (robust losses against gross outliers) or linear (plain "
                        "least squares)")
    c.add_argument("--exclude-outliers", action="store_true",
                   help="refit without the training rows flagged as outliers (> 5 robust σ) after the first fit; they "
                        "are listed")
    c.add_argument("--exclude-rows", metavar="ROWS", help="data rows to leave out (1-based, e.g. 3,17,40-45)")
    c.add_argument("--max-angle-deg", type=float, default=5.0,
                   help="plausibility bound on DH angle deviations (default 5°)")
    c.add_argument("--max-length-mm", type=float, default=20.0,
                   help="plausibility bound on DH length deviations (default 20 mm)")
    c.add_argument("--accept-implausible", action="store_true",
                   help="exit 0 even when a deviation exceeds the plausibility bounds (default: exit 1)")
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
    c.add_argument("--tolerance-mm", type=float, metavar="MM",
                   help="with several files: flag units whose train RMSE exceeds MM in the summary")
    c.add_argument("--noise-std", type=float, metavar="MM",
                   help="with several files: the sensor's noise σ per reading (mm), for the summary's "
                        "statistical-floor column (train RMSE / floor ≈ 1 for a good fit)")
    c.add_argument("--verbose", action="store_true", help="print where the time went (imports, data, fit, output)")
    c.set_defaults(func=_cmd_calibrate)

    s = sub.add_parser(
        "simulate", formatter_class=fmt, help="write a simulated data set (CSV) to try `calibrate` on",
        description="Simulate the paper's experiment: a 'true' robot = nominal + random DH deviations (~0.2°, "
                    "~0.6 mm), joint angles uniform within the limits, readings with Gaussian noise σ (mm).",
        epilog=_DATA_FORMAT + "\n\n" + _ROBOT_FORMAT,
    )
    s.add_argument("--out", required=True, help="CSV file to write")
    s.add_argument("--samples", type=int, default=2000, help="number of samples (default 2000)")
    s.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    s.add_argument("--noise-std", type=float, default=0.5, help="sensor noise σ in mm (default 0.5)")
    s.add_argument("--robot", default="hsr_jr680", help="preset name, DH table CSV or URDF file (default hsr_jr680)")
    s.add_argument("--base", metavar="LINK", help="URDF robot: the chain's base link")
    s.add_argument("--tip", metavar="LINK", help="URDF robot: the chain's tip link")
    s.add_argument("--measurement", choices=("cable", "position", "pose", "camera", "plane", "point", "distance"),
                   default="cable",
                   help="sensor: cable (draw-wire length), position (x,y,z), pose (x,y,z + rotation vector; default "
                        "cable); camera (--samples images of a 9×6 checkerboard, 20 mm squares, 1280×1024 px, "
                        "f = 1000 px, only poses that see the whole target; --noise-std in px); plane: a probe "
                        "touching three planes (a `plane` label column); point: the tool tip pivoting on two fixed "
                        "points (a `point` label column); distance: pose pairs 150 or 300 mm apart (a bar with two "
                        "nests)")
    s.add_argument("--mount", choices=("eye-in-hand", "eye-to-hand"), default="eye-in-hand",
                   help="camera: on the flange (eye-in-hand, default) or fixed, the target on the flange")
    s.add_argument("--radius-mm", type=float, metavar="R",
                   help="point: a ball touching two fixed spheres instead of a pivoting tip, R = sphere + ball radius "
                        "(mm; written as '# radius_mm: R')")
    s.add_argument("--missing-corners", type=float, default=0.0, metavar="FRACTION",
                   help="camera: fraction of corners left undetected at random (empty cells; default 0)")
    s.add_argument("--anchor", metavar="X,Y,Z", help="draw-wire anchor, mm (default (reach/2, 0, 0))")
    s.set_defaults(func=_cmd_simulate)

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

    ev = sub.add_parser(
        "evaluate", formatter_class=fmt, help="check a saved calibration on new measurements (before/after)",
        description="Check a calibration (`jaxcal calibrate --out RESULT.json`) on new measurements DATA.csv (e.g. "
                    "the next day's): RMSE/MEAN/MAX (mm) of the nominal robot ('before') and the calibrated robot "
                    "('after'), each with the sensor extras (draw-wire anchor and cable offset, tracker / mocap "
                    "frame, marker positions) registered again on the new rows with the robot fixed (closed form, "
                    "then a fit of the extras only) — a new day's set-up — or, with --keep-extras, the calibrated "
                    "robot with the result's extras. The raw nominal line uses the guessed extras. Prints which "
                    "extras were registered, the rows that are outliers after calibration (> 5 robust σ, 1-based), "
                    "and writes per-row errors to --out (EVAL.json: metrics_mm.before/after with rmse, mean, max).",
        epilog=_DATA_FORMAT + "\n\nThe data file's kind comes from the result (cable, position, pose, markers).\n\n"
               "exit status: 0 the calibrated robot predicts the new data at least as well as the nominal one, "
               "1 worse, 2 bad input.",
    )
    ev.add_argument("result", help="RESULT.json written by `jaxcal calibrate --out`")
    ev.add_argument("data", help="CSV data file with new measurements (same robot and sensor kind)")
    ev.add_argument("--out", metavar="EVAL.json", help="write the evaluation (metrics, per-row errors) as JSON; "
                                                       "`jaxcal report EVAL.json --html page.html` shows it")
    ev.add_argument("--keep-extras", action="store_true",
                    help="the new data share the calibration's sensor set-up: take the extras from the result "
                         "instead of registering them again")
    ev.set_defaults(func=_cmd_evaluate)

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
    pl = sub.add_parser(
        "plan", formatter_class=fmt, help="choose the poses to measure and predict the accuracy (before measuring)",
        description="Measurement planning: draw candidate poses within the joint limits and the sensor's range "
                    "(or read them), select --poses of them (greedy D/A/E/I-optimal selection with rank-m updates, "
                    "then a DETMAX exchange), print the observability indices O1-O5 and the predicted test RMSE "
                    "and per-parameter σ (linearised covariance σ²(JᵀJ)⁻¹; no measurement needed), and write the "
                    "poses as a data file with empty reading columns.",
        epilog="O1 = (σ1⋯σp)^(1/p)/√N (Borm & Menq 1991, D-optimality), O2 = σp/σ1 (inverse condition number, "
               "Driels & Pathre 1990), O3 = σp (Nahvi et al. 1994), O4 = σp²/σ1 (noise amplification, Nahvi & "
               "Hollerbach 1996), O5 = 1/Σ(1/σi) (Sun & Hollerbach 2008), of the column-scaled identification "
               "Jacobian on the identifiable parameters.\n\n" + _ROBOT_FORMAT,
    )
    pl.add_argument("--robot", default="hsr_jr680", help="preset name, DH table CSV or URDF file (default hsr_jr680)")
    pl.add_argument("--base", metavar="LINK", help="URDF robot: the chain's base link")
    pl.add_argument("--tip", metavar="LINK", help="URDF robot: the chain's tip link")
    pl.add_argument("--measurement", choices=("cable", "position", "pose", "plane", "point", "distance", "camera"),
                    default="cable",
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
    pl.set_defaults(func=_cmd_plan)
    return p


def _enable_compilation_cache() -> None:
    """JAX's persistent compilation cache in ``$JAXCAL_CACHE_DIR`` (default ``~/.cache/jaxcal/jax``),
    unless the user configured one already; silently skipped if the directory is not writable."""
    import os

    import jax

    if jax.config.jax_compilation_cache_dir:
        return
    path = pathlib.Path(os.environ.get("JAXCAL_CACHE_DIR") or pathlib.Path.home() / ".cache" / "jaxcal" / "jax")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return
    jax.config.update("jax_compilation_cache_dir", str(path))
    # cache every compilation, also the small ones (identifiability, diagnostics: ~0.1-0.5 s each
    # on 2 cores; JAX's default only caches compilations over 1 s)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


def main(argv: list[str] | None = None) -> int:
    """Run the command line with ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help (0) or a usage error (2, message already printed)
        return int(e.code or 0)
    if not getattr(args, "command", None):
        parser.print_help()
        return _EXIT_USAGE
    from ._precision import enable_x64

    enable_x64()
    if not args.no_cache:
        _enable_compilation_cache()
    from ._calibrate import CalibrationError

    try:
        return args.func(args)
    except _Usage as e:
        return _die(str(e))
    except (ValueError, TypeError, KeyError, FileNotFoundError, CalibrationError) as e:
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        return _die(msg.strip("'\""))
    except OSError as e:
        return _die(f"{e.strerror or e}: {getattr(e, 'filename', '') or ''}".rstrip(": "))
    except KeyboardInterrupt:
        print("jaxcal: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
