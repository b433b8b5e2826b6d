"""What a calibration returns: parameters, per-iteration history, status, timings."""

from __future__ import annotations

import dataclasses
import enum
from typing import Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._json import to_jsonable
from ._measurement import MeasurementModel
from ._metrics import Metrics, compute_metrics
from ._params import Deviations, ParameterSpace
from ._robot import DHRobot

__all__ = ["Status", "CalibrationResult", "iterations_to_converge", "CONVERGENCE_RTOL"]

#: "Iterations to converge in RMSE": the first iteration from which the training RMSE stays
#: within this relative tolerance of its final value. Used by every method, table and plot.
CONVERGENCE_RTOL = 0.01


class Status(enum.IntEnum):
    """Outcome of a calibration run."""

    #: the method's stopping test was met (LM/GN tolerances).
    CONVERGED = 0
    #: a fixed-budget method (gradient, population, filter) ran all its iterations.
    COMPLETED = 1
    #: the stopping test was not met within ``max_steps``.
    MAX_STEPS = 2
    #: the loss became NaN/inf or grew by more than 1e3×; parameters are the last finite ones.
    DIVERGED = 3
    #: the solver reported a failure (e.g. singular linear system).
    FAILED = 4

    def message(self, method: str = "calibration") -> str:
        return {
            Status.CONVERGED: f"{method}: converged (stopping tolerance met)",
            Status.COMPLETED: f"{method}: completed its iteration budget",
            Status.MAX_STEPS: f"{method}: step budget exhausted before the stopping tolerance was met",
            Status.DIVERGED: f"{method}: diverged (NaN/inf or exploding loss); returned the last finite parameters",
            Status.FAILED: f"{method}: solver failure (e.g. singular linear system)",
        }[self]


def iterations_to_converge(
    history: Float[Array, " T"], n_iterations: Int[Array, ""], rtol: float = CONVERGENCE_RTOL
) -> Int[Array, ""]:
    """First iteration ``k`` such that ``history[j] ≤ (1 + rtol)·history[n]`` for all
    ``k ≤ j ≤ n``, where ``n = n_iterations`` and ``history[0]`` is the starting RMSE.

    Pure and ``vmap``-able. Entries after ``n`` are ignored.
    """
    history = jnp.asarray(history)
    idx = jnp.arange(history.shape[-1])
    final = jnp.take_along_axis(history, jnp.asarray(n_iterations)[..., None], axis=-1)
    ok = (history <= final * (1 + rtol)) | (idx > jnp.asarray(n_iterations)[..., None])
    last_bad = jnp.max(jnp.where(ok, -1, idx), axis=-1)
    return last_bad + 1


@dataclasses.dataclass(frozen=True, eq=False)
class CalibrationResult:
    """Result of :func:`jaxcal.calibrate`.

    Attributes:
        method: method name (``"lm"``, ``"adamodw"``, ..., or ``"optax"`` for a user chain).
        deviations: calibrated deviations Δ from nominal.
        x: ``[p]`` the free parameters (``space.free_names`` order; rad and mm).
        space: which parameters were free.
        robot, measurement: the nominal models calibrated.
        history: ``[max_iterations + 1]`` training RMSE (mm); entry 0 is the start, entries
            after ``n_iterations`` repeat the final value (NaN after a divergence).
        n_iterations: iterations run.
        iterations_to_converge: see :func:`iterations_to_converge`.
        status: :class:`Status`.
        train_metrics: RMSE/MEAN/MAX on the training data (mm).
        wall_time_s: run time after compilation (s); ``compile_time_s`` separately.
        hyperparameters: the method's settings.
        extra: method-specific state (e.g. the RBF network), or ``None``.
        identifiability: the :class:`~jaxcal.IdentifiabilityReport` that chose the free set.
        prior, loss, loss_scale_mm: the objective (``None``/``"linear"`` = least squares).
        start: the deviations the fit started from (extras initialised from the data).
        diagnostics: :class:`~jaxcal.Diagnostics` (plausibility, conditioning, coverage,
            outliers; its ``warnings``).
        uncertainty: :class:`~jaxcal.Uncertainty` (posterior σ of every free parameter).
    """

    method: str
    deviations: Deviations
    x: np.ndarray
    space: ParameterSpace
    robot: DHRobot
    measurement: MeasurementModel
    history: np.ndarray
    n_iterations: int
    iterations_to_converge: int
    status: Status
    train_metrics: Metrics
    wall_time_s: float
    compile_time_s: float
    hyperparameters: dict[str, Any]
    extra: Any = None
    predictor: Any = None
    identifiability: Any = None
    prior: Any = None
    loss: str = "linear"
    loss_scale_mm: float | None = None
    start: Deviations | None = None
    diagnostics: Any = None
    uncertainty: Any = None

    @property
    def message(self) -> str:
        return self.status.message(self.method)

    @property
    def ok(self) -> bool:
        """The method finished: converged, or completed its fixed budget. ``MAX_STEPS`` (an
        iterative solver stopped before its tolerance) is not success."""
        return self.status in (Status.CONVERGED, Status.COMPLETED)

    @property
    def plausible(self) -> bool:
        """No DH deviation beyond the plausibility bounds (see :class:`~jaxcal.Checks`)."""
        return self.diagnostics is None or self.diagnostics.plausible

    @property
    def warnings(self) -> tuple[str, ...]:
        """The diagnostics' warnings (empty if none)."""
        return () if self.diagnostics is None else self.diagnostics.warnings

    def prediction_std(self, q) -> np.ndarray:
        """Standard deviation (mm) of the calibrated model's predicted reading at joint angles
        ``q`` ``[n, dof]`` from the parameter uncertainty (``sqrt(diag(J·Cov·Jᵀ))``, summed over
        a sample's coordinates for position data; position part for poses). Add the sensor noise
        (``uncertainty.noise_std``) in quadrature for the expected error of a new reading."""
        if self.uncertainty is None:
            raise ValueError("this result has no uncertainty (computed by jaxcal.calibrate)")
        from ._problem import Problem

        q = jnp.asarray(q)
        y = jnp.zeros((q.shape[0], *self.measurement.sample_shape), q.dtype)
        pr = Problem(self.robot, self.measurement, q, y, self.space, self.deviations.astype(q.dtype))
        J = np.asarray(pr.jacobian(pr.x0()), np.float64).reshape(q.shape[0], self.measurement.size, -1)
        if self.measurement.kind == "pose":
            J = J[:, :3]
        C = np.asarray(self.uncertainty.covariance, np.float64)
        var = np.einsum("nmp,pk,nmk->n", J, C, J)
        return np.sqrt(np.maximum(var, 0.0))

    def predict(self, q) -> Array:
        """Predicted readings of the calibrated model for joint angles ``q`` ``[n, dof]``."""
        q = jnp.asarray(q)
        if self.predictor is not None:
            return self.predictor(self, q)
        return self.measurement.predict(self.robot, self.deviations.astype(q.dtype), q)

    def sample_errors(self, data) -> Array:
        """Per-sample errors (mm) of the calibrated model on ``data`` (a Dataset)."""
        pred = self.predict(data.q)
        q = jnp.asarray(data.q)
        if self.predictor is None:
            from ._calibrate import _residual_blocks
            from ._problem import Problem

            pr = Problem(self.robot, self.measurement, q, data.y, self.space, self.deviations.astype(q.dtype))
            r = _residual_blocks(pr, pr.x0())  # jitted (cached per shape): fast on repeated use
        else:
            r = (pred - data.y).reshape(q.shape[0], self.measurement.size)
        return self.measurement.sample_error(r)

    def evaluate(self, data) -> Metrics:
        """RMSE/MEAN/MAX (mm) on ``data`` (e.g. the held-out test split)."""
        return Metrics(*(float(v) for v in compute_metrics(self.sample_errors(data))))

    def dh_table(self) -> np.ndarray:
        """Calibrated DH table ``[dof, 4]``: α/°, a/mm, d/mm, θ/° (the paper's Table V); angles
        wrapped to (−180°, 180°]."""
        from ._diagnostics import wrap_angle_deg

        r, d = self.robot, self.deviations
        return np.stack([
            wrap_angle_deg(np.rad2deg(np.asarray(r.alpha + d.alpha))), np.asarray(r.a + d.a),
            np.asarray(r.d + d.d), wrap_angle_deg(np.rad2deg(np.asarray(r.theta + d.theta))),
        ], axis=1)

    def to_dict(self) -> dict:
        """JSON-friendly summary (parameters in rad/mm by name, history, metrics, status)."""
        return {
            "method": self.method,
            "status": self.status.name.lower(),
            "message": self.message,
            "free_parameters": dict(zip(self.space.free_names, map(float, self.x))),
            "units": dict(zip(self.space.free_names, self.space.free_units)),
            "deviations": dict(zip(self.space.names, map(float, np.asarray(self.deviations.ravel())))),
            "n_iterations": self.n_iterations,
            "iterations_to_converge": self.iterations_to_converge,
            "history_rmse_mm": [float(v) for v in self.history[: self.n_iterations + 1]],
            "train_metrics_mm": self.train_metrics._asdict(),
            "wall_time_s": self.wall_time_s,
            "compile_time_s": self.compile_time_s,
            "hyperparameters": to_jsonable(self.hyperparameters),
            "ok": self.ok,
            "plausible": self.plausible,
            "prior": None if self.prior is None else self.prior.describe(),
            "loss": self.loss,
            "loss_scale_mm": self.loss_scale_mm,
            "diagnostics": None if self.diagnostics is None else self.diagnostics.to_dict(),
            "uncertainty": None if self.uncertainty is None else self.uncertainty.to_dict(),
        }

    def __repr__(self) -> str:
        m = self.train_metrics
        return (
            f"CalibrationResult(method={self.method!r}, status={self.status.name}, "
            f"n_iterations={self.n_iterations}, iterations_to_converge={self.iterations_to_converge}, "
            f"train_rmse={m.rmse:.4f} mm, p={self.space.n_free}, wall_time_s={self.wall_time_s:.4f})"
        )
