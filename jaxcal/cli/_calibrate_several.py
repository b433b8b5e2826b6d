"""``jaxcal calibrate`` of several data files: ``--combine`` (one robot's sensors) or a fleet (a unit per file).
"""

from __future__ import annotations

import pathlib
import sys
import time
import warnings

from ._calibrate_setup import _calibration_setup
from ._common import _EXIT_FAILED, _as_usage, _today, _Usage

__all__ = ["fleet_kinds"]


def _same_tree(a, b) -> bool:
    """Two pytrees (measurement models) with the same structure and equal array leaves."""
    import jax
    import numpy as np

    (la, ta), (lb, tb) = jax.tree_util.tree_flatten(a), jax.tree_util.tree_flatten(b)
    return ta == tb and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))


def fleet_kinds() -> list[str]:
    """The measurement kinds `jaxcal calibrate` takes several files of (one sensor set-up per fleet)."""
    from .._sensors._kind import sensor_kinds

    return [k.name for k in sensor_kinds() if k.fleet]


#: what to do about a combined fit's outlier rows (--exclude-rows applies to one file)
_OUTLIER_TODO = ("check those rows (a mis-read, a wrong label); to leave them out, delete them from the file and fit "
                 "again")


def _cmd_calibrate_combined(args, method: str, t_start: float) -> int:
    """`jaxcal calibrate a.csv b.csv ... --combine --out-dir DIR [--relations FILE]`: the files are
    blocks of one robot (:func:`jaxcal.calibrate_blocks`): one fit, each block's σ estimated; one
    result JSON per block (:func:`~jaxcal._calibration._blocks.block_result`, read by `jaxcal
    evaluate`) and ``combined.json`` (:func:`jaxcal.save_combined_result`: every block's statistics and result, the
    relations, σ, the deviations). ``t_start``: when the command began (after start-up), for
    ``--verbose``."""

    from .._calibration._blocks import block_extras, block_result, calibrate_blocks, save_combined_result
    from .._calibration._calibrate import CalibrationWarning, OutlierWarning, StatedNoiseWarning
    from .._calibration._io import save_result
    from .._sensors._blocks import Block, check_shared_labels, load_relations

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
    with _as_usage(errors=(ValueError, OSError)):
        relations = load_relations(args.relations) if args.relations else ()
        blocks = [Block(n, s.measurement, s.data, extras=block_extras(s.estimate)) for n, s in zip(names, setups)]
        check_shared_labels(blocks, sources={n: str(s.path) for n, s in zip(names, setups)})
    print(f"combined fit of robot {first.robot.name}: {len(blocks)} blocks ("
          + ", ".join(f"{n}: {s.data.n} {s.kind} rows" for n, s in zip(names, setups))
          + (f"), {len(relations)} relations from {args.relations}" if relations else ")") + f", method {method}; "
          "every row trains; each block's σ estimated (variance components)")
    for s in setups:
        for n in s.notes:
            print(f"note: {s.path.name}: {n}")
    t_loaded = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CalibrationWarning)
        with _as_usage():
            res = calibrate_blocks(first.robot, blocks, relations, method, prior=first.prior, loss=first.loss,
                                   checks=first.checks, free=args.free, fix=args.fix or (), **first.hyper)
    t_fit = time.perf_counter()
    for w in caught:  # a block's σ̂ against its noise line, its outlier rows: below, naming the file
        if issubclass(w.category, CalibrationWarning) and not issubclass(w.category, (StatedNoiseWarning,
                                                                                      OutlierWarning)):
            print(f"jaxcal: warning: {w.message}", file=sys.stderr)
    for m in res.block_messages:
        print(f"start: {m}")
    print(f"status {res.status.name.lower()}, {res.variance_rounds} fit(s) with re-estimated σ, "
          f"{res.space.n_free} free parameters; whitened train RMSE {res.train_metrics.rmse:.4f} (1 at the floor)")
    if res.prior is not None and res.prior.evidence is not None:  # --prior evidence: the scale the data chose
        print(res.prior.evidence.describe() + " (the verdicts below are under this prior)")
    for st in res.blocks:
        print("  " + st.line())
    for line in res.block_report:
        print("  " + line)
    results = {n: block_result(res, n) for n in names}
    tables = _print_block_tables(res, results, setups, out_dir=args.out_dir)
    for st, s in zip(res.blocks, setups):
        msg = st.noise_warning(str(s.path), getattr(first.checks, "noise_warn_factor", None))
        if msg is not None:
            print(f"jaxcal: warning: {msg}", file=sys.stderr)
    paths = {n: s.path for n, s in zip(names, setups)}
    for sc in res.diagnostics.outlier_scans:  # each file's rows in their own robust σ̂ (every row trains)
        if sc.rows:
            print(f"jaxcal: warning: {sc.message(str(paths[sc.block]), [i + 1 for i in sc.rows], _OUTLIER_TODO)}",
                  file=sys.stderr)
    out = pathlib.Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    info = {}
    for n, s in zip(names, setups):
        settings = {"data": str(s.path), "n_samples": s.data.n, "n_train": s.data.n, "n_test": 0, "method": method,
                    "prior": args.prior, "loss": first.loss, "combined": names,
                    "relations": None if not args.relations else str(args.relations)}
        info[n] = {"settings": settings, **tables[n]}
        save_result(results[n], out / f"{n}.json", **info[n])
    save_combined_result(res, out / "combined.json", block_info=info,
                         settings={"data": [str(s.path) for s in setups], "method": method, "prior": args.prior,
                                   "loss": first.loss, "relations": None if not args.relations else str(args.relations)})
    print(f"wrote {len(names)} block result(s) and combined.json to {out}")
    if args.verbose:
        from ._common import times_line

        print(times_line(t_start, t_loaded, t_fit, res, f"calibrate_blocks() ({res.variance_rounds} fit(s))"))
    return 0 if res.status.name not in ("DIVERGED", "FAILED") else _EXIT_FAILED


def _print_block_tables(res, results: dict, setups, out_dir) -> dict:
    """What ``jaxcal calibrate`` of one file prints of its result, for a combined fit ``res``: per
    block the before/after table of its rows in its own unit (``results``: ``{block:``
    :func:`~jaxcal._calibration._blocks.block_result` ``}``, ``setups`` the files' set-ups in
    block order), the calibrated robot's table with the verdicts' marks, and each block's
    estimated extras. Returns ``{block: {"metrics_mm": …, "rows": …}}`` for its result file (the
    single command's entries: before/after metrics, per-row errors of its 1-based data rows)."""
    from .._calibration._evaluate import before_after_errors, joints_to_file_units
    from .._core._metrics import metrics_numpy
    from ._tables import _accuracy_table, _extras_line, _print_nongeometric, _print_robot_table

    robot = res.robot
    print(f"\nAccuracy before/after calibration, per block in its own unit ({res.method}: "
          f"{res.status.name.lower()}, {res.n_iterations} iterations in the last fit, {res.wall_time_s:.3f} s + "
          f"compile {res.compile_time_s:.1f} s)")
    out, any_raw = {}, False
    for st, s in zip(res.blocks, setups):
        br = results[st.name]
        show_raw, errors = before_after_errors(br, robot, br.measurement, {"train": (s.data, br.measurement)})
        eb, ea, raw = errors["train"]
        any_raw |= show_raw
        pairs = ([("train, raw nominal", metrics_numpy(raw))] if show_raw else []) + [
            ("train, before", metrics_numpy(eb)), ("train, after", metrics_numpy(ea))]
        print(_accuracy_table(pairs, st.unit, f"{st.name} ({s.path.name}: {st.n_samples} {st.kind} rows)"))
        out[st.name] = {"metrics_mm": {name: m._asdict() for name, m in pairs},
                        "rows": {"train": {"row": list(range(1, s.data.n + 1)),
                                           "q_deg": joints_to_file_units(robot, s.data.q).tolist(),
                                           "before_mm": eb.tolist(), "after_mm": ea.tolist()}}}
    print("before = the nominal robot with each block's sensor extras estimated from its data (closed-form start)"
          + ("; raw nominal = the guessed extras, nothing estimated" if any_raw else "")
          + "; every row of every file trains, so these are training numbers: nothing was held out (jaxcal evaluate "
          f"{pathlib.Path(out_dir) / (res.blocks[0].name + '.json')} NEW.csv checks a block on new rows)")
    sd = res.uncertainty.std_display() if res.uncertainty is not None else {}
    _print_robot_table(robot, res, sd)
    asked = sorted({e for s in setups for e in s.estimate})  # one line over the combined layout: a shared
    line = _extras_line(res, sd, asked)  # extra (the tool, a plane both arms touch) is one entry, printed once
    if line is not None:
        print(f"estimated extras (a name@LABEL belongs to that block, plane or point) {line}")
    _print_nongeometric(res, sd)
    return out


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
    if args.measurement is not None and args.measurement not in fleet_kinds():
        raise _Usage(f"several data files take --measurement {', '.join(fleet_kinds())}; calibrate "
                     f"{args.measurement} data one file at a time")
    setups = [_calibration_setup(args, method, f) for f in args.data]
    first = setups[0]
    if first.kind not in fleet_kinds():
        raise _Usage(f"several data files take {', '.join(fleet_kinds())} data; calibrate {first.kind} data "
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
    noise_std = args.noise_std
    if noise_std is None:  # the sensor σ the files state (their '# noise_std_mm:' lines), where they agree
        from .._fit._diagnostics import given_noise_std

        stated = {given_noise_std(s.data, None, s.measurement) for s in setups}
        if len(stated) == 1 and None not in stated:
            noise_std = stated.pop()
            print(f"note: the floor is for the sensor σ the files state, {noise_std:g} mm "
                  "(give --noise-std MM for another)")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CalibrationWarning)
        with _as_usage(errors=(TypeError,)):  # a --set name the method does not take
            fleet = calibrate_many(robot, measurement, trains, method, names=names, key=k_method, extras=extras,
                                   prior=first.prior, loss=first.loss, checks=first.checks, free=args.free,
                                   fix=args.fix or (), tolerance_mm=args.tolerance_mm, noise_std=noise_std,
                                   **first.hyper)
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
