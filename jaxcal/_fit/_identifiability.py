"""Which parameters the data can identify: rank, singular values and an identifiable subset."""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._core._buckets import LeanJit, cache_size, pad_model_rows
from .._core._params import Deviations, ParameterSpace, layout_for
from .._core._precision import to_device
from .._core._xla import computed_once, jit
from .._models._abstract import AbstractRobot
from .._models._kinematics import shared_joint_trig
from .._sensors._measurement import MeasurementModel
from ._problem import Problem, value_and_jacfwd
from ._verdicts import DATA, HELD, UNDETERMINED, Verdicts, prior_lines

__all__ = ["IdentifiabilityReport", "identifiability", "KEEP_PREFERENCE", "default_rtol", "select_free",
           "STILL_JOINT_DEG", "still_joints"]

#: Which of a group of (exactly) dependent parameters is kept free: the parameter whose group
#: comes first here, then the lower joint index / component order, then the earlier entry of the
#: layout (e.g. the first session's frame of :class:`~jaxcal.SessionMarkers`, whose per-label
#: groups ``base_rotation@F``... rank as their groups here). The sensor/set-up **extras come
#: first**: where a robot parameter and an extra act alike (a tool offset along the flange x axis
#: and Δa_6; a rotation of the anchor about z_0 and Δθ_1), the robot parameter is held at its
#: nominal value — it has one, and a tight prior — and the extra, whose size nobody knows, carries
#: the effect. Among the robot's parameters the joint offsets θ come first, because encoder zero
#: offsets are what a calibration is most often for. Generic chains (:class:`~jaxcal.SerialChain`)
#: follow the same idea: joint offsets, then the origins' translations dx, dy, dz, then their
#: rotations drx, dry, drz, then the tip transform's translation (tip_dx, tip_dy, tip_dz) and
#: rotation (tip_drx, tip_dry, tip_drz): an error the last joint's origin can carry stays there.
#: Other extras (marker positions) rank after ``base_translation``, other robots' geometric
#: groups after β, the non-geometric groups after every geometric one.
KEEP_PREFERENCE: tuple[str, ...] = (
    "anchor", "tool", "cable_offset", "base_rotation", "base_translation",
    "theta", "d", "a", "alpha", "beta", "offset", "dx", "dy", "dz", "drx", "dry", "drz",
    "tip_translation", "tip_rotation",
)
#: a dependent parameter is swapped for a less preferred kept one only if its (column-scaled)
#: coefficient on that one is at least this large: the swap then keeps the subset about as well
#: conditioned (the volume of the kept columns shrinks by at most this factor).
_SWAP_MIN_COEF = 0.1


#: a revolute joint whose readings span less than this (degrees) counts as near-still: what only its
#: motion would show is judged as if it stood still (see :func:`still_joints`).
STILL_JOINT_DEG = 3.0


def still_joints(robot, q, still_deg: float = STILL_JOINT_DEG) -> tuple[int, ...]:
    """1-based revolute joints whose readings ``q`` ``[n, dof]`` (rad) span less than ``still_deg``
    degrees: near-still joints.

    A joint that barely moves (a 1.5° span on a real tracker set) still makes the identification
    Jacobian full rank in exact arithmetic, but what only its motion shows — the parameters of the
    joint's own link, which otherwise act exactly like the sensor frame — is seen through a few
    hundredths of a radian of motion: least squares fits the noise and the unmodelled errors with
    them (a₁ drifted to +94 mm with predictions equal to a fit that held it). Prismatic joints are
    not judged."""
    qn = np.asarray(q, np.float64)
    if qn.shape[0] < 2:
        return ()
    units = tuple(robot.joint_units())
    span = np.rad2deg(np.ptp(qn, axis=0))
    return tuple(j + 1 for j in range(qn.shape[1]) if units[j] == "rad" and span[j] < still_deg)


def default_rtol(dtype) -> float:
    """The relative singular-value threshold for the rank: 1e-9 in float64, 1e-4 in float32
    (a float32 Jacobian carries ~1e-6 relative round-off, which gives spurious singular values
    of that size to exactly dependent columns)."""
    return 1e-4 if np.dtype(dtype) == np.float32 else 1e-9


#: where groups missing from :data:`KEEP_PREFERENCE` rank, by kind: other extras (e.g. markers)
#: after the standard ones, other robots' geometric groups after β, non-geometric groups last
_KIND_RANK = {"extra": KEEP_PREFERENCE.index("base_translation") + 0.5,
              "geometric": KEEP_PREFERENCE.index("beta") + 0.5, "nongeometric": len(KEEP_PREFERENCE) + 0.7}


#: the built-in non-geometric groups (:mod:`jaxcal._models._nongeometric`) rank after every group of
#: :data:`KEEP_PREFERENCE`: compliance (a physical model with a mass
#: model) first, then the harmonic transmission errors, once-per-revolution before twice
NONGEOMETRIC_PREFERENCE: tuple[str, ...] = ("compliance", "h1s", "h1c", "h2s", "h2c")


@functools.lru_cache(maxsize=4096)
def _preference_key(name: str) -> tuple[float, int]:
    from .._core._params import group_kind, group_of

    full = group_of(name)
    g = full.split("@", 1)[0]  # per-session groups rank as their group
    tail = name.split("@", 1)[0].rsplit("_", 1)[-1]
    order = int(tail) if tail.isdigit() else {"x": 1, "y": 2, "z": 3, "rx": 1, "ry": 2, "rz": 3, "dx": 1, "dy": 2,
                                              "dz": 3, "drx": 1, "dry": 2, "drz": 3}.get(tail, 0)
    if g in NONGEOMETRIC_PREFERENCE:
        rank = len(KEEP_PREFERENCE) + 0.01 * NONGEOMETRIC_PREFERENCE.index(g)
    else:
        rank = KEEP_PREFERENCE.index(g) if g in KEEP_PREFERENCE else _KIND_RANK[group_kind(full)]
    return rank, order


@dataclasses.dataclass(frozen=True)
class IdentifiabilityReport:
    """Result of :func:`identifiability`.

    Attributes:
        names: the free parameters examined (length ``p``).
        rank: numerical rank of the column-scaled identification Jacobian.
        singular_values: ``[p]`` singular values of the column-scaled Jacobian, descending.
        identifiable: names of a maximal identifiable subset: QR with column pivoting finds
            one, then within each group of dependent parameters the ones first in
            :data:`KEEP_PREFERENCE` order are kept (θ, d, a, α, β, then the extras; lower joint
            first), so the choice does not depend on round-off or the data.
        unidentifiable: the other names; each is (locally) a combination of identifiable ones.
        dependencies: for each unidentifiable name, ``[(coefficient, name), ...]`` such that a
            change ``δ`` of it has the same first-order effect as changing each listed
            parameter by ``coefficient·δ`` (physical units: mm/rad, rad/mm, mm/mm, rad/rad, as
            printed); empty if it has no effect at all.
        condition_number: condition number of the column-scaled Jacobian restricted to the
            identifiable subset.
        space: :class:`ParameterSpace` with only the identifiable subset free (the default mask
            of :func:`jaxcal.calibrate`).
        rtol: relative singular-value threshold used for the rank.
        prior_covered: the names with a finite prior σ when the report was made for a
            maximum-a-posteriori fit (``prior_std=``), else empty. Under a prior every one of them
            is free (the prior makes the directions the data cannot see well posed); of the
            others only a subset the data identify on its own is free (:func:`select_free`).
        still_joints: 1-based joints that barely move in the data (:func:`still_joints`); rank,
            subset and dependencies are then those of the data with these joints standing still
            at their mean reading.
        still_unseen: the names the data would identify only through the near-still joints'
            motion (identifiable with the readings as they are, not with those joints still):
            held at their start, with or without a prior.
        verdicts: the verdict of each parameter after a fit (:class:`~jaxcal._fit._verdicts.Verdicts`:
            determined by the data, held by the prior, not calibrated), which ``str()`` then
            reports in place of the rank test's subset; ``None`` before a fit. The rank test picks
            one of each group of dependent parameters (``d_2`` of ``d_2``, ``d_3``), while under a
            prior neither is determined by the data alone: the verdict says so.
    """

    names: tuple[str, ...]
    rank: int
    singular_values: np.ndarray
    identifiable: tuple[str, ...]
    unidentifiable: tuple[str, ...]
    dependencies: dict
    condition_number: float
    space: ParameterSpace
    rtol: float
    prior_covered: tuple[str, ...] = ()
    still_joints: tuple[int, ...] = ()
    still_unseen: tuple[str, ...] = ()
    verdicts: Verdicts | None = dataclasses.field(default=None, repr=False)

    @property
    def held(self) -> tuple[str, ...]:
        """The candidates held at their start value: neither the data nor a prior determine them."""
        free = set(self.space.free_names)
        return tuple(n for n in self.names if n not in free)

    def _describe(self, n: str) -> str:
        """The dependency line of a left-out parameter: what a change of it acts like."""
        unit = dict(zip(self.space.layout.names, self.space.layout.units))
        deps = self.dependencies.get(n, [])
        if not deps:
            return f"  {n}: has no effect on the measurements"
        combo = " ".join(f"{c:+.4g} {unit[m]}/{unit[n]}·{m}" for c, m in deps)
        return (f"  {n}: a change δ acts like {combo}·δ" if len(deps) == 1
                else f"  {n}: a change δ acts like ({combo})·δ")

    def _verdict_lines(self) -> list[str]:
        """The lines after a fit: each candidate's verdict (:attr:`verdicts`), the dependencies
        explaining what the prior holds or what is held at its start."""
        v = self.verdicts
        of = {n: v.verdict.get(n, HELD) for n in self.names}
        lines = ["determined by the data: " + (", ".join(n for n in self.names if of[n] == DATA) or "none")]
        left_out = set(self.unidentifiable)
        lines += prior_lines(v, self.names, lambda n: self._describe(n) if n in left_out else None)
        undetermined = [n for n in self.names if of[n] == UNDETERMINED]
        if undetermined:
            lines.append("determined neither by the data nor by a prior (σ infinite): " + ", ".join(undetermined))
        if self.still_joints:
            lines.append(f"joint(s) {', '.join(str(j) for j in self.still_joints)} barely move in the data: judged as "
                         "standing still" + (f"; seen only through their motion, held at their start value: "
                                             f"{', '.join(self.still_unseen)}" if self.still_unseen else ""))
        held = [n for n in self.names if of[n] == HELD]
        if held:
            lines.append("not calibrated (*), held at their start value: " + ", ".join(held))
            lines += [self._describe(n) for n in held if n in left_out]
        return lines

    def __str__(self) -> str:
        lines = [
            f"identification Jacobian rank {self.rank} of {len(self.names)} candidate parameters "
            f"(column-scaled, rtol={self.rtol:g}); condition number of the identifiable "
            f"subset {self.condition_number:.3g}",
        ]
        if self.verdicts is not None:
            return "\n".join(lines + self._verdict_lines())
        lines.append("identifiable from the data: " + ", ".join(self.identifiable))
        covered = set(self.prior_covered)
        held = set(self.held)
        describe = self._describe

        by_prior = [n for n in self.unidentifiable if n in covered and n not in held]
        if by_prior:
            lines.append("not identifiable from the data alone, estimated under the prior (maximum a posteriori; "
                         "the prior sets these directions):")
            lines += [describe(n) for n in by_prior]
        if self.still_joints:
            lines.append(f"joint(s) {', '.join(str(j) for j in self.still_joints)} barely move in the data: judged as "
                         "standing still" + (f"; seen only through their motion, held at their start value: "
                                             f"{', '.join(self.still_unseen)}" if self.still_unseen else ""))
        fixed = [n for n in self.unidentifiable if n in held]
        if fixed:
            lines.append("not identifiable and without a prior (held at their start value):")
            lines += [describe(n) for n in fixed]
        extra_free = [n for n in self.space.free_names if n not in set(self.identifiable) and n not in covered]
        if extra_free:  # pragma: no cover - select_free never frees a no-prior name the data cannot see
            lines.append("free: " + ", ".join(extra_free))
        return "\n".join(lines)

    def unseen_directions(self, names) -> np.ndarray:
        """``[len(names), k]``: the directions the data cannot see, over the parameters ``names``
        (physical units): per left-out parameter ``j``, ``e_j − Σ_k c_jk e_k`` with its
        :attr:`dependencies` (a change of ``j`` acts like changing each ``k`` by ``c_jk`` times
        it), the entries outside ``names`` left out; none for a left-out parameter not in
        ``names`` (held)."""
        at = {n: i for i, n in enumerate(names)}
        cols = []
        for j in self.unidentifiable:
            if j not in at:
                continue
            v = np.zeros(len(at))
            v[at[j]] = 1.0
            for c, k in self.dependencies.get(j, []):
                if k in at:
                    v[at[k]] -= c
            cols.append(v)
        return np.stack(cols, axis=1) if cols else np.zeros((len(at), 0))

    def equivalent(self, deviations, held=None) -> np.ndarray:
        """The values ``[p_identifiable]`` the identifiable parameters take when the unidentifiable
        ones are held at ``held`` (default zero; a calibration holds them at its start,
        ``result.start``) and ``deviations`` is the truth, to first order:
        ``x_k + Σ_j coefficient_jk·(x_j − held_j)`` over the dependencies. This is what a
        calibration of the identifiable subset estimates (compare estimates with it, not with the
        raw truth)."""
        names = list(self.space.names)
        flat = np.asarray(deviations.ravel(), np.float64)
        base = np.zeros_like(flat) if held is None else np.asarray(held.ravel(), np.float64)
        value = {n: flat[names.index(n)] for n in self.names}
        out = {n: value[n] for n in self.identifiable}
        for dropped, deps in self.dependencies.items():
            for coef, kept in deps:
                out[kept] += coef * (value[dropped] - base[names.index(dropped)])
        return np.asarray([out[n] for n in self.identifiable])

    def to_dict(self) -> dict:
        """JSON-friendly summary."""
        return {
            "rank": self.rank,
            "n_free": len(self.names),
            "singular_values": [float(s) for s in self.singular_values],
            "identifiable": list(self.identifiable),
            "unidentifiable": list(self.unidentifiable),
            "dependencies": {k: [[float(c), n] for c, n in v] for k, v in self.dependencies.items()},
            "condition_number": self.condition_number,
            "rtol": self.rtol,
            "free": list(self.space.free_names),
            "held": list(self.held),
            "prior_covered": list(self.prior_covered),
            "still_joints": list(self.still_joints),
            "still_unseen": list(self.still_unseen),
        }


def _prefer(Rs: np.ndarray, keep: list[int], pref: list) -> np.ndarray:
    """Swap kept columns of ``Rs`` (unit-norm columns) for left-out ones that come earlier in
    the preference order ``pref`` and depend on them (scaled coefficient ≥ _SWAP_MIN_COEF).
    Each swap makes the kept set strictly earlier in preference order, so this terminates; the
    span (and the rank) of the kept columns is unchanged up to round-off. The coefficients of
    all left-out columns come from one least-squares solve per kept set."""
    p = Rs.shape[1]
    keep = list(keep)
    acts = np.any(Rs != 0, axis=0)  # columns with an effect (the others have nothing to swap for)
    for _ in range(p * p):
        kept = set(keep)
        out = [j for j in sorted((i for i in range(p) if i not in kept), key=lambda i: pref[i]) if acts[j]]
        if not keep or not out:
            break
        coefs, *_ = np.linalg.lstsq(Rs[:, keep], Rs[:, out], rcond=None)
        for col, j in enumerate(out):
            worse = [(pref[k], i) for i, k in enumerate(keep)
                     if pref[k] > pref[j] and abs(coefs[i, col]) >= _SWAP_MIN_COEF]
            if worse:
                _, i = max(worse)
                keep[i] = j
                break
        else:
            break
    return np.asarray(sorted(keep), dtype=int)


def _householder(A: Array, pivot: bool) -> tuple[Array, Array]:
    """Householder QR of ``A`` ``[N, p]`` (``N ≥ p``) in XLA operations (``lax.fori_loop`` over
    the columns): ``(R [p, p], piv [p])`` with ``A[:, piv] = QR``. With ``pivot``, each step first
    brings the column with the largest remaining norm to the front (Businger & Golub, 1965;
    LAPACK ``geqp3``'s rule, the first on ties; norms recomputed, not downdated); without it
    ``piv`` is the identity. Works on ``Aᵀ``, so that each reflection reads and updates contiguous
    rows (1600 × 24: 0.28 instead of 0.41 ms on a 2-core CPU)."""
    n, p = A.shape
    entries, cols = jnp.arange(n), jnp.arange(p)

    def reflect(k, carry):
        At, piv = carry  # row i of At: column i of A
        if pivot:
            norms = jnp.sum(jnp.where(entries >= k, At * At, 0.0), axis=1)
            j = jnp.argmax(jnp.where(cols >= k, norms, -1.0))
            swap = cols.at[k].set(j).at[j].set(k)
            At, piv = At[swap], piv[swap]
        x = jnp.where(entries >= k, At[k], 0.0)
        alpha = jnp.sqrt(jnp.sum(x * x))
        v = x.at[k].add(jnp.where(x[k] >= 0, alpha, -alpha))
        vv = jnp.sum(v * v)
        beta = jnp.where(vv > 0, 2.0 / jnp.where(vv > 0, vv, 1.0), 0.0)
        return At - beta * jnp.outer(At @ v, v), piv

    At, piv = jax.lax.fori_loop(0, p, reflect, (A.T, cols))
    return jnp.triu(At[:, :p].T), piv


def householder_r(A: Array) -> Array:
    """The triangular factor ``R`` ``[p, p]`` of ``A = QR`` (``A`` ``[N, p]``, ``Q`` orthonormal
    ``[N, p]``), by Householder reflections written in XLA operations (``lax.fori_loop`` over the
    ``p`` columns; for ``N < p`` the rows are padded with zeros).

    Backward stable like LAPACK's ``geqrf``, but no LAPACK call: on a shared 2-core machine the
    multithreaded LAPACK QR of the tall identification Jacobian (NumPy's or ``jnp.linalg.qr``'s)
    took 0.1–0.3 s per call instead of 0.2–0.4 ms, its threads waiting for cores that XLA's
    thread pool and other processes held. Jittable; ``R``'s diagonal signs are not normalised.
    """
    n, p = A.shape
    if n < p:
        A = jnp.concatenate([A, jnp.zeros((p - n, p), A.dtype)])
    return _householder(A, pivot=False)[0]


def pivot_triangular(R0: Array) -> tuple[Array, Array]:
    """QR with column pivoting (Businger & Golub, 1965; LAPACK ``geqp3``'s rule) of a matrix given
    by its triangular factor ``R₀`` ``[p, p]`` (``A = Q₀R₀``): returns ``(R, piv)`` with
    ``A[:, piv] = Q R``. ``R₀`` has ``A``'s column norms, inner products and singular values, so
    pivoting it picks the columns pivoting ``A`` would, at ``p×p`` cost instead of ``N×p`` per
    step. Jittable (XLA operations, see :func:`householder_r`)."""
    return _householder(jnp.asarray(R0), pivot=True)


@jit
def _pivoted_qr(A):
    return pivot_triangular(householder_r(A))


def pivoted_qr(A) -> tuple[np.ndarray, np.ndarray]:
    """``(R [p, p], piv [p])`` as NumPy with ``A[:, piv] = Q R`` for a tall ``A`` ``[N, p]``:
    :func:`householder_r`, then :func:`pivot_triangular` of its factor, in one XLA program."""
    R, piv = _pivoted_qr(jnp.asarray(A, jnp.result_type(float)))
    return np.asarray(R, np.float64), np.asarray(piv)


def _start_factor(robot, measurement, q, deviations, space, y=None, weight=None):
    """Column norms ``d`` ``[p]`` of the identification Jacobian at the start and the pivoted
    triangular factor of its column-scaled ``J/d`` (:func:`householder_r`, then
    :func:`pivot_triangular`; ``(R, piv)``), in one compiled program, with the prediction at the
    start as the "measured" sample; the ``N×p`` Jacobian stays on the device. With measurements ``y``,
    also their residual blocks ``[n, m]`` at the start (what :func:`jaxcal.calibrate` scans
    first; the kinematics are shared) and, where it does not depend on the readings
    (:attr:`~jaxcal.MeasurementModel.jacobian_free_of_data`), the Jacobian ``[N, p]`` itself (the
    start Jacobian of the fit); else ``None`` for each. ``weight``: ``[n]`` 0 on padding rows
    (shape buckets), whose Jacobian rows are then zero (the factor is the real rows')."""
    # the measured sample only enters a pose residual's orientation part (δθ from R_mᵀR_p): take
    # the prediction itself, not zeros (a zero "rotation" would hide the orientation entirely);
    # where the Jacobian does not depend on the readings, take the readings (the residual there
    # is then the Jacobian pass's own primal)
    free = y is not None and measurement.jacobian_free_of_data
    with shared_joint_trig(q):  # one cos/sin of q for the prediction, the Jacobian and the residuals
        sample = jnp.asarray(y, q.dtype) if free else measurement.predict(robot, deviations, q).astype(q.dtype)
        problem = Problem(robot, measurement, q, sample.reshape(q.shape[0], *measurement.sample_shape), space,
                          deviations, weight)
        # J has three uses below (norms, the scaled copy, the output): computed once, not per use
        r, J = computed_once(value_and_jacfwd(problem.residual, problem.x0(), q), q[0, 0])
        if y is None:
            resid = None
        elif free:
            resid = problem.to_blocks(r)
        else:
            resid = measurement.residual(robot, deviations, q, jnp.asarray(y, q.dtype))
    d = jnp.sqrt(jnp.sum(J * J, axis=0))
    # a column the data cannot see may come out at round-off size (e.g. θ_1 under distance data, where
    # two tool points' derivatives cancel): scaled by its own norm it would look like a unit column
    # of noise, independent of the others. Take it as zero.
    d = jnp.where(d > 1e-10 * jnp.max(d), d, 0.0)
    R, piv = pivot_triangular(householder_r(J / jnp.where(d > 0, d, 1.0)))
    return d, R, piv, resid, (J if free else None)


#: compiled once per (models, parameter space, bucket of sample counts): an LRU of executables
_start_factor = LeanJit(_start_factor, static_argnames=("space",), maxsize=cache_size("identifiability", 16))


def identifiability(
    robot: AbstractRobot,
    measurement: MeasurementModel,
    q,
    space: ParameterSpace | None = None,
    deviations: Deviations | None = None,
    *,
    rtol: float | None = None,
    prior=None,
) -> IdentifiabilityReport:
    """Rank, singular values and an identifiable subset of the free parameters.

    With a ``prior`` (a :class:`~jaxcal.Prior`, ``"default"`` or a ``"key=value,..."`` string)
    the report is that of a maximum-a-posteriori fit: its ``space`` frees every candidate the
    prior covers and the data-identifiable subset of the others (:func:`select_free`); what the
    data alone identify is reported as without it.

    The identification Jacobian ``J = ∂residual/∂Δ`` ``[n·m, p]`` (``jax.jacfwd``) is taken at
    ``deviations`` (nominal by default) for joint angles ``q`` ``[n, dof]``; its columns are
    scaled to unit norm so that mm and rad columns compare. The rank counts singular values
    above ``rtol·s_max`` (default :func:`default_rtol`: 1e-9 in float64, 1e-4 in float32);
    QR with column pivoting picks a maximal well-conditioned subset; then, as long as a left-out
    parameter depends on a kept one that comes later in :data:`KEEP_PREFERENCE` (coefficient
    ≥ 0.1 on the scaled columns), the two are swapped — so of d2/d3 (parallel axes) d2 is kept,
    whatever the poses or the round-off. Each left-out column is expressed in the kept ones by
    least squares.
    """
    from ._objective import resolve_prior

    prior = resolve_prior(prior)
    if prior is None:
        return identify_with_residuals(robot, measurement, q, space, deviations, rtol=rtol)[0]
    space = ParameterSpace.for_robot(robot, measurement=measurement) if space is None else space
    return identify_with_residuals(robot, measurement, q, space, deviations, rtol=rtol, prior_std=prior.std(space))[0]


def select_free(Rs: np.ndarray, norms: np.ndarray, s0: float, pref: list, prior_std, rtol: float) -> np.ndarray:
    """The free set of a maximum-a-posteriori fit: ``[p]`` bool over the candidates.

    Every candidate with a finite prior σ is free: with the prior's residuals appended, the
    information matrix ``JᵀJ/σ² + diag(1/s_j²)`` is positive definite on their span, so each
    direction the data cannot see is set by the prior instead of being frozen at a start value.
    Candidates without a prior (the sensor/set-up extras by default) are free only where the data
    see them: in :data:`KEEP_PREFERENCE` order, each is added while the column-scaled Jacobian of
    the no-prior candidates chosen so far keeps its smallest singular value above ``rtol·s0``
    (``s0`` the largest singular value of the whole scaled Jacobian). A direction is then left
    undetermined only if it lies entirely in the no-prior candidates and the data cannot see it —
    e.g. two extras without a prior that act alike; the later one in preference order is held.

    Args:
        Rs: ``[p, p]`` triangular factor of the column-scaled Jacobian (``J/norms = Q·Rs``).
        norms: ``[p]`` column norms (0: no effect at all).
        s0: largest singular value of ``Rs``.
        pref: ``[p]`` sort keys (:func:`_preference_key`, then the position).
        prior_std: ``[p]`` prior σ (``inf``: none).
        rtol: relative singular-value threshold.
    """
    prior_std = np.asarray(prior_std, np.float64)
    free = np.isfinite(prior_std)
    chosen: list[int] = []
    for j in sorted(np.flatnonzero(~free).tolist(), key=lambda i: pref[i]):
        if norms[j] == 0:
            continue
        sv = np.linalg.svd(Rs[:, chosen + [j]], compute_uv=False)
        if s0 > 0 and sv[-1] > rtol * s0:
            chosen.append(j)
    free[chosen] = True
    return free


class _Selection(NamedTuple):
    """The identifiable subset of one pivoted factor (see :func:`identify_with_residuals`)."""

    norms: np.ndarray
    Rs: np.ndarray
    Rj: np.ndarray
    s: np.ndarray
    rank: int
    keep_idx: np.ndarray
    drop_idx: list
    cond: float

    def deps(self, names) -> dict:
        """Each left-out column with an effect in the kept ones, by one least-squares solve."""
        norms, keep_idx = self.norms, self.keep_idx
        moving = [j for j in self.drop_idx if norms[j] != 0]
        coefs = np.linalg.lstsq(self.Rj[:, keep_idx], self.Rj[:, moving], rcond=None)[0] if moving else None
        deps = {}
        for j in self.drop_idx:
            if norms[j] == 0:
                deps[names[j]] = []
                continue
            coef = coefs[:, moving.index(j)]
            # significance judged on the scaled coefficients
            sig = np.abs(coef * norms[keep_idx] / norms[j]) > 1e-6
            order = np.argsort(-np.abs(coef * norms[keep_idx]))
            deps[names[j]] = [(float(coef[k]), names[keep_idx[k]]) for k in order if sig[k]][:6]
        return deps


def _select(norms, R, piv, rtol: float, pref) -> _Selection:
    """Rank, the preferred identifiable subset (:func:`_prefer`) and its condition number from the
    column norms and the pivoted triangular factor of :func:`_start_factor`."""
    # Js = J/norms, Js[:, piv] = Q R with orthonormal Q: Js, J and their column subsets have the
    # singular values and least-squares solutions of the columns of the small triangular factor,
    # so the SVDs and least squares run on R (p×p), not on the N×p Jacobian (multithreaded
    # LAPACK on the tall matrices took 0.1–1 s per call on a busy 2-core machine).
    norms, R, piv = np.asarray(norms, np.float64), np.asarray(R, np.float64), np.asarray(piv)
    if not (np.all(np.isfinite(norms)) and np.all(np.isfinite(R))):
        raise ValueError("identification Jacobian contains NaN/inf (check joint angles and anchor)")
    scale = np.where(norms > 0, norms, 1.0)
    Rs = np.zeros((R.shape[0], len(piv)))
    Rs[:, piv] = R  # Js = Q Rs
    s = np.linalg.svd(Rs, compute_uv=False)
    rank = int(np.sum(s > rtol * s[0])) if s[0] > 0 else 0
    keep_idx = _prefer(Rs, sorted(piv[:rank].tolist()), pref)
    kept_set = set(keep_idx.tolist())
    drop_idx = [i for i in range(len(piv)) if i not in kept_set]
    sv = np.linalg.svd(Rs[:, keep_idx], compute_uv=False) if keep_idx.size else np.array([1.0])
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    return _Selection(norms, Rs, Rs * scale, s, rank, keep_idx, drop_idx, cond)


def _preference(names) -> list:
    """A total order of the candidates for :func:`_select`: equal keys (e.g. the same component of
    two sessions' frames) are ordered by their position, so that no choice is left to the pivots'
    round-off."""
    return [(*_preference_key(n), i) for i, n in enumerate(names)]


def identifiable_columns(J, names, *, prior_std=None, rtol: float | None = None) -> np.ndarray:
    """``[p]`` bool: the columns of an identification Jacobian ``J`` ``[N, p]`` (host array, in
    any units per column) that :func:`identify_with_residuals` would free — the same column
    scaling (a round-off-size column counts as zero), pivoted factor, preference order and, with
    ``prior_std`` ``[p]`` (``inf`` = no prior), :func:`select_free` — for a Jacobian its caller
    assembles itself (the combined whitened rows of a planned set-up). The factor is formed on the
    host (LAPACK QR, then ``geqp3``-pivoting of the ``p×p`` factor: the rows themselves, not a Gram
    matrix, which would square the condition number)."""
    import scipy.linalg

    J = np.asarray(J, np.float64)
    norms = np.linalg.norm(J, axis=0)
    norms = np.where(norms > 1e-10 * norms.max(), norms, 0.0)
    R0 = np.linalg.qr(J / np.where(norms > 0, norms, 1.0), mode="r")
    R, piv = scipy.linalg.qr(R0, mode="r", pivoting=True)
    pref = _preference(names)
    rtol = default_rtol(np.float64) if rtol is None else float(rtol)
    sel = _select(norms, R, piv, rtol, pref)
    if prior_std is not None:
        return select_free(sel.Rs, norms, float(sel.s[0]), pref, np.asarray(prior_std, np.float64), rtol)
    keep = np.zeros(len(names), bool)
    keep[sel.keep_idx] = True
    return keep


def start_jacobian(robot, measurement, q, space, deviations, y, *, n_to=None):
    """``(residual blocks [n, m] NumPy, Jacobian [N, p] device)`` of the data ``y`` at
    ``deviations`` for the free parameters of ``space``, from the identifiability program
    (:func:`identify_with_residuals` with the same arguments compiles nothing more), without its
    host-side selection; for measurements whose Jacobian does not depend on the readings
    (:attr:`~jaxcal.MeasurementModel.jacobian_free_of_data`; else ``ValueError``). The Jacobian
    carries zero rows for the padding at its end, as :func:`identify_with_residuals`'s."""
    if not measurement.jacobian_free_of_data:
        raise ValueError(f"{type(measurement).__name__}'s Jacobian depends on the readings: no start Jacobian "
                         "from the identifiability program")
    q = to_device(q)
    n = int(q.shape[0])
    measurement, qp, yp, w = pad_model_rows(measurement, q, y, n_to)
    resid, J = _start_factor(robot, measurement, qp, deviations.astype(q.dtype), space, yp, w)[3:]
    return np.asarray(resid, np.float64)[:n], J


def identify_with_residuals(robot, measurement, q, space=None, deviations=None, y=None, *, rtol=None,
                            prior_std=None, n_to=None, still_deg=None):
    """:func:`identifiability`, and with measurements ``y`` also their residual blocks ``[n, m]``
    (NumPy, mm) at ``deviations`` and the identification Jacobian ``[N, p]`` there (a device
    array; only where :attr:`~jaxcal.MeasurementModel.jacobian_free_of_data`), from the same
    compiled program: ``(report, residuals | None, jacobian | None)``.

    ``prior_std``: ``[p]`` prior σ of the candidates (``inf`` = no prior) for a
    maximum-a-posteriori fit: the report's ``space`` then frees every candidate with a prior and
    the data-identifiable subset of the others (:func:`select_free`); without it ``space`` frees
    the identifiable subset.


    The compiled program runs on the samples padded to their shape bucket
    (shape buckets; one program per bucket, not per sample count): the report and the
    residuals are the real rows', and the Jacobian carries zero rows for the padding at its end
    (``bucket_size(n)·m`` rows). ``n_to``: pad to this row count instead (a caller with its own
    bucket, as :func:`jaxcal.sweep`'s padded simulation). ``still_deg``: the span (degrees) below
    which a joint counts as near-still (default :data:`STILL_JOINT_DEG`; see :func:`still_joints`):
    with such joints, rank, subset and dependencies are those of the data with them standing still,
    and the report's ``still_unseen`` names what only their motion would show."""
    q = to_device(q)  # not jnp.asarray: a copy program per new shape
    space = ParameterSpace.for_robot(robot, measurement=measurement) if space is None else space
    if space.n_free == 0:
        raise ValueError("no free parameters to examine")
    dev0 = Deviations.zeros(layout_for(robot, measurement), q.dtype) if deviations is None else deviations.astype(q.dtype)
    n = int(q.shape[0])
    measurement, qp, yp, w = pad_model_rows(measurement, q, y, n_to)
    norms, R, piv, resid, J = _start_factor(robot, measurement, qp, dev0, space, yp, w)
    # host work that needs none of its outputs first, while the program runs (dispatched asynchronously)
    rtol = default_rtol(q.dtype) if rtol is None else float(rtol)
    names = space.free_names
    pref = _preference(names)
    still = still_joints(robot, np.asarray(q)) if still_deg is None else still_joints(robot, np.asarray(q), still_deg)
    if resid is not None and w is not None:
        resid = np.asarray(resid)[:n]
    sel = _select(norms, R, piv, rtol, pref)
    unseen: tuple[str, ...] = ()
    if still:
        # judged with the near-still joints standing still at their mean reading: what only their
        # few degrees of motion show is not taken from the data. The same compiled program: the
        # readings enter the factor only where the Jacobian does not depend on them
        qs = np.asarray(qp).copy()
        cols = [j - 1 for j in still]
        qs[:, cols] = np.mean(np.asarray(q)[:, cols], axis=0)
        moving = sel
        sel = _select(*_start_factor(robot, measurement, to_device(qs, q.dtype), dev0, space, yp, w)[:3], rtol, pref)
        kept_still = {names[i] for i in sel.keep_idx}
        unseen = tuple(names[i] for i in moving.keep_idx if names[i] not in kept_still)
    norms, Rs, s, rank, keep_idx, drop_idx, deps, cond = (sel.norms, sel.Rs, sel.s, sel.rank, sel.keep_idx,
                                                           sel.drop_idx, sel.deps(names), sel.cond)
    keep = np.zeros(len(names), dtype=bool)
    keep[keep_idx] = True
    covered = ()
    if prior_std is not None:
        prior_std = np.asarray(prior_std, np.float64)
        if prior_std.shape != (len(names),):
            raise ValueError(f"prior_std must have one σ per candidate ({len(names)}), got shape {prior_std.shape}")
        keep = select_free(Rs, norms, float(s[0]), pref, prior_std, rtol)
        covered = tuple(n for n, v in zip(names, prior_std) if np.isfinite(v))
        # what only a near-still joint's motion shows is held under a prior too: a weak pull of the
        # noise along it moved a₁ 15 mm (7σ of its prior) on a simulated tracker set
        keep[[names.index(n) for n in unseen]] = False
    report = IdentifiabilityReport(
        names=names,
        rank=rank,
        singular_values=s,
        identifiable=tuple(names[i] for i in keep_idx),
        unidentifiable=tuple(names[i] for i in drop_idx),
        dependencies=deps,
        condition_number=cond,
        space=space.restrict(keep),
        rtol=rtol,
        prior_covered=covered,
        still_joints=still,
        still_unseen=unseen,
    )
    return report, None if resid is None else np.asarray(resid, np.float64), J
