"""``jaxcal simulate``.
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib

from ._common import _as_usage, _robot, _Usage


@dataclasses.dataclass(frozen=True)
class _Like:
    """A new day of a simulated set-up (``--like``): the true robot's seed, the words naming where
    it came from (the ``# like:`` line) and the first file's metadata (its set-up lines)."""

    truth_seed: int
    source: str
    meta: dict


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
    return _simulate(args, _robot(args.robot, args.base, args.tip), None)


def _simulate(args, robot, like: _Like | None) -> int:
    """Write ``args.out``: ``args.samples`` rows of ``args.measurement`` data of ``robot`` (the true
    robot of ``args.seed``, or of ``like.truth_seed`` with the set-up of ``like.meta``), by the
    kind's own simulator (:func:`~jaxcal._simulation._simulate_files.simulate_file`)."""
    from .._simulation._simulate_files import FileRequest, simulate_file

    request = FileRequest(robot, args.seed, args.samples, args.noise_std,
                          truth_seed=None if like is None else like.truth_seed,
                          like_source=None if like is None else like.source,
                          like_meta=None if like is None else like.meta, anchor=args.anchor,
                          unknown_anchor=bool(args.unknown_anchor), radius_mm=args.radius_mm, mount=args.mount,
                          missing_corners=args.missing_corners,
                          orientation_noise_deg=0.0 if args.orientation_noise_deg is None else args.orientation_noise_deg)
    with _as_usage():
        sim = simulate_file(args.measurement, request)
    sim.data.to_csv(args.out)
    print(f"wrote {sim.summary} to {args.out}")
    return 0


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
    """Raises _Usage: ``kind`` is not one ``jaxcal simulate`` writes (nor so ``--like`` re-simulates):
    a kind without a simulator (``SensorKind.simulator``), or no kind at all."""
    from .._sensors._kind import sensor_kind, simulated_kind_names

    try:
        simulated = sensor_kind(str(kind)).simulator is not None
    except ValueError:  # not a kind at all
        simulated = False
    if not simulated:
        raise _Usage(f"--like cannot re-simulate {kind} data ({src}): `jaxcal simulate` writes "
                     f"{', '.join(simulated_kind_names())} data only; measure a new file instead")


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
