"""One fit over several data blocks: :func:`calibrate_blocks` (issue 34).

The blocks (:class:`jaxcal.Block`: a measurement model, its data and its noise σ) and the known
relations between their extras are one :class:`~jaxcal._sensors._blocks.Combined` measurement,
whose residual is each block's residual over its σ_b; :func:`jaxcal.calibrate` fits it. A σ_b
not given is estimated by **variance components** (Förstner 1979; Koch 1999, §3.6): after a fit
with the current σ, each block's σ̂_b² = RSS_b / r_b, with ``RSS_b`` the block's residual sum of
squares (its unit) and ``r_b = Σ_{i∈b} (1 − h_ii)`` its redundancy, ``h_ii`` the diagonal of the
whitened hat matrix ``J (JᵀJ + Λ)⁻¹ Jᵀ`` (``Λ`` the prior's precision in whitened units); then
the fit is repeated with the new σ until no σ moves by more than ``sigma_rtol``. These rounds are
:func:`jaxcal.calibrate`'s own (the model's :meth:`~jaxcal.Combined.estimates_weights`): each
warm-started from the last, re-estimating the block σ together with the prior's noise σ and the
robust scale, after one parameter selection and with one diagnosis at the end. The redundancies
sum to ``N − p`` (the residual count less the parameters the data determine), so each block gets
its share of the degrees of freedom the fit used, and σ̂_b is unbiased for a linear model.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Sequence

import numpy as np

from .._core._params import STANDARD_EXTRAS, Deviations, ParameterSpace, layout_for
from .._core._precision import to_device
from .._datasets._dataset import Dataset, mm_joints_metadata
from .._sensors._blocks import Block, Combined, Relations, combine
from .._sensors._initial_extras import initial_extras
from .._sensors._initialise import row_errors
from .._sensors._measurement import xyz_entries
from ._variance import _information, _variance_components

__all__ = ["calibrate_blocks", "BlockStats", "block_statistics", "block_information", "block_directions",
           "length_scale_direction", "scale_shares", "free_scale_direction", "combined_floor", "block_result",
           "who_sees_what", "CombinedResult", "combined_result_to_dict", "save_combined_result",
           "load_combined_result", "COMBINED_FORMAT"]

#: a block's ``extras=`` names → the standard groups they free
_EXTRA_GROUPS = {"tool": ("tool",), "base": ("base_rotation", "base_translation"), "anchor": ("anchor",),
                 "cable_offset": ("cable_offset",), "offset": ("cable_offset",)}


def block_extras(names) -> list[str]:
    """The entries of ``names`` (extras as :func:`jaxcal.calibrate` names them, e.g. what
    :func:`jaxcal.measurement_for` chose for a data file) that a
    :class:`jaxcal.Block` takes as its ``extras``, sorted; a sensor's own unknowns (planes,
    points, hand-eye, ...) are always estimated and are not named."""
    return sorted(e for e in names if e in _EXTRA_GROUPS)


#: a measurement's own groups that :func:`initial_extras` starts (free by default, as alone)
_OWN_INIT = ("plane", "point", "markers", "handeye", "target")


@dataclasses.dataclass(frozen=True)
class BlockStats:
    """One block's statistics after a combined fit.

    Attributes:
        name, kind: the block's name and measurement kind (``"relations"`` for the relations).
        unit: its residuals' unit (``"mm"``, ``"px"``; ``"σ"`` for the whitened relations).
        n_samples: its rows; n_residuals: its real residual entries (masked ones left out).
        sigma: the σ its residuals were divided by in the final fit (its unit).
        sigma_given: whether ``sigma`` was given (else estimated by variance components).
        sigma_hat: the variance-component estimate ``sqrt(RSS_b / r_b)`` at the solution (its unit).
        redundancy: ``r_b``, the block's share of the residual degrees of freedom.
        rmse: RMS of its per-sample errors (its unit: the sensor's own metric, e.g. the 3-D
            distance of a position, the RMS reprojection distance of an image).
        rms: RMS of its residual entries (its unit).
        mean, max: mean and largest of its per-sample errors (its unit; signed errors by
            absolute value).
        information: ``{free parameter: share}``, the block's share of each free parameter's
            information at the solution, ``Σ_{i∈b} J_ij² / Σ_i J_ij²`` of the whitened Jacobian
            (1: only this block sees the parameter; 0: it does not see it at all). Shares of one
            parameter sum to 1 over the blocks; a prior's information is not counted.
        directions: the directions of the free parameters that (nearly) only this block
            determines (:func:`block_directions`): ``((share, ((coefficient, name), ...)), ...)``,
            ``share`` the block's share of the information along the direction (≥ 0.99),
            the coefficients those of the unit direction in column-scaled parameters (largest
            first). A direction of one parameter alone is left out (``information`` has it).
        rank_without: the rank of the data's information matrix without this block's rows
            (compare :attr:`rank`): what becomes unidentifiable when the block is removed.
        rank: the rank with every block (the same in each block's stats).
        scale_share: the block's share ``vᵀG_b v / vᵀG v`` of the information along the robot's
            **length scale** ``v`` (every length of the set-up times ``1 + ε``:
            :func:`length_scale_direction`; :func:`scale_shares`); ``nan`` where it was not computed
            (a file written before it) or no length is free. Read it with :attr:`scale_seen`: plane
            or pivot data alone keep all of the little information along the scale (their
            residuals' own, ``J·v = r``) and do not see it.
        scale_seen: whether the data (all blocks together) see the length scale at all
            (:func:`scale_shares`); ``None`` where not computed. The same in each block's stats.
        sigma_stated: the noise σ the block's data file states (its ``# noise_std_mm:`` /
            ``# noise_std_px:`` line; its unit), ``None`` without one; σ̂ at or above
            :attr:`~jaxcal.Checks.noise_warn_factor` times it is warned about
            (:meth:`noise_warning`).
    """

    name: str
    kind: str
    unit: str
    n_samples: int
    n_residuals: int
    sigma: float
    sigma_given: bool
    sigma_hat: float
    redundancy: float
    rmse: float
    rms: float
    mean: float = float("nan")
    max: float = float("nan")
    information: dict = dataclasses.field(default_factory=dict, repr=False)
    directions: tuple = dataclasses.field(default=(), repr=False)
    rank_without: int = -1
    rank: int = -1
    scale_share: float = float("nan")
    scale_seen: bool | None = None
    sigma_stated: float | None = None

    def noise_warning(self, where: str | None = None, factor: float | None = None) -> str | None:
        """:func:`~jaxcal._fit._diagnostics.stated_noise_warning` of this block: the warning when
        its σ̂ is at least ``factor`` (default :attr:`~jaxcal.Checks.noise_warn_factor`) times the
        noise its file states, else ``None``; ``where`` names it (default ``block 'name'``)."""
        from .._fit._diagnostics import Checks, stated_noise_warning

        return stated_noise_warning(where or f"block {self.name!r}", self.sigma_hat, self.sigma_stated, self.unit,
                                    Checks.noise_warn_factor if factor is None else factor)

    def line(self) -> str:
        given = "given" if self.sigma_given else "estimated"
        return (f"{self.name} ({self.kind}): {self.n_samples} rows, {self.n_residuals} residuals, σ = {self.sigma:.4g} "
                f"{self.unit} ({given}), σ̂ = {self.sigma_hat:.4g} {self.unit} (redundancy {self.redundancy:.1f}), "
                f"RMSE {self.rmse:.4g} {self.unit}")


#: relative eigenvalue of the column-scaled information matrix below which a direction counts as
#: unseen by the data (a singular value 1e-6 of the largest: the noise-level curvature a scale
#: direction of plane data keeps away from exact contacts is above it)
_UNSEEN_RTOL = 1e-12


#: a direction the other blocks give less than this share of its information counts as lost without
#: the block: its posterior σ would grow more than 100-fold
_LOST_SHARE = 1e-4


def block_directions(grams, names, share_min: float = 0.99, rtol: float = _UNSEEN_RTOL,
                     lost_share: float = _LOST_SHARE):
    """Which block alone determines which direction of the free parameters.

    The shares along a direction ``v`` are ``vᵀG_b v / vᵀG v`` (``G_b`` block ``b``'s information
    matrix, ``G = Σ_b G_b``); the directions where block ``b``'s share is largest are the
    generalised eigenvectors of ``(G_b, G)`` on the span the data see. A share of 1 means the other
    blocks do not see the direction at all: without block ``b`` it is unidentifiable (e.g. the
    length scale of plane data and a known distance; a plane's offset against ``d_1`` where only a
    tracker tells them apart).

    Args:
        grams: ``[B, p, p]`` the blocks' information matrices (:func:`block_information`).
        names: the ``p`` free parameters' names.
        share_min: the smallest share reported.
        rtol: eigenvalues of the column-scaled ``G`` below ``rtol·max`` are directions no block sees.
        lost_share: a direction where the other blocks give less than this share of the
            information is lost without the block (its σ would grow more than 100-fold). Not an
            eigenvalue threshold of ``G − G_b``: away from exact data a blind block keeps a
            noise-level curvature (plane contact along the length scale: ~1e-6 of a known
            distance's), which a rank would count.

    Returns:
        ``(rank, ranks_without [B], directions [B])``: the numerical rank of the column-scaled
        ``G``, that rank less the directions lost without each block, and per block its directions
        ``((share, ((coefficient, name), ...)), ...)`` (share ≥ ``share_min``, largest first;
        each unit direction in column-scaled parameters, its entries ≥ 0.2 of the largest, at
        most 6; the parameters lying in that span alone are left out: the shares of
        :attr:`BlockStats.information` name them).
    """
    grams = np.asarray(grams, np.float64)
    total = grams.sum(0)
    d = np.sqrt(np.clip(np.diag(total), 0.0, None))
    inv = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
    Gs = grams * inv[None, :, None] * inv[None, None, :]
    T = Gs.sum(0)
    lam, U = np.linalg.eigh(T)
    cut = rtol * max(lam[-1], 0.0)

    keep = lam > cut if lam[-1] > 0 else np.zeros(lam.shape, bool)
    W = U[:, keep] / np.sqrt(lam[keep])  # Wᵀ T W = I on the seen span
    ranks_without, directions = [], []
    for Gb in Gs:
        mu, Z = np.linalg.eigh(W.T @ Gb @ W)
        ranks_without.append(int(W.shape[1] - np.sum(mu >= 1.0 - lost_share)))
        V = W @ Z[:, mu >= share_min]  # the span where the block's share is ≥ share_min
        found = []
        if V.shape[1]:
            # a canonical basis of that span (its eigenvectors mix where shares tie, e.g. at 1): the
            # parameters lying in it alone first (the information shares name those), then the rest
            Q = np.linalg.svd(V, full_matrices=False)[0]
            alone = np.linalg.norm(Q, axis=1) > 0.95
            rest = np.where(alone[:, None], 0.0, Q)
            u, sv, _ = np.linalg.svd(rest, full_matrices=False)
            for v in u[:, sv > 0.5].T:
                share = float(v @ Gb @ v / (v @ T @ v))
                if share < share_min:
                    continue
                order = np.argsort(-np.abs(v))
                big = [i for i in order[:6] if abs(v[i]) >= 0.2 * abs(v[order[0]])]
                sign = np.sign(v[order[0]])
                found.append((min(share, 1.0), tuple((float(sign * v[i]), names[i]) for i in big)))
        found.sort(key=lambda f: -f[0])
        directions.append(tuple(found))
    return int(keep.sum()), ranks_without, directions


def _direction(terms) -> str:
    return " ".join(f"{c:+.2f}·{n}" for c, n in terms)


def _nominal_lengths(robot, model) -> dict[str, float]:
    """``{entry: nominal value}`` (mm) of the length entries of one (non-combined) measurement
    model's layout: the robot's own (``robot.nominal_lengths()``: a DH table's ``a_i``, ``d_i``, a
    chain's joint-origin and flange translations), its tool point, and the model's own extras
    (:meth:`~jaxcal.MeasurementModel.nominal_lengths`). Entries left out have nominal 0 (a base
    translation, a cable's zero offset)."""
    out = robot.nominal_lengths() | xyz_entries("tool_", robot.tool)
    return out if model is None else out | model.nominal_lengths()


def length_scale_direction(robot, model, deviations: Deviations, space: ParameterSpace) -> np.ndarray:
    """The direction ``v`` ``[p]`` of the free parameters along which every length of the set-up
    grows by the same factor (``d/dε`` of each length ``x`` at ``x·(1 + ε)``): for each free entry
    in mm its current absolute value (nominal + deviation: the DH ``a_i``, ``d_i``, the tool point,
    base and frame translations, plane offsets, point centres, sphere radii, marker positions,
    anchors), 0 for angles and other units. Data whose residuals keep every contact under that
    scaling (plane contact, pivots, spheres of unknown radius) cannot see it
    (:func:`jaxcal.identifiability` shows it as a rank deficiency); a known length (a distance bar,
    a known sphere radius, a known distance between labels, a camera's target) does.

    Args:
        robot: the nominal robot.
        model: the measurement model; for a :class:`~jaxcal._sensors._blocks.Combined` model each
            block's extras take their block model's nominal values under their combined names.
        deviations: the current deviations (``model``'s layout).
        space: the free parameters (``v``'s entries, in ``space.free_names`` order).
    """
    nominal: dict[str, float] = {}
    if isinstance(model, Combined):
        for b, mod in enumerate(model.models):
            if model.views[b] is None:
                continue
            own = _nominal_lengths(robot, mod)
            for bn, cn in model.names_in(b, space.layout).items():
                if bn in own:
                    nominal.setdefault(cn, own[bn])
        nominal = _nominal_lengths(robot, None) | nominal
    else:
        nominal = _nominal_lengths(robot, model)
    dev = deviations.named()
    return np.asarray([nominal.get(n, 0.0) + float(dev.get(n, 0.0)) if u == "mm" else 0.0
                       for n, u in zip(space.free_names, space.free_units)], np.float64)


#: the data see the length scale when the information along it exceeds this many times what the
#: residuals themselves give: a residual that keeps every contact under the scaling is homogeneous of
#: degree 1 in the lengths, so its derivative along ``v`` is the residual itself (``J·v = r``) and
#: ``vᵀG v`` equals the whitened residual sum of squares (≈ N: the scale known to ≈ 1/√N only)
_SCALE_SEEN_FACTOR = 100.0


def scale_shares(grams, v, rss: float = 0.0, rtol: float = _UNSEEN_RTOL):
    """Each block's share of the information along the length scale ``v``.

    Args:
        grams: ``[B, p, p]`` the blocks' whitened information matrices (:func:`block_information`).
        v: ``[p]`` the length-scale direction (:func:`length_scale_direction`).
        rss: the whitened residual sum of squares at the solution (``Σ r²``): data that cannot
            see the scale still give ``vᵀG v = rss`` along it (``J·v = r``).
        rtol: as :func:`block_directions`, in the same column scaling: ``vᵀG v`` below ``rtol``
            times the largest eigenvalue (``v`` a unit vector in column-scaled parameters) is
            unseen.

    Returns:
        ``(shares [B], seen)``: ``vᵀG_b v / vᵀG v`` (the column scaling cancels in the ratio), and
        whether the data see the scale at all: ``vᵀG v`` above ``rtol·λ_max`` and above
        ``_SCALE_SEEN_FACTOR · rss``. ``shares`` is ``nan`` when ``v`` is zero (no free length).
    """
    grams = np.asarray(grams, np.float64)
    v = np.asarray(v, np.float64)
    total = grams.sum(0)
    d = np.sqrt(np.clip(np.diag(total), 0.0, None))
    vs = v * d  # the same direction in block_directions' column-scaled parameters
    norm = float(np.linalg.norm(vs))
    if not norm > 0:
        return np.full(grams.shape[0], np.nan), False
    inv = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
    Gs = grams * inv[None, :, None] * inv[None, None, :]
    u = vs / norm
    per = np.einsum("i,bij,j->b", u, Gs, u)
    along = float(per.sum())
    lam_max = float(np.linalg.eigvalsh(Gs.sum(0))[-1]) if Gs.size else 0.0
    seen = along > rtol * max(lam_max, 0.0) and float(v @ total @ v) > _SCALE_SEEN_FACTOR * rss
    shares = per / along if along > 0 else np.full(grams.shape[0], np.nan)
    return np.clip(shares, 0.0, 1.0), bool(seen)


def scale_line(stats) -> str | None:
    """The length-scale line of the block report (:attr:`BlockStats.scale_share`,
    :attr:`BlockStats.scale_seen`): ``"length scale: set by bar (98 % of the information along
    it)"`` (the blocks with ≥ 5 % named when none has 90 %), ``"length scale: not seen by any
    block (...)"``, or ``None`` where it is not known (a file written before it; no free length)."""
    if not stats or stats[0].scale_seen is None:
        return None
    if not stats[0].scale_seen:
        return _UNSEEN_SCALE
    shares = sorted(((s.name, s.scale_share) for s in stats if not math.isnan(s.scale_share)), key=lambda t: -t[1])
    if not shares:
        return None
    name, top = shares[0]
    if top >= 0.9:
        return f"length scale: set by {name} ({100 * top:.0f} % of the information along it)"
    return ("length scale: set by " + " and ".join(f"{n} ({100 * x:.0f} %)" for n, x in shares if x >= 0.05)
            + " (their shares of the information along it)")


_UNSEEN_SCALE = ("length scale: not seen by any block (scaling every length of the set-up keeps every reading: "
                 "the prior, a length held at nominal or a known length sets it)")


def who_sees_what(stats, threshold: float = 0.9, max_directions: int = 3, verdicts=None) -> tuple[str, ...]:
    """Lines naming, per block, the free parameters it alone (nearly) determines (information share
    ≥ ``threshold``, :attr:`BlockStats.information`), the directions of several parameters only it
    determines (:attr:`BlockStats.directions`; more than ``max_directions`` are counted, not listed:
    a block that carries nearly all the information determines most directions alone), what
    removing it leaves unidentifiable, which block sets the length scale (:func:`scale_line`) and
    the parameters no block dominates.

    ``verdicts``: the fit's :class:`~jaxcal._fit._verdicts.Verdicts`. A block's share of a
    parameter's information says which block sees it, not that the data determine it (plane data
    see ``d_1`` only together with the planes' offsets, so the prior holds it): with the verdicts
    the per-block lists name only the parameters the data determine, and the parameters the prior
    holds get lines of their own (:func:`~jaxcal._fit._verdicts.prior_lines`)."""
    from .._fit._verdicts import DATA, prior_lines

    by_data = (lambda n: True) if verdicts is None else (lambda n: verdicts.verdict.get(n) == DATA)  # noqa: E731
    lines, seen = [], set()
    for s in stats:
        own = [n for n, v in s.information.items() if v >= threshold and by_data(n)]
        seen |= set(own)
        if own:
            lines.append(f"{s.name} alone determines: {', '.join(own)}")
        if len(s.directions) > max_directions:
            lines.append(f"{s.name} alone determines {len(s.directions)} directions of several parameters")
        for share, terms in s.directions if len(s.directions) <= max_directions else ():
            lines.append(f"{s.name} alone determines the direction ({_direction(terms)}) "
                         f"({share:.1%} of its information)")
        if 0 <= s.rank_without < s.rank:
            lost = s.rank - s.rank_without
            lines.append(f"without {s.name}: {lost} direction{'s' if lost > 1 else ''} not identifiable "
                         f"(rank {s.rank_without} of {s.rank})")
    scale = scale_line(stats)
    if scale is not None:
        lines.append(scale)
    if stats:
        shared = [n for n in stats[0].information if n not in seen and by_data(n)]
        if verdicts is not None:
            lines += prior_lines(verdicts, list(stats[0].information))
        if shared:
            lines.append("shared by several blocks: " + ", ".join(
                f"{n} ({' / '.join(f'{s.name} {s.information[n]:.0%}' for s in stats if s.information[n] >= 0.05)})"
                for n in shared))
    return tuple(lines)


def combined_floor(n_params: int, n_residuals: int):
    """The statistical floor of a combined (whitened) problem: ``Floor(train, test)`` of the RMS
    whitened residual entry, ``sqrt(1 − p/N)`` and ``sqrt(1 + p/(N − p − 1))``
    (:func:`jaxcal.statistical_floor` with σ = 1): each block's residual over its true σ_b."""
    from .._core._metrics import statistical_floor

    return statistical_floor(1.0, n_params, n_residuals, 1)


def block_information(result, model: Combined, q, y, *, every: bool = False):
    """Each block's information matrix of the free parameters at a combined fit's solution.

    Args:
        result: a :class:`jaxcal.CalibrationResult` of ``model`` on ``(q, y)``.
        model: the :class:`~jaxcal._sensors._blocks.Combined` model; q ``[N, dof]`` rad; y ``[N, W]``.

    Returns:
        ``(r [N, m], grams [B, p, p])``: the whitened residual (unitless) and per block
        ``J_bᵀJ_b`` of the whitened Jacobian over ``result.space``'s free parameters
        (``p = n_free``; units 1/unit_i·1/unit_j of the parameters); masked entries count nowhere.
        With ``every``, ``grams`` is over every parameter of the layout (free or held).
    """
    r, grams = _information(result.robot, model, result.space, result.deviations, q, y)
    if every:
        return r, grams
    idx = result.space.free_index
    return r, grams[:, idx][:, :, idx]


def free_scale_direction(v, grams, free, rcond: float = 1e-10) -> np.ndarray:
    """The length-scale direction over the free parameters when some lengths are held: ``v``
    ``[P]`` over every parameter (:func:`length_scale_direction` of the whole layout), ``grams``
    ``[B, P, P]`` (:func:`block_information` with ``every=True``), ``free`` ``[P]`` bool. A held
    length that the free ones stand in for (``d_6`` beside ``tool_z``, ``d_3`` beside ``d_2`` on
    parallel axes, ``d_1`` beside plane offsets: why it is held) moves onto them:
    ``v_f + G_ff⁺ G_fh v_h`` (``G`` the blocks' total, column-scaled), the free step whose
    readings best match scaling the held lengths too. Returns ``[p]`` (the free entries)."""
    v = np.asarray(v, np.float64)
    free = np.asarray(free, bool)
    G = np.asarray(grams, np.float64).sum(0)
    f, h = np.flatnonzero(free), np.flatnonzero(~free)
    vf = v[f]
    if not h.size or not np.any(v[h]):
        return vf
    d = np.sqrt(np.clip(np.diag(G)[f], 0.0, None))
    inv = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
    Gff = G[np.ix_(f, f)] * inv[:, None] * inv[None, :]
    rhs = (G[np.ix_(f, h)] @ v[h]) * inv
    return vf + inv * (np.linalg.pinv(Gff, rcond=rcond, hermitian=True) @ rhs)


def block_statistics(result, model: Combined, q, y, prior_noise: float = 1.0) -> tuple[BlockStats, ...]:
    """Per-block σ̂ (variance components), redundancy, RMSE and information shares of a combined
    fit ``result`` (a :class:`jaxcal.CalibrationResult` of ``model`` on ``(q, y)``). Each block's
    redundancy is ``r_b = n_b − tr(A⁺ J_bᵀJ_b)`` (``n_b`` its real residual entries, ``A`` the
    whitened information ``Σ_b J_bᵀJ_b + Λ``, ``Λ`` the prior's precision): the sum of ``1 − h_ii``
    over its entries."""
    r, every = block_information(result, model, q, y, every=True)
    grams, A_inv, obs, red, sig_hat = _variance_components(model, result.space, result.prior, r, every, y,
                                                           prior_noise)
    col = np.diag(grams.sum(0))
    rank, ranks_without, directions = block_directions(grams, result.space.free_names)
    full = ParameterSpace.from_names(result.space.layout, result.space.layout.names)
    v = free_scale_direction(length_scale_direction(result.robot, model, result.deviations, full), every,
                             result.space.free)
    shares, seen = scale_shares(grams, v, rss=float(np.sum(r[obs] ** 2)))
    seen = None if np.all(np.isnan(shares)) else seen
    out = []
    sigma = np.asarray(model.sigma, np.float64)
    for b, (name, mod, rb, ob) in enumerate(zip(model.names, model.models, model._rows(r, r.shape[0]),
                                               model._rows(obs, r.shape[0]))):
        raw = rb[:, : mod.size] * sigma[b]  # its own unit
        ob = ob[:, : mod.size]
        err = row_errors(mod, raw)
        unit = "σ" if isinstance(mod, Relations) else getattr(mod, "unit", "mm")
        share = np.diag(grams[b]) / np.where(col > 0, col, 1.0)
        out.append(BlockStats(name, mod.kind, unit, rb.shape[0], int(ob.sum()), float(sigma[b]), False,
                              float(sig_hat[b]), float(red[b]),
                              float(np.sqrt(np.mean(err**2))), float(np.sqrt(np.mean(raw[ob] ** 2))),
                              float(np.mean(np.abs(err))), float(np.max(np.abs(err))),
                              dict(zip(result.space.free_names, share.tolist())), directions[b], ranks_without[b],
                              rank, float(shares[b]), seen))
    return tuple(out)


def _groups_of(model: Combined, b: int) -> dict[str, str]:
    """Block ``b``'s group → the combined group."""
    return dict(model.views[b][1])


def _block_groups(blk: Block, key: str) -> tuple[str, ...]:
    """The groups (in the block's own layout) that a block's extra ``key`` frees: ``tool`` is the
    tool point its model sees (``tool@<tip>`` on another tip of a kinematic tree)."""
    return (blk.measurement.tool_group,) if key == "tool" else _EXTRA_GROUPS[key]


def _extras_and_fix(robot, model: Combined, blocks: Sequence[Block]):
    """``(extras, fix)`` of :func:`jaxcal.calibrate` for the blocks' ``extras``: the standard groups a
    block asks for under their own name, and the renamed per-block groups nobody asked for."""
    plain, wanted = set(), set()
    for b, blk in enumerate(blocks):
        names = _groups_of(model, b)
        for e in blk.extras:
            key = e.strip().lower()
            if key not in _EXTRA_GROUPS:
                raise ValueError(f"block {blk.name!r}: unknown extra {e!r}; choose from tool, base, anchor, cable_offset")
            for g in _block_groups(blk, key):
                c = names[g]
                (plain if c == g and "@" not in c else wanted).add(c)
    extras = sorted({k for k, gs in _EXTRA_GROUPS.items() if k != "offset" and any(g in plain for g in gs)})
    std = {g.name for g in STANDARD_EXTRAS}
    layout = layout_for(robot, model)
    fix = [n for g in layout.groups if g.name.partition("@")[0] in std and g.name not in std and g.name not in wanted
           for n in g.names]
    return extras, fix


def _initial_start(robot, model: Combined, blocks: Sequence[Block], q, y, start: Deviations):
    """Each block's extras from its data in closed form (:func:`jaxcal.initial_extras`), in block
    order; a shared tool point is started by the first block that estimates it."""
    vals = dict(start.values)
    msgs = []
    tool_done = set()
    qs, ys = model._rows(np.asarray(q), q.shape[0]), model._rows(np.asarray(y), q.shape[0])
    for b, blk in enumerate(blocks):
        mod = blk.measurement
        names = _groups_of(model, b)
        asked = {g for e in blk.extras for g in _EXTRA_GROUPS.get(e.strip().lower(), ())}
        can = mod.initialisable
        est = [e for e in can if e in _OWN_INIT]
        est += [e for e in can if e not in _OWN_INIT and set(_EXTRA_GROUPS.get(e, (e,))) & asked]
        tool = names[mod.tool_group]  # the tool point this block sees, under its combined name
        if "tool" in est and tool in tool_done:
            est.remove("tool")
        if not est:
            continue
        view = model.view(b, Deviations(vals, start.layout))
        try:
            res = initial_extras(robot, mod, (qs[b], model._y(b, ys[b])), estimate=est, start=view)
        except ValueError as e:
            raise ValueError(f"block {blk.name!r}: {e}") from None
        for g, c in names.items():
            if res.deviations.layout.group(g).kind == "extra":
                vals[c] = np.asarray(res.deviations.values[g])
        if "tool" in est:
            tool_done.add(tool)
        msgs.append(f"{blk.name}: {res.message}")
    return Deviations(vals, start.layout, dtype=start.arrays[0].dtype), msgs


def calibrate_blocks(robot, blocks: Sequence[Block], relations: Sequence = (), method="lm", *,
                     start: Deviations | None = None, init: str = "auto", sigma_rtol: float = 0.01,
                     max_rounds: int = 10, **kwargs):
    """Calibrate ``robot`` from several data blocks at once, sharing the robot's parameters.

    Args:
        robot: nominal robot model.
        blocks: :class:`jaxcal.Block` s (name, measurement model, data, σ or ``None``, extras).
        relations: known relations between labelled extras (:class:`jaxcal.KnownDistance`,
            :class:`jaxcal.PlaneDistance`, :class:`jaxcal.PlaneAngle`, :class:`jaxcal.PointOnPlane`).
        method: as :func:`jaxcal.calibrate` (least-squares methods estimate the variance
            components; any method fits).
        start: starting deviations in the combined layout (default nominal + ``init``).
        init: ``"auto"``: each block's extras started in closed form from its data; ``"none"``.
        sigma_rtol: stop the variance-component rounds when no estimated σ moves by more than this.
        max_rounds: at most this many fits.
        **kwargs: :func:`jaxcal.calibrate`'s other arguments (``prior``, ``loss``, ``objective``,
            ``free``, ``fix``, ``space``, ``checks``...). Its σ-dependent parts (the prior's weight,
            the robust scale) act on the whitened residuals, where σ = 1 at the truth.

    Returns:
        The :class:`jaxcal.CalibrationResult` of the last fit (its measurement the
        :class:`~jaxcal._sensors._blocks.Combined` model, its train metrics whitened), with
        ``blocks`` (:class:`BlockStats` per block, the relations last), ``sigma`` (``{block: σ}``
        of the last fit, each block's unit), ``variance_rounds`` (the fits run),
        ``block_messages`` (the closed-form starts) and ``block_report`` (which block determines
        which parameter: :func:`who_sees_what`). Its ``start`` is the first fit's start (the
        nominal robot with each block's extras from its data, as ``init`` made them), not the
        last round's: the "before" of each block's accuracy table (:func:`block_result`,
        :func:`~jaxcal._calibration._evaluate.before_after_errors`).

    Raises:
        ValueError: naming the block or relation at fault (see :func:`combine`).
    """
    from ._calibrate import calibrate

    blocks = tuple(blocks)
    for blk in blocks:  # each block's data as calibrate would check them alone (shapes, units, NaN)
        qb, yb = blk.arrays()
        if not hasattr(blk.data, "q"):
            try:
                Dataset(qb, yb, blk.measurement.kind, mm_joints_metadata(robot))
            except ValueError as e:
                raise ValueError(f"block {blk.name!r}: {e}") from None
    model, q, y = combine(robot, blocks, relations)
    model = model.estimating(sigma_rtol, max_rounds)  # its σ's rounds: jaxcal.calibrate's reweighting
    extras, fix = _extras_and_fix(robot, model, blocks)
    user_fix = kwargs.pop("fix", ())
    user_fix = [s for s in user_fix.split(",") if s.strip()] if isinstance(user_fix, str) else list(user_fix or ())
    user_extras = kwargs.pop("extras", ())
    if user_extras:
        raise TypeError("calibrate_blocks takes the extras per block (Block(..., extras=...)), not extras=")
    layout = layout_for(robot, model)
    cur = Deviations.zeros(layout) if start is None else start
    msgs = []
    if init == "auto":
        cur, msgs = _initial_start(robot, model, blocks, q, y, cur)
    elif init != "none":
        raise ValueError(f"init must be 'auto' or 'none', got {init!r}")
    # one calibrate: its rounds re-estimate the blocks' σ (variance components) with the prior's
    # noise σ and the robust scale, after one selection, diagnosed once at the end
    res = calibrate(robot, model, (to_device(q), to_device(y)), method, start=cur, init="none", extras=extras,
                    fix=[*fix, *user_fix], **kwargs)
    stats = block_statistics(res, res.measurement, q, y)
    from .._fit._diagnostics import Checks, given_noise_std
    from ._calibrate import StatedNoiseWarning

    stated = [given_noise_std(blk.data, None, blk.measurement) for blk in blocks] + [None]  # the files' lines
    stats = tuple(dataclasses.replace(s, sigma_given=not est, sigma_stated=st)
                  for s, est, st in zip(stats, res.measurement.estimated, stated))
    factor = (kwargs.get("checks") or Checks()).noise_warn_factor
    for s in stats:  # a block far above the noise its file states: another set-up, or a wrong noise line
        msg = s.noise_warning(factor=factor)
        if msg is not None:
            warnings.warn(msg, StatedNoiseWarning, stacklevel=2)
    object.__setattr__(res, "blocks", stats)
    object.__setattr__(res, "sigma", {s.name: s.sigma for s in stats})
    object.__setattr__(res, "variance_rounds", res.diagnostics.rounds)
    object.__setattr__(res, "block_messages", tuple(msgs))
    object.__setattr__(res, "block_report", who_sees_what(stats, verdicts=res.diagnostics.verdicts))
    return res


def block_result(result, name: str):
    """Block ``name``'s part of a combined result (:func:`calibrate_blocks`) as a one-sensor
    :class:`jaxcal.CalibrationResult`: its own measurement model, the robot's parameters and the
    block's extras under their own names (``base_rotation@tracker`` → ``base_rotation``), its
    train metrics in its unit (:class:`BlockStats`), and the posterior covariance of its free
    parameters taken from the combined fit (σ̂ = the block's σ). :func:`jaxcal.save_result`,
    ``jaxcal evaluate`` and :meth:`~jaxcal.CalibrationResult.predict` read it like any result.

    Raises ``KeyError`` for an unknown block, ``ValueError`` for the relations block."""
    from .._core._metrics import Metrics
    from .._core._params import ParameterSpace
    from .._fit._diagnostics import Uncertainty
    from .._fit._result import CalibrationResult

    model = result.measurement
    if not isinstance(model, Combined) or not hasattr(result, "blocks"):
        raise TypeError("block_result takes a result of jaxcal.calibrate_blocks")
    b = model.block_index(name)
    if model.views[b] is None:
        raise ValueError("the relations block has no result of its own: it has no measurement model")
    layout = model.views[b][0]
    to_comb = model.names_in(b, result.space.layout)
    free_c = set(result.space.free_names)
    space = ParameterSpace.from_names(layout, [n for n in layout.names if to_comb[n] in free_c])
    dev = model.view(b, result.deviations)
    stats = {s.name: s for s in result.blocks}[name]
    out = CalibrationResult(
        method=result.method, deviations=dev, x=space.to_vector_numpy(dev), space=space, robot=result.robot,
        measurement=model.models[b], history=result.history, n_iterations=result.n_iterations,
        iterations_to_converge=result.iterations_to_converge, status=result.status,
        train_metrics=Metrics(stats.rmse, stats.mean, stats.max), wall_time_s=result.wall_time_s,
        compile_time_s=result.compile_time_s, hyperparameters=result.hyperparameters, prior=result.prior,
        loss=result.loss, start=None if result.start is None else model.view(b, result.start))
    unc = getattr(result, "uncertainty", None)
    if unc is not None:
        idx = [unc.names.index(to_comb[n]) for n in space.free_names]
        cov = np.asarray(unc.covariance)[np.ix_(idx, idx)]
        unc = Uncertainty(space.free_names, space.free_units, np.asarray(unc.std)[idx], cov, stats.sigma,
                          float(len(idx)), stats.n_residuals)
    object.__setattr__(out, "uncertainty", unc)
    object.__setattr__(out, "identifiability", None)
    diag = getattr(result, "diagnostics", None)
    if diag is not None and diag.verdicts is not None:  # the combined fit's verdicts under the block's names
        diag = dataclasses.replace(diag, verdicts=diag.verdicts.renamed(to_comb))
    object.__setattr__(out, "diagnostics", diag)
    return out


# -- one JSON for a combined result ---------------------------------------------------------------
#: the format tag of :func:`save_combined_result` files
COMBINED_FORMAT = "jaxcal-combined/2"


def _stats_to_dict(s: BlockStats) -> dict:
    return {f.name: getattr(s, f.name) for f in dataclasses.fields(BlockStats)}


def _stats_from_dict(d: dict) -> BlockStats:
    from .._core._json import from_json_number

    names = {f.name for f in dataclasses.fields(BlockStats)}
    kw = {k: v for k, v in d.items() if k in names}
    for k in ("sigma", "sigma_hat", "redundancy", "rmse", "rms", "mean", "max", "scale_share"):
        if k in kw:
            kw[k] = from_json_number(kw[k])
    kw["directions"] = tuple((float(share), tuple((float(c), str(n)) for c, n in terms))
                             for share, terms in kw.get("directions", ()))
    return BlockStats(**kw)


def combined_result_to_dict(result, block_info: dict | None = None, **info) -> dict:
    """A :func:`calibrate_blocks` result as one JSON-friendly object: per block its statistics
    (:class:`BlockStats`) and, for each data block, its one-sensor result
    (:func:`block_result` as :func:`jaxcal.save_result` writes it: the robot, the block's extras
    under their own names, its measurement model, posterior covariance; ``block_info[name]``'s
    entries added to it, as :func:`jaxcal.save_result`'s ``info``: ``jaxcal calibrate
    --combine`` gives each block's ``settings``, before/after ``metrics_mm`` and per-row errors
    ``rows``, which ``jaxcal report`` draws); the relations (kind and fields), each block's σ, the
    free parameters, every deviation (rad, mm) and the who-sees-what lines; plus ``info`` entries
    (e.g. ``settings=``) under their names."""
    from .._core._json import to_jsonable
    from ._io import result_to_dict

    model = result.measurement
    if not isinstance(model, Combined) or not hasattr(result, "blocks"):
        raise TypeError("combined_result_to_dict takes a result of jaxcal.calibrate_blocks")
    blocks = []
    for s in result.blocks:
        entry = _stats_to_dict(s)
        if model.views[model.block_index(s.name)] is not None:
            entry["result"] = result_to_dict(block_result(result, s.name), **(block_info or {}).get(s.name, {}))
        blocks.append(entry)
    rel = model.relations
    out = {"format": COMBINED_FORMAT, "robot": result.robot.name, "status": result.status.name.lower(),
           "method": result.method, "blocks": blocks, "sigma": result.sigma,
           "relations": [] if rel is None else [{"kind": r.kind, **dataclasses.asdict(r)} for r in rel.relations],
           "free_names": list(result.space.free_names), "deviations": result.deviations.named(),
           "variance_rounds": result.variance_rounds, "who_sees_what": list(result.block_report),
           "train_metrics_whitened": result.train_metrics._asdict()}
    return to_jsonable(out | info)


def save_combined_result(result, path, block_info: dict | None = None, **info) -> None:
    """Write a :func:`calibrate_blocks` result as one JSON file (:func:`combined_result_to_dict`,
    ``block_info`` and ``info`` as there); :func:`load_combined_result` reads it back."""
    import json
    import pathlib

    text = json.dumps(combined_result_to_dict(result, block_info, **info), indent=1, allow_nan=False)
    pathlib.Path(path).write_text(text + "\n", encoding="utf-8")


@dataclasses.dataclass(frozen=True)
class CombinedResult:
    """A combined result read back by :func:`load_combined_result`.

    Attributes:
        results: ``{block: CalibrationResult}`` of the data blocks (each as :func:`block_result`
            made it: predicts, evaluates and saves like a one-sensor result).
        blocks: the blocks' :class:`BlockStats` (the relations last, if any).
        relations: the relation objects (:class:`jaxcal.KnownDistance`...).
        sigma: ``{block: σ}`` of the final fit (each block's unit).
        deviations: ``{name: value}`` every deviation of the combined layout (rad, mm).
        free_names: the combined fit's free parameters.
        block_report: the who-sees-what lines (:func:`who_sees_what`).
        raw: the whole JSON object (status, method, rounds, ``info`` entries).
    """

    results: dict
    blocks: tuple
    relations: tuple
    sigma: dict
    deviations: dict
    free_names: tuple
    block_report: tuple
    raw: dict = dataclasses.field(repr=False)


def load_combined_result(path) -> CombinedResult:
    """Read a file of :func:`save_combined_result` (``jaxcal calibrate --combine``'s
    ``combined.json``). Raises ``ValueError`` naming the file if it is not one."""
    import json
    import pathlib

    from .._sensors._blocks import RELATIONS
    from ._io import result_from_dict

    try:
        d = json.loads(pathlib.Path(path).read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise ValueError(f"{path} is not a JSON file: {e}") from None
    if not isinstance(d, dict) or d.get("format") != COMBINED_FORMAT:
        raise ValueError(f"{path} is not a jaxcal combined result (no 'format': {COMBINED_FORMAT!r} entry)")
    kinds = {c.kind: c for c in RELATIONS}
    relations = []
    for r in d.get("relations", []):
        r = dict(r)
        cls = kinds.get(r.pop("kind", None))
        if cls is None:
            raise ValueError(f"{path}: unknown relation {r!r}")
        relations.append(cls(**r))
    results = {b["name"]: result_from_dict(b["result"], f"{path}, block {b['name']!r}")
               for b in d["blocks"] if "result" in b}
    return CombinedResult(results, tuple(_stats_from_dict(b) for b in d["blocks"]), tuple(relations),
                          dict(d["sigma"]), dict(d["deviations"]), tuple(d["free_names"]),
                          tuple(d.get("who_sees_what", ())), d)
