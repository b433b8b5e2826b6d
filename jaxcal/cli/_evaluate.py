"""``jaxcal evaluate``.
"""

from __future__ import annotations

import pathlib
import sys

from ._common import _EXIT_FAILED, _Usage

__all__ = ["EVALUATION_FORMAT"]

#: exit status of ``jaxcal evaluate`` when the calibrated robot beats the nominal one but fits the
#: new rows far worse than the calibration predicts (a remounted tool, a moved sensor)
_EXIT_UNEXPECTED = 3


#: ``"format"`` of the files ``jaxcal evaluate --out`` writes.
EVALUATION_FORMAT = "jaxcal-evaluation/1"


def _cmd_evaluate(args) -> int:
    """A saved calibration on new measurements: before/after, per-row errors, outliers (issue 24)."""
    import json

    from .._calibration._evaluate import evaluate_result
    from .._calibration._io import load_result, load_result_dict, measurement_to_dict, robot_to_dict
    from .._core._json import to_jsonable
    from .._datasets._dataset import load_csv
    from .._sensors._kind import sensor_kind
    from ._calibrate_setup import joint_columns_message

    src, path = pathlib.Path(args.result), pathlib.Path(args.data)
    if not src.exists():
        raise _Usage(f"result file {args.result!r} not found")
    if not path.exists():
        raise _Usage(f"data file {args.data!r} not found")
    raw = load_result_dict(src)
    res = load_result(src)
    m = res.measurement
    sessions = m.row_sessions  # a SessionMarkers result: the file's own sessions and marker count
    data = load_csv(path, kind=m.kind, n_markers=m.expected_points(),  # a marker set's markers
                    kind_from=f"the calibration {src} is of {m.kind} data")
    if data.dof != res.robot.dof:
        raise _Usage(joint_columns_message(path, data.dof, res.robot, "the calibrated robot"))
    if data.labels and not sessions:
        raise _Usage(f"{path} has session/frame/placement columns; evaluate takes one session per file")
    if sensor_kind(data.kind).labelled:
        from .._calibration._evaluate import match_labels

        res, data, new = match_labels(res, data)
        m = res.measurement
        if new:  # a new set-up (another plate placement, another table): its planes/points registered here
            print(f"new {data.kind} labels in {path}: {', '.join(new)} — registered on its rows (robot fixed)")
    objective = raw.get("settings", {}).get("objective") or (
        f"objective: {raw.get('loss', 'linear')} loss; {raw.get('prior') or 'no prior'}")
    from ._calibrate_setup import _outlier_rate

    ev = evaluate_result(res, data, extras="result" if args.keep_extras else "auto", objective=objective,
                         outlier_rate=_outlier_rate(args.outlier_rate))
    print(f"calibration: {src} ({res.robot.name}, {res.method}, {raw.get('status')}; {len(res.space.free_names)} "
          f"free parameters); new data: {data.n} {m.kind} samples from {path}")
    print(f"calibrated with the {objective}" if objective.startswith("measured") else f"calibrated with: {objective}")
    print(ev.describe(outliers=False))
    outliers = ev.outlier_message(str(path))
    if outliers is not None:  # named by the file's 1-based data rows, as `jaxcal calibrate` names them
        print(f"jaxcal: warning: {outliers}", file=sys.stderr)
    if args.out:
        out = {"format": EVALUATION_FORMAT, "result": str(src), "data": str(path), "method": res.method,
               "status": raw.get("status"), "robot": robot_to_dict(res.robot), "measurement": measurement_to_dict(m),
               **ev.to_dict()}
        pathlib.Path(args.out).write_text(json.dumps(to_jsonable(out), indent=1, allow_nan=False) + "\n",
                                          encoding="utf-8")
        print(f"\nwrote {args.out}")
    warning = ev.expectation()[1]
    if ev.worse:
        if warning is not None:
            print(f"jaxcal: warning: {path}: {warning}", file=sys.stderr)
        print(f"jaxcal: the calibrated robot predicts {path} worse than the nominal robot (RMSE {ev.after.rmse:.4g} "
              f"vs {ev.before.rmse:.4g} {ev.unit}); exit status 1", file=sys.stderr)
        return _EXIT_FAILED
    if warning is not None:  # better than nominal, but far worse than the calibration predicts
        print(f"jaxcal: warning: {path}: {warning}; exit status {_EXIT_UNEXPECTED}", file=sys.stderr)
        return _EXIT_UNEXPECTED
    return 0
