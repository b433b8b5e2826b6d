"""What a calibration returns: parameters, per-iteration history, status, timings."""

from __future__ import annotations

import dataclasses
import enum
from typing import Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._core._json import to_jsonable
from .._core._metrics import Metrics, metrics_numpy
from .._core._params import Deviations, ParameterSpace
from .._models._abstract import AbstractRobot
from .._sensors._measurement import MeasurementModel

__all__ = ["Status", "CalibrationResult", "DHTable", "iterations_to_converge", "still_improving", "budget_status",
           "CONVERGENCE_RTOL", "FINAL_FRACTION"]

#: "Iterations to converge in RMSE": the first iteration from which the training RMSE stays
#: within this relative tolerance of its final value. Used by every method, table and plot.
CONVERGENCE_RTOL = 0.01
#: A fixed-budget run is "still improving" when its last ``FINAL_FRACTION`` of iterations
#: lowered the training objective below everything before by more than ``CONVERGENCE_RTOL``
#: (relative) plus ``STILL_IMPROVING_ATOL`` (mm: improvements under a micrometre do not count,
#: so a noiseless fit creeping toward zero RMSE is not flagged).
FINAL_FRACTION = 0.1
STILL_IMPROVING_ATOL = 1e-3


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
    #: a fixed-budget method ran all its iterations but was still improving at the end: the
    #: best training RMSE of its last 10 % of iterations is more than 1 % (+ 1 µm) below the
    #: best before (see :func:`still_improving`). Not ``ok``: raise ``steps``/the learning rate.
    STILL_IMPROVING = 5

    def message(self, method: str = "calibration") -> str:
        return {
            Status.CONVERGED: f"{method}: converged (stopping tolerance met)",
            Status.COMPLETED: f"{method}: completed its iteration budget",
            Status.MAX_STEPS: f"{method}: step budget exhausted before the stopping tolerance was met",
            Status.DIVERGED: f"{method}: diverged (NaN/inf or exploding loss); returned the last finite parameters",
            Status.FAILED: f"{method}: solver failure (e.g. singular linear system)",
            Status.STILL_IMPROVING: f"{method}: iteration budget exhausted while still improving (the last "
                                    f"{FINAL_FRACTION:.0%} of iterations lowered the training RMSE by more than "
                                    f"{CONVERGENCE_RTOL:.0%}) — not converged; raise steps or the learning rate",
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


def iterations_to_converge_numpy(history, n_iterations: int, rtol: float = CONVERGENCE_RTOL) -> int:
    """:func:`iterations_to_converge` of one history on the host (NumPy): the same comparisons in
    the dtype JAX would use (float32 without x64), so the same answer, without running (or, at a
    process start, loading) a compiled program."""
    from .._core._precision import canonical_numpy

    history = canonical_numpy(history)
    n = int(n_iterations)
    idx = np.arange(history.shape[-1])
    ok = (history <= history[n] * np.asarray(1 + rtol, history.dtype)) | (idx > n)
    return int(np.max(np.where(ok, -1, idx))) + 1


class DHTable:
    """A DH table ``[dof, 4]`` in the paper's Table V layout: α/°, a/mm, d/mm, θ/° per joint
    (angles wrapped to (−180°, 180°]).

    Behaves as the array for numerics — ``np.asarray(t)``, ``t[j, col]``, ``t.shape``,
    ``t - other`` — and prints as a table (``str(t)``, :meth:`to_markdown`); entries that were
    not calibrated (fixed: not identifiable or not free) are marked ``*``.

    Attributes:
        values: ``[dof, 4]`` float array.
        columns: ``("alpha_deg", "a_mm", "d_mm", "theta_deg")``.
        rows: joint numbers ``(1, ..., dof)``.
        fixed: ``[dof, 4]`` bool, True where the entry was not calibrated (or ``None``).
    """

    columns = ("alpha_deg", "a_mm", "d_mm", "theta_deg")
    headers = ("Joint i", "α_i/°", "a_i/mm", "d_i/mm", "θ_i/°")

    def __init__(self, values, fixed=None, title: str | None = None):
        self.values = np.asarray(values, dtype=np.float64)
        self.fixed = None if fixed is None else np.asarray(fixed, dtype=bool)
        self.title = title
        self.rows = tuple(range(1, self.values.shape[0] + 1))

    def __array__(self, dtype=None, copy=None):
        return self.values if dtype is None else self.values.astype(dtype)

    def __getitem__(self, index):
        return self.values[index]

    def __len__(self) -> int:
        return len(self.values)

    def __iter__(self):
        return iter(self.values)

    @property
    def shape(self) -> tuple[int, ...]:
        return self.values.shape

    def tolist(self) -> list:
        return self.values.tolist()

    def __sub__(self, other):
        return self.values - np.asarray(other)

    def __rsub__(self, other):
        return np.asarray(other) - self.values

    def __add__(self, other):
        return self.values + np.asarray(other)

    __radd__ = __add__

    def _rows(self):
        out = []
        for j, row in enumerate(self.values):
            marks = [""] * 4 if self.fixed is None else ["*" if f else "" for f in self.fixed[j]]
            out.append([str(j + 1)] + [f"{v:.4f}{m}" for v, m in zip(row, marks)])
        return out

    def _note(self, sep: str = "\n") -> str:
        return "" if self.fixed is None or not self.fixed.any() else \
            sep + "\\* not calibrated (not identifiable or not free): the nominal/start value"

    def to_markdown(self) -> str:
        from .._core._metrics import format_table

        return format_table(self._rows(), self.headers, markdown=True, title=self.title) + self._note("\n\n")

    def __str__(self) -> str:
        from .._core._metrics import format_table

        return format_table(self._rows(), self.headers, title=self.title) + self._note().replace("\\*", "*")

    def __repr__(self) -> str:
        return f"DHTable(columns={self.columns}, values=\n{self.values!r})"


def still_improving(
    history: Float[Array, " T"], n_iterations: Int[Array, ""], rtol: float = CONVERGENCE_RTOL,
    fraction: float = FINAL_FRACTION,
) -> Array:
    """Whether the final ``fraction`` of a run still improved: ``min(history[:k+1]) >
    (1 + rtol)·history[n] + atol`` with ``n = n_iterations``, ``k = n − ceil(fraction·n)`` and
    ``atol = STILL_IMPROVING_ATOL`` (1e-3 mm). Robust
    to oscillating histories (compares with the best value before the final stretch). Pure and
    ``vmap``-able; False for runs of fewer than 10 iterations."""
    history = jnp.asarray(history)
    n = jnp.asarray(n_iterations)
    idx = jnp.arange(history.shape[-1])
    final = jnp.take_along_axis(history, n[..., None], axis=-1)[..., 0]
    k = n - jnp.ceil(n.astype(history.dtype) * jnp.asarray(fraction, history.dtype)).astype(n.dtype)
    best_before = jnp.min(jnp.where(idx <= k[..., None], history, jnp.inf), axis=-1)
    atol = jnp.asarray(STILL_IMPROVING_ATOL, history.dtype)
    return (best_before > jnp.asarray(1 + rtol, history.dtype) * final + atol) & (n >= 10)


def budget_status(status: Int[Array, ""], history, n_iterations) -> Int[Array, ""]:
    """``COMPLETED`` → ``STILL_IMPROVING`` where :func:`still_improving`; others unchanged."""
    return jnp.where((status == int(Status.COMPLETED)) & still_improving(history, n_iterations),
                     int(Status.STILL_IMPROVING), status)


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
        wall_time_s: run time after compilation (s), from dispatch until the result is ready;
            :func:`~jaxcal.calibrate` runs ~0.2 ms of host checks meanwhile, so a solve shorter
            than that reads ~0.2 ms. ``compile_time_s`` separately.
        compile_time_s: seconds spent compiling (or loading compiled) the solve programs of this
            call, also where :func:`~jaxcal.calibrate` compiled one on its background thread while
            it did other work (then the call waited for less than this, or nothing); the
            identifiability and residual programs it compiles are not counted.
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
    robot: AbstractRobot
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
        """The method finished: converged, or completed its fixed budget with a flat end.
        ``MAX_STEPS`` (an iterative solver stopped before its tolerance) and
        ``STILL_IMPROVING`` (a fixed budget ran out while the fit was still descending) are not
        success; :func:`jaxcal.calibrate` warns about them."""
        return self.status in (Status.CONVERGED, Status.COMPLETED)

    @property
    def plausible(self) -> bool:
        """No DH deviation beyond the plausibility bounds (see :class:`~jaxcal.Checks`)."""
        return self.diagnostics is None or self.diagnostics.plausible

    @property
    def warnings(self) -> tuple[str, ...]:
        """The diagnostics' warnings (empty if none)."""
        return () if self.diagnostics is None else self.diagnostics.warnings

    def prediction_std(self, q, y=None) -> np.ndarray:
        """Standard deviation (mm) of the calibrated model's predicted reading at joint angles
        ``q`` ``[n, dof]`` from the parameter uncertainty (``sqrt(diag(J·Cov·Jᵀ))``, summed over
        a sample's coordinates for position data; position part for poses). Add the sensor noise
        (``uncertainty.noise_std``) in quadrature for the expected error of a new reading.

        ``y``: the rows' readings ``[n, …]`` where the model's prediction depends on them (the
        plane / point label of a contact row, a distance bar's second pose and length): without
        them every contact row counts as touching the first plane / point."""
        if self.uncertainty is None:
            raise ValueError("this result has no uncertainty (computed by jaxcal.calibrate)")
        from .._core._precision import to_device
        from ._problem import Problem, prediction_variance_at

        q = to_device(q)
        y = (jnp.zeros((q.shape[0], *self.measurement.sample_shape), q.dtype) if y is None
             else to_device(np.asarray(y, np.float64), q.dtype))
        pr = Problem(self.robot, self.measurement, q, y, self.space, self.deviations.astype(q.dtype))
        C = to_device(np.asarray(self.uncertainty.covariance, np.float64), q.dtype)
        var = np.asarray(prediction_variance_at(pr, pr.x0(), C), np.float64)
        return np.sqrt(np.maximum(var, 0.0))

    def predict(self, q) -> Array:
        """Predicted readings of the calibrated model for joint angles ``q`` ``[n, dof]``."""
        q = jnp.asarray(q)
        if self.predictor is not None:
            return self.predictor(self, q)
        from ._problem import predict_jit

        return predict_jit(self.measurement, self.robot, self.deviations.astype(q.dtype), q)

    def sample_errors(self, data) -> Array:
        """Per-sample errors (mm) of the calibrated model on ``data`` (a Dataset)."""
        q = jnp.asarray(data.q)
        if self.predictor is None:
            from ._problem import Problem, sample_errors_at

            pr = Problem(self.robot, self.measurement, q, data.y, self.space, self.deviations.astype(q.dtype))
            return sample_errors_at(pr, pr.x0())  # jitted (cached per shape): fast on repeated use
        r = (self.predict(data.q) - data.y).reshape(q.shape[0], self.measurement.size)
        return self.measurement.sample_error(r)

    def evaluate(self, data, **kwargs) -> Metrics:
        """RMSE/MEAN/MAX (mm) on ``data`` (e.g. the held-out test split of the training session),
        with the result's own sensor extras: a :class:`~jaxcal._core._metrics.Metrics`.

        On new measurements, where the sensor was set up again (a new anchor, frame or marker
        plate), :func:`jaxcal.evaluate_result` ``(result, data, extras="auto")`` registers the
        sensor extras again and reports before and after (a :class:`jaxcal.Evaluation`).

        Raises:
            TypeError: a keyword such as ``extras=`` (that is :func:`jaxcal.evaluate_result`).
        """
        if kwargs:
            raise TypeError(f"CalibrationResult.evaluate(data) takes no {', '.join(map(repr, kwargs))}: to register "
                            "the sensor extras on new data, call jaxcal.evaluate_result(result, data, extras=...)")
        return metrics_numpy(self.sample_errors(data))

    def dh_table(self) -> DHTable:
        """Calibrated DH table ``[dof, 4]``: α/°, a/mm, d/mm, θ/° per joint (the paper's
        Table V), angles wrapped to (−180°, 180°]: a :class:`DHTable` that prints as the table
        (uncalibrated entries marked ``*``) and indexes like the array (``np.asarray(t)``,
        ``t[j, col]``)."""
        from .._core._trig import wrap_angle_deg

        r = self.robot
        rows = r.dh_rows_deg(self.deviations)
        if rows is None:
            raise TypeError(f"robot {r.name!r} is a generic chain, not a DH table: its calibrated model is "
                            "the per-joint corrections in .deviations; jaxcal.export_urdf writes it as URDF")
        free = dict(zip(self.space.names, np.asarray(self.space.free, bool)))
        fixed = np.asarray([[not free[f"{g}_{j + 1}"] for g in ("alpha", "a", "d", "theta")] for j in range(r.dof)])
        return DHTable(np.stack([wrap_angle_deg(rows[:, 0]), rows[:, 1], rows[:, 2], wrap_angle_deg(rows[:, 3])],
                                axis=1), fixed, title=f"Calibrated DH table ({self.method})")

    def to_dict(self) -> dict:
        """JSON-friendly summary (parameters in rad/mm by name, history, metrics, status)."""
        return {
            "method": self.method,
            "status": self.status.name.lower(),
            "message": self.message,
            "free_parameters": dict(zip(self.space.free_names, map(float, self.x))),
            "units": dict(zip(self.space.free_names, self.space.free_units)),
            "deviations": self.deviations.named(),
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
            "prior_evidence": None if getattr(self.prior, "evidence", None) is None else self.prior.evidence.to_dict(),
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
