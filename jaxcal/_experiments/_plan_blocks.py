"""Planning a combined set-up: which poses of one sensor add most to the data of others.

A cell with several sensors (plane contact and a distance bar, a camera and a tracker...) is
calibrated in one fit (:func:`jaxcal.calibrate_blocks`): the blocks share the robot's
parameters, each block's residual is divided by its noise σ_b (whitened), and each block keeps
its own extras. Planning one block therefore has to look at the **combined** information

``G = Σ_b J_bᵀJ_b / σ_b² (+ the relations' rows, already whitened) + Λ``

(``J_b`` ``[n_b·m_b, p]`` block ``b``'s identification Jacobian at the nominal robot, in its unit
per parameter unit; ``Λ`` the prior's precision, :class:`jaxcal.Prior`, none by default): plane
contact alone cannot see the robot's length scale, but 30 camera views or a few bar lengths can,
and the plane poses worth measuring are then the ones that sharpen what the camera leaves vague.

:func:`plan_blocks` puts the information of the blocks already in hand (measured data, or poses
already planned) into the starting information matrix ``M0`` of :func:`jaxcal.select_poses`'
greedy selection and DETMAX exchange, and selects among the candidates of one planned block (or
of several: a budget split between sensors chosen by the same criterion, pose for pose).
:func:`predicted_accuracy_blocks` predicts the per-parameter σ and each block's test RMSE from
``Σ = G⁻¹`` (Cramér–Rao, linearised at the nominal robot, σ_b known).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .._core._params import ParameterSpace
from .._core._xla import jit
from .._sensors._blocks import Block, Relations, combine
from ._plan import (
    CRITERIA,
    PoseSelection,
    _compressed,
    _error_points,
    _error_rows,
    _exchange,
    _greedy,
    _objective,
    _selected_data,
    candidate_rows,
    indices_from_jacobian,
    planning_jacobian,
)

__all__ = ["BlockPrediction", "CombinedPrediction", "CombinedPlan", "plan_blocks", "predicted_accuracy_blocks"]


# -- results ----------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class BlockPrediction:
    """One block's predicted accuracy in a combined set-up (:class:`CombinedPrediction`).

    Attributes:
        name, kind: the block's name and measurement kind.
        unit: of its readings, ``sigma`` and ``test_rmse`` (``"mm"``; ``"px"`` for a camera).
        sigma: its noise σ per residual entry.
        n_poses: its rows in the fit (planned or in hand).
        test_rmse: the expected RMSE of the calibrated model on fresh readings of this sensor at its
            test poses, ``sqrt((m_e·σ² + mean_t tr(J_t Σ J_tᵀ))/points)`` (as
            :func:`jaxcal.predicted_accuracy`, ``J_t`` in the block's unit).
        n_test: the number of test poses.
    """

    name: str
    kind: str
    unit: str
    sigma: float
    n_poses: int
    test_rmse: float
    n_test: int

    def line(self) -> str:
        return (f"{self.name} ({self.kind}, σ = {self.sigma:g} {self.unit}, {self.n_poses} poses): predicted test RMSE "
                f"{self.test_rmse:.4f} {self.unit} over {self.n_test} test poses")


@dataclasses.dataclass(frozen=True)
class CombinedPrediction:
    """Predicted accuracy of a combined calibration (:func:`predicted_accuracy_blocks`).

    Attributes:
        names, units: the free parameters (the combined set: robot + each block's extras) and
            their units (``"rad"``, ``"mm"``).
        param_std: ``[p]`` predicted standard deviations of the estimates (rad / mm); ``inf``
            where the combined information is singular.
        covariance: ``[p, p]`` ``Σ = G⁻¹`` (rad, mm).
        information: ``[p, p]`` the combined whitened information ``G`` (prior included).
        blocks: :class:`BlockPrediction` per data block (the relations have none).
        rank: the numerical rank of the data's information (without the prior), of ``p``.
    """

    names: tuple[str, ...]
    units: tuple[str, ...]
    param_std: np.ndarray
    covariance: np.ndarray = dataclasses.field(repr=False)
    information: np.ndarray = dataclasses.field(repr=False)
    blocks: tuple[BlockPrediction, ...] = ()
    rank: int = -1

    def block(self, name: str) -> BlockPrediction:
        for b in self.blocks:
            if b.name == name:
                return b
        raise KeyError(f"no block {name!r}; blocks: {[b.name for b in self.blocks]}")

    def table(self) -> str:
        rows = [f"combined prediction: {len(self.names)} parameters, information rank {self.rank}"]
        rows += ["  " + b.line() for b in self.blocks]
        rows.append("per-parameter σ:")
        for name, unit, sd in zip(self.names, self.units, self.param_std):
            rows.append(f"  {name:<16} {math.degrees(sd):.4g}°" if unit == "rad" else f"  {name:<16} {sd:.4g} mm")
        return "\n".join(rows)

    def __str__(self) -> str:
        return self.table()


@dataclasses.dataclass(frozen=True)
class CombinedPlan:
    """Result of :func:`plan_blocks`.

    Attributes:
        selections: ``{block: PoseSelection}`` per planned block: its selected candidates (``q``
            ``[n_b, dof]`` rad, ``index`` into its own candidates, ``data`` the selected rows of a
            candidate Dataset); ``indices`` there are those of the combined whitened Jacobian
            (the blocks in hand and every selected pose), column-scaled by ``scale``.
        prediction: :class:`CombinedPrediction` of the blocks in hand plus the selection.
        criterion: ``"D"``, ``"A"``, ``"E"`` or ``"I"`` (of :func:`jaxcal.select_poses`, on the
            combined information in scaled units).
        criterion_value: its value with the selection (larger is better); ``fixed_value``: that of
            the starting information ``M0`` (the blocks in hand, relations, prior; ``ε`` = 1e-8 on
            directions nothing determines), ``-inf`` with nothing in hand.
        method: ``"greedy"`` or ``"greedy+exchange"``.
        space: the free parameters planned for (identifiable with the blocks in hand and every
            candidate).
        scale: ``[p]`` column scales (RMS whitened sensitivity per residual row).
        n_exchanges, seconds: exchange iterations run; wall time of the whole call.
    """

    selections: dict
    prediction: CombinedPrediction
    criterion: str
    criterion_value: float
    fixed_value: float
    method: str
    space: ParameterSpace
    scale: np.ndarray
    n_exchanges: int
    seconds: float
    _state: object = dataclasses.field(repr=False, default=None)

    @property
    def selection(self) -> PoseSelection:
        """The selection of the planned block (one planned block only)."""
        if len(self.selections) != 1:
            raise ValueError(f"{len(self.selections)} blocks were planned: use selections[name]")
        return next(iter(self.selections.values()))

    @property
    def split(self) -> dict:
        """``{block: poses selected}``."""
        return {k: v.n for k, v in self.selections.items()}

    def criterion_of(self, index) -> float:
        """The criterion (same scaling, same blocks in hand) of another selection: ``index`` the
        candidates' rows of the planned block, or for several planned blocks ``{block: rows}``."""
        st = self._state
        M = st.M0 + _gram(st.Jc[st.pooled(index)])
        return float(_objective(jnp.asarray(M), self.criterion, jnp.asarray(st.W)))

    def prediction_of(self, index) -> CombinedPrediction:
        """:class:`CombinedPrediction` of another selection (as :meth:`criterion_of` takes it),
        from the Jacobians already computed (no new compilation)."""
        st = self._state
        return st.predict({name: np.asarray(i) for name, i in st.per_block(index).items()})

    def table(self) -> str:
        head = ", ".join(f"{k}: {v.n}" for k, v in self.selections.items())
        return "\n".join([
            f"{head} poses selected ({self.method}, {self.criterion}-optimal on the combined information) for "
            f"{self.space.n_free} parameters in {self.seconds:.2f} s; criterion {self.criterion_value:.6g} "
            f"(blocks in hand alone: {self.fixed_value:.6g})",
            self.prediction.table(),
        ])

    def __str__(self) -> str:
        return self.table()


# -- the combined rows ------------------------------------------------------------------------------


def _gram(J) -> np.ndarray:
    J = np.asarray(J, np.float64)
    return np.einsum("kap,kaq->pq", J, J) if J.ndim == 3 else J.T @ J


def _block_rows(robot, blk: Block, what: str):
    """``(q [n, dof] rad, y [n, *sample_shape])`` of a block: its readings where given (a Dataset,
    a ``(q, y)`` pair, contact candidates' labels, bar pose pairs), else the nominal predictions."""
    m = blk.measurement
    if blk.sigma is None:
        raise ValueError(f"block {blk.name!r}: planning needs each block's noise σ (Block(..., sigma=...), in its unit)")
    data = blk.data
    if isinstance(data, (tuple, list)) and len(data) == 2 and not np.isscalar(data[0]):
        q, y = candidate_rows(robot, m, data[0], np.asarray(data[1], np.float64))
    else:
        q, y = candidate_rows(robot, m, data)
    if y is None:
        y = np.asarray(m.predict(robot, None, jnp.asarray(q, jnp.result_type(float))), np.float64)
    y = np.asarray(y, np.float64).reshape(q.shape[0], *m.sample_shape)
    if q.shape[0] == 0:
        raise ValueError(f"block {blk.name!r}: no {what}")
    return np.asarray(q, np.float64), y


@functools.partial(jit, static_argnames=("space",))
def _relations_jac(robot, rel, space, base, q, y):
    """``∂ residual/∂x`` of the relations at ``x = 0`` (one small program per relation set)."""
    f = lambda x: rel.residual(robot, space.from_vector(x, base), q, y).reshape(-1)  # noqa: E731
    return jax.jacfwd(f)(jnp.zeros(space.n_free, q.dtype))


class _Setup:
    """The combined model of the blocks (in hand, then planned) and each block's whitened Jacobian
    over the candidate parameters (robot + the extras :func:`jaxcal.calibrate_blocks` frees)."""

    def __init__(self, robot, blocks, relations, prior):
        from .._calibration._blocks import _extras_and_fix
        from .._calibration._calibrate import candidate_space
        from .._fit._objective import resolve_prior

        self.robot = robot
        self.blocks = tuple(blocks)
        self.rows = [_block_rows(robot, b, "rows") for b in self.blocks]
        plain = [dataclasses.replace(b, data=r) for b, r in zip(self.blocks, self.rows)]
        self.model, _, _ = combine(robot, plain, relations)
        extras, fix = _extras_and_fix(robot, self.model, plain)
        self.cand = candidate_space(robot, self.model, extras, None, fix)
        self.prior = resolve_prior(prior)
        self.J = [self._jacobian(b, *r) for b, r in enumerate(self.rows)]  # whitened [n, m_b, p_cand]
        self.obs = []
        for b, (_, y) in enumerate(self.rows):
            own = self.model.models[b].observed(y)
            self.obs.append(None if own is None else np.asarray(own, bool))
        rel = self.model.relations
        self.J_rel = None if rel is None else self._relations_jacobian(rel)

    def _columns(self, b: int):
        """Block ``b``'s own space over the candidate parameters and their combined columns."""
        layout_b = self.model.views[b][0]
        to_comb = self.model.names_in(b, self.cand.layout)
        col = {n: i for i, n in enumerate(self.cand.free_names)}
        space_b = ParameterSpace.from_names(layout_b, [n for n in layout_b.names if to_comb[n] in col])
        return space_b, np.asarray([col[to_comb[n]] for n in space_b.free_names], int)

    def _jacobian(self, b: int, q, y) -> np.ndarray:
        """Whitened Jacobian ``[n, m_b, p_cand]`` of block ``b`` at ``(q, y)`` (unmasked)."""
        mod = self.model.models[b]
        space_b, cols = self._columns(b)
        out = np.zeros((q.shape[0], mod.size, self.cand.n_free))
        if cols.size:
            out[:, :, cols] = planning_jacobian(self.robot, mod, q, space_b, y)
        return out / float(self.blocks[b].sigma)

    def _relations_jacobian(self, rel: Relations) -> np.ndarray:
        """The relations' whitened rows ``[n_rel, p_cand]``."""
        from .._core._params import Deviations

        dtype = jnp.result_type(float)
        q = jnp.zeros((len(rel.relations), self.robot.dof), dtype)  # not read
        J = _relations_jac(self.robot, rel, self.cand, Deviations.zeros(self.cand.layout, dtype), q,
                           jnp.asarray(rel.targets(), dtype))
        return np.asarray(J, np.float64).reshape(-1, self.cand.n_free)

    def masked(self, b: int, idx=None) -> np.ndarray:
        J = self.J[b] if idx is None else self.J[b][idx]
        obs = self.obs[b]
        if obs is None:
            return J
        obs = obs if idx is None else obs[idx]
        return np.where(obs[:, :, None], J, 0.0)

    def identifiable(self, rows) -> tuple[ParameterSpace, np.ndarray]:
        """The free set :func:`jaxcal.calibrate` would choose from the whitened Jacobian ``rows``
        ``[R, p_cand]`` (:func:`~jaxcal._fit._identifiability.identifiable_columns`; with a prior
        every parameter it covers and the data-identifiable rest) and its columns."""
        from .._fit._identifiability import identifiable_columns

        keep = identifiable_columns(rows, self.cand.free_names,
                                    prior_std=None if self.prior is None else self.prior.std(self.cand))
        return self.cand.restrict(keep), np.flatnonzero(keep)

    def stacked(self, blocks, idx=None) -> np.ndarray:
        """The whitened rows ``[R, p_cand]`` of ``blocks`` (each its rows ``idx[b]`` or all) and the
        relations."""
        parts = [self.masked(b, None if idx is None else idx.get(b)).reshape(-1, self.cand.n_free) for b in blocks]
        if self.J_rel is not None:
            parts.append(self.J_rel)
        return np.concatenate(parts)

    def precision(self, space) -> np.ndarray:
        """``[p]`` the prior's precision on the whitened problem (σ = 1; 0 = no prior)."""
        if self.prior is None:
            return np.zeros(space.n_free)
        sd = self.prior.std(space)
        return np.where(np.isfinite(sd), 1.0 / sd**2, 0.0)

    def fixed_gram(self, blocks) -> np.ndarray:
        G = sum((_gram(self.masked(b)) for b in blocks), np.zeros((self.cand.n_free,) * 2))
        return G if self.J_rel is None else G + _gram(self.J_rel)

    def test_jacobian(self, b: int, q_test) -> np.ndarray:
        """Block ``b``'s whitened Jacobian on its error rows at test poses (nominal readings)."""
        mod = self.model.models[b]
        if q_test is None:
            J = self.J[b]
        else:
            q, y = _block_rows(self.robot, dataclasses.replace(self.blocks[b], data=q_test), "test poses")
            J = self._jacobian(b, q, y)
        return J[:, _error_rows(mod), :]


#: relative eigenvalue of the column-scaled information below which a direction counts as unseen
#: (a singular value 1e-6 of the largest)
_RANK_RTOL = 1e-12


def _prediction(setup: _Setup, cols, space, gram, tests, counts) -> CombinedPrediction:
    """:class:`CombinedPrediction` from the data's information ``gram`` over the candidate
    parameters (``cols`` the free ones) and per data block its test Jacobian (whitened)."""
    G = gram[np.ix_(cols, cols)]
    info = G + np.diag(setup.precision(space))
    d = np.sqrt(np.clip(np.diag(info), 0.0, None))
    d = np.where(d > 0, d, 1.0)
    dd = np.outer(d, d)
    ev = np.linalg.eigvalsh(G / dd)  # column-scaled: mm and rad columns compare
    rank = int(np.sum(ev > _RANK_RTOL * ev[-1])) if ev.size and ev[-1] > 0 else 0
    ev_info = np.linalg.eigvalsh(info / dd)
    if ev_info.size and ev_info[0] > _RANK_RTOL * ev_info[-1]:
        cov = np.linalg.inv(info / dd) / dd
        cov = 0.5 * (cov + cov.T)
    else:  # a direction neither the data nor the prior determine
        cov = np.full(info.shape, np.inf)
    out = []
    for b, blk in enumerate(setup.blocks):
        mod = setup.model.models[b]
        Jt = tests[b][:, :, cols] * float(blk.sigma)  # the block's unit
        var = np.einsum("tap,pq,taq->t", Jt, cov, Jt) if np.all(np.isfinite(cov)) else np.full(Jt.shape[0], np.inf)
        m_e = Jt.shape[1]
        test = math.sqrt((m_e * float(blk.sigma) ** 2 + float(np.mean(var))) / _error_points(mod))
        out.append(BlockPrediction(blk.name, mod.kind, getattr(mod, "unit", "mm"), float(blk.sigma), int(counts[b]),
                                   test, int(Jt.shape[0])))
    return CombinedPrediction(space.free_names, space.free_units, np.sqrt(np.diag(cov)), cov, info, tuple(out), rank)


def _check_blocks(blocks, what):
    blocks = (blocks,) if isinstance(blocks, Block) else tuple(blocks)
    for b in blocks:
        if not isinstance(b, Block):
            raise TypeError(f"{what} must be jaxcal.Block s, got {type(b).__name__}")
    return blocks


# -- prediction -------------------------------------------------------------------------------------


def predicted_accuracy_blocks(robot, blocks: Sequence[Block], relations: Sequence = (), *, prior=None,
                              q_test=None) -> CombinedPrediction:
    """Predicted accuracy of a combined calibration (:func:`jaxcal.calibrate_blocks`) before, or
    after, measuring: the blocks' poses (measured or planned) and each block's noise σ.

    Args:
        robot: nominal robot.
        blocks: :class:`jaxcal.Block` s with ``sigma`` given (each block's unit: mm, px) and as
            ``data`` a :class:`~jaxcal.Dataset`, a ``(q, y)`` pair, or planned poses ``[n, dof]``
            (rad; bar pose pairs ``[n, 2·dof]``); readings are used where the Jacobian needs
            them (contact labels, the bar's second pose, a camera's missing corners), else the
            nominal predictions. ``extras`` and ``own_tool`` as in the fit.
        relations: known relations (:class:`jaxcal.KnownDistance`, ...): their whitened rows count.
        prior: :class:`jaxcal.Prior` on the whitened problem (as :func:`jaxcal.calibrate_blocks`
            applies it); default none.
        q_test: ``{block: poses}`` test poses per block (as ``data``); default each block's own
            poses (fresh readings there).

    Returns:
        :class:`CombinedPrediction`: ``Σ = (Σ_b J_bᵀJ_b/σ_b² + J_relᵀJ_rel + Λ)⁻¹`` on the free set
        :func:`jaxcal.calibrate_blocks` would choose on these poses (identifiable subset of the robot's
        parameters and the blocks' extras), per-parameter σ, each block's predicted test RMSE in its
        unit. Linearised at the nominal robot; σ_b as given.
    """
    blocks = _check_blocks(blocks, "blocks")
    setup = _Setup(robot, blocks, relations, prior)
    gram = setup.fixed_gram(range(len(blocks)))
    space, cols = setup.identifiable(setup.stacked(range(len(blocks))))
    q_test = dict(q_test or {})
    tests = [setup.test_jacobian(b, q_test.pop(blk.name, None)) for b, blk in enumerate(blocks)]
    if q_test:
        raise ValueError(f"q_test names no block: {sorted(q_test)}; blocks: {[b.name for b in blocks]}")
    return _prediction(setup, cols, space, gram, tests, [r[0].shape[0] for r in setup.rows])


# -- selection --------------------------------------------------------------------------------------


class _PlanState:
    """What :class:`CombinedPlan` needs to score other selections without new programs."""

    def __init__(self, setup, planned, offsets, sizes, Jc, M0, W, cols, space, gram_fixed, tests):
        self.setup, self.planned, self.offsets, self.sizes = setup, planned, offsets, sizes
        self.Jc, self.M0, self.W, self.cols, self.space = Jc, M0, W, cols, space
        self.gram_fixed, self.tests = gram_fixed, tests

    def per_block(self, index) -> dict:
        if not isinstance(index, dict):
            if len(self.planned) != 1:
                raise ValueError("several blocks were planned: give {block: candidate rows}")
            index = {self.setup.blocks[self.planned[0]].name: index}
        names = [self.setup.blocks[b].name for b in self.planned]
        bad = sorted(set(index) - set(names))
        if bad:
            raise ValueError(f"{bad} are not planned blocks; planned: {names}")
        return {n: np.asarray(index.get(n, []), int) for n in names}

    def pooled(self, index) -> np.ndarray:
        per = self.per_block(index)
        return np.concatenate([o + per[self.setup.blocks[b].name] for b, o in zip(self.planned, self.offsets)])

    def predict(self, per: dict) -> CombinedPrediction:
        setup = self.setup
        gram = self.gram_fixed.copy()
        counts = [r[0].shape[0] for r in setup.rows]
        for b in self.planned:
            idx = per[setup.blocks[b].name]
            gram += _gram(setup.masked(b, idx))
            counts[b] = idx.size
        return _prediction(setup, self.cols, self.space, gram, self.tests, counts)


def plan_blocks(
    robot,
    planned,
    n: int,
    *,
    fixed: Sequence[Block] = (),
    relations: Sequence = (),
    criterion: str = "D",
    exchange: bool = True,
    prior=None,
    q_test=None,
    max_exchanges: int | None = None,
) -> CombinedPlan:
    """Choose ``n`` poses of one sensor block to measure given the blocks already in hand, on the
    combined whitened information (module docstring) — or split ``n`` poses between several
    planned blocks.

    Example: 30 camera views in hand, which 200 of 2 000 plane-contact candidates add most::

        plan = jaxcal.plan_blocks(robot, Block("plane", planes, candidates, sigma=0.05, extras="tool"), 200,
                                  fixed=[Block("camera", camera, views, sigma=0.3)])
        plan.selection.data      # the 200 contacts (labels), to measure
        plan.prediction.table()  # per-parameter σ, each block's predicted test RMSE

    1. Each block's identification Jacobian at the nominal robot over the robot's parameters
       and the extras :func:`jaxcal.calibrate_blocks` would free (each block's own; the tool
       shared unless ``own_tool``), divided by its σ; the relations' rows (already whitened).
       The free set is the identifiable subset with the blocks in hand and every candidate
       (column-scaled pivoted QR; with a ``prior`` every parameter it covers too).
    2. :func:`jaxcal.select_poses`' greedy selection and DETMAX exchange with the starting
       information ``M0 = G_fixed + Λ`` (the blocks in hand, the relations and the prior, in
       column-scaled units), candidates of several planned blocks pooled (each candidate's rows
       padded with zeros to the widest block; a pose of any block costs one of ``n``).
    3. The prediction (:func:`predicted_accuracy_blocks`' formulas) of the blocks in hand with
       the selection; the test poses of a planned block are its candidates (a workspace sample),
       those of a block in hand its own poses, unless ``q_test`` names others.

    Args:
        robot: nominal robot.
        planned: a :class:`jaxcal.Block` (or a sequence of them) whose ``data`` are its candidates
            (:func:`jaxcal.candidate_poses`: ``[N, dof]`` joint angles in rad, a contact
            candidate Dataset, bar pose pairs) and ``sigma`` its noise σ (its unit).
        n: poses to select (in all, over the planned blocks).
        fixed: blocks in hand (measured data, or poses already planned), each with ``sigma``.
        relations: known relations between labelled extras.
        criterion: ``"D"``, ``"A"``, ``"E"`` or ``"I"`` as :func:`jaxcal.select_poses` (I: the
            sum over all blocks of the average whitened prediction variance at their test poses).
        exchange: run the DETMAX exchange after the greedy picks.
        prior: :class:`jaxcal.Prior` (whitened problem, as :func:`jaxcal.calibrate_blocks`).
        q_test: ``{block: poses}`` test poses of the prediction (default above).
        max_exchanges: default ``10·n``.

    Returns:
        :class:`CombinedPlan`. Deterministic for the same candidates.
    """
    if criterion not in CRITERIA:
        raise ValueError(f"criterion must be one of {CRITERIA}, got {criterion!r}")
    t0 = time.perf_counter()
    planned_blocks = _check_blocks(planned, "planned")
    fixed = _check_blocks(fixed, "fixed")
    if not planned_blocks:
        raise ValueError("plan_blocks needs a block to plan")
    setup = _Setup(robot, (*fixed, *planned_blocks), relations, prior)
    nf = len(fixed)
    planned_idx = list(range(nf, nf + len(planned_blocks)))
    sizes = [setup.rows[b][0].shape[0] for b in planned_idx]
    N = sum(sizes)
    if not 1 <= n <= N:
        raise ValueError(f"cannot select {n} of {N} candidate poses")
    gram_fixed = setup.fixed_gram(range(nf))
    # identifiable with the blocks in hand and every candidate (structural; at most 4 096 rows a block)
    every = {b: slice(None, None, max(1, -(-s // 4096))) for b, s in zip(planned_idx, sizes)}
    space, cols = setup.identifiable(setup.stacked(range(len(setup.blocks)), every))
    q_test = dict(q_test or {})
    tests = [setup.test_jacobian(b, q_test.pop(blk.name, None)) for b, blk in enumerate(setup.blocks)]
    if q_test:
        raise ValueError(f"q_test names no block: {sorted(q_test)}")
    # column scales: RMS whitened sensitivity per residual row over the blocks in hand and the candidates
    rows = sum(int(np.prod(setup.J[b].shape[:2])) for b in range(len(setup.blocks)))
    rows += 0 if setup.J_rel is None else setup.J_rel.shape[0]
    norms = np.sqrt(np.diag(setup.fixed_gram(range(len(setup.blocks))))[cols] / rows)
    scale = np.where(norms > 0, norms, 1.0)
    lam = setup.precision(space) / scale**2
    M0 = gram_fixed[np.ix_(cols, cols)] / np.outer(scale, scale) + np.diag(np.maximum(lam, 1e-8))
    parts = []
    for b in planned_idx:
        Jc = setup.masked(b)[:, :, cols] / scale
        parts.append(_compressed(setup.model.models[b], Jc))
    m = max(p.shape[1] for p in parts)
    Jc = np.concatenate([np.pad(p, ((0, 0), (0, m - p.shape[1]), (0, 0))) for p in parts])
    W = sum(np.einsum("kap,kaq->pq", t[:, :, cols], t[:, :, cols]) / t.shape[0] for t in tests) / np.outer(scale, scale)
    Jc_j, M0_j = jnp.asarray(Jc), jnp.asarray(M0)
    W_j = jnp.asarray(np.eye(len(cols)) if criterion == "A" else W)
    sel, _ = _greedy(Jc_j, M0_j, W_j, jnp.ones(N, bool), n, criterion)
    method, n_ex = "greedy", 0
    if exchange:
        sel, _, it = _exchange(Jc_j, M0_j, W_j, sel, criterion, int(max_exchanges or 10 * n))
        method, n_ex = "greedy+exchange", int(it)
    sel = np.asarray(sel)
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(int)
    state = _PlanState(setup, planned_idx, offsets, sizes, Jc, M0, W, cols, space, gram_fixed, tests)
    per = {}
    for b, o, s in zip(planned_idx, offsets, sizes):
        mine = sel[(sel >= o) & (sel < o + s)] - o
        per[setup.blocks[b].name] = mine
    prediction = state.predict(per)
    value = float(_objective(jnp.asarray(M0 + _gram(Jc[sel])), criterion, W_j))
    fixed_value = float(_objective(M0_j, criterion, W_j)) if nf or setup.J_rel is not None else float("-inf")
    # observability indices of the combined whitened Jacobian: the blocks in hand and the selection
    stack = [setup.masked(b)[:, :, cols].reshape(-1, len(cols)) for b in range(nf)]
    stack += [setup.masked(b, per[setup.blocks[b].name])[:, :, cols].reshape(-1, len(cols)) for b in planned_idx]
    if setup.J_rel is not None:
        stack.append(setup.J_rel[:, cols])
    indices = indices_from_jacobian(np.concatenate(stack), scale)
    seconds = time.perf_counter() - t0
    selections = {}
    for b in planned_idx:
        blk, idx = setup.blocks[b], per[setup.blocks[b].name]
        selections[blk.name] = PoseSelection(setup.rows[b][0][idx], idx, criterion, method, indices, space, scale,
                                             n_ex, seconds, _selected_data(blk.data, idx))
    return CombinedPlan(selections, prediction, criterion, value, fixed_value, method, space, scale, n_ex, seconds,
                        state)
