"""Methods in stages: a global or gradient search handing over to a local polish (``"ga>lm"``).

:class:`Staged` runs registered methods (or :class:`Method` instances, or optax
transformations) one after the other inside one pure, jittable, vmappable ``run``: each stage
starts where the last one ended. Names join stages with ``>``: ``calibrate(..., method="ga>lm")``,
``sweep(["adamodw>lm"], ...)``, ``jaxcal fit --method ga>lm``, or
:func:`~jaxcal.methods.stages` (``stages("bso", "lm", **{"lm.max_steps": 50})``).

**Hand-over.** Stage ``k + 1`` runs on the problem *re-centred* at stage ``k``'s result:
``ScaledProblem.build(problem.problem, x_start=x_k, objective=problem.objective)`` — ``z = 0`` is
the hand-over point and the column scaling is recomputed from the Jacobian there. That is
exactly what a user does by hand, ``calibrate(..., method=stage_2, start=result_1.deviations,
init="none", space=result_1.space, key=keys[1])`` (tested step for step). Rescaling at the new
point (rather than keeping the first stage's scale) keeps the scaled coordinates well
conditioned for the polishing stage when the first stage moved far (a start 300 mm off).

**Keys.** ``jax.random.split(key, n_stages)``; stage ``k`` gets ``keys[k]``.

**History.** One curve across the stages, compact: stage 1's history up to its iteration count
``n_1``, then stage 2's from index ``n_1`` (its entry 0, the hand-over point, replaces stage 1's
last entry — the same point), and so on; ``n_iterations = Σ n_k``, the length
``max_iterations + 1 = Σ max_k + 1`` as for any method. The stage ends (history indices
``n_1, n_1 + n_2, …``) are in ``RawRun.extra`` (:class:`StageInfo`), so in
``CalibrationResult.extra`` and ``SweepRun.stage_ends``; Fig. 3 marks them.

**Status.** The first stage that DIVERGED or FAILED gives the status (later stages still run,
from the last finite point); otherwise the last stage's status (a first stage that used its
whole budget is no failure). Iterations to converge are computed on the whole history like any
method's; time is the whole run's.

**Settings** are addressed per stage as ``stage.setting``: the stage's registry name
(``lm.max_steps=50``, ``ga.generations=100``) or its 1-based position (``2.max_steps=50``, needed
when a name occurs twice, e.g. ``"lm>gn>lm"``).

The model used for predictions and test errors is the last stage's (e.g. ``"lm>rbfnn"`` with
``rbfnn.base="nominal"`` is an LM fit compensated by an RBF network).
"""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Int

from .._core._host_method import host_method
from .._fit._result import Status, budget_status
from ._base import METHODS, Method, RawRun, ScaledProblem, finish_history

__all__ = ["Staged", "StageInfo", "is_staged_name", "check_method_name", "SEPARATOR"]

#: joins stage names: ``"ga>lm"``.
SEPARATOR = ">"


class StageInfo(NamedTuple):
    """``RawRun.extra`` of a :class:`Staged` run (a pytree; batched under ``vmap``).

    Attributes:
        ends: ``[S]`` history index where each stage ended (cumulative iterations); the last
            equals ``n_iterations``.
        iterations: ``[S]`` iterations of each stage.
        statuses: ``[S]`` each stage's :class:`~jaxcal.Status` code.
        extras: each stage's own ``RawRun.extra`` (e.g. the RBF network of a last ``rbfnn`` stage).
    """

    ends: Int[Array, " S"]
    iterations: Int[Array, " S"]
    statuses: Int[Array, " S"]
    extras: tuple


class Staged(Method):
    """Methods run one after the other, each from where the last ended (``"ga>lm"``).

    Stage ``k + 1`` runs on the problem re-centred at stage ``k``'s result, its column scaling
    recomputed there (what ``calibrate(..., start=result_1.deviations, init="none")`` does by
    hand); stage ``k`` gets ``jax.random.split(key, n_stages)[k]``. The history is one curve across
    the stages (``n_iterations = Σ n_k``), the stage ends are in :class:`StageInfo`
    (``CalibrationResult.extra``). The status is the first DIVERGED or FAILED stage's, otherwise
    the last stage's. Settings are addressed per stage as ``"lm.max_steps"`` or by 1-based
    position, ``"2.max_steps"``; predictions use the last stage's model.

    Attributes:
        stages: the stage methods, in order (at least two).
        prefixes: how each stage's settings are addressed and reported (``"lm"`` or ``"2"``).
    """

    stages: tuple
    prefixes: tuple = eqx.field(static=True, default=())
    name: ClassVar[str] = "stages"

    def __check_init__(self):
        if len(self.stages) < 2:
            raise ValueError(f"a staged method needs at least two stages, got {len(self.stages)}")
        for m in self.stages:
            if not isinstance(m, Method):
                raise TypeError(f"every stage must be a jaxcal Method, got {type(m)}")
        if len(self.prefixes) != len(self.stages):
            raise ValueError("prefixes must name every stage")

    @property
    def max_iterations(self) -> int:
        return sum(m.max_iterations for m in self.stages)

    @host_method
    def label(self) -> str:
        return SEPARATOR.join(m.label() for m in self.stages)

    @host_method
    def hyperparameters(self) -> dict[str, Any]:
        out: dict[str, Any] = {"stages": self.label()}
        for p, m in zip(self.prefixes, self.stages):
            out |= {f"{p}.{k}": v for k, v in m.hyperparameters().items()}
        return out

    def run(self, problem: ScaledProblem, key) -> RawRun:
        keys = jax.random.split(key, len(self.stages))
        hist = jnp.full(self.max_iterations + 1, jnp.nan, problem.dtype)
        offset = jnp.asarray(0)
        first_bad = jnp.asarray(-1)
        cur, x = problem, problem.x_start
        ends, its, statuses, extras = [], [], [], []
        for i, (m, k) in enumerate(zip(self.stages, keys)):
            if i > 0:  # re-centre at the hand-over point (what a user does by hand with start=)
                cur = ScaledProblem.build(problem.problem, x_start=x, objective=problem.objective)
            raw = m.run(cur, k)
            n = jnp.asarray(raw.n_iterations)
            # offset <= Σ earlier max_iterations, so the stage's whole history fits
            hist = jax.lax.dynamic_update_slice(hist, raw.history.astype(hist.dtype), (offset,))
            offset = offset + n
            finite = jnp.all(jnp.isfinite(raw.z))
            x = jnp.where(finite, cur.x(jnp.where(finite, raw.z, 0.0)), cur.x_start)
            # as a run of that method alone would report it (a fixed budget still improving included)
            st = jnp.asarray(budget_status(raw.status, raw.history, raw.n_iterations))
            bad = (st == int(Status.DIVERGED)) | (st == int(Status.FAILED))
            first_bad = jnp.where((first_bad < 0) & bad, st, first_bad)
            ends.append(offset)
            its.append(n)
            statuses.append(st)
            extras.append(raw.extra)
        status = jnp.where(first_bad >= 0, first_bad, statuses[-1])
        hist = finish_history(hist, offset)
        info = StageInfo(jnp.stack(ends), jnp.stack(its), jnp.stack(statuses), tuple(extras))
        return RawRun(problem.z(x), hist, offset, status, info)

    @property
    def paddable(self) -> bool:
        return all(m.paddable for m in self.stages)

    def sample_errors(self, problem, x, extra):
        """The last stage's model (e.g. an RBF network on top of the kinematics)."""
        return self.stages[-1].sample_errors(problem, x, extra.extras[-1])

    def predictor(self):
        """The last stage's predictor, given its own ``extra``; ``None`` for a kinematic model."""
        inner = getattr(self.stages[-1], "predictor", lambda: None)()
        if inner is None:
            return None
        import dataclasses

        return lambda result, q: inner(dataclasses.replace(result, extra=result.extra.extras[-1]), q)


def is_staged_name(name) -> bool:
    """Whether ``name`` is a string of stages joined by ``>`` (``"ga>lm"``)."""
    return isinstance(name, str) and SEPARATOR in name


def check_method_name(name: str) -> str:
    """``name`` in lower case if it is a registered method or stages of registered methods;
    ``ValueError`` naming the available methods otherwise."""
    key = name.strip().lower()
    parts = [p.strip() for p in key.split(SEPARATOR)] if is_staged_name(key) else [key]
    unknown = [p for p in parts if p not in METHODS]
    if unknown:
        what = f"stage(s) {unknown} of {name!r}" if len(parts) > 1 else f"method {name!r}"
        raise ValueError(f"unknown {what}; available: {', '.join(sorted(METHODS))} "
                         f"(stages join with '{SEPARATOR}', e.g. 'ga{SEPARATOR}lm')")
    return SEPARATOR.join(parts)
