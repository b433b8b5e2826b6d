"""calibrate(), checking on new data, result files."""

from .._fit._result import set_extras_evaluator


def _evaluate_result(result, data, *, extras):
    """``CalibrationResult.evaluate(data, extras=...)``: :func:`jaxcal.evaluate_result` (imported on
    first use: importing the calibration package stays as light as before)."""
    from ._evaluate import evaluate_result

    return evaluate_result(result, data, extras=extras)


#: CalibrationResult (floor 5) cannot import the evaluation (floor 7, it calibrates the extras):
#: this package, which makes every result, provides the method instead.
set_extras_evaluator(_evaluate_result)
