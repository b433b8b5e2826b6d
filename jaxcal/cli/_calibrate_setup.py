"""What ``jaxcal calibrate`` builds from its arguments and one data file before fitting.
"""

from __future__ import annotations

import ast
import pathlib
import types

from ._common import _as_usage, _floats, _robot, _Usage


def joint_columns_message(path, n: int, robot, what: str = "robot") -> str:
    """The one line for a data file with ``n`` joint columns where ``robot`` has another number.
    A kinematic tree's file holds a column for every joint of the tree (``q1 … qN`` in its joint
    order), also the joints its sensor's tip does not move: the line names the missing columns
    with their joints and branches, and how to calibrate with fewer (``--tip``: fewer tips)."""
    head = f"{path} has {n} joint columns but {what} {robot.name!r} has {robot.dof} joints"
    branches = getattr(robot, "branches", None)
    if branches is None or n > robot.dof or len(robot.tip_names()) < 2:
        return head
    branch_of = {j: b for b, _parent, joints in branches for j in joints}
    names = robot.joint_names
    missing = range(n, robot.dof)
    first, last = missing[0], missing[-1]
    span = (f"q{first + 1} ({names[first]}, branch {branch_of[first]})" if first == last else
            f"q{first + 1} … q{last + 1} ({names[first]} … {names[last]}, "
            + _branch_words(dict.fromkeys(branch_of[j] for j in missing)) + ")")
    return (f"{head} (tips {', '.join(robot.tip_names())}): missing {span}; a kinematic tree's data file holds a "
            f"column for every joint of the tree, q1 … q{robot.dof} in its joint order, also those its sensor's tip "
            "does not move (fewer tips, fewer joints: --tip A[,B...])")


def _branch_words(names) -> str:
    names = list(names)
    return ("branch " if len(names) == 1 else "branches ") + ", ".join(names)


def _outlier_rate(rate: float) -> float:
    """``--outlier-rate``, checked: a probability in (0, 1)."""
    if not (0.0 < rate < 1.0):
        raise _Usage(f"--outlier-rate must be a probability between 0 and 1 (e.g. 0.01), got {rate:g}")
    return rate


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


def _nongeometric_robot(robot, compliance: str | None, harmonics: str | None):
    """``robot`` with the non-geometric error models of ``--compliance`` / ``--harmonics``."""
    with _as_usage("--compliance/--harmonics: ", (ValueError, OSError, NotImplementedError)):
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
    return robot


def _calibration_setup(args, method: str, data_file: str) -> types.SimpleNamespace:
    """What `jaxcal calibrate` builds from its arguments and one data file before fitting: the robot,
    the loaded data, the measurement model, the extras to estimate, the objective, the checks and the
    method's settings (raises :class:`_Usage` on bad input)."""
    from .._calibration._evaluate import MEASURED_DEFAULTS
    from .._calibration._setup import measurement_for
    from .._datasets._dataset import load_csv
    from .._fit._diagnostics import Checks
    from .._fit._objective import LOSSES, Prior
    from .._sensors._kind import sensor_kind

    robot = _nongeometric_robot(_robot(args.robot, args.base, args.tip), args.compliance, args.harmonics)
    path = pathlib.Path(data_file)
    if not path.exists():
        raise _Usage(f"data file {data_file!r} not found")
    counted = args.measurement is None or sensor_kind(args.measurement).counts_markers
    if args.markers is not None and not counted:
        raise _Usage("--markers applies to --measurement markers only")
    if args.markers is not None and args.markers < 1:
        raise _Usage(f"--markers must be at least 1, got {args.markers}")
    try:  # without --measurement: the file's '# kind:' line, else the kind its columns show
        data = load_csv(path, kind=args.measurement, n_markers=args.markers)
    except ValueError as e:
        if args.measurement is None or not counted:
            raise
        raise _Usage(str(e)) from None
    kind = data.kind
    if data.dof != robot.dof:
        raise _Usage(joint_columns_message(path, data.dof, robot))
    if data.labels and args.test:
        raise _Usage(f"{path} has session/frame/placement columns (several recording sessions): --test FILE takes "
                     "one-session files; hold a session out with jaxcal.holdout_session (Python) instead")
    anchor = _floats(args.anchor, 3, "--anchor") if args.anchor else None
    with _as_usage():  # the model and extras from the file and the options (its metadata lines as defaults)
        ms = measurement_for(data, robot, anchor_mm=anchor, radius_mm=args.radius_mm, estimate=args.estimate or (),
                             target=args.target, camera_intrinsics=args.camera, mount=args.mount, path=path)
    estimate, notes, measurement = set(ms.estimate), list(ms.notes), ms.measurement
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
        test_file = load_csv(tpath, kind=data.kind, n_markers=sensor_kind(data.kind).n_points(data.y))
        if test_file.dof != robot.dof:
            raise _Usage(joint_columns_message(tpath, test_file.dof, robot))
        if test_file.labels:
            raise _Usage(f"{tpath} has session/frame/placement columns; the command line takes one session per file")
        if sensor_kind(test_file.kind).labelled:
            from .._datasets._dataset import relabel

            test_file = relabel(test_file, measurement.labels)
    with _as_usage("--prior: "):
        prior = Prior.parse(args.prior)
    checks = Checks(angle_deg=args.max_angle_deg, length_mm=args.max_length_mm,
                    outlier_rate=_outlier_rate(args.outlier_rate))
    hyper = _hyper(args.set)
    from ..methods import method_settings

    valid = method_settings(method)
    if valid is not None and set(hyper) - set(valid):
        raise _Usage(f"--set: unknown setting(s) {sorted(set(hyper) - set(valid))} for method {method}; "
                     f"its settings: {', '.join(valid)}")
    return types.SimpleNamespace(robot=robot, path=path, data=data, kind=kind, estimate=estimate, notes=notes,
                                 measurement=measurement, extras=ms.extras, test_fraction=test_fraction, loss=loss,
                                 test_file=test_file, prior=prior, checks=checks, hyper=hyper)
