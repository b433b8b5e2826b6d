"""``jaxcal calibrate`` of one data file (several files: :mod:`._calibrate_several`).
"""

from __future__ import annotations

import contextlib
import math
import sys
import time
import warnings

from ._calibrate_setup import _calibration_setup
from ._calibrate_several import _cmd_calibrate_combined, _cmd_calibrate_fleet
from ._common import _EXIT_FAILED, _as_usage, _today, _Usage, times_line
from ._tables import (
    _accuracy_table,
    _outlier_line,
    _print_estimates,
    _print_outliers_and_warnings,
    _print_robot_table,
)


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


@contextlib.contextmanager
def _rows_needed(n_file: int, n_train: int, path, split: bool, test_fraction: float):
    """``jaxcal calibrate``'s "too few samples" in the rows of the user's file: how many of its rows
    went to the random test split, and how many rows the file needs (exit 2, one line)."""
    from .._calibration._selection import TooFewSamples

    try:
        yield
    except TooFewSamples as e:
        held = n_file - n_train
        if split and held:
            need = math.ceil(e.samples_needed / (1.0 - test_fraction))
            raise _Usage(f"{e}, for training; {path} has {n_file} rows, of which {held} went to the test split "
                         f"(--test-fraction {test_fraction:g}): give at least {need} rows, or train on every row "
                         "with --test-fraction 0") from None
        raise _Usage(f"{e}; {path} has {n_file} rows") from None


def _cmd_calibrate(args) -> int:
    t_start = time.perf_counter()
    from ..methods._stages import check_method_name

    with _as_usage():
        method = check_method_name(args.method)  # a registry name, or stages such as ga>lm
    if args.combine or args.relations:
        return _cmd_calibrate_combined(args, method, t_start)
    if len(args.data) > 1 or args.out_dir:
        return _cmd_calibrate_fleet(args, method)
    setup = _calibration_setup(args, method, args.data[0])
    split = _split(args, setup)
    objective_line = _print_set_up(args, setup, split, method)
    t_loaded = time.perf_counter()
    res, split = _fit(args, setup, split, method)
    t_fit = time.perf_counter()
    if res.identifiability is not None:
        print(res.identifiability)
    if res.prior is not None and res.prior.evidence is not None:  # --prior evidence: the scale the data chose
        print(res.prior.evidence.describe() + " (the verdicts above are under this prior)")
    for line in res.diagnostics.reselection:
        print(line)
    if res.diagnostics.extras:
        print(res.diagnostics.extras)
    rows, per_row, evaluation = _accuracy(args, setup, split, res)
    test_outliers = _print_findings(args, setup, split, res)
    if args.out:
        _save(args, setup, split, res, method, objective_line, rows, per_row, evaluation, test_outliers)
    if args.verbose:
        print(times_line(t_start, t_loaded, t_fit, res, "calibrate()"))
    return _exit_status(res, args, split.measurement, setup.extras)


def _split(args, setup):
    """The file's rows to train and test on (:func:`jaxcal.split_rows`), and the shape bucket of the
    whole file."""
    from .._calibration._rows import split_rows
    from .._core._buckets import bucket_size

    data = setup.data
    with _as_usage():
        split = split_rows(data, setup.measurement, seed=args.seed, test_fraction=setup.test_fraction,
                           exclude_rows=_rows(args.exclude_rows), test_file=setup.test_file is not None)
    if split.excluded_rows:
        setup.notes.append(f"excluded data rows (your choice): {', '.join(map(str, split.excluded_rows))}")
    if len(split.train_idx) < 2:
        raise _Usage(f"too few samples: {split.data.n} in the file, {len(split.train_idx)} for training")
    # the whole file's shape bucket first: the training rows then pad to it (jaxcal._core._buckets'
    # reuse rule), so that `jaxcal evaluate` of a file of this size — a new day of the same
    # measurement program, in a fresh process — runs the programs this command compiled and kept
    # on disk instead of compiling its own (the fit changes by round-off only)
    bucket_size(split.data.n, width=split.measurement.size)
    return split


def _test_set(setup, split):
    """The test rows: the held-out split, or the separate test file."""
    return split.test if setup.test_file is None else setup.test_file


def _print_set_up(args, setup, split, method) -> str:
    """The data, split, notes and objective lines; the objective line."""
    from .._calibration._evaluate import describe_objective

    n_train, n_test = len(split.train_idx), _test_set(setup, split).n
    how = (f"{n_train} train / {n_test} test (seed {args.seed})" if setup.test_file is None else
           f"all {n_train} for training; test: {n_test} samples from {args.test}")
    print(f"data: {split.data.n} {split.measurement.kind} samples from {setup.path} → {how}; robot "
          f"{setup.robot.name}; method {method}")
    for n in setup.notes:
        print(f"note: {n}")
    objective_line = describe_objective(setup.prior, setup.loss)
    print(objective_line)
    return objective_line


def _file_rows(split) -> int:
    """The rows of the file the outlier scans spread their false-alarm rate over: its training and
    test rows, those ``--exclude-outliers`` drops included (not those ``--exclude-rows`` leaves out)."""
    return int(split.data.n)


def _fit(args, setup, split, method):
    """``(result, split)``: the calibration of the training rows; with ``--exclude-outliers``, refitted
    without the rows the first fit found gross (named by their data rows)."""
    import dataclasses

    from .._calibration._calibrate import CalibrationWarning, calibrate
    from .._fit._diagnostics import file_rate

    n_file = _file_rows(split)

    def run(split):
        # the training rows' share of the file's false-alarm rate (its test rows get the rest)
        checks = dataclasses.replace(setup.checks, outlier_rate=file_rate(setup.checks.outlier_rate,
                                                                          len(split.train_idx), n_file))
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", CalibrationWarning)
            # TypeError: a --set name the method does not take; too few samples: in the file's rows
            with _as_usage(errors=(TypeError,)), _rows_needed(split.data.n, len(split.train_idx), setup.path,
                                                             setup.test_file is None, setup.test_fraction):
                res = calibrate(setup.robot, split.measurement, split.train, method, key=split.key,
                                extras=setup.extras, prior=setup.prior, loss=setup.loss, checks=checks,
                                free=args.free, fix=args.fix or (), **setup.hyper)
        for w in caught:
            if not issubclass(w.category, CalibrationWarning):
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        return res

    res = run(split)
    if args.exclude_outliers and res.diagnostics.outliers_after:
        drop = split.train_file_rows(res.diagnostics.outliers_after)
        print(f"--exclude-outliers: refitting without data rows {', '.join(map(str, drop))}")
        split = split.without_train(res.diagnostics.outliers_after)
        res = run(split)
    return res, split


def _accuracy(args, setup, split, res):
    """Print the before/after table of the training and test rows; ``(table rows, per-row errors,
    the test file's evaluation or None)``."""
    import numpy as np

    from .._calibration._evaluate import before_after_errors, evaluate_result, joints_to_file_units, sample_errors
    from .._core._metrics import metrics_numpy
    from .._core._params import Deviations

    robot, measurement, train, test_file = setup.robot, split.measurement, split.train, setup.test_file
    # "before" = the nominal robot with the sensor extras estimated from the data (closed-form start);
    # the raw nominal row (the guessed extras) where extras were estimated and the model has a guess
    # (a camera's identity hand-eye and target are none: their reprojection errors mean nothing)
    sets = {"train": (train, measurement)}
    if test_file is None and len(split.test_idx):
        sets["test"] = (split.test, split.test_measurement)
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

    rows = part("train", train, split.train_rows)
    evaluation = None
    if test_file is not None:
        evaluation = evaluate_result(res, test_file, extras="result" if args.keep_extras else "auto")
        rows += part("test", test_file, list(range(1, test_file.n + 1)), evaluation)
    elif len(split.test_idx):
        rows += part("test", split.test, split.test_rows)
    print()
    unit = getattr(measurement, "unit", "mm")  # px for camera data
    print(_accuracy_table(rows, unit, f"Accuracy before/after calibration ({res.method}: {res.status.name.lower()}, "
                                      f"{res.n_iterations} iterations, {res.wall_time_s:.3f} s + compile "
                                      f"{res.compile_time_s:.1f} s)"))
    print("before = the nominal robot with the sensor extras estimated from the data (closed-form start)"
          + ("; raw nominal = the guessed extras, nothing estimated" if show_raw else "")
          + (f"; {measurement.row_error}" if measurement.row_error else "")
          + ("" if evaluation is None else f"\ntest file: {evaluation.message}"))
    line, warning = (None, None) if evaluation is None else evaluation.expectation()
    if line is not None:
        print(f"test file: {line}")
    if warning is not None:
        print(f"jaxcal: warning: test file: {warning}", file=sys.stderr)
    return rows, per_row, evaluation


def _print_findings(args, setup, split, res) -> list[int]:
    """The calibrated table, the estimates, outliers and warnings, the file's stated noise against
    σ̂, and the held-out rows' gross errors; the latter's 1-based data rows."""
    from .._calibration._evaluate import residual_outliers
    from .._fit._diagnostics import given_noise_std, stated_noise_warning

    robot, measurement, checks = setup.robot, split.measurement, setup.checks
    unit = getattr(measurement, "unit", "mm")  # px for camera data
    sd = res.uncertainty.std_display() if res.uncertainty is not None else {}
    _print_robot_table(robot, res, sd)
    _print_estimates(res, sd, setup.extras, unit)
    rate, n_file, where = checks.outlier_rate, _file_rows(split), str(setup.path)
    _print_outliers_and_warnings(res, args, lambda i: split.train_file_rows([i])[0], where, rate, n_file)
    stated = stated_noise_warning(str(setup.path), res.uncertainty.noise_std if res.uncertainty is not None else math.nan,
                                  given_noise_std(setup.data, None, measurement), unit, checks.noise_warn_factor)
    if stated is not None:  # σ̂ far above the file's noise line: another set-up, or a wrong line
        print(f"jaxcal: warning: {stated}", file=sys.stderr)
    if setup.test_file is not None or not len(split.test_idx):
        return []
    # the held-out rows' gross errors, named as the training rows' are (they enter the test
    # RMSE/MAX above, not the fit)
    scan = residual_outliers(robot, split.test_measurement, res.deviations, split.test, checks.outlier_k,
                             rate=checks.outlier_rate, n_file=n_file)
    test_outliers = split.test_file_rows(scan.rows)
    if test_outliers:
        print(f"jaxcal: warning: {_outlier_line(scan, where, test_outliers, rate, n_file, args, train=False)}",
              file=sys.stderr)
    return test_outliers


def _save(args, setup, split, res, method, objective_line, rows, per_row, evaluation, test_outliers) -> None:
    """``--out``: the result file with the command's settings, metrics and per-row errors."""
    from .._calibration._io import save_result  # only with --out

    diag = res.diagnostics
    settings = {"data": str(setup.path), "n_samples": split.data.n, "n_train": len(split.train_idx),
                "n_test": _test_set(setup, split).n, "seed": args.seed, "test_fraction": setup.test_fraction,
                "test_file": args.test, "method": method, "estimate": setup.extras, "hyperparameters": setup.hyper,
                "prior": args.prior, "loss": setup.loss, "objective": objective_line,
                "excluded_rows": list(split.excluded_rows), "compliance": args.compliance,
                "harmonics": args.harmonics,
                "outlier_rows_after": split.train_file_rows(diag.outliers_after),
                "outlier_rows_test": test_outliers}
    info = {"test_extras": {"source": evaluation.extras, "registered": list(evaluation.registered),
                            "message": evaluation.message}} if evaluation is not None else {}
    save_result(res, args.out, settings=settings, metrics_mm={name: m._asdict() for name, m in rows},
                rows=per_row, calibrated_at=_today(), **info)
    print(f"\nwrote {args.out}")


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
        hint, known = "", measurement.known_setup
        if known is not None and not set(known[0]) <= set(extras):
            hint = (f"; {known[1]} taken as known — if not exact, estimate {'them' if len(known[0]) > 1 else 'it'} "
                    f"({known[2]}), or the robot's parameters absorb the error")
        print("jaxcal: calibration implausible (see the warning above); exit status 1 — use "
              f"--accept-implausible to accept it, or a stronger --prior{hint}", file=sys.stderr)
        return _EXIT_FAILED
    return 0
