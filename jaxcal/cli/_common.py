"""What several ``jaxcal`` commands share: errors, robot and measurement from the arguments, tables, the date.
"""

from __future__ import annotations

import contextlib
import pathlib
import sys
import time

_EXIT_FAILED = 1


class _Usage(Exception):
    """Bad command-line input: reported as one line, exit status 2."""


_T0 = time.perf_counter()  # the command line's start (before JAX is imported)


@contextlib.contextmanager
def _as_usage(prefix: str = "", errors: tuple[type[BaseException], ...] = (ValueError,)):
    """The library's ``errors`` raised inside the block (bad values the user typed or pointed to)
    re-raised as :class:`_Usage`, their message after ``prefix``."""
    try:
        yield
    except errors as e:
        raise _Usage(f"{prefix}{e}") from None


def _floats(text: str, n: int, what: str) -> list[float]:
    from .._core._csvfile import number_list

    with _as_usage():
        return number_list(text, n, what)


def _robot(spec: str, base: str | None = None, tip: str | None = None):
    """The robot of ``--robot`` (a preset, a DH table file, a URDF file with ``--base``/``--tip``;
    several comma-separated ``--tip`` links: a :class:`~jaxcal.KinematicTree` with those tips; a
    tree preset or a DH tree file (``# branch:`` lines) with ``--tip``: the tree of those of its
    tips, :meth:`KinematicTree.with_tips`)."""
    from .. import robots
    from .._calibration._io import load_robot_csv

    p = pathlib.Path(spec)
    tips = [t.strip() for t in (tip or "").split(",") if t.strip()]
    if p.suffix.lower() == ".urdf":
        from .._models._urdf import load_urdf

        if not p.exists():
            raise _Usage(f"robot file {spec!r} not found")
        if len(tips) > 1:
            with _as_usage("--tip: "):
                return load_urdf(p, base=base, tips=tips)
        return load_urdf(p, base=base, tip=tip)
    robot = None
    if spec in robots.TREE_PRESETS and base is None:
        robot = robots.get_robot(spec)
    elif spec not in robots.PRESETS and (p.suffix.lower() in (".csv", ".txt") or p.exists()):
        if not p.exists():
            raise _Usage(f"robot file {spec!r} not found")
        robot = load_robot_csv(p)  # a DH tree file (with '# branch:' lines) gives a KinematicTree
    if robot is not None and len(robot.tip_names()) > 1 and base is None:  # a tree: the tips to keep
        if tip is None:
            return robot
        with _as_usage("--tip: "):
            return robot.with_tips(tips)
    if base is not None or tip is not None:
        raise _Usage("--base/--tip apply to a URDF robot (--robot FILE.urdf) only, and --tip to a tree preset "
                     f"({', '.join(robots.TREE_PRESETS)}) or a DH tree file: the tips to keep")
    if robot is not None:
        return robot
    if spec in robots.PRESETS:
        return robots.get_robot(spec)
    raise _Usage(f"unknown robot {spec!r}; presets: {', '.join(robots.PRESETS)}; or a robot file: a DH table "
                 "(.csv, see jaxcal calibrate --help) or a URDF (.urdf, with --base LINK and --tip LINK)")


def _robot_and_sensor(args, robot=None):
    """``(robot, measurement)`` of ``jaxcal plan`` from ``--robot/--base/--tip`` (or ``robot``, given),
    ``--measurement``, ``--anchor`` and ``--mount`` (the kind's :meth:`SensorKind.planning_model`)."""
    from .._sensors._kind import sensor_kind

    robot = _robot(args.robot, args.base, args.tip) if robot is None else robot
    anchor = _floats(args.anchor, 3, "--anchor") if args.anchor else None
    with _as_usage():
        measurement = sensor_kind(args.measurement).planning_model(robot, anchor_mm=anchor,
                                                                   mount=args.mount.replace("-", "_"))
    radius = getattr(args, "radius_mm", None)
    if radius is not None:
        measurement = _sphere_model(args.measurement, measurement, radius, False)
    return robot, measurement


def _sphere_model(kind: str, measurement, radius_mm, estimate: bool):
    """``--radius-mm`` / ``--estimate radius``: the point model as spheres (``SensorKind.spheres``;
    bad input: :class:`_Usage`)."""
    from .._sensors._kind import sensor_kind

    with _as_usage():
        return sensor_kind(kind).spheres(measurement, radius_mm, estimate)


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


def _today() -> str:
    """The UTC date a result is written (``jaxcal drift`` names the earlier calibration by it)."""
    import datetime

    return datetime.datetime.now(datetime.timezone.utc).date().isoformat()


def times_line(t_start: float, t_loaded: float, t_fit: float, res, call: str) -> str:
    """``--verbose``'s line of where the time went, from the command line's start (:data:`_T0`):
    start-up to ``t_start``, the data to ``t_loaded``, the fit (``call``, result ``res``) to
    ``t_fit``, the output to now (``time.perf_counter`` values)."""
    t_end = time.perf_counter()
    return (f"\ntimes: start-up (arguments, importing JAX) {t_start - _T0:.2f} s, reading and checking the data "
            f"{t_loaded - t_start:.2f} s, "
            f"{call} {t_fit - t_loaded:.2f} s (compiling the solve {res.compile_time_s:.2f} s, on a background "
            f"thread beside the rest where there is a second core; solve {res.wall_time_s:.3f} s; "
            f"the rest: initialisation, identifiability, diagnostics), output {t_end - t_fit:.2f} s; "
            f"total {t_end - _T0:.2f} s since the command line started (Python's own start-up and the "
            "interpreter's exit come on top)")
