"""``jaxcal calibrate``.
"""

from __future__ import annotations

import ast
import math
import pathlib
import sys
import time
import types
import warnings

from ._common import _EXIT_FAILED, _floats, _robot, _Usage

__all__ = ["FLEET_KINDS"]


_T0 = time.perf_counter()  # process start-up (as near as the CLI can tell)


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


def _metrics_rows(pairs):
    return [[name, m.rmse, m.mean, m.max] for name, m in pairs]


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
    from .._core._metrics import format_table
    from .._core._trig import wrap_angle_deg

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
    from .._core._metrics import format_table
    from .._models._chain import GEOMETRIC_GROUPS, TIP_GROUPS, correction_entries

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
    from .._calibration._evaluate import MEASURED_DEFAULTS
    from .._calibration._setup import measurement_for
    from .._datasets._dataset import load_csv
    from .._fit._diagnostics import Checks
    from .._fit._objective import LOSSES, Prior

    robot = _nongeometric_robot(_robot(args.robot, args.base, args.tip), args.compliance, args.harmonics)
    path = pathlib.Path(data_file)
    if not path.exists():
        raise _Usage(f"data file {data_file!r} not found")
    if args.markers is not None and args.measurement not in (None, "markers"):
        raise _Usage("--markers applies to --measurement markers only")
    if args.markers is not None and args.markers < 1:
        raise _Usage(f"--markers must be at least 1, got {args.markers}")
    try:  # without --measurement: the file's '# kind:' line, else the kind its columns show
        data = load_csv(path, kind=args.measurement, n_markers=args.markers)
    except ValueError as e:
        if args.measurement != "markers":
            raise
        raise _Usage(str(e)) from None
    kind = data.kind
    if data.dof != robot.dof:
        raise _Usage(f"{path} has {data.dof} joint columns but robot {robot.name!r} has {robot.dof} joints")
    if data.labels and args.test:
        raise _Usage(f"{path} has session/frame/placement columns (several recording sessions): --test FILE takes "
                     "one-session files; hold a session out with jaxcal.holdout_session (Python) instead")
    anchor = _floats(args.anchor, 3, "--anchor") if args.anchor else None
    try:  # the model and extras from the file and the options (its metadata lines as defaults)
        ms = measurement_for(data, robot, anchor_mm=anchor, radius_mm=args.radius_mm, estimate=args.estimate or (),
                             target=args.target, camera_intrinsics=args.camera, mount=args.mount, path=path)
    except ValueError as e:
        raise _Usage(str(e)) from None
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
        test_file = load_csv(tpath, kind=data.kind, n_markers=data.y.shape[1] if data.kind == "markers" else None)
        if test_file.dof != robot.dof:
            raise _Usage(f"{tpath} has {test_file.dof} joint columns but robot {robot.name!r} has {robot.dof} joints")
        if test_file.labels:
            raise _Usage(f"{tpath} has session/frame/placement columns; the command line takes one session per file")
        if test_file.kind in ("plane", "point"):
            from .._datasets._dataset import relabel

            test_file = relabel(test_file, measurement.labels)
    try:
        prior = Prior.parse(args.prior)
    except ValueError as e:
        raise _Usage(f"--prior: {e}") from None
    checks = Checks(angle_deg=args.max_angle_deg, length_mm=args.max_length_mm)
    hyper = _hyper(args.set)
    from ..methods import method_settings

    valid = method_settings(method)
    if valid is not None and set(hyper) - set(valid):
        raise _Usage(f"--set: unknown setting(s) {sorted(set(hyper) - set(valid))} for method {method}; "
                     f"its settings: {', '.join(valid)}")
    return types.SimpleNamespace(robot=robot, path=path, data=data, kind=kind, estimate=estimate, notes=notes,
                                 measurement=measurement, extras=ms.extras, test_fraction=test_fraction, loss=loss,
                                 test_file=test_file, prior=prior, checks=checks, hyper=hyper)


def _same_tree(a, b) -> bool:
    """Two pytrees (measurement models) with the same structure and equal array leaves."""
    import jax
    import numpy as np

    (la, ta), (lb, tb) = jax.tree_util.tree_flatten(a), jax.tree_util.tree_flatten(b)
    return ta == tb and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))


#: measurement kinds `jaxcal calibrate` takes several files of (one sensor set-up per fleet)
FLEET_KINDS = ("cable", "position", "pose")


def _cmd_calibrate_combined(args, method: str) -> int:
    """`jaxcal calibrate a.csv b.csv ... --combine --out-dir DIR [--relations FILE]`: the files are
    blocks of one robot (:func:`jaxcal.calibrate_blocks`): one fit, each block's σ estimated; one
    result JSON per block (:func:`~jaxcal._calibration._blocks.block_result`, read by `jaxcal
    evaluate`) and ``combined.json`` (:func:`jaxcal.save_combined_result`: every block's statistics and result, the
    relations, σ, the deviations)."""

    from .._calibration._blocks import block_extras, block_result, calibrate_blocks, save_combined_result
    from .._calibration._calibrate import CalibrationWarning
    from .._calibration._io import save_result
    from .._sensors._blocks import Block, load_relations

    if not args.combine:
        raise _Usage("--relations applies to --combine (several files of one robot)")
    for given, flag in ((args.out, "--out"), (args.test, "--test"), (args.exclude_rows, "--exclude-rows"),
                        (args.exclude_outliers, "--exclude-outliers"), (args.measurement, "--measurement")):
        if given:
            raise _Usage(f"{flag} does not apply to --combine: every row of every file trains, each file says its "
                         "kind ('# kind:' line or columns), the results go to --out-dir DIR")
    if not args.out_dir:
        raise _Usage("--combine: give --out-dir DIR (one RESULT.json per file and combined.json)")
    setups = [_calibration_setup(args, method, f) for f in args.data]
    names = [s.path.stem for s in setups]
    if len(set(names)) != len(names):
        raise _Usage(f"--combine: the files' names (their blocks) must differ, got {names}")
    first = setups[0]
    try:
        relations = load_relations(args.relations) if args.relations else ()
        blocks = [Block(n, s.measurement, s.data, extras=block_extras(s.estimate)) for n, s in zip(names, setups)]
    except (ValueError, OSError) as e:
        raise _Usage(str(e)) from None
    print(f"combined fit of robot {first.robot.name}: {len(blocks)} blocks ("
          + ", ".join(f"{n}: {s.data.n} {s.kind} rows" for n, s in zip(names, setups))
          + (f"), {len(relations)} relations from {args.relations}" if relations else ")") + f", method {method}; "
          "every row trains; each block's σ estimated (variance components)")
    for s in setups:
        for n in s.notes:
            print(f"note: {s.path.name}: {n}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CalibrationWarning)
        try:
            res = calibrate_blocks(first.robot, blocks, relations, method, prior=first.prior, loss=first.loss,
                                   checks=first.checks, free=args.free, fix=args.fix or (), **first.hyper)
        except ValueError as e:
            raise _Usage(str(e)) from None
    for w in caught:
        if issubclass(w.category, CalibrationWarning):
            print(f"jaxcal: warning: {w.message}", file=sys.stderr)
    for m in res.block_messages:
        print(f"start: {m}")
    print(f"status {res.status.name.lower()}, {res.variance_rounds} fit(s) with re-estimated σ, "
          f"{res.space.n_free} free parameters; whitened train RMSE {res.train_metrics.rmse:.4f} (1 at the floor)")
    for st in res.blocks:
        print("  " + st.line())
    for line in res.block_report:
        print("  " + line)
    out = pathlib.Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for n, s in zip(names, setups):
        br = block_result(res, n)
        settings = {"data": str(s.path), "n_samples": s.data.n, "n_train": s.data.n, "n_test": 0, "method": method,
                    "prior": args.prior, "loss": first.loss, "combined": names,
                    "relations": None if not args.relations else str(args.relations)}
        save_result(br, out / f"{n}.json", settings=settings, metrics_mm={"train, after": br.train_metrics._asdict()})
    save_combined_result(res, out / "combined.json",
                         settings={"data": [str(s.path) for s in setups], "method": method, "prior": args.prior,
                                   "loss": first.loss, "relations": None if not args.relations else str(args.relations)})
    print(f"wrote {len(names)} block result(s) and combined.json to {out}")
    return 0 if res.status.name not in ("DIVERGED", "FAILED") else _EXIT_FAILED


def _cmd_calibrate_fleet(args, method: str) -> int:
    """`jaxcal calibrate a.csv b.csv ... --out-dir DIR`: every file one unit of the same robot model,
    calibrated by :func:`jaxcal.calibrate_many` (the solves as one compiled program); one result
    JSON per unit and the summary table (``summary.md``, ``summary.csv``) in ``DIR``."""
    import numpy as np

    from .._calibration._calibrate import CalibrationWarning
    from .._calibration._fleet import calibrate_many
    from .._calibration._io import save_result
    from .._core._metrics import metrics_numpy
    from .._datasets._split import seed_split

    for given, flag in ((args.out, "--out"), (args.test, "--test"), (args.exclude_rows, "--exclude-rows"),
                        (args.exclude_outliers, "--exclude-outliers")):
        if given:
            raise _Usage(f"{flag} applies to one data file; several files write one result each to --out-dir DIR")
    if not args.out_dir:
        raise _Usage("several data files: give --out-dir DIR (one RESULT.json per file and the summary table)")
    if args.measurement is not None and args.measurement not in FLEET_KINDS:
        raise _Usage(f"several data files take --measurement {', '.join(FLEET_KINDS)}; calibrate "
                     f"{args.measurement} data one file at a time")
    setups = [_calibration_setup(args, method, f) for f in args.data]
    first = setups[0]
    if first.kind not in FLEET_KINDS:
        raise _Usage(f"several data files take {', '.join(FLEET_KINDS)} data; calibrate {first.kind} data "
                     "(from the files' '# kind:' lines or columns) one file at a time")
    for s in setups[1:]:
        if s.kind != first.kind:
            raise _Usage(f"{s.path} holds {s.kind} data but {first.path} {first.kind} data: the units of a fleet "
                         "share one sensor kind")
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
        k, train_idx, test_idx = seed_split(args.seed, s.data.n, first.test_fraction)
        k_method = k if k_method is None else k_method  # one key for every unit (same seed)
        trains.append(s.data.subset(train_idx))
        tests.append(s.data.subset(test_idx))
    extras = first.extras
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
        save_result(res, out / f"{pathlib.Path(name).stem}.json", settings=settings, metrics_mm=metrics,
                    calibrated_at=_today())
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

    from .._calibration._calibrate import CalibrationWarning, calibrate
    from .._calibration._evaluate import (
        before_after_errors,
        describe_objective,
        evaluate_result,
        joints_to_file_units,
        sample_errors,
    )
    from .._core._metrics import format_table, metrics_numpy
    from .._core._params import Deviations
    from .._datasets._split import seed_split
    from ..methods._stages import check_method_name

    try:
        method = check_method_name(args.method)  # a registry name, or stages such as ga>lm
    except ValueError as e:
        raise _Usage(str(e)) from None
    if args.combine or args.relations:
        return _cmd_calibrate_combined(args, method)
    if len(args.data) > 1 or args.out_dir:
        return _cmd_calibrate_fleet(args, method)
    setup = _calibration_setup(args, method, args.data[0])
    robot, path, data, notes, measurement = setup.robot, setup.path, setup.data, setup.notes, setup.measurement
    test_fraction, loss, test_file, prior, checks, hyper = (
        setup.test_fraction, setup.loss, setup.test_file, setup.prior, setup.checks, setup.hyper)
    excluded = sorted(set(_rows(args.exclude_rows)))
    if excluded and (excluded[0] < 1 or excluded[-1] > data.n):
        raise _Usage(f"--exclude-rows: data rows are numbered 1..{data.n}, got {excluded[0]}..{excluded[-1]}")
    kept_rows = np.setdiff1d(np.arange(data.n), np.asarray(excluded, int) - 1)
    if excluded:
        notes.append(f"excluded data rows (your choice): {', '.join(map(str, excluded))}")
    data = data.subset(kept_rows)
    k_method, train_idx, test_idx = seed_split(args.seed, data.n, test_fraction)
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
    extras = setup.extras
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

    # "before" = the nominal robot with the sensor extras estimated from the data (closed-form start);
    # the raw nominal row (the guessed extras) where extras were estimated and the model has a guess
    # (a camera's identity hand-eye and target are none: their reprojection errors mean nothing)
    sets = {"train": (train, measurement)}
    if test_file is None and test.n:
        sets["test"] = (test, measurement if full is None else full.take(test_idx))
    show_raw, errors = before_after_errors(res, robot, measurement, sets)
    per_row = {}

    def part(name, ds, rows_1based, ev=None):
        if ev is not None:
            eb, ea = ev.before_errors, ev.after_errors
            zero = Deviations.zeros(res.space.layout, np.asarray(train.q).dtype)
            raw = sample_errors(robot, measurement, zero, ds) if show_raw else None
        else:
            eb, ea, raw = errors[name]
        per_row[name] = {"row": rows_1based, "q_deg": joints_to_file_units(robot, ds.q).tolist(),
                         "before_mm": eb.tolist(), "after_mm": ea.tolist()}
        out = []
        if show_raw:
            out.append((f"{name}, raw nominal", metrics_numpy(raw)))
        return out + [(f"{name}, before", metrics_numpy(eb)),
                      (f"{name}, after", metrics_numpy(ea))]

    rows = part("train", train, [file_row(i) for i in range(train.n)])
    evaluation = None
    if test_file is not None:
        evaluation = evaluate_result(res, test_file, extras="result" if args.keep_extras else "auto")
        rows += part("test", test_file, list(range(1, test_file.n + 1)), evaluation)
    elif test.n:
        rows += part("test", test, [int(kept_rows[i]) + 1 for i in test_idx])
    print()
    unit = getattr(measurement, "unit", "mm")  # px for camera data
    print(format_table(_metrics_rows(rows), ["data", f"RMSE/{unit}", f"MEAN/{unit}", f"MAX/{unit}"],
                       title=f"Accuracy before/after calibration ({res.method}: {res.status.name.lower()}, "
                             f"{res.n_iterations} iterations, {res.wall_time_s:.3f} s + compile {res.compile_time_s:.1f} s)"))
    print("before = the nominal robot with the sensor extras estimated from the data (closed-form start)"
          + ("; raw nominal = the guessed extras, nothing estimated" if show_raw else "")
          + ("" if evaluation is None else f"\ntest file: {evaluation.message}"))
    line, warning = (None, None) if evaluation is None else evaluation.expectation()
    if line is not None:
        print(f"test file: {line}")
    if warning is not None:
        print(f"jaxcal: warning: test file: {warning}", file=sys.stderr)
    sd = res.uncertainty.std_display() if res.uncertainty is not None else {}
    if hasattr(robot, "dh_table_deg"):
        _print_dh_table(robot, res, sd)
    else:
        _print_chain_table(robot, res, sd)
    _print_estimates(res, sd, extras, unit)
    _print_outliers_and_warnings(res, args, checks, file_row)
    diag = res.diagnostics
    if args.out:
        settings = {"data": str(path), "n_samples": data.n, "n_train": train.n, "n_test": test.n,
                    "seed": args.seed, "test_fraction": test_fraction, "test_file": args.test, "method": method,
                    "estimate": extras, "hyperparameters": hyper, "prior": args.prior, "loss": loss,
                    "objective": objective_line,
                    "excluded_rows": excluded, "compliance": args.compliance, "harmonics": args.harmonics,
                    "outlier_rows_after": [file_row(i) for i in diag.outliers_after]}
        info = {"test_extras": {"source": evaluation.extras, "registered": list(evaluation.registered),
                                "message": evaluation.message}} if evaluation is not None else {}
        from .._calibration._io import save_result  # only with --out

        save_result(res, args.out, settings=settings, metrics_mm={name: m._asdict() for name, m in rows},
                    rows=per_row, calibrated_at=_today(), **info)
        print(f"\nwrote {args.out}")
    if args.verbose:
        t_end = time.perf_counter()
        print(f"\ntimes: reading and checking the data {t_loaded - t_start:.2f} s, "
              f"calibrate() {t_fit - t_loaded:.2f} s (compilation {res.compile_time_s:.2f} s, solve {res.wall_time_s:.3f} s, "
              f"the rest: initialisation, identifiability, diagnostics), output {t_end - t_fit:.2f} s; "
              f"total {t_end - _T0:.2f} s since jaxcal was imported (Python + JAX start-up come before: ~1 s)")
    return _exit_status(res, args, measurement, extras)


def _print_estimates(res, sd: dict, extras, unit: str) -> None:
    """The estimated extras (and those asked for but held), the non-geometric errors, σ̂ and the
    condition number, each ± one posterior σ (``sd``: :meth:`Uncertainty.std_display`); ``unit``:
    the readings' unit (mm, px)."""
    import numpy as np

    from .._calibration._calibrate import SELECT_GROUPS
    from .._core._params import group_kind, group_of

    # every estimated sensor/set-up unknown: anchor, tool, cable offset, sensor frame, marker positions
    extra_names = [n for n in res.space.free_names if group_kind(n) == "extra"]
    # asked for but held (no prior, and the data cannot tell them from another extra): at their start
    asked = {g for e in extras for g in SELECT_GROUPS.get(e, ())}
    frozen = [n for n in res.space.names if group_kind(n) == "extra" and group_of(n) in asked
              and n not in res.space.free_names]
    if extra_names or frozen:
        dev = {**res.deviations.named(), **dict(zip(res.space.free_names, np.asarray(res.x)))}
        units = dict(zip(res.space.names, res.space.units))
        parts = []
        for n in extra_names + frozen:
            u = "°" if units[n] == "rad" else units[n]
            v = math.degrees(dev[n]) if units[n] == "rad" else dev[n]
            s_ = sd.get(n, (None,))[0]
            parts.append(f"{n} {_fmt_value(v, s_, u)}{'*' if n in frozen else ''} {u}")
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


def _print_outliers_and_warnings(res, args, checks, file_row) -> None:
    """Outlier rows after the fit (as 1-based data rows, ``file_row``) and the result's warnings."""
    diag = res.diagnostics
    if diag.outliers_after:
        listed = ", ".join(str(file_row(i)) for i in diag.outliers_after[:20])
        print(f"outliers after the fit (residual > {checks.outlier_k:g} × {diag.outlier_scale_mm:.3g} mm, the robust σ): data rows "
              f"{listed}{' …' if len(diag.outliers_after) > 20 else ''}"
              + ("" if args.exclude_outliers else
                 " (kept, down-weighted by the robust loss; --exclude-outliers drops them)" if args.loss != "linear" else
                 " (kept; --exclude-outliers or --loss huber to guard against them)"))
    for w in res.warnings:
        if diag.outliers_after and "outlier sample(s)" in w:
            w = (f"{len(diag.outliers_after)} outlier sample(s) at data rows "
                 f"{', '.join(str(file_row(i)) for i in diag.outliers_after[:20])} (see above)")
        print(f"jaxcal: warning: {w}", file=sys.stderr)


def _exit_status(res, args, measurement, extras) -> int:
    """0, or ``_EXIT_FAILED`` (with the reason on stderr) for a failed or implausible calibration."""
    diag = res.diagnostics
    cause = f"; likely cause: {diag.likely_cause}" if diag is not None and diag.likely_cause else ""
    if not res.ok:
        print(f"jaxcal: calibration failed: {res.message}{cause}", file=sys.stderr)
        return _EXIT_FAILED
    if diag is not None and diag.suspect and not args.accept_implausible:
        print(f"jaxcal: calibration not credible (see the warning above){cause}; exit status 1 — check the data's "
              "units, the --measurement kind and the --robot model (--accept-implausible to accept it anyway)",
              file=sys.stderr)
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


def _today() -> str:
    """The UTC date a result is written (``jaxcal drift`` names the earlier calibration by it)."""
    import datetime

    return datetime.datetime.now(datetime.timezone.utc).date().isoformat()
