"""``jaxcal simulate``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import pathlib

from ._common import _as_usage, _floats, _robot, _robot_and_sensor, _Usage

#: ``--unknown-anchor``: σ per axis (mm) of the true anchor around the default one, and σ (mm) of
#: the wire's zero offset; neither is written where ``jaxcal calibrate`` reads a known anchor.
UNKNOWN_ANCHOR_STD_MM = 50.0
UNKNOWN_OFFSET_STD_MM = 20.0
#: The kinds ``jaxcal simulate`` writes (its ``--measurement`` choices), each re-simulated by ``--like``
#: from the set-up lines its file carries.
SIMULATED_KINDS = ("cable", "position", "pose", "camera", "plane", "point", "distance", "self_contact")
#: The camera files' set-up: a 9×6 checkerboard of 20 mm squares, OpenCV intrinsics ``fx, fy, cx,
#: cy, k1, k2, p1, p2, k3`` (px), the image size (px).
CAMERA_TARGET = "checkerboard:9x6:20"
CAMERA_INTRINSICS = (1000.0, 1000.0, 640.0, 512.0, -0.05, 0.02, 0.0005, -0.0003, 0.0)
CAMERA_IMAGE_SIZE = (1280, 1024)


@dataclasses.dataclass(frozen=True)
class _Like:
    """A new day of a simulated set-up (``--like``): the true robot's seed, the words naming where
    it came from (the ``# like:`` line) and the first file's metadata (its set-up lines)."""

    truth_seed: int
    source: str
    meta: dict


def _seed_lines(args, like: _Like | None) -> dict:
    """The file's ``seed`` line (poses and noise) and, for ``--like``, ``true_robot_seed`` (the
    true robot) and ``like`` (the result it repeats)."""
    if like is None:
        return {"seed": args.seed}
    return {"seed": args.seed, "true_robot_seed": like.truth_seed, "like": like.source}


def _cmd_simulate(args) -> int:
    if args.like:
        return _simulate_like(args)
    if args.out_dir:
        raise _Usage("--out-dir applies to --like of a combined result (combined.json: one file per block); "
                     "give --out FILE.csv")
    if not args.out:
        raise _Usage("give --out FILE.csv (the data file to write)")
    if args.samples is None:
        args.samples = 2000
    args.robot = args.robot or "hsr_jr680"
    args.measurement = args.measurement or "cable"
    args.noise_std = 0.5 if args.noise_std is None else args.noise_std
    if args.unknown_anchor and (args.measurement != "cable" or args.anchor):
        raise _Usage("--unknown-anchor applies to --measurement cable without --anchor (it draws the anchor)")
    return _simulate(args, _robot(args.robot, args.base, args.tip), None)


def _simulate(args, robot, like: _Like | None) -> int:
    """Write ``args.out``: ``args.samples`` rows of ``args.measurement`` data of ``robot`` (the true
    robot of ``args.seed``, or of ``like.truth_seed`` with the set-up of ``like.meta``)."""
    import jax

    from .._datasets._dataset import Dataset, mm_joints_metadata
    from .._sensors._measurement import CableLength
    from .._simulation._simulate import simulate_experiment

    if args.measurement != "camera" and args.samples < 2:  # camera: at least 3 images (_simulate_camera)
        raise _Usage(f"--samples must be at least 2, got {args.samples}")
    if args.measurement == "camera":
        return _simulate_camera(args, robot, like)
    if args.measurement == "self_contact":
        return _simulate_self_contact(args, robot, like)
    robot, measurement = _robot_and_sensor(args, robot)
    if measurement.kind in ("plane", "point", "distance"):
        return _simulate_contact(args, robot, measurement, like)
    noise = args.noise_std
    if like is not None and "true_anchor_mm" in like.meta:  # the drawn anchor and offset, to the last bit
        measurement = CableLength(_floats(like.meta["true_anchor_mm"], 3, "the first file's true_anchor_mm"))
        measurement, truth = _true_setup(robot, measurement, like.truth_seed, False,
                                         float(like.meta["true_cable_offset_mm"]))
    else:
        measurement, truth = _true_setup(robot, measurement, args.seed if like is None else like.truth_seed,
                                         args.unknown_anchor)
    ex = simulate_experiment(jax.random.key(args.seed), robot, n_samples=args.samples, noise_std=noise,
                             measurement=measurement, true_deviations=truth, test_fraction=0.5)
    import jax.numpy as jnp

    q = jnp.concatenate([ex.train.q, ex.test.q])
    y = jnp.concatenate([ex.train.y, ex.test.y])
    rot = _orientation_noise_deg(args, measurement)
    meta = {"source": "jaxcal simulate", "robot": robot.name, **_seed_lines(args, like), "noise_std_mm": noise,
            **_setup_metadata(measurement, truth, args.unknown_anchor), **mm_joints_metadata(robot)}
    rot_text = ""
    if rot:
        from .._simulation._simulate import add_orientation_noise

        y = add_orientation_noise(y, math.radians(rot), args.seed)
        meta["orientation_noise_std_deg"] = rot
        rot_text = f", {rot}° per axis on the orientation"
    Dataset(q, y, measurement.kind, meta).to_csv(args.out)
    print(f"wrote {args.samples} {measurement.kind} samples of robot {robot.name} (σ = {noise} mm{rot_text}, "
          f"seed {args.seed}{_like_words(like)}) to {args.out}")
    return 0


def _like_words(like: _Like | None) -> str:
    return "" if like is None else f", the robot and set-up of {like.source}"


def _orientation_noise_deg(args, measurement) -> float:
    """``--orientation-noise-deg`` (deg; ``--like``: the first file's unless given), checked:
    pose data only, not negative."""
    rot = 0.0 if args.orientation_noise_deg is None else args.orientation_noise_deg
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


def _simulate_like(args) -> int:
    """``--like RESULT.json``: a new file of the robot and set-up a result was calibrated on
    (:func:`_like_file`); ``--like DIR/combined.json --out-dir NEW``: one per block of a combined
    result, each under its data file's name in ``NEW``, so that ``jaxcal evaluate DIR/<block>.json
    NEW/<file>`` tries each block's calibration on the new day."""
    from .._calibration._blocks import COMBINED_FORMAT, load_combined_result
    from .._calibration._io import load_result, load_result_dict, result_data_file

    given = [f for f, v in (("--robot", args.robot), ("--base", args.base), ("--tip", args.tip),
                            ("--measurement", args.measurement), ("--anchor", args.anchor),
                            ("--unknown-anchor", args.unknown_anchor), ("--radius-mm", args.radius_mm),
                            ("--mount", args.mount), ("--missing-corners", args.missing_corners)) if v is not None and v is not False]
    if given:
        raise _Usage(f"--like takes the robot, the measurement and the set-up from the result; drop {', '.join(given)}")
    src = pathlib.Path(args.like)
    if not src.exists():
        raise _Usage(f"--like: result file {args.like!r} not found")
    if _json_format(src) == COMBINED_FORMAT:
        if args.out or not args.out_dir:
            raise _Usage(f"--like: {src} is a combined result: give --out-dir DIR (one new file per block, under "
                         "the names of the files it was calibrated on) instead of --out")
        with _as_usage("--like: "):
            comb = load_combined_result(src)
        out_dir = pathlib.Path(args.out_dir)
        files = comb.raw.get("settings", {}).get("data") or []
        by_block = {pathlib.Path(f).stem: f for f in files if isinstance(f, str)}
        for name, res in comb.results.items():
            path = result_data_file(src, {"settings": {"data": by_block.get(name)}})
            if path is None:
                raise _Usage(f"--like: the data file {by_block.get(name)!r} of block {name!r} of {src} is not found")
            out = out_dir / path.name
            if out.resolve() == path.resolve():
                raise _Usage(f"--like: --out-dir {args.out_dir} would overwrite {path}, the data of block {name!r}; "
                             "choose another folder")
            block_args = argparse.Namespace(**vars(args))
            block_args.out = str(out)
            out_dir.mkdir(parents=True, exist_ok=True)
            code = _like_file(block_args, res, path, f"{src.name}, block {name}")
            if code:
                return code
        return 0
    if args.out_dir:
        raise _Usage("--out-dir applies to --like of a combined result (combined.json); give --out FILE.csv")
    if not args.out:
        raise _Usage("give --out FILE.csv (the data file to write)")
    with _as_usage("--like: "):
        raw = load_result_dict(src)
    path = result_data_file(src, raw)
    if path is None:
        data_path = (raw.get("settings") or {}).get("data")
        raise _Usage(f"--like: the data file {data_path!r} that {src} was calibrated on is not found"
                     if isinstance(data_path, str) else
                     f"--like: {src} does not name one data file (a fleet result or one saved from Python); "
                     "simulate with --robot/--seed instead")
    kind = (raw.get("measurement") or {}).get("kind")
    _check_simulated(kind, src)
    with _as_usage("--like: "):
        res = load_result(src)
    return _like_file(args, res, path, src.name)


def _json_format(path) -> str | None:
    """The ``"format"`` entry of a JSON file (``None``: none, or not JSON: the result reader says why)."""
    import json

    try:
        d = json.loads(pathlib.Path(path).read_text(encoding="utf-8"))
    except (ValueError, OSError):
        return None
    return d.get("format") if isinstance(d, dict) else None


def _check_simulated(kind, src) -> None:
    """Raises _Usage: ``kind`` is not one ``jaxcal simulate`` writes (nor so ``--like`` re-simulates)."""
    if kind not in SIMULATED_KINDS:
        raise _Usage(f"--like cannot re-simulate {kind} data ({src}): `jaxcal simulate` writes "
                     f"{', '.join(SIMULATED_KINDS)} data only; measure a new file instead")


def _like_file(args, res, path, source: str) -> int:
    """A new day of the file ``path`` a result ``res`` was calibrated on (``source`` names the result
    in the ``# like:`` line): the file must be one ``jaxcal simulate`` wrote. Its ``seed`` (or
    ``true_robot_seed``) line gives the true robot (:func:`~jaxcal._simulation._truth.simulated_truth`),
    its set-up lines the set-up, as ``jaxcal simulate`` wrote them (draw wire: ``anchor_mm`` or
    ``true_anchor_mm`` / ``true_cable_offset_mm``; point: ``radius_mm``; camera: ``target``,
    ``camera_intrinsics``, ``image_size_px``, ``mount``, ``missing_corners``; self-contact: ``tips``;
    pose: ``orientation_noise_std_deg``), its ``noise_std_mm`` / ``noise_std_px`` line the noise
    (unless ``--noise-std``) and its row count the ``--samples`` (unless given). ``--seed`` draws
    the new poses and noise. The robot is the result's nominal robot."""
    from .._datasets._dataset import load_csv
    from .._sensors._kind import sensor_kind

    kind = res.measurement.kind
    _check_simulated(kind, source)
    with _as_usage("--like: "):
        first = load_csv(path)
    meta = first.meta
    if meta.get("source") != "jaxcal simulate" or "seed" not in meta:
        raise _Usage(f"--like: {path} was not written by `jaxcal simulate` (no '# source: jaxcal simulate' and "
                     "'# seed:' lines), so its true robot is not known; measure a new file instead")
    if meta.get("robot") != res.robot.name:
        raise _Usage(f"--like: {path} was simulated for robot {meta.get('robot')!r} but {source} calibrates "
                     f"{res.robot.name!r}; the true robot is not known")
    if first.kind != kind:
        raise _Usage(f"--like: {path} holds {first.kind} data but {source} calibrates {kind} data")
    args = argparse.Namespace(**vars(args))  # the first file's set-up, as its options
    args.measurement = kind
    if args.samples is None:  # the same measurement program: as many rows as the first file
        args.samples = first.n
    if args.noise_std is None:
        args.noise_std = float(meta.get(f"noise_std_{sensor_kind(kind).noise_unit}", 0.5))
    if args.orientation_noise_deg is None and "orientation_noise_std_deg" in meta:
        args.orientation_noise_deg = float(meta["orientation_noise_std_deg"])
    args.unknown_anchor = "true_anchor_mm" in meta  # the new file keeps the set-up's lines as the first had them
    args.anchor = meta.get("anchor_mm")
    args.radius_mm = float(meta["radius_mm"]) if "radius_mm" in meta else None
    like = _Like(int(meta.get("true_robot_seed", meta["seed"])), f"{source} (data {path.name})", meta)
    return _simulate(args, res.robot, like)


def _simulate_contact(args, robot, measurement, like: _Like | None) -> int:
    """``jaxcal simulate --measurement plane|point|distance``:
    :func:`~jaxcal._simulation._simulate_sensors.simulated_contact_data` → ``args.out``."""
    from .._datasets._dataset import Dataset
    from .._simulation._simulate_sensors import simulated_contact_data

    if like is not None:
        want = like.meta.get(f"{measurement.kind}_labels")
        have = ",".join(getattr(measurement, "labels", ()))
        if want is not None and want != have:
            raise _Usage(f"--like: the first file's {measurement.kind}s are {want}, `jaxcal simulate` now writes "
                         f"{have}; the set-up is not known")
    with _as_usage():
        data = simulated_contact_data(args.seed, robot, measurement, n_samples=args.samples, noise_std=args.noise_std,
                                      truth_seed=None if like is None else like.truth_seed)
    Dataset(data.q, data.y, data.kind, {**data.meta, **_seed_lines(args, like)}).to_csv(args.out)
    labels = getattr(measurement, "labels", ())
    if measurement.kind == "distance":
        what = "bar lengths 150 and 300 mm"
    elif getattr(measurement, "sphere", False):
        what = f"{len(labels)} spheres of radius {data.meta['radius_mm']} mm: {', '.join(labels)}"
    else:
        what = f"{len(labels)} {measurement.kind}s: {', '.join(labels)}"
    print(f"wrote {args.samples} {measurement.kind} samples of robot {robot.name} (σ = {args.noise_std} mm, "
          f"seed {args.seed}, {what}{_like_words(like)}) to {args.out}")
    return 0


def _simulate_camera(args, robot, like: _Like | None) -> int:
    """``jaxcal simulate --measurement camera``: :func:`jaxcal.simulate_camera` (a 9×6 checkerboard of
    20 mm squares, 1280×1024 px, f = 1000 px; ``--like``: the first file's), written with the target,
    intrinsics, image size and mount lines (and ``missing_corners`` where corners were left out).
    ``--mount tip-to-tip`` (a robot with two tips or more, ``--robot FILE.urdf --tip A,B``): the
    camera on the first tip sees the target on the second (self-observation; ``--like``: the first
    file's tips), with ``# tip:`` and ``# target_tip:`` lines."""
    import jax
    import numpy as np

    from .._datasets._dataset import Dataset, mm_joints_metadata
    from .._sensors._camera import Camera, load_target
    from .._simulation._simulate_sensors import simulate_camera
    from .._simulation._truth import simulated_truth

    lines = {} if like is None else like.meta
    mount = (args.mount or lines.get("mount") or "eye-in-hand").replace("-", "_")
    missing = args.missing_corners if args.missing_corners is not None else float(lines.get("missing_corners", 0.0))
    if args.anchor:
        raise _Usage("--anchor applies to --measurement cable only")
    if args.samples < 3:
        raise _Usage(f"--samples (images) must be at least 3, got {args.samples}")
    if not 0.0 <= missing < 1.0:
        raise _Usage(f"--missing-corners must be in [0, 1), got {missing}")
    target = lines.get("target", CAMERA_TARGET)
    intr = [float(v) for v in _floats(lines["camera_intrinsics"], 9, "the first file's camera_intrinsics")] \
        if "camera_intrinsics" in lines else list(CAMERA_INTRINSICS)
    size = tuple(int(v) for v in _floats(lines["image_size_px"], 2, "the first file's image_size_px")) \
        if "image_size_px" in lines else CAMERA_IMAGE_SIZE
    tips = {}
    if mount == "tip_to_tip":  # self-observation: the camera on the first tip, the target on the second
        names = robot.tip_names()[:2] if like is None else [lines.get("tip", ""), lines.get("target_tip", "")]
        if len(names) != 2 or not all(names):
            raise _Usage("--mount tip-to-tip needs a robot with two tips (--robot FILE.urdf --tip A,B: the camera on A, "
                         f"the target on B); robot {robot.name!r} has {len(robot.tip_names()) or 'one unnamed'} tip(s)")
        tips = {"tip": names[0], "target_tip": names[1]}
    with _as_usage():
        from .._sensors._kind import resolve_tip

        on = {k: resolve_tip(robot, v) for k, v in tips.items()}  # None: the robot's default tip
        cam = Camera(load_target(target), intr, mount, image_size=size, **on)
        key = jax.random.key(args.seed)  # the poses and noise; the seed's robot and tool, as every kind's
        truth = simulated_truth(key if like is None else jax.random.key(like.truth_seed), robot)
        q, y, cam, truth = simulate_camera(key, robot, cam, n_views=args.samples, noise_px=args.noise_std,
                                           missing=missing, true_deviations=truth)
    n_masked = int(np.isnan(np.asarray(y)).any(axis=-1).sum())
    meta = {"source": "jaxcal simulate", "robot": robot.name, **_seed_lines(args, like),
            "noise_std_px": args.noise_std, "target": target, "camera_intrinsics": ",".join(repr(v) for v in intr),
            "mount": cam.mount, "image_size_px": ",".join(str(v) for v in size),
            **({"missing_corners": missing} if missing else {}), **tips, **mm_joints_metadata(robot)}
    Dataset(q, y, "camera", meta).to_csv(args.out)
    where = f": camera on {tips['tip']}, target on {tips['target_tip']}" if tips else ""
    print(f"wrote {args.samples} camera images ({cam.mount}{where}, {cam.n_points} target points, {n_masked} corner(s) "
          f"left undetected) of robot {robot.name} (σ = {args.noise_std} px, seed {args.seed}{_like_words(like)}) "
          f"to {args.out}")
    return 0


def _simulate_self_contact(args, robot, like: _Like | None) -> int:
    """``jaxcal simulate --measurement self_contact --robot FILE.urdf --tip A,B``: the two tips touch
    (:func:`jaxcal.simulate_self_contact`, 30 mm balls: 60 mm apart at contact) on the seed's robot,
    written with the ``# tips:`` line (``--like``: the first file's tips)."""
    import jax

    from .._datasets._dataset import Dataset, mm_joints_metadata
    from .._sensors._self_contact import simulate_self_contact
    from .._simulation._truth import simulated_truth

    tips = robot.tip_names()[:2] if like is None else [t.strip() for t in like.meta.get("tips", "").split(",")]
    if len(tips) != 2:
        raise _Usage("--measurement self_contact needs a robot with two tips: --robot FILE.urdf --tip A,B")
    if args.anchor:
        raise _Usage("--anchor applies to --measurement cable only")
    key = jax.random.key(args.seed)  # the poses and noise; the seed's robot, as every kind's (simulated_truth)
    with _as_usage():
        truth = simulated_truth(key if like is None else jax.random.key(like.truth_seed), robot)
        q, y = simulate_self_contact(key, robot, tips, n_samples=args.samples, noise_std=args.noise_std,
                                     true_deviations=truth)
    meta = {"source": "jaxcal simulate", "robot": robot.name, **_seed_lines(args, like), "noise_std_mm": args.noise_std,
            "tips": ",".join(tips), **mm_joints_metadata(robot)}
    Dataset(q, y, "self_contact", meta).to_csv(args.out)
    print(f"wrote {len(y)} self-contact rows of {tips[0]} and {tips[1]} of robot {robot.name} (σ = {args.noise_std} mm "
          f"contact scatter, seed {args.seed}{_like_words(like)}) to {args.out}")
    return 0
