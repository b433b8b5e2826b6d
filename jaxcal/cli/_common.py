"""What several ``jaxcal`` commands share: errors, robot and measurement from the arguments, tables.
"""

from __future__ import annotations

import math
import pathlib
import sys

_EXIT_FAILED = 1


class _Usage(Exception):
    """Bad command-line input: reported as one line, exit status 2."""


def _floats(text: str, n: int, what: str) -> list[float]:
    parts = [p for p in text.replace(";", ",").split(",") if p.strip()]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise _Usage(f"{what} must be {n} comma-separated numbers, got {text!r}") from None
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise _Usage(f"{what} must be {n} finite comma-separated numbers, got {text!r}")
    return vals


def _robot(spec: str, base: str | None = None, tip: str | None = None):
    from .. import robots
    from .._calibration._io import load_robot_csv

    p = pathlib.Path(spec)
    if p.suffix.lower() == ".urdf":
        from .._models._urdf import load_urdf

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


def _measurement(kind: str, anchor, robot, n_markers: int | None = None, data=None):
    from .._sensors._measurement import CableLength, Markers, Pose, Position

    if kind in ("plane", "point", "distance"):  # contact data (jaxcal._sensors._contact): planes/points from the data's labels
        if anchor is not None:
            raise _Usage("--anchor applies to --measurement cable only")
        from .._sensors._contact import contact_model

        return contact_model(kind, robot, data)

    if kind == "cable":
        if anchor is None:
            from .._simulation._simulate import default_anchor

            return CableLength(default_anchor(robot))
        from .._core._precision import to_device

        return CableLength(to_device(anchor))  # as jnp.asarray, without a compiled conversion program
    if anchor is not None:
        raise _Usage("--anchor applies to --measurement cable only")
    if kind == "markers":
        # marker positions on the flange unknown: they start from the data (closed form) and are calibrated
        import numpy as np

        return Markers(np.zeros((int(n_markers), 3)))
    return Pose() if kind == "pose" else Position()


def _robot_and_sensor(args):
    """``(robot, measurement)`` from ``--robot/--base/--tip``, ``--measurement`` and ``--anchor``
    (``jaxcal simulate`` and ``jaxcal plan``)."""
    robot = _robot(args.robot, args.base, args.tip)
    anchor = _floats(args.anchor, 3, "--anchor") if args.anchor else None
    if args.measurement == "camera":  # jaxcal plan: the simulation's set-up as the nominal frames
        if anchor is not None:
            raise _Usage("--anchor applies to --measurement cable only")
        from .._sensors._camera import planning_camera

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
    from .._sensors._contact import FixedPoint

    return FixedPoint(measurement.labels, measurement.centres, radii_mm=r, estimate_radius=estimate)


def _write_outputs(res, out, *, figures: bool) -> dict:
    """Print Tables III-V, write them (and the figures) into ``out``; ``{name: path}``."""
    from ..report import write_report

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
    from ..plots import save_figures

    return save_figures(res, out)


def _print_tables(res) -> None:
    from ..report import accuracy_table, convergence_table, dh_table

    print()
    print(accuracy_table(res))
    print()
    print(convergence_table(res))
    print()
    print(dh_table(res))
