"""``jaxcal simulate``.
"""

from __future__ import annotations

import math
import pathlib

from ._common import _as_usage, _robot, _robot_and_sensor, _Usage

#: ``--unknown-anchor``: σ per axis (mm) of the true anchor around the default one, and σ (mm) of
#: the wire's zero offset; neither is written where ``jaxcal calibrate`` reads a known anchor.
UNKNOWN_ANCHOR_STD_MM = 50.0
UNKNOWN_OFFSET_STD_MM = 20.0
#: The kinds ``--like`` re-simulates (those of :func:`jaxcal.simulate_experiment`).
LIKE_KINDS = ("cable", "position", "pose")


def _cmd_simulate(args) -> int:
    import jax

    from .._datasets._dataset import Dataset, mm_joints_metadata
    from .._simulation._simulate import simulate_experiment

    if args.like:  # --samples default: the row count of the first file
        robot, measurement, truth, noise, meta = _like(args)
    elif args.samples is None:
        args.samples = 2000
    if args.measurement != "camera" and args.samples < 2:  # camera: at least 3 images (_simulate_camera)
        raise _Usage(f"--samples must be at least 2, got {args.samples}")
    if not args.like:
        args.robot = args.robot or "hsr_jr680"
        args.measurement = args.measurement or "cable"
        noise = args.noise_std = 0.5 if args.noise_std is None else args.noise_std
        if args.unknown_anchor and (args.measurement != "cable" or args.anchor):
            raise _Usage("--unknown-anchor applies to --measurement cable without --anchor (it draws the anchor)")
        if args.measurement == "camera":
            return _simulate_camera(args)
        if args.measurement == "self_contact":
            return _simulate_self_contact(args)
        robot, measurement = _robot_and_sensor(args)
        if measurement.kind in ("plane", "point", "distance"):
            return _simulate_contact(args, robot, measurement)
        measurement, truth = _true_setup(robot, measurement, args.seed, args.unknown_anchor)
        meta = {"seed": args.seed}
    ex = simulate_experiment(jax.random.key(args.seed), robot, n_samples=args.samples, noise_std=noise,
                             measurement=measurement, true_deviations=truth, test_fraction=0.5)
    import jax.numpy as jnp

    q = jnp.concatenate([ex.train.q, ex.test.q])
    y = jnp.concatenate([ex.train.y, ex.test.y])
    rot = _orientation_noise_deg(args, measurement, meta)
    meta = {"source": "jaxcal simulate", "robot": robot.name, **meta, "noise_std_mm": noise,
            **_setup_metadata(measurement, truth, args.unknown_anchor), **mm_joints_metadata(robot)}
    rot_text = ""
    if rot:
        from .._simulation._simulate import add_orientation_noise

        y = add_orientation_noise(y, math.radians(rot), args.seed)
        meta["orientation_noise_std_deg"] = rot
        rot_text = f", {rot}° per axis on the orientation"
    Dataset(q, y, measurement.kind, meta).to_csv(args.out)
    like = f", the robot and set-up of {args.like}" if args.like else ""
    print(f"wrote {args.samples} {measurement.kind} samples of robot {robot.name} (σ = {noise} mm{rot_text}, "
          f"seed {args.seed}{like}) to {args.out}")
    return 0


def _orientation_noise_deg(args, measurement, meta: dict) -> float:
    """``--orientation-noise-deg`` (deg; ``--like``: the first file's unless given), checked:
    pose data only, not negative."""
    rot = args.orientation_noise_deg
    if rot is None:
        rot = float(meta.pop("orientation_noise_std_deg", 0.0))
    if rot and measurement.kind != "pose":
        raise _Usage(f"--orientation-noise-deg applies to --measurement pose, not {measurement.kind}")
    if not (math.isfinite(rot) and rot >= 0):
        raise _Usage(f"--orientation-noise-deg must be a σ ≥ 0 in degrees, got {rot}")
    return rot


def _true_setup(robot, measurement, robot_seed: int, unknown_anchor: bool, cable_offset_mm: float | None = None):
    """``(measurement, true_deviations)`` of the simulated robot of ``robot_seed``.

    The deviations are the seed's true set-up (:func:`~jaxcal._simulation._truth.simulated_truth`:
    those :func:`jaxcal.simulate_experiment` draws from ``jax.random.key(robot_seed)``, the tool
    and sensor frame nominal, as for every kind), so a file's rows follow from its seed alone and
    files of one seed can be combined. The measurement
    carries the true anchor (cable). ``unknown_anchor``: the anchor is moved by
    ``N(0, UNKNOWN_ANCHOR_STD_MM²)`` per axis and the wire gets a zero offset
    ``N(0, UNKNOWN_OFFSET_STD_MM²)`` (mm), drawn from the same key; ``cable_offset_mm`` instead
    sets the offset (``--like``: the one the first file recorded)."""
    import jax
    import jax.numpy as jnp

    from .._core._params import Deviations
    from .._sensors._measurement import CableLength
    from .._simulation._truth import simulated_truth

    dev = simulated_truth(jax.random.key(robot_seed), robot,
                          anchor_std_mm=UNKNOWN_ANCHOR_STD_MM if unknown_anchor else 0.0,
                          cable_offset_std_mm=UNKNOWN_OFFSET_STD_MM if unknown_anchor else 0.0)
    vals = dict(dev.values)
    if measurement.kind == "cable":  # the true anchor in the model; the deviation's anchor back to 0
        measurement = CableLength(measurement.anchor + vals["anchor"])
        vals["anchor"] = jnp.zeros_like(vals["anchor"])
    if cable_offset_mm is not None:
        vals["cable_offset"] = jnp.full_like(vals["cable_offset"], cable_offset_mm)
    return measurement, Deviations(vals, dev.layout)


def _setup_metadata(measurement, truth, unknown_anchor: bool) -> dict:
    """The set-up lines of a simulated file: ``anchor_mm`` (the known anchor, which calibrate uses)
    or, for an unknown one, ``true_anchor_mm`` and ``true_cable_offset_mm`` (the simulation's truth
    in full precision, which calibrate does not read: it estimates both from the data)."""
    if measurement.kind != "cable":
        return {}
    if not unknown_anchor:
        return {"anchor_mm": ",".join(f"{float(v):.6g}" for v in measurement.anchor)}
    # the truth to the last bit: --like simulates from these lines
    return {"true_anchor_mm": ",".join(repr(float(v)) for v in measurement.anchor),
            "true_cable_offset_mm": repr(float(truth.cable_offset))}


def _like(args):
    """``--like RESULT.json``: ``(robot, measurement, true deviations, noise σ, metadata)`` of a new
    file of the robot and set-up a result was calibrated on. The result names its data file
    (``settings.data``, as given to calibrate or relative to the result's folder); that file must
    be one ``jaxcal simulate`` wrote: its ``seed`` (or ``true_robot_seed``) line gives the true
    robot, its ``anchor_mm`` or ``true_anchor_mm``/``true_cable_offset_mm`` lines the set-up and
    its ``noise_std_mm`` the noise (unless ``--noise-std``). ``--seed`` draws the new poses and noise."""
    from .._calibration._io import load_result, load_result_dict, result_data_file
    from .._datasets._dataset import load_csv
    from .._sensors._measurement import CableLength
    from ._common import _floats

    if args.robot or args.base or args.tip or args.measurement or args.anchor or args.unknown_anchor:
        raise _Usage("--like takes the robot, the measurement and the set-up from the result; drop --robot, "
                     "--base, --tip, --measurement, --anchor and --unknown-anchor")
    src = pathlib.Path(args.like)
    if not src.exists():
        raise _Usage(f"--like: result file {args.like!r} not found")
    with _as_usage("--like: "):
        raw = load_result_dict(src)
    path = result_data_file(src, raw)
    if path is None:
        data_path = (raw.get("settings") or {}).get("data")
        raise _Usage(f"--like: the data file {data_path!r} that {src} was calibrated on is not found"
                     if isinstance(data_path, str) else
                     f"--like: {src} does not name one data file (a fleet result or one saved from Python); "
                     "simulate with --robot/--seed instead")
    first = load_csv(path)
    meta = first.meta
    if args.samples is None:  # the same measurement program: as many rows as the first file
        args.samples = first.n
    if meta.get("source") != "jaxcal simulate" or "seed" not in meta:
        raise _Usage(f"--like: {path} was not written by `jaxcal simulate` (no '# source: jaxcal simulate' and "
                     "'# seed:' lines), so its true robot is not known; measure a new file instead")
    res = load_result(src)
    if meta.get("robot") != res.robot.name:
        raise _Usage(f"--like: {path} was simulated for robot {meta.get('robot')!r} but {src} calibrates "
                     f"{res.robot.name!r}; the true robot is not known")
    kind = res.measurement.kind
    if kind not in LIKE_KINDS:
        raise _Usage(f"--like re-simulates {', '.join(LIKE_KINDS)} data, not {kind!r}")
    robot_seed = int(meta.get("true_robot_seed", meta["seed"]))
    unknown = "true_anchor_mm" in meta
    measurement = res.measurement
    if kind == "cable":
        measurement = CableLength(_floats(meta["true_anchor_mm" if unknown else "anchor_mm"], 3, f"{path}'s anchor"))
    offset = float(meta["true_cable_offset_mm"]) if unknown else None
    measurement, truth = _true_setup(res.robot, measurement, robot_seed, False, offset)
    args.unknown_anchor = unknown  # the new file keeps the set-up's lines as the first one had them
    noise = float(meta.get("noise_std_mm", 0.5)) if args.noise_std is None else args.noise_std
    rot = {} if "orientation_noise_std_deg" not in meta else {
        "orientation_noise_std_deg": float(meta["orientation_noise_std_deg"])}  # taken by _orientation_noise_deg
    return res.robot, measurement, truth, noise, {"seed": args.seed, "true_robot_seed": robot_seed,
                                                  "like": f"{src.name} (data {path.name})", **rot}


def _simulate_contact(args, robot, measurement) -> int:
    """``jaxcal simulate --measurement plane|point|distance``:
    :func:`~jaxcal._simulation._simulate_sensors.simulated_contact_data` → ``args.out``."""
    from .._simulation._simulate_sensors import simulated_contact_data

    data = simulated_contact_data(args.seed, robot, measurement, n_samples=args.samples, noise_std=args.noise_std)
    data.to_csv(args.out)
    labels = getattr(measurement, "labels", ())
    if measurement.kind == "distance":
        what = "bar lengths 150 and 300 mm"
    elif getattr(measurement, "sphere", False):
        what = f"{len(labels)} spheres of radius {data.meta['radius_mm']} mm: {', '.join(labels)}"
    else:
        what = f"{len(labels)} {measurement.kind}s: {', '.join(labels)}"
    print(f"wrote {args.samples} {measurement.kind} samples of robot {robot.name} (σ = {args.noise_std} mm, "
          f"seed {args.seed}, {what}) to {args.out}")
    return 0


def _simulate_camera(args) -> int:
    """``jaxcal simulate --measurement camera``: :func:`jaxcal.simulate_camera` (a 9×6 checkerboard of
    20 mm squares, 1280×1024 px, f = 1000 px), written with the target, intrinsics and mount lines."""
    import jax
    import numpy as np

    from .._datasets._dataset import Dataset, mm_joints_metadata
    from .._sensors._camera import Camera, checkerboard
    from .._simulation._simulate_sensors import simulate_camera
    from .._simulation._truth import simulated_truth

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
    with _as_usage():
        key = jax.random.key(args.seed)  # the seed's robot and tool, as every kind's (simulated_truth)
        q, y, cam, truth = simulate_camera(key, robot, cam, n_views=args.samples, noise_px=args.noise_std,
                                           missing=args.missing_corners, true_deviations=simulated_truth(key, robot))
    n_masked = int(np.isnan(np.asarray(y)).any(axis=-1).sum())
    meta = {"source": "jaxcal simulate", "robot": robot.name, "seed": args.seed, "noise_std_px": args.noise_std,
            "target": target, "camera_intrinsics": ",".join(repr(v) for v in intr), "mount": cam.mount,
            "image_size_px": "1280,1024", **mm_joints_metadata(robot)}
    Dataset(q, y, "camera", meta).to_csv(args.out)
    print(f"wrote {args.samples} camera images ({cam.mount}, {cam.n_points} target points, {n_masked} corner(s) "
          f"left undetected) of robot {robot.name} (σ = {args.noise_std} px, seed {args.seed}) to {args.out}")
    return 0


def _simulate_self_contact(args) -> int:
    """``jaxcal simulate --measurement self_contact --robot FILE.urdf --tip A,B``: the two tips touch
    (:func:`jaxcal.simulate_self_contact`, 30 mm balls: 60 mm apart at contact) on the seed's robot,
    written with the ``# tips:`` line."""
    import jax

    from .._datasets._dataset import Dataset, mm_joints_metadata
    from .._sensors._self_contact import simulate_self_contact
    from .._simulation._truth import simulated_truth

    robot = _robot(args.robot, args.base, args.tip)
    tips = robot.tip_names()[:2]
    if len(tips) != 2:
        raise _Usage("--measurement self_contact needs a robot with two tips: --robot FILE.urdf --tip A,B")
    if args.anchor:
        raise _Usage("--anchor applies to --measurement cable only")
    key = jax.random.key(args.seed)  # the seed's robot, as every kind's (simulated_truth)
    with _as_usage():
        q, y = simulate_self_contact(key, robot, tips, n_samples=args.samples, noise_std=args.noise_std,
                                     true_deviations=simulated_truth(key, robot))
    meta = {"source": "jaxcal simulate", "robot": robot.name, "seed": args.seed, "noise_std_mm": args.noise_std,
            "tips": ",".join(tips), **mm_joints_metadata(robot)}
    Dataset(q, y, "self_contact", meta).to_csv(args.out)
    print(f"wrote {len(y)} self-contact rows of {tips[0]} and {tips[1]} of robot {robot.name} (σ = {args.noise_std} mm "
          f"contact scatter, seed {args.seed}) to {args.out}")
    return 0

