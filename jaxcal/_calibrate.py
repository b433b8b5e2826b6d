"""One entry point for every method: :func:`calibrate`, and its pure core :class:`Calibrator`."""

from __future__ import annotations

import functools
import time
import warnings
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._dataset import Dataset
from ._identifiability import identifiability
from ._measurement import MeasurementModel
from ._metrics import Metrics, compute_metrics
from ._params import Deviations, ParameterSpace
from ._precision import cast_floating, dtype_scope, warn_if_float32
from ._problem import Problem
from ._result import CalibrationResult, Status, iterations_to_converge
from ._robot import DHRobot
from ._xla import compile_lowered
from .methods import Method, ScaledProblem, make_method

__all__ = ["calibrate", "Calibrator", "CalibrationOutput", "CalibrationWarning", "CalibrationError", "resolve_space"]


class CalibrationWarning(RuntimeWarning):
    """A calibration diverged or failed (the result's ``status`` says how)."""


class CalibrationError(RuntimeError):
    """Raised instead of :class:`CalibrationWarning` with ``calibrate(..., throw=True)``."""


class CalibrationOutput(NamedTuple):
    """Pure output of :class:`Calibrator` (a pytree; batched under ``vmap``)."""

    x: Float[Array, " p"]
    history: Float[Array, " T"]
    n_iterations: Int[Array, ""]
    iterations_to_converge: Int[Array, ""]
    status: Int[Array, ""]
    train_metrics: Metrics
    extra: object = None


class Calibrator(eqx.Module):
    """A calibration as a pure function ``(q, y, key) -> CalibrationOutput``.

    ``jax.jit`` it, or ``jax.vmap`` it over keys and datasets for seed sweeps.

    Attributes:
        robot, measurement: nominal models.
        method: a :class:`~jaxcal.methods.Method`.
        start: deviations the run starts from (zeros = nominal); non-free entries stay fixed.
        space: free parameters (static).
    """

    robot: DHRobot
    measurement: MeasurementModel
    method: Method
    start: Deviations
    space: ParameterSpace = eqx.field(static=True)

    def problem(self, q, y) -> Problem:
        return Problem(self.robot, self.measurement, q, y, self.space, self.start)

    def __call__(self, q: Float[Array, "n dof"], y: Array, key: Array) -> CalibrationOutput:
        problem = self.problem(q, y)
        scaled = ScaledProblem.build(problem)
        raw = self.method.run(scaled, key)
        x = scaled.x(raw.z)
        its = iterations_to_converge(raw.history, raw.n_iterations)
        metrics = compute_metrics(self.method.sample_errors(problem, x, raw.extra))
        return CalibrationOutput(x, raw.history, raw.n_iterations, its, raw.status, metrics, raw.extra)


@functools.partial(jax.jit, static_argnums=1)
def _run_calibrator(dynamic, static, q, y, key) -> CalibrationOutput:
    """The jitted core of :func:`calibrate` (module level, so compilations are cached)."""
    return eqx.combine(dynamic, static)(q, y, key)


def _as_arrays(data, measurement: MeasurementModel, robot: DHRobot):
    if isinstance(data, Dataset):
        if data.kind != measurement.kind:
            raise ValueError(f"data are {data.kind!r} measurements but the measurement model is {measurement.kind!r}")
        q, y = data.q, data.y
    elif isinstance(data, (tuple, list)) and len(data) == 2:
        q, y = data
        q = jnp.asarray(q)
        y = jnp.asarray(y, q.dtype)
        Dataset(q, y, measurement.kind)  # validates shapes, NaN/inf, degrees
    else:
        raise TypeError("data must be a jaxcal.Dataset or a (q, y) pair of arrays")
    if q.shape[1] != robot.dof:
        raise ValueError(f"data have {q.shape[1]} joint angles per sample but robot {robot.name!r} has {robot.dof} joints")
    measurement.check_measurements(y, q.shape[0])
    qn = np.asarray(q)
    lo, hi = np.asarray(robot.q_min), np.asarray(robot.q_max)
    outside = (qn < lo - 1e-6) | (qn > hi + 1e-6)
    if outside.any():
        joints = sorted({int(j) + 1 for j in np.nonzero(outside)[1]})
        warnings.warn(
            f"{int(outside.any(axis=1).sum())} sample(s) have joint angles outside robot {robot.name!r}'s limits "
            f"(joints {joints}); check the units (radians expected) and the robot model",
            UserWarning,
            stacklevel=3,
        )
    return q, y


def resolve_space(robot, measurement, q, space, start=None) -> tuple[ParameterSpace, object]:
    """``space=None`` or ``"identifiable"``: the identifiable subset of all DH (+β) deviations
    (QR with column pivoting, :func:`jaxcal.identifiability`); ``"all"``: every DH (+β)
    deviation; or a :class:`ParameterSpace` as given. Returns ``(space, report_or_None)``."""
    if space is None or (isinstance(space, str) and space == "identifiable"):
        report = identifiability(robot, measurement, q, ParameterSpace.for_robot(robot), start)
        return report.space, report
    if isinstance(space, str):
        if space == "all":
            return ParameterSpace.for_robot(robot), None
        raise ValueError(f"space must be None, 'identifiable', 'all' or a ParameterSpace, got {space!r}")
    if not isinstance(space, ParameterSpace):
        raise TypeError(f"space must be a ParameterSpace, got {type(space)}")
    if space.dof != robot.dof:
        raise ValueError(f"parameter space is for {space.dof} joints but the robot has {robot.dof}")
    return space, None


def calibrate(
    robot: DHRobot,
    measurement: MeasurementModel,
    data,
    method="lm",
    *,
    key: Array | None = None,
    space: ParameterSpace | str | None = None,
    start: Deviations | None = None,
    throw: bool = False,
    **hyperparameters,
) -> CalibrationResult:
    """Calibrate ``robot`` from measured ``data`` with one of the registered methods.

    Args:
        robot: nominal robot model.
        measurement: the measurement model the data come from (e.g. :class:`CableLength`).
        data: training data, a :class:`Dataset` or a ``(q [n, dof] rad, y)`` pair.
        method: a registry name (``"lm"``, ``"gn"``, ``"adam"``, ``"adamw"``, ``"adamod"``,
            ``"adamodw"``, and the baselines), a :class:`~jaxcal.methods.Method`, or any
            ``optax.GradientTransformation`` (run full batch; pass ``steps=``).
        key: ``jax.random`` key for the method's randomness (default ``jax.random.key(0)``).
        space: free parameters; default: the identifiable subset of the DH deviations
            (see :func:`resolve_space`).
        start: starting deviations (default: nominal); entries that are not free keep these.
        throw: raise :class:`CalibrationError` on divergence/failure instead of warning.
        **hyperparameters: the method's settings (e.g. ``learning_rate=``, ``steps=``,
            ``batch_size=``, ``max_steps=``).

    Returns:
        :class:`CalibrationResult` with calibrated deviations, the per-iteration training
        RMSE history, iterations (and iterations to converge), status, and the run time
        excluding compilation.
    """
    meth = make_method(method, **hyperparameters)
    q, y = _as_arrays(data, measurement, robot)
    warn_if_float32(q.dtype, "calibrate")
    start = Deviations.zeros(robot.dof, q.dtype) if start is None else start.astype(q.dtype)
    space, report = resolve_space(robot, measurement, q, space, start)
    n_res = q.shape[0] * measurement.size
    if n_res <= space.n_free:
        raise ValueError(
            f"too few samples: {q.shape[0]} sample(s) give {n_res} residuals for {space.n_free} free parameters; "
            "need more residuals than parameters"
        )
    key = jax.random.key(0) if key is None else key
    cal = Calibrator(robot, measurement, meth, start, space)
    dyn, stat = eqx.partition(cal, eqx.is_array)
    with dtype_scope(q.dtype):
        dyn = cast_floating(dyn, q.dtype)
        t0 = time.perf_counter()
        compiled = compile_lowered(_run_calibrator.lower(dyn, stat, q, y, key))
        t1 = time.perf_counter()
        out = jax.block_until_ready(compiled(dyn, q, y, key))
        t2 = time.perf_counter()
    status = Status(int(out.status))
    label = meth.label() if hasattr(meth, "label") else type(meth).name
    result = CalibrationResult(
        method=label,
        deviations=space.from_vector(out.x, start),
        x=np.asarray(out.x),
        space=space,
        robot=robot,
        measurement=measurement,
        history=np.asarray(out.history),
        n_iterations=int(out.n_iterations),
        iterations_to_converge=int(out.iterations_to_converge),
        status=status,
        train_metrics=Metrics(*(float(v) for v in out.train_metrics)),
        wall_time_s=t2 - t1,
        compile_time_s=t1 - t0,
        hyperparameters=meth.hyperparameters(),
        extra=out.extra,
        predictor=getattr(meth, "predictor", lambda: None)(),
    )
    if status in (Status.DIVERGED, Status.FAILED):
        if throw:
            raise CalibrationError(result.message)
        warnings.warn(result.message, CalibrationWarning, stacklevel=2)
    object.__setattr__(result, "identifiability", report)
    return result
