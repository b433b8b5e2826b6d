"""What a sweep returns (:class:`SweepResult`, one :class:`SweepRun` per method or grid point) and
:func:`load_sweep`, which rebuilds it from a sweep's ``out_dir``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import jax
import jax.numpy as jnp
import numpy as np

from .._calibration._io import measurement_from_dict, robot_from_dict
from .._core._json import to_jsonable
from .._core._metrics import Floor, Metrics, statistical_floor
from .._core._params import Deviations, ParameterSpace, layout_for
from .._models._abstract import AbstractRobot
from .._sensors._measurement import MeasurementModel
from ._sweep_chunks import _Store, _unflatten
from ._sweep_trials import _TRIAL_LIKE, _DataOut, _Split

__all__ = ["SweepResult", "SweepRun", "PAPER_METHODS", "load_sweep"]


#: The paper's compared methods M1–M8 (Table II) as registry names, in the paper's order.
PAPER_METHODS: tuple[str, ...] = ("ga", "ekf", "bso", "lm", "iwoa", "rbfnn", "adam", "adamodw")


@dataclasses.dataclass(eq=False)
class SweepRun:
    """Per-trial results of one method (or one grid point) in a sweep. Arrays have a leading
    ``[n_seeds]`` axis (trial ``i`` = seed ``i``).

    Attributes:
        label: display name (``"adamodw"``, ``"adamodw[b3=0.99, weight_decay=0.001]"``, ...).
        method: registry name (or the label of a user's method).
        hyperparameters: the method's settings.
        grid_point: the grid values of this run, or ``None``.
        test: RMSE/MEAN/MAX (mm) on each trial's held-out split, arrays ``[n]``.
        train: RMSE/MEAN/MAX (mm) on the training split.
        n_iterations, iterations_to_converge, status: ``[n]`` ints (:class:`~jaxcal.Status` codes).
        time_per_trial_s: ``[n]`` wall time of the trial's chunk divided by the chunk size
            (compilation excluded; under ``vmap`` a chunk of LM runs lasts until its slowest
            member converges).
        compile_time_s: compilation time of the chunk function (s; 0 when loaded from disk).
        x: ``[n, p]`` calibrated free parameters (rad, mm; ``SweepResult.space`` order).
        history: ``[n, T+1]`` training RMSE per iteration (``[n, 1]``: final only, if not kept).
        test_errors: ``[n, n_test]`` per-sample test errors (mm; signed for wire lengths), or
            an empty ``[n, 0]`` array if not kept.
        stage_ends: staged methods (``"ga>lm"``): ``[n, S]`` history index where each stage
            ended; ``None`` otherwise.
    """

    label: str
    method: str
    hyperparameters: dict
    grid_point: dict | None
    test: Metrics
    train: Metrics
    n_iterations: np.ndarray
    iterations_to_converge: np.ndarray
    status: np.ndarray
    time_per_trial_s: np.ndarray
    compile_time_s: float
    x: np.ndarray
    history: np.ndarray
    test_errors: np.ndarray
    stage_ends: np.ndarray | None = None

    @property
    def n_seeds(self) -> int:
        return int(self.status.shape[0])

    def summary(self) -> dict:
        """Mean and standard deviation over seeds (``ddof=1``) of every scalar per-trial
        quantity, plus status counts: ``{"test_rmse": (mean, std), ..., "status": {...}}``."""
        from .._fit._result import Status

        out = {}
        for split, m in (("test", self.test), ("train", self.train)):
            for f in m._fields:
                out[f"{split}_{f}"] = _mean_std(getattr(m, f))
        for f in ("n_iterations", "iterations_to_converge", "time_per_trial_s"):
            out[f] = _mean_std(getattr(self, f))
        out["time_to_converge_s"] = _mean_std(self.time_to_converge_s)
        codes, counts = np.unique(self.status, return_counts=True)
        out["status"] = {Status(int(c)).name.lower(): int(k) for c, k in zip(codes, counts)}
        return out

    @property
    def time_to_converge_s(self) -> np.ndarray:
        """Estimated time to converge in RMSE: ``time_per_trial_s × iterations_to_converge /
        n_iterations`` (the paper's Table IV "Time (RMSE)"), ``[n]``."""
        its = np.maximum(self.n_iterations, 1)
        return self.time_per_trial_s * np.minimum(self.iterations_to_converge, its) / its


def _mean_std(a) -> tuple[float, float]:
    a = np.asarray(a, dtype=np.float64)
    if a.size == 0:
        return (math.nan, math.nan)
    return float(np.mean(a)), float(np.std(a, ddof=1)) if a.size > 1 else 0.0


@dataclasses.dataclass(eq=False)
class SweepResult:
    """Result of :func:`sweep`.

    Attributes:
        runs: ``{label: SweepRun}`` in the order the methods (then grid points) were given.
        n_seeds: number of trials.
        before: RMSE/MEAN/MAX (mm) of the nominal model ("BC", before calibration) on each
            trial's test split, arrays ``[n]``.
        oracle: the same for the true model (simulation only; NaN for given data): the noise
            level actually present in each test split, the best any method can do there.
        floor: theoretical statistical floor ``Floor(train, test)`` (mm) for σ = ``noise_std``,
            ``p = space.n_free`` and the training size (:func:`~jaxcal.statistical_floor`), or
            ``None`` when the noise level is unknown.
        before_errors: ``[n, n_test]`` per-sample test errors of the nominal model (mm).
        space: the free parameters (the same for every trial and method).
        robot, measurement, start: the nominal models and the start deviations.
        true_deviations: the true deviations per trial (a :class:`Deviations` with a leading
            ``[n]`` axis; simulation only, else ``None``).
        settings: the sweep's settings (JSON-friendly).
    """

    runs: dict[str, SweepRun]
    n_seeds: int
    before: Metrics
    oracle: Metrics
    floor: Floor | None
    before_errors: np.ndarray
    space: ParameterSpace
    robot: AbstractRobot
    measurement: MeasurementModel
    start: Deviations
    true_deviations: Deviations | None
    settings: dict

    def __getitem__(self, label: str) -> SweepRun:
        try:
            return self.runs[label]
        except KeyError:
            raise KeyError(f"no run {label!r} in this sweep; runs: {list(self.runs)}") from None

    def __iter__(self):
        return iter(self.runs.values())

    @property
    def labels(self) -> list[str]:
        return list(self.runs)

    def deviations(self, label: str, trial: int = 0) -> Deviations:
        """Calibrated deviations of run ``label`` in trial ``trial`` (non-free entries from
        ``start``)."""
        return self.space.from_vector(jnp.asarray(self[label].x[trial]), self.start)

    def true_deviation(self, trial: int = 0) -> Deviations | None:
        """The true deviations of trial ``trial`` (simulation only)."""
        if self.true_deviations is None:
            return None
        return jax.tree.map(lambda a: jnp.asarray(a)[trial], self.true_deviations)

    def summary(self) -> dict:
        """``{"before": ..., "oracle": ..., "floor": ..., "runs": {label: SweepRun.summary()}}``."""
        m = lambda met: {f: _mean_std(getattr(met, f)) for f in met._fields}  # noqa: E731
        return {
            "n_seeds": self.n_seeds,
            "n_free": self.space.n_free,
            "before": m(self.before),
            "oracle": m(self.oracle),
            "floor": None if self.floor is None else self.floor._asdict(),
            "runs": {k: r.summary() | {"hyperparameters": r.hyperparameters, "grid_point": r.grid_point}
                     for k, r in self.runs.items()},
        }

    def __repr__(self) -> str:
        parts = ", ".join(f"{k}: {np.mean(r.test.rmse):.4f}" for k, r in self.runs.items())
        return f"SweepResult(n_seeds={self.n_seeds}, p={self.space.n_free}, mean test RMSE (mm) {{{parts}}})"


def _make_run(label, name, report, point, merged, times, compile_time) -> SweepRun:
    out = _unflatten(_TRIAL_LIKE, merged)
    return SweepRun(
        label=label, method=name, hyperparameters=to_jsonable(report), grid_point=None if point is None else to_jsonable(point),
        test=Metrics(*(np.asarray(v) for v in out.test)), train=Metrics(*(np.asarray(v) for v in out.train)),
        n_iterations=np.asarray(out.n_iterations), iterations_to_converge=np.asarray(out.iterations_to_converge),
        status=np.asarray(out.status), time_per_trial_s=np.asarray(times), compile_time_s=float(compile_time),
        x=np.asarray(out.x), history=np.asarray(out.history), test_errors=np.asarray(out.test_errors),
        stage_ends=_stage_ends(merged),
    )


def _stage_ends(merged: dict) -> np.ndarray | None:
    """The ``stage_ends`` leaf of a flattened :class:`_TrialOut` (absent for single methods)."""
    for k, v in merged.items():
        if k.endswith("stage_ends"):
            return np.asarray(v)
    return None


def load_sweep(out_dir, *, partial: bool = False):
    """Rebuild a :class:`SweepResult` from a sweep's ``out_dir``.

    Args:
        out_dir: the directory passed to ``sweep(..., out_dir=)``.
        partial: load only the trials finished by every run of an interrupted sweep (default:
            raise if any chunk is missing; rerun ``sweep`` with the same settings to resume).
    """
    root = pathlib.Path(out_dir)
    meta_path = root / "sweep.json"
    if not meta_path.exists():
        raise FileNotFoundError(f"{root} holds no sweep (no sweep.json)")
    st = json.loads(meta_path.read_text())
    robot = robot_from_dict(st["robot_dict"])
    measurement = measurement_from_dict(st["measurement_dict"])
    n, csize = int(st["n_seeds"]), int(st["chunk_size"])
    store = _Store(root)

    def chunks(unit):
        out = []
        for a in range(0, n, csize):
            b = min(a + csize, n)
            p = store.path(unit, a, b)
            if not p.exists():
                break
            with np.load(p, allow_pickle=False) as f:
                meta = json.loads(str(f["__meta__"]))
                out.append(({k: np.array(f[k]) for k in f.files if k != "__meta__"}, meta, b - a))
        return out

    units = {"_data": chunks("_data")}
    for r in st["runs"]:
        units[r["unit"]] = chunks(r["unit"])
    done = min(sum(c[2] for c in ch) for ch in units.values())
    if done < n and not partial:
        raise ValueError(f"{root}: the sweep is incomplete ({done} of {n} trials in every run); rerun the sweep "
                         "with the same settings to resume it, or use the trials finished so far (jaxcal report --partial, "
                         "the partial argument in Python)")
    if done == 0:
        raise ValueError(f"{root}: no finished trials")

    def merge(unit, axis):
        ch = units[unit]
        merged, times, k = {}, [], 0
        for arrays, meta, m in ch:
            if k >= done:
                break
            take = min(m, done - k)
            for key, v in arrays.items():
                merged.setdefault(key, []).append(v[:, :take] if axis == 1 else v[:take])
            times.append(np.full(take, meta["time_per_trial_s"]))
            k += take
        return ({key: np.concatenate(v, axis=axis) for key, v in merged.items()}, np.concatenate(times),
                float(ch[0][1].get("compile_time_s", 0.0)))

    dtype = np.float64 if st["dtype"] == "float64" else np.float32
    layout = layout_for(robot, measurement)
    has_truth = st["source"]["kind"] in ("simulated", "experiment")
    met = Metrics(0.0, 0.0, 0.0)
    dlike = _DataOut(met, met, Deviations.zeros(layout) if has_truth else None, 0.0,
                     _Split(0.0, 0.0, 0.0, 0.0, None), 0)
    dmerged, _, _ = merge("_data", 0)
    dout = _unflatten(dlike, dmerged)
    runs = {}
    for r in st["runs"]:
        axis = 1 if r["grid_index"] is not None else 0
        merged, times, ct = merge(r["unit"], axis)
        if axis == 1:
            merged = {k: v[r["grid_index"]] for k, v in merged.items()}
        out = _unflatten(_TRIAL_LIKE, merged)
        runs[r["label"]] = SweepRun(
            label=r["label"], method=r["method"], hyperparameters=r["hyperparameters"], grid_point=r["grid_point"],
            test=Metrics(*out.test), train=Metrics(*out.train), n_iterations=out.n_iterations,
            iterations_to_converge=out.iterations_to_converge, status=out.status, time_per_trial_s=times,
            compile_time_s=ct, x=out.x, history=out.history, test_errors=out.test_errors,
            stage_ends=_stage_ends(merged),
        )
    space = ParameterSpace.from_names(layout, st["space"])
    start = Deviations.unravel(jnp.asarray(np.asarray(st["start_values"], dtype)), layout)
    noise = st["noise_std"]
    floor = None if noise is None else statistical_floor(float(noise), space.n_free, int(st["n_train"]),
                                                         measurement.size)
    settings = dict(st)
    settings["n_seeds"] = done
    return SweepResult(
        runs=runs, n_seeds=done, before=Metrics(*dout.before), oracle=Metrics(*dout.oracle), floor=floor,
        before_errors=dout.before_errors, space=space, robot=robot, measurement=measurement, start=start,
        true_deviations=dout.truth, settings=settings,
    )
