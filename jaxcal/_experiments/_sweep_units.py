"""A sweep's plan (:mod:`jaxcal._experiments._sweep`): the methods and hyperparameter grids as
compiled units, and the free parameters every trial shares.

:func:`_method_specs` reads ``methods``/``hyperparameters``/``grid`` into :class:`_RunSpec` (a
method, or grid points that compile together), :func:`_plan_units` makes one :class:`_Unit` per
compiled function (float grid axes vmapped, the others compiled per value), and
:func:`_free_parameters` chooses the free set at trial 0's training poses (as
:func:`jaxcal.calibrate` does) with the statistical floor; :func:`_trial_objective` is the fixed
objective every trial minimises.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._calibration._calibrate import resolve_space
from .._core._buckets import buckets_enabled
from .._core._json import to_jsonable
from .._core._metrics import statistical_floor
from .._core._precision import dtype_scope, to_device
from .._fit._diagnostics import error_dims
from .._fit._objective import LOSSES, Objective
from ..methods import METHODS, Method, make_method

__all__ = []


def _label_value(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _grid_points(grid: Mapping[str, Sequence]) -> list[dict]:
    names = list(grid)
    for n in names:
        if isinstance(grid[n], (str, bytes)) or not isinstance(grid[n], Sequence) or len(grid[n]) == 0:
            raise ValueError(f"grid values for {n!r} must be a non-empty list, got {grid[n]!r}")
    return [dict(zip(names, combo)) for combo in itertools.product(*(list(grid[n]) for n in names))]


def _is_traceable(values) -> bool:
    """A grid axis whose values are numbers with at least one float is vmapped over (traced);
    others (integers such as ``steps``, strings) change shapes or code and are compiled per value."""
    nums = all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) for v in values)
    return nums and any(isinstance(v, (float, np.floating)) for v in values)


@dataclasses.dataclass
class _RunSpec:
    """One compiled unit: a method (``points`` None) or a method's grid points."""

    name: str  # registry name or user label
    method: Method | None  # plain run
    labels: list[str]
    hyper_reports: list[dict]
    points: list[dict] | None = None
    traced_keys: tuple[str, ...] = ()
    static_hyper: dict = dataclasses.field(default_factory=dict)
    fingerprint_extra: str = ""


def _method_specs(methods, hyperparameters, grid) -> list[_RunSpec]:
    import optax

    hyperparameters = dict(hyperparameters or {})
    grid = dict(grid or {})
    if isinstance(methods, (str, Method, optax.GradientTransformation)):
        methods = [methods]
    items: list[tuple[str | None, Any]]
    if isinstance(methods, Mapping):
        items = list(methods.items())
    else:
        items = [(None, m) for m in methods]
    specs: list[_RunSpec] = []
    for label, m in items:
        if isinstance(m, str) and m.lower() in grid:
            continue  # run as a grid below
        hyper = hyperparameters.get(m, {}) if isinstance(m, str) else {}
        meth = make_method(m, **hyper)
        lab = label or (m.lower() if isinstance(m, str) else meth.label())
        specs.append(_RunSpec(m.lower() if isinstance(m, str) else lab, meth, [lab], [meth.hyperparameters()],
                              fingerprint_extra=repr(sorted(hyper.items()))))
    for name, g in grid.items():
        if not isinstance(name, str) or name.lower() not in METHODS:
            raise ValueError(f"grid keys must be registered method names, got {name!r}; available: {sorted(METHODS)}")
        name = name.lower()
        if not isinstance(g, Mapping) or not g:
            raise ValueError(f"grid[{name!r}] must be a non-empty mapping hyperparameter -> list of values")
        base = dict(hyperparameters.get(name, {}))
        points = _grid_points(g)
        reports, labels = [], []
        for pt in points:
            meth = make_method(name, **(base | pt))  # validates every point eagerly
            reports.append(meth.hyperparameters())
            labels.append(f"{name}[" + ", ".join(f"{k}={_label_value(v)}" for k, v in pt.items()) + "]")
        traced = tuple(k for k in g if _is_traceable(list(g[k])))
        static_keys = [k for k in g if k not in traced]
        # group the points by their static values: one compilation per group, traced axes vmapped
        groups: dict[tuple, list[int]] = {}
        for i, pt in enumerate(points):
            groups.setdefault(tuple((k, pt[k]) for k in static_keys), []).append(i)
        for stat, idx in groups.items():
            specs.append(_RunSpec(
                name, None, [labels[i] for i in idx], [reports[i] for i in idx],
                points=[points[i] for i in idx], traced_keys=traced, static_hyper=base | dict(stat),
                fingerprint_extra=repr(sorted((base | dict(stat)).items())),
            ))
    seen = set()
    for s in specs:
        for lab in s.labels:
            if lab in seen:
                raise ValueError(f"two runs are labelled {lab!r}; pass methods as a dict {{label: method}}")
            seen.add(lab)
    if not specs:
        raise ValueError("no methods to run")
    return specs


def _paddable(specs) -> bool:
    """Whether a simulated sweep runs padded to its shape bucket (:mod:`jaxcal._core._buckets`):
    buckets turned on explicitly (:func:`jaxcal.set_buckets`, ``JAXCAL_BUCKETS=on``; not by default),
    JAX's partitionable threefry (the padded simulation's real rows equal the unpadded one's only
    then), and every method paddable (:attr:`Method.paddable`)."""
    if not buckets_enabled(explicit=True) or not jax.config.jax_threefry_partitionable:
        return False
    for s in specs:
        m = s.method if s.method is not None else make_method(s.name, **(s.static_hyper | s.points[0]))
        if not m.paddable:
            return False
    return True


def _fingerprint(obj) -> str:
    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=repr).encode()).hexdigest()[:16]


def _free_parameters(robot, measurement, dout, space, start, prior, noise_std, real=None):
    """Step 2: the free parameters chosen at trial 0's training poses, the statistical floor
    (or ``None``), and the settings entries they add. ``real``: ``(n_train, n_test)`` of a padded
    simulation (its real rows come first)."""
    n_train, n_test = (dout.split.q_train.shape[1], dout.split.q_test.shape[1]) if real is None else real
    n_train, n_test = int(n_train), int(n_test)
    # padded: the identifiability program pads to the sweep's own train rows (one program per bucket)
    n_to = None if real is None else int(dout.split.q_train.shape[1])
    q0 = to_device(dout.split.q_train[0][:n_train])  # not jnp.asarray: no copy program per shape
    space, report = resolve_space(robot, measurement, q0, space, start, prior=prior, n_to=n_to)
    if n_train * measurement.size <= space.n_free + 1:
        raise ValueError(
            f"too few samples: {n_train} training sample(s) give {n_train * measurement.size} residuals "
            f"for {space.n_free} free parameters"
        )
    # p of the floor: what the data identify (under a prior the free set also holds what only the prior sets)
    p_floor = space.n_free if report is None else report.rank
    floor = None if noise_std is None else statistical_floor(float(noise_std), p_floor, n_train, measurement.size)
    return space, floor, {"n_train": n_train, "n_test": n_test, "space": list(space.free_names),
                          "identifiability": None if report is None else report.to_dict()}


def _trial_objective(space, prior, loss, loss_scale, noise_std, dtype, measurement=None) -> Objective | None:
    """The objective every trial minimises (``None``: plain least squares), with fixed scales (a
    robust loss's default scale: its constant times a clean sample's RMS error,
    :func:`~jaxcal._fit._diagnostics.error_dims` of ``measurement``, as :func:`jaxcal.calibrate`)."""
    if prior is None and loss == "linear":
        return None
    sigma = prior.noise_std if prior is not None and prior.noise_std is not None else noise_std
    if sigma is None:
        raise ValueError("a prior or robust loss in a sweep of given data needs noise_std (mm) or Prior.noise_std")
    dims = 1 if measurement is None or loss == "linear" or loss_scale is not None else error_dims(measurement)
    scale = loss_scale if loss_scale is not None else (LOSSES[loss] * math.sqrt(dims) * sigma
                                                        if loss != "linear" else None)
    objective = Objective.build(space, prior, sigma, loss, scale, dtype)
    return None if objective.plain_least_squares else objective


@dataclasses.dataclass
class _Unit:
    name: str
    fingerprint: str
    trial: eqx.Module
    hyper: dict | None
    spec: _RunSpec
    grid_index: list


def _grid_trial(s: _RunSpec, mk, space, dtype, trial_args):
    """The vmapped-grid trial and its ``[G]`` hyperparameter arrays, or ``(None, None)`` when the
    method cannot be built from traced hyperparameters (then each point compiles on its own)."""
    if not s.traced_keys:
        return None, None
    hyper = {k: jnp.asarray([float(pt[k]) for pt in s.points], dtype) for k in s.traced_keys}
    trial = mk(None, space, method_name=s.name, static_hyper=tuple(sorted(s.static_hyper.items())))
    try:
        with dtype_scope(dtype):
            eqx.filter_eval_shape(lambda t, a, h: t(*a, h), trial, trial_args, jax.tree.map(lambda a: a[0], hyper))
    except Exception:  # noqa: BLE001 - the method needs concrete values: compile per point instead
        return None, None
    return trial, hyper


def _plan_units(specs, mk, space, dtype, trial_args, common) -> list[_Unit]:
    """Step 3: the compiled units: one per plain method, one per group of grid points that can be
    vmapped together, one per point of a grid the method needs concrete values for."""
    units: list[_Unit] = []
    for s in specs:
        fp = _fingerprint(common | {"unit": s.name, "labels": s.labels, "hyper": to_jsonable(s.hyper_reports),
                                    "extra": s.fingerprint_extra})
        if s.points is None:
            units.append(_Unit(s.labels[0], fp, mk(s.method, space), None, s, [None]))
            continue
        trial, hyper = _grid_trial(s, mk, space, dtype, trial_args)
        if hyper is None:  # the method needs concrete values: one compilation per point
            for i, (lab, pt) in enumerate(zip(s.labels, s.points)):
                sub = dataclasses.replace(s, labels=[lab], hyper_reports=[s.hyper_reports[i]], points=[pt])
                units.append(_Unit(lab, _fingerprint([fp, lab]), mk(make_method(s.name, **(s.static_hyper | pt)), space),
                                   None, sub, [None]))
        else:
            unit = s.labels[0] if len(s.labels) == 1 else f"{s.name}-grid-{fp[:8]}"
            units.append(_Unit(unit, fp, trial, hyper, s, list(range(len(s.points)))))
    return units


def _run_entries(units) -> list[dict]:
    """``sweep.json``'s ``runs``: one entry per run (label, method, unit, grid point)."""
    return [
        {"label": lab, "method": u.spec.name, "unit": u.name, "grid_index": g,
         "hyperparameters": to_jsonable(u.spec.hyper_reports[i]),
         "grid_point": None if u.spec.points is None else to_jsonable(u.spec.points[i])}
        for u in units for i, (lab, g) in enumerate(zip(u.spec.labels, u.grid_index))
    ]
