"""``jaxcal plan``.
"""

from __future__ import annotations

import math
import pathlib

from ._common import _as_usage, _floats, _robot_and_sensor, _sphere_model, _Usage


def _cmd_plan(args) -> int:
    """Which poses to measure: candidates, selection, indices, predicted accuracy (issue 12)."""
    import jax
    import numpy as np

    from .._experiments import _plan
    from .._sensors._kind import sensor_kind

    robot, measurement = _robot_and_sensor(args)
    kind = sensor_kind(args.measurement)
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
    sensor = kind.planner is not None  # the sensor's own candidates, not joint angles over the workspace
    unit = kind.noise_unit
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
        if kind.labelled or kind.own_table:
            from .._datasets._dataset import load_csv

            cand = load_csv(spec, kind=args.measurement)  # labels / the bar's second pose are part of a candidate
            if kind.labelled:
                from .._datasets._dataset import relabel

                measurement = kind.default_model(robot, data=cand)
                if args.radius_mm is not None:
                    measurement = _sphere_model(args.measurement, measurement, args.radius_mm, False)
                cand = relabel(cand, measurement.labels)
        else:
            cand = _plan.load_joint_angles(spec, robot.dof)
        source = f"{len(cand.q) if hasattr(cand, 'q') else cand.shape[0]} candidates from {spec}"
    n_cand = len(cand.q) if hasattr(cand, "q") else cand.shape[0]
    if args.poses > n_cand:
        raise _Usage(f"--poses {args.poses} is more than the {n_cand} candidates")
    if args.with_files:
        return _plan_combined(args, robot, measurement, cand, source, unit, k_perm)
    if args.with_sigma:
        raise _Usage("--with-sigma applies to --with FILE (one σ per file, in order)")
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
    _write_plan(args.out, robot, measurement, sel, meta)
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
    print(f"\nwrote {sel.n} poses to {args.out}: {kind.plan_next}, then "
          f"`jaxcal calibrate {args.out} --robot {args.robot}{_robot_flags(args)} --measurement {args.measurement}`")
    if args.plot:
        top = min(cand.shape[0], max(4 * args.poses, 100))
        ns = sorted({int(round(v)) for v in np.geomspace(max(len(sel.space.free_names) + 2, 5), top, 12)})
        curve = _plan.accuracy_curve(robot, measurement, cand, ns, args.noise_std, q_test=q_test,
                                     criterion=args.criterion, key=k_perm)
        fig = curve.plot()
        fig.savefig(args.plot, dpi=120)
        print(f"wrote the predicted RMSE-vs-poses curve to {args.plot}")
    return 0


def _write_plan(path, robot, measurement, sel, meta: list) -> None:
    """The selected poses as a data file of the kind with empty readings: ``meta``, the joint units
    and the kind's set-up lines (:meth:`SensorKind.plan_lines`: a draw wire's anchor, the labels, a
    camera's target, intrinsics, mount and image size). Where the candidates are rows of the kind
    (contact rows with their label, bar rows with both poses and the bar length) they are written
    as they are; a camera's rows get empty pixel columns (:meth:`SensorKind.plan_readings`)."""
    from .._datasets._dataset import Dataset, mm_joints_metadata
    from .._experiments import _plan
    from .._sensors._kind import sensor_kind

    kind = sensor_kind(measurement.kind)
    lines = kind.plan_lines(measurement)
    units = list(mm_joints_metadata(robot).items())
    if kind.planner is None:  # joint angles only: the kind's columns left empty
        _plan.save_plan_csv(path, sel.q, measurement.kind, [*meta, *lines.items(), *units])
        return
    meta = dict([*meta, *units]) | lines
    if sel.data is None:
        Dataset(sel.q, kind.plan_readings(measurement, sel.n), measurement.kind, meta).to_csv(path)
    else:
        Dataset(sel.data.q, sel.data.y, measurement.kind, meta).to_csv(path)


def _fixed_block(path: str, sigma, robot):
    """``(block, unit)``: a ``--with`` data file as a :class:`jaxcal.Block`
    (:func:`~jaxcal._calibration._setup.block_from_file`: its model as ``jaxcal calibrate`` builds
    it, σ given or the file's ``noise_std_mm`` / ``noise_std_px`` line)."""
    from .._calibration._setup import block_from_file

    if not pathlib.Path(path).exists():
        raise _Usage(f"--with: data file {path!r} not found")
    try:
        block = block_from_file(path, robot, sigma=sigma)
    except ValueError as e:  # the file's own faults start with its path: said as --with FILE
        msg = str(e)
        raise _Usage(f"--with {msg}" if msg.startswith(f"{path}: ") else msg) from None
    return block, getattr(block.measurement, "unit", "mm")


def _plan_combined(args, robot, measurement, cand, source, unit, k_perm) -> int:
    """`jaxcal plan ... --with FILE [--with FILE ...]`: the poses of this sensor that add most to the
    data in hand (:func:`jaxcal.plan_blocks`), the combined prediction, the poses file."""
    import jax
    import numpy as np

    from .._calibration._blocks import block_extras
    from .._experiments._plan_blocks import plan_blocks
    from .._sensors._blocks import Block
    from .._sensors._kind import sensor_kind

    if args.plot:
        raise _Usage("--plot does not apply to --with (the curve is of one sensor alone)")
    sigmas = list(args.with_sigma or [])
    if sigmas and len(sigmas) != len(args.with_files):
        raise _Usage(f"--with-sigma: give one σ per --with file ({len(args.with_files)}), got {len(sigmas)}")
    fixed, units = [], []
    for i, path in enumerate(args.with_files):
        blk, u = _fixed_block(path, sigmas[i] if sigmas else None, robot)
        fixed.append(blk)
        units.append(u)
    names = [b.name for b in fixed]
    if len(set(names)) != len(names):
        raise _Usage(f"--with: the files' names (their blocks) must differ, got {names}")
    name = args.measurement if args.measurement not in names else f"planned_{args.measurement}"
    extras, _ = sensor_kind(measurement.kind).required_extras(set(), sphere=bool(getattr(measurement, "sphere", False)))
    planned = Block(name, measurement, cand, sigma=args.noise_std, extras=block_extras(extras))
    with _as_usage():
        plan = plan_blocks(robot, planned, args.poses, fixed=fixed, criterion=args.criterion,
                           exchange=not args.no_exchange)
    sel, pred = plan.selection, plan.prediction
    n_cand = len(cand.q) if hasattr(cand, "q") else cand.shape[0]
    rnd_idx = np.sort(np.asarray(jax.random.permutation(k_perm, n_cand))[: args.poses])
    rnd = plan.prediction_of(rnd_idx)
    in_hand = ", ".join(f"{b.name} ({b.measurement.kind}, {len(np.asarray(b.data.q))} rows, σ = {b.sigma:g} {u})"
                        for b, u in zip(fixed, units))
    print(f"{source}; {sel.n} selected ({args.criterion}-optimal on the combined information, {sel.method}, "
          f"{plan.seconds:.2f} s) for {plan.space.n_free} parameters (robot and every block's extras), given the "
          f"data in hand: {in_hand}")
    blocks = [b.name for b in pred.blocks]
    print(f"\n| poses | {args.criterion} criterion (combined) | rank | "
          + " | ".join(f"predicted test RMSE {b.name} / {b.unit}" for b in pred.blocks) + " |")
    print("|---|---|---|" + "---|" * len(blocks))
    for label, crit, pr in (("selected", plan.criterion_value, pred),
                            ("random", plan.criterion_of(rnd_idx), rnd),
                            ("none (data in hand only)", plan.fixed_value, None)):
        rest = [str(pr.rank), *(f"{b.test_rmse:.4f}" for b in pr.blocks)] if pr is not None else [""] * (1 + len(blocks))
        cells = [f"{crit:.6g}", *rest]
        print(f"| {label} | " + " | ".join(cells) + " |")
    print(f"\n({args.poses} random candidates for comparison; each block's test RMSE on fresh readings at its "
          "poses — a planned block's: its candidates — with the σ given; linearised at the nominal robot)\n")
    print(pred.table())
    meta = [("source", "jaxcal plan --with"), ("robot", robot.name), ("planned_poses", args.poses),
            ("criterion", f"{args.criterion}-optimal on the combined information ({sel.method})"),
            ("seed", args.seed), ("planned_with", ",".join(str(pathlib.Path(f).name) for f in args.with_files)),
            (f"predicted_test_rmse_{unit}", f"{pred.block(name).test_rmse:.4f}"), (f"noise_std_{unit}", args.noise_std)]
    _write_plan(args.out, robot, measurement, sel, meta)
    files = " ".join([args.out, *args.with_files])
    print(f"\nwrote {sel.n} poses to {args.out}: {sensor_kind(args.measurement).plan_next}, then "
          f"`jaxcal calibrate {files} --robot {args.robot}{_robot_flags(args)} --combine --out-dir fit`")
    return 0


def _robot_flags(args) -> str:
    """`` --base B --tip T`` as given (a URDF's chain, a tree preset's tips): the robot the plan was
    made for, for the ``jaxcal calibrate`` command it suggests."""
    return "".join(f" {flag} {v}" for flag, v in (("--base", args.base), ("--tip", args.tip)) if v)
