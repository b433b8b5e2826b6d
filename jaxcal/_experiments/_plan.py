"""Measurement planning: which poses to measure, how many, and how accurate the result will be.

Before touching the robot: generate candidate poses inside the joint limits and the sensor's
range (:func:`candidate_poses`), score pose sets by the observability indices O1–O5 of the
column-scaled identification Jacobian (:func:`observability_indices`), pick the poses
(:func:`select_poses`: greedy D/A/E/I-optimal selection with rank-``m`` updates, then a DETMAX
exchange; or the convex relaxation :func:`relaxed_design`), and predict the accuracy a
calibration with them will reach (:func:`predicted_accuracy`).

Notation. ``J`` ``[n·m, p]`` is the identification Jacobian ``∂residual/∂Δ`` (``jax.jacfwd``,
:meth:`jaxcal.Problem.jacobian`) of ``n`` poses with ``m`` residual entries each, on the ``p``
identifiable parameters (the subset :func:`jaxcal.identifiability` keeps). Columns are scaled,
``J_s = J·diag(1/s)``, with ``s_j`` the root-mean-square sensitivity of parameter ``j`` per
residual row (mm per rad or mm per mm) so that angle and length columns compare. With noise σ
(mm) and Gaussian priors of σ_j (:class:`jaxcal.Prior`; none by default, as in
:func:`jaxcal.calibrate`), the information matrix in scaled units is
``M = J_sᵀJ_s + Λ``, ``Λ = diag(σ²/(s_j σ_j)²)``, and the covariance of the estimate is
``Σ = σ²·(JᵀJ + σ²·diag(1/σ_j²))⁻¹`` (Cramér–Rao).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time

import jax
import jax.numpy as jnp
import numpy as np

from .._core._params import ParameterSpace
from .._core._xla import jit
from .._datasets._dataset import Dataset
from .._fit._problem import Problem
from .._models._abstract import AbstractRobot
from .._models._kinematics import fk_position
from .._sensors._measurement import CableLength, MeasurementModel, Pose, Position

__all__ = [
    "ObservabilityIndices",
    "observability_indices",
    "indices_from_jacobian",
    "candidate_poses",
    "PoseSelection",
    "select_poses",
    "relaxed_design",
    "PredictedAccuracy",
    "predicted_accuracy",
    "simulate_readings",
    "planning_jacobian",
    "CRITERIA",
    "AccuracyCurve",
    "accuracy_curve",
    "save_plan_csv",
    "load_joint_angles",
]

#: selection criteria: D (max log det M), A (min tr M⁻¹ in scaled units), E (max λ_min(M)),
#: I (min the average prediction variance over the candidate workspace, tr(W M⁻¹) with
#: W = mean_t J_tᵀJ_t — the criterion that is the predicted test MSE).
CRITERIA = ("D", "A", "E", "I")


# -- observability indices --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ObservabilityIndices:
    """Observability indices of a pose set (Sun & Hollerbach 2008 numbering).

    From the singular values ``σ_1 ≥ … ≥ σ_p`` of the column-scaled Jacobian ``J_s``
    ``[N, p]`` (``N = n·m`` residual rows):

    * ``o1`` = ``(σ_1⋯σ_p)^(1/p)/√N`` — Borm & Menq (1991): the volume of the error ellipsoid,
      D-optimality; with the default scaling (column RMS 1 per row) ``0 ≤ O1 ≤ 1``, 1 for
      orthogonal columns. Larger is better.
    * ``o2`` = ``σ_p/σ_1`` — the inverse condition number (Driels & Pathre 1990): how round the
      ellipsoid is. Larger is better. ``condition_number`` = ``σ_1/σ_p``, smaller is better.
    * ``o3`` = ``σ_p`` — the minimum singular value (Nahvi, Hollerbach & Hayward 1994): the
      worst-determined direction, E-optimality. Larger is better; 0 for a singular set.
    * ``o4`` = ``σ_p²/σ_1`` — the noise amplification index (Nahvi & Hollerbach 1996).
      Larger is better.
    * ``o5`` = ``1/Σ_i(1/σ_i)`` — Sun & Hollerbach (2008), related to A-optimality. Larger is
      better.

    (Some texts call O2 the "condition number"; in the literature it is the inverse condition
    number. Both are reported, as ``o2`` and ``condition_number``.)

    Attributes:
        singular_values: ``[p]`` descending.
        n_rows: ``N``.
        rank: number of singular values above ``1e-9·σ_1``.
    """

    o1: float
    o2: float
    o3: float
    o4: float
    o5: float
    condition_number: float
    singular_values: np.ndarray
    n_rows: int
    rank: int

    def as_dict(self) -> dict:
        return {"O1": self.o1, "O2": self.o2, "O3": self.o3, "O4": self.o4, "O5": self.o5,
                "condition_number": self.condition_number, "rank": self.rank}

    def __str__(self) -> str:
        return (f"O1 {self.o1:.4g} (D-opt.) · O2 {self.o2:.4g} (1/cond) · O3 {self.o3:.4g} (σ_min) · "
                f"O4 {self.o4:.4g} (noise ampl.) · O5 {self.o5:.4g} · cond {self.condition_number:.4g} · "
                f"rank {self.rank}/{len(self.singular_values)}")


def indices_from_jacobian(J, scale=None) -> ObservabilityIndices:
    """:class:`ObservabilityIndices` of a Jacobian ``J`` ``[N, p]`` (or ``[n, m, p]``).

    ``scale`` ``[p]``: the column scales ``s`` (``J_s = J/s``); default the set's own column
    RMS ``‖J_j‖/√N`` (columns of zero norm get scale 1). Pass common scales (e.g.
    :attr:`PoseSelection.scale`) to compare different pose sets. Measuring every pose of a set
    twice multiplies each σ_i by √2 (with either scaling): O1 (normalised by √N) and O2 do not
    change, O3, O4 and O5 (not normalised) grow by √2.
    """
    J = np.asarray(J, np.float64)
    J = J.reshape(-1, J.shape[-1])
    N, p = J.shape
    if scale is None:
        norms = np.linalg.norm(J, axis=0) / math.sqrt(N)
        scale = np.where(norms > 0, norms, 1.0)
    s = np.linalg.svd(J / np.asarray(scale, np.float64), compute_uv=False)
    s = np.pad(s, (0, p - s.size))
    smax, smin = float(s[0]), float(s[-1])
    rank = int(np.sum(s > 1e-9 * smax)) if smax > 0 else 0
    if rank < p:
        smin = 0.0
    with np.errstate(divide="ignore"):
        o1 = float(np.exp(np.mean(np.log(s))) / math.sqrt(N)) if smin > 0 else 0.0
        o5 = float(1.0 / np.sum(1.0 / s)) if smin > 0 else 0.0
    return ObservabilityIndices(
        o1=o1, o2=smin / smax if smax > 0 else 0.0, o3=smin, o4=smin**2 / smax if smax > 0 else 0.0, o5=o5,
        condition_number=smax / smin if smin > 0 else math.inf, singular_values=s, n_rows=N, rank=rank,
    )


# -- Jacobians --------------------------------------------------------------------------------------


@jit
def _jac(problem: Problem):
    return problem.to_blocks(problem.jacobian(problem.x0()))


def candidate_rows(robot: AbstractRobot, measurement: MeasurementModel, candidates, y=None):
    """``(q [N, dof] rad, y | None)``: the poses and (where they carry information the Jacobian
    needs) the readings of planning candidates.

    ``candidates`` is ``[N, dof]`` joint angles, or a :class:`~jaxcal.Dataset` whose readings say
    which contact a pose makes (plane / point labels: :func:`candidate_poses` for those models
    returns one), or for a :class:`~jaxcal.DistanceBar` ``[N, 2·dof]`` pose pairs ``(q_a, q_b)``
    (rad; the bar length is then the nominal distance of the pair, which the Jacobian does not
    depend on) or a distance Dataset. ``y`` given explicitly wins. Without readings a model's
    nominal prediction is used (the nearest plane / point for contact models)."""
    from .._sensors._contact import DistanceBar

    if isinstance(candidates, Dataset):
        q = np.asarray(candidates.q, np.float64)
        y = np.asarray(candidates.y, np.float64) if y is None else y
    else:
        q = np.asarray(candidates, np.float64)
    if isinstance(measurement, DistanceBar) and y is None:
        dof = measurement.dof
        if q.ndim != 2 or q.shape[1] != 2 * dof:
            raise ValueError(f"distance-bar candidates are pose pairs: [N, {2 * dof}] joint angles (q_a, q_b; rad) or "
                             f"a distance Dataset, got shape {q.shape}")
        qa, qb = q[:, :dof], q[:, dof:]
        pa, pb = (np.asarray(fk_position(robot, jnp.asarray(x)), np.float64) for x in (qa, qb))
        return qa, np.concatenate([qb, np.linalg.norm(pa - pb, axis=1)[:, None]], axis=1)
    if q.ndim != 2 or q.shape[1] != robot.dof:
        raise ValueError(f"candidates must be [N, {robot.dof}] joint angles (rad), got shape {q.shape}")
    return q, (None if y is None else np.asarray(y, np.float64))


def planning_jacobian(robot: AbstractRobot, measurement: MeasurementModel, q, space: ParameterSpace, y=None) -> np.ndarray:
    """The identification Jacobian at the nominal robot, ``[n, m, p]`` (mm per rad / mm per mm;
    px per rad / px per mm for a camera), for joint angles ``q`` ``[n, dof]`` (rad; or
    candidates as :func:`candidate_rows` reads them) and the free parameters of ``space``. The
    readings are ``y`` or the candidates' own where given (contact labels, the bar's second
    pose), else the nominal predictions (only a pose's orientation residual depends on them)."""
    q, y = candidate_rows(robot, measurement, q, y)
    dtype = jnp.result_type(float)
    q = jnp.asarray(q, dtype)
    y = measurement.predict(robot, None, q) if y is None else jnp.asarray(y, dtype)
    y = y.reshape(q.shape[0], *measurement.sample_shape)
    J = _jac(Problem(robot, measurement, q, y, space))
    return np.asarray(J, np.float64).reshape(q.shape[0], measurement.size, space.n_free)


def _identifiable_space(robot, measurement, space, q, prior=None, y=None) -> ParameterSpace:
    """The free set :func:`jaxcal.calibrate` would choose on these poses (readings ``y``, or the
    nominal predictions): the identifiable subset of ``space``, or under a ``prior`` every
    parameter it covers and the data-identifiable rest (maximum a posteriori,
    :func:`~jaxcal._fit._identifiability.select_free`)."""
    from .._fit._identifiability import identifiability, identify_with_residuals
    from .._fit._objective import resolve_prior

    if y is None:
        return identifiability(robot, measurement, q, space, prior=prior).space
    prior = resolve_prior(prior)
    dtype = jnp.result_type(float)
    return identify_with_residuals(robot, measurement, jnp.asarray(q, dtype), space, y=jnp.asarray(y, dtype),
                                   prior_std=None if prior is None else prior.std(space))[0].space


def _generic_space(robot, measurement, space=None) -> ParameterSpace:
    """The identifiable subset of ``space`` (default: the DH deviations) with poses spread over
    the whole joint range — what the sensor can identify at all (fixed key, deterministic)."""
    from .._models._robot import sample_joint_angles

    q = sample_joint_angles(jax.random.key(12), robot, 512, dtype=jnp.result_type(float))
    space = ParameterSpace.for_robot(robot, measurement=measurement) if space is None else space
    return _identifiable_space(robot, measurement, space, q)


def observability_indices(
    robot: AbstractRobot, measurement: MeasurementModel, q, *, space: ParameterSpace | None = None, scale=None,
) -> ObservabilityIndices:
    """Observability indices O1–O5 of the pose set ``q`` ``[n, dof]`` (rad) for ``measurement``.

    ``space``: the parameters judged (default: the DH deviations the sensor can identify at
    all, found on poses spread over the joint range — so a poor pose set shows O3 ≈ 0 instead
    of being judged on fewer parameters). ``scale``: column scales, see
    :func:`indices_from_jacobian`. Definitions and references: :class:`ObservabilityIndices`.
    """
    space = _generic_space(robot, measurement) if space is None else space
    return indices_from_jacobian(planning_jacobian(robot, measurement, q, space), scale)


# -- candidates -------------------------------------------------------------------------------------


def candidate_poses(
    key,
    robot: AbstractRobot,
    measurement: MeasurementModel,
    n: int,
    *,
    coverage: float = 1.0,
    wire_range_mm: tuple[float, float] | None = None,
    min_height_mm: float | None = 0.0,
    box_mm=None,
    tracker_mm=None,
    tracker_axis=(0.0, 0.0, 1.0),
    cone_half_angle_deg: float = 60.0,
    oversample: int = 8,
    bar_lengths_mm=(150.0, 300.0),
    min_visible: float = 1.0,
    around=None,
    spread_deg=(8.0, 8.0, 8.0, 25.0, 25.0, 25.0),
):
    """``[n, dof]`` candidate joint angles (rad), uniform over the joint limits (the central
    ``coverage`` fraction), kept where the nominal tool point is reachable by the sensor.

    Sensors without a tracker (contact sensors, cameras) constrain the pose itself, so their candidates are made
    to satisfy the constraint on the nominal robot (IK-free: random joint configurations, the
    ones nearest to the constraint moved onto it by minimum-norm Newton steps, as the
    simulations do; rows that leave the joint limits or do not converge are dropped):

    * :class:`~jaxcal.PlaneContact` / :class:`~jaxcal.FixedPoint`: a :class:`~jaxcal.Dataset`
      of ``n`` poses whose tool point lies on the model's nominal planes / at its points (on its
      spheres), labels in turn (:func:`jaxcal.simulate_contact` on the nominal robot without
      noise); its readings are the labels. ``min_height_mm``/``box_mm`` do not apply (the
      planes and points fix where the tool is).
    * :class:`~jaxcal.DistanceBar`: a distance :class:`~jaxcal.Dataset` of ``n`` pose *pairs*
      whose tool points are a bar length apart on the nominal robot, lengths ``bar_lengths_mm``
      in turn (:func:`~jaxcal._simulation._simulate_sensors.simulate_distance` without noise; pose *a*'s tool point
      above the base plane).
    * :class:`~jaxcal.Camera`: ``[n, dof]`` joint angles at which at least the fraction
      ``min_visible`` of the target points (default 1: the whole target) lies in front of the
      camera and projects inside the image (:func:`~jaxcal._sensors._camera.target_in_view`; the model
      needs ``image_size`` and its nominal hand-eye/target frames, e.g.
      :func:`~jaxcal._sensors._camera.planning_camera`). Draws are uniform over the limits and around
      ``around`` (``[k, dof]`` rad; default the middle of the joint ranges) spread uniformly by
      ``±spread_deg`` per joint (the last value repeats); then, while too few see the target,
      around poses that do.

    Filters (nominal robot, tool point in the base frame, mm):

    * ``min_height_mm``: the tool point at least this high (``None``: no height filter);
    * draw-wire (:class:`CableLength`): wire length ``‖p − anchor‖`` within ``wire_range_mm``,
      default ``[0.05, 1.2]·reach`` as in :func:`jaxcal.simulate_experiment`;
    * ``box_mm``: ``((x_lo, y_lo, z_lo), (x_hi, y_hi, z_hi))`` workspace box;
    * tracker line of sight as a simple cone: ``tracker_mm`` ``[3]`` (the tracker's position in
      the base frame); the direction from the tracker to the tool point within
      ``cone_half_angle_deg`` of ``tracker_axis``.

    Pure in ``key`` (same key ⇒ same candidates). Raises ``ValueError`` if fewer than ``n`` of
    ``n·oversample`` draws pass.
    """
    planner = _planner(measurement)
    if planner is not None:  # the sensor's own candidates (SensorKind.planner)
        return planner(key, robot, measurement, n, coverage=coverage, wire_range_mm=wire_range_mm,
                       min_height_mm=min_height_mm, box_mm=box_mm, tracker_mm=tracker_mm, tracker_axis=tracker_axis,
                       cone_half_angle_deg=cone_half_angle_deg, oversample=oversample, bar_lengths_mm=bar_lengths_mm,
                       min_visible=min_visible, around=around, spread_deg=spread_deg)
    return _workspace_candidates(key, robot, measurement, n, coverage, wire_range_mm, min_height_mm, box_mm,
                                 tracker_mm, tracker_axis, cone_half_angle_deg, oversample)


def _planner(measurement):
    """The candidate function :attr:`SensorKind.planner <jaxcal._sensors._kind.SensorKind>` of
    ``measurement``'s kind names (imported here: the hook by which the sensors name their planning
    code on this floor), or ``None``: joint angles over the workspace (also for a model of no
    registered kind)."""
    from .._sensors._kind import kind_names, resolve_hook, sensor_kind

    name = getattr(measurement, "kind", None)
    hook = sensor_kind(name).planner if name in kind_names() else None
    return None if hook is None else resolve_hook(hook)


def _workspace_candidates(key, robot, measurement, n, coverage, wire_range_mm, min_height_mm, box_mm, tracker_mm,
                          tracker_axis, cone_half_angle_deg, oversample):
    """:func:`candidate_poses` for a sensor without its own (a tracker, a draw wire): random joint
    angles kept by the workspace filters."""
    from .._models._robot import sample_joint_angles

    dtype = jnp.result_type(float)
    reach = robot.reach_mm()
    total = 0
    kept = []
    for attempt in range(4):
        k = jax.random.fold_in(key, attempt)
        q = sample_joint_angles(k, robot, n * oversample, coverage=coverage, dtype=dtype)
        p = np.asarray(fk_position(robot, q), np.float64)
        ok = np.ones(q.shape[0], bool)
        if min_height_mm is not None:
            ok &= p[:, 2] >= min_height_mm
        ok &= measurement.in_range(p, reach, wire_range_mm)  # a draw wire's length range
        if box_mm is not None:
            lo3, hi3 = (np.asarray(b, np.float64) for b in box_mm)
            ok &= np.all((p >= lo3) & (p <= hi3), axis=1)
        if tracker_mm is not None:
            v = p - np.asarray(tracker_mm, np.float64)
            axis = np.asarray(tracker_axis, np.float64)
            cosang = v @ axis / (np.linalg.norm(v, axis=1) * np.linalg.norm(axis) + 1e-300)
            ok &= cosang >= math.cos(math.radians(cone_half_angle_deg))
        kept.append(np.asarray(q)[ok])
        total += int(ok.sum())
        if total >= n:
            break
    q = np.concatenate(kept)
    if q.shape[0] < n:
        raise ValueError(f"candidate_poses: only {q.shape[0]} of {4 * n * oversample} random joint configurations pass "
                         "the workspace/sensor filters; relax them or raise `oversample`")
    return jnp.asarray(q[:n], dtype)


def contact_candidates(key, robot, measurement, n: int, **_):
    """:func:`candidate_poses` for the contact models (the planner of the plane and point kinds): a
    noise-free simulation on the nominal robot (its readings are the labels)."""
    from .._core._params import Deviations, layout_for
    from .._simulation._simulate_sensors import simulate_contact

    zero = Deviations.zeros(layout_for(robot, measurement), jnp.result_type(float))
    return simulate_contact(key, robot, measurement, n_samples=n, noise_std=0.0, test_fraction=0.0,
                            true_deviations=zero, tries=4).train


def distance_candidates(key, robot, measurement, n: int, *, bar_lengths_mm=(150.0, 300.0), **_):
    """:func:`candidate_poses` for the distance bar (its kind's planner): a noise-free simulation on
    the nominal robot (its readings are the second pose and the bar length)."""
    from .._core._params import Deviations, layout_for
    from .._simulation._simulate_sensors import simulate_distance

    zero = Deviations.zeros(layout_for(robot, measurement), jnp.result_type(float))
    return simulate_distance(key, robot, n_samples=n, noise_std=0.0, lengths_mm=bar_lengths_mm,
                             test_fraction=0.0, true_deviations=zero, tries=8).train


def camera_candidates(key, robot, camera, n: int, *, coverage=1.0, oversample=8, min_visible=1.0, around=None,
                      spread_deg=(8.0, 8.0, 8.0, 25.0, 25.0, 25.0), **_):
    """:func:`candidate_poses` for a camera (its kind's planner): poses that see at least
    ``min_visible`` of the target."""
    from .._models._robot import sample_joint_angles
    from .._sensors._camera import target_in_view

    if not 0.0 < min_visible <= 1.0:
        raise ValueError(f"min_visible must be in (0, 1], got {min_visible}")
    dtype = jnp.result_type(float)
    lo, hi = np.asarray(robot.q_min, np.float64), np.asarray(robot.q_max, np.float64)
    centres = ((lo + hi) / 2)[None] if around is None else np.asarray(around, np.float64).reshape(-1, robot.dof)
    spread = np.deg2rad(np.resize(np.asarray(spread_deg, np.float64), robot.dof))
    need = math.ceil(min_visible * camera.n_points)
    m = max(n * oversample, 256)

    def near(k, c):
        u = np.asarray(jax.random.uniform(k, (m, robot.dof), dtype, -1.0, 1.0), np.float64)
        return np.clip(c[np.arange(m) % len(c)] + u * spread, lo, hi)

    kept = []
    total = 0
    for attempt in range(6):
        k1, k2 = jax.random.split(jax.random.fold_in(key, attempt))
        if attempt == 0:
            q = np.concatenate([np.asarray(sample_joint_angles(k1, robot, m, coverage=coverage, dtype=dtype)),
                                near(k2, centres)])
        else:  # around poses that see the target
            q = near(k2, np.concatenate(kept) if total else centres)
        ok = target_in_view(robot, camera, q).sum(axis=1) >= need
        kept.append(q[ok])
        total += int(ok.sum())
        if total >= n:
            break
    q = np.concatenate(kept)
    if q.shape[0] < n:
        raise ValueError(f"candidate_poses: only {q.shape[0]} joint configurations see at least {need} of the "
                         f"{camera.n_points} target points (in front of the camera, inside the {camera.image_size} px "
                         "image); check the camera's nominal hand-eye/target frames, pass `around` poses that see "
                         "the target, or lower min_visible")
    perm = np.asarray(jax.random.permutation(jax.random.fold_in(key, 99), q.shape[0]))
    return jnp.asarray(q[np.sort(perm[:n])], dtype)


# -- selection --------------------------------------------------------------------------------------


def _objective(M, criterion: str, W):
    """The criterion value to maximise, exactly, from the information matrix ``M`` ``[p, p]``."""
    if criterion == "D":
        return jnp.linalg.slogdet(M)[1]
    if criterion == "E":
        return jnp.linalg.eigvalsh(M)[0]
    L = jnp.linalg.cholesky(M)
    Minv = jax.scipy.linalg.cho_solve((L, True), jnp.eye(M.shape[0], dtype=M.dtype))
    return -jnp.trace(W @ Minv)


def _delta_one(Jk, Minv, W, v_min, *, sign: float, criterion: str):
    """Change of the criterion when ``M → M + sign·J_kᵀJ_k`` for one candidate ``J_k`` ``[m, p]``,
    by the matrix determinant lemma / Woodbury identity (exact for D, A, I; first order for E)."""
    m = Jk.shape[0]
    B = Jk @ Minv  # J_k M⁻¹  [m, p]
    A = jnp.eye(m, dtype=Jk.dtype) + sign * B @ Jk.T  # I + sign·J_k M⁻¹ J_kᵀ
    if criterion == "D":
        if m == 1:
            return jnp.log(jnp.maximum(A[0, 0], 1e-300))
        sgn, logdet = jnp.linalg.slogdet(A)
        return jnp.where(sgn > 0, logdet, -jnp.inf)
    if criterion == "E":
        return sign * jnp.sum((Jk @ v_min) ** 2)
    C = B @ W @ B.T  # J_k M⁻¹ W M⁻¹ J_kᵀ
    if m == 1:
        return sign * C[0, 0] / A[0, 0]
    return sign * jnp.trace(jnp.linalg.solve(A, C))


def _deltas(Minv, M, Jc, sign, criterion: str, W):
    """:func:`_delta_one` for every candidate of ``Jc`` ``[K, m, p]`` at once (``jax.vmap``)."""
    v_min = jnp.linalg.eigh(M)[1][:, 0] if criterion == "E" else jnp.zeros(M.shape[0], M.dtype)
    one = functools.partial(_delta_one, sign=sign, criterion=criterion)
    return jax.vmap(one, in_axes=(0, None, None, None))(Jc, Minv, W, v_min)


def _woodbury(Minv, Jk, sign):
    """``(M + sign·J_kᵀJ_k)⁻¹`` from ``M⁻¹`` (rank-``m`` Sherman–Morrison–Woodbury update)."""
    m = Jk.shape[0]
    B = Jk @ Minv  # [m, p]
    A = jnp.eye(m, dtype=Jk.dtype) + sign * B @ Jk.T
    out = Minv - sign * B.T @ jnp.linalg.solve(A, B)
    return 0.5 * (out + out.T)


def _inv(M):
    L = jnp.linalg.cholesky(M)
    return jax.scipy.linalg.cho_solve((L, True), jnp.eye(M.shape[0], dtype=M.dtype))


@functools.partial(jit, static_argnames=("n", "criterion"))
def _greedy(Jc, M0, W, avail0, n: int, criterion: str):
    def step(carry, _):
        Minv, M, avail = carry
        g = jnp.where(avail, _deltas(Minv, M, Jc, 1.0, criterion, W), -jnp.inf)
        k = jnp.argmax(g)
        Jk = Jc[k]
        return (_woodbury(Minv, Jk, 1.0), M + Jk.T @ Jk, avail.at[k].set(False)), k

    (_, M, _), picks = jax.lax.scan(step, (_inv(M0), M0, avail0), None, length=n)
    return picks, M


@functools.partial(jit, static_argnames=("criterion", "max_iter"))
def _exchange(Jc, M0, W, sel0, criterion: str, max_iter: int):
    """DETMAX-style exchange (Mitchell 1974; Fedorov 1972): add the candidate that improves the
    criterion most, drop the selected pose (the new one included) whose removal costs least;
    keep the swap if the exact criterion improves, stop when it does not."""
    N = Jc.shape[0]

    def info(sel):
        Js = Jc[sel]
        return M0 + jnp.einsum("kap,kaq->pq", Js, Js)

    def body(state):
        sel, M, f, it, _ = state
        Minv = _inv(M)
        avail = jnp.ones(N, bool).at[sel].set(False)
        g = jnp.where(avail, _deltas(Minv, M, Jc, 1.0, criterion, W), -jnp.inf)
        k = jnp.argmax(g)
        M1 = M + Jc[k].T @ Jc[k]
        sel1 = jnp.concatenate([sel, k[None]])
        loss = _deltas(_inv(M1), M1, Jc[sel1], -1.0, criterion, W)
        r = jnp.argmax(loss)
        new_sel = jnp.where(r < sel.shape[0], sel.at[jnp.minimum(r, sel.shape[0] - 1)].set(k), sel)
        M2 = info(new_sel)
        f2 = _objective(M2, criterion, W)
        better = (r < sel.shape[0]) & (f2 > f + 1e-10 * jnp.abs(f) + 1e-12)
        return (jnp.where(better, new_sel, sel), jnp.where(better, M2, M), jnp.where(better, f2, f), it + 1, better)

    M = info(sel0)
    state = (sel0, M, _objective(M, criterion, W), jnp.asarray(0), jnp.asarray(True))
    sel, M, f, it, _ = jax.lax.while_loop(lambda s: s[4] & (s[3] < max_iter), body, state)
    return sel, M, it


@dataclasses.dataclass(frozen=True)
class PoseSelection:
    """Result of :func:`select_poses` / :func:`relaxed_design`.

    Attributes:
        q: ``[n, dof]`` the selected joint angles (rad), in order of selection.
        index: ``[n]`` their rows in the candidate array.
        criterion: ``"D"``, ``"A"``, ``"E"`` or ``"I"``.
        method: how they were chosen (``"greedy"``, ``"greedy+exchange"``, ``"relaxation"``, ...).
        indices: :class:`ObservabilityIndices` of the selection (scaled by ``scale``).
        space: the parameters planned for (the identifiable subset).
        scale: ``[p]`` the column scales (RMS sensitivity per residual row over the candidates).
        n_exchanges: exchange iterations run (0 without exchange).
        seconds: wall time of the selection (Jacobians, identifiability, greedy, exchange).
        data: the selected rows of a candidate :class:`~jaxcal.Dataset` (their readings: which
            plane / point each pose touches, a bar's second pose and length), else ``None``.
    """

    q: np.ndarray
    index: np.ndarray
    criterion: str
    method: str
    indices: ObservabilityIndices
    space: ParameterSpace
    scale: np.ndarray
    n_exchanges: int
    seconds: float
    data: Dataset | None = None

    @property
    def n(self) -> int:
        return int(self.index.size)

    def table(self) -> str:
        i = self.indices
        return "\n".join([
            f"{self.n} poses selected ({self.method}, {self.criterion}-optimal) for {len(self.space.free_names)} "
            f"identifiable parameters in {self.seconds:.2f} s",
            "| O1 (D) | O2 (1/cond) | O3 (σ_min) | O4 (noise ampl.) | O5 | condition number |",
            "|---|---|---|---|---|---|",
            f"| {i.o1:.4g} | {i.o2:.4g} | {i.o3:.4g} | {i.o4:.4g} | {i.o5:.4g} | {i.condition_number:.4g} |",
        ])

    def __str__(self) -> str:
        return self.table()


def _prior_info(space, prior, noise_std, scale, n_rows):
    """Diagonal prior information ``Λ`` in scaled units (``[p]``), or ``ε`` (1e-8 of one
    pose's information) so that the first picks are defined."""
    from .._fit._objective import resolve_prior

    prior = resolve_prior(prior)
    if prior is None:
        return np.full(space.n_free, 1e-8)
    sd = prior.std(space)
    sigma = prior.noise_std if prior.noise_std is not None else noise_std
    lam = np.where(np.isfinite(sd), (sigma / (scale * sd)) ** 2, 0.0)
    return np.maximum(lam, 1e-8)


def _setup(robot, measurement, candidates, space, prior, noise_std):
    """``(q, space, scale, Jc, Λ, W)`` of the candidates (see :func:`_setup_rows`)."""
    return _setup_rows(robot, measurement, candidates, space, prior, noise_std)[:6]


def _setup_rows(robot, measurement, candidates, space, prior, noise_std):
    """``(q, space, scale, Jc, Λ, W, J)``: candidate poses, identifiable space, column scales, the
    scaled candidate Jacobians (compressed where the kind says, :func:`_compressed`), the prior
    information, the workspace weight of "I", and the unscaled ``[N, m, p]`` Jacobians."""
    q, y = candidate_rows(robot, measurement, candidates)
    base = ParameterSpace.for_robot(robot, measurement=measurement) if space is None else space
    # the identifiable subset is structural: judge it on at most 4 096 candidates spread over the
    # set (every k-th), which is 5x faster than the pivoted QR of all 20 000 on 2 cores
    every = max(1, -(-q.shape[0] // 4096))
    space = _identifiable_space(robot, measurement, base, q[::every], prior, None if y is None else y[::every])
    J = planning_jacobian(robot, measurement, q, space, y)
    rows = J.shape[0] * J.shape[1]
    norms = np.linalg.norm(J.reshape(rows, -1), axis=0) / math.sqrt(rows)
    scale = np.where(norms > 0, norms, 1.0)
    Jc = J / scale
    lam = _prior_info(space, prior, noise_std, scale, rows)
    W = np.einsum("kap,kaq->pq", Jc, Jc) / J.shape[0]  # mean per pose: the workspace weight of "I"
    return q, space, scale, _compressed(measurement, Jc), lam, W, J


def _compressed(measurement, Jc: np.ndarray) -> np.ndarray:
    """``Jc`` :func:`_compress`-ed for a kind that plans on compressed rows
    (:attr:`SensorKind.plan_compressed <jaxcal._sensors._kind.SensorKind>`: a camera), else as it is."""
    from .._sensors._kind import kind_names, sensor_kind

    name = getattr(measurement, "kind", None)
    return _compress(Jc) if name in kind_names() and sensor_kind(name).plan_compressed else Jc


def _compress(Jc: np.ndarray) -> np.ndarray:
    """``[N, m, p]`` → ``[N, min(m, p), p]`` with the same information ``J_kᵀJ_k`` per candidate
    (the ``R`` of ``J_k = Q_k R_k``): every criterion and update of the selection depends on a
    candidate only through ``J_kᵀJ_k``, and a camera image has ``m = 2N`` (108 for a 9×6 board)
    rows against ``p`` ≈ 30 parameters, so the rank-``m`` updates shrink to rank ``p``. Used for
    the camera only: the other models have ``m ≤ 6`` rows, and the round-off of the factor would
    change which of equally good poses they pick."""
    N, m, p = Jc.shape
    if m <= p:
        return Jc
    return np.linalg.qr(Jc, mode="r")


def select_poses(
    robot: AbstractRobot,
    measurement: MeasurementModel,
    candidates,
    n: int,
    *,
    criterion: str = "D",
    exchange: bool = True,
    space: ParameterSpace | None = None,
    prior=None,
    noise_std: float = 0.5,
    max_exchanges: int | None = None,
    start=None,
) -> PoseSelection:
    """Choose ``n`` of the candidate poses ``candidates`` ``[N, dof]`` (rad) to measure.

    1. The identifiable subset of ``space`` (default the DH deviations) on the candidates and
       all candidate Jacobians ``[N, m, p]`` at once (``jax.jacfwd`` on the whole batch),
       column-scaled, ``J_s = J·diag(1/s)`` with ``s_j`` parameter ``j``'s root-mean-square
       sensitivity per residual row (mm per rad or mm per mm), so that angle and length columns
       compare; the information matrix is ``M = J_sᵀJ_s + Λ``.
    2. Greedy selection: starting from the prior information ``Λ`` (``prior``, weighed against
       ``noise_std`` mm; without a prior ``ε·I`` so that the first picks are defined), add the
       candidate with the largest gain, every candidate scored at once (``jax.vmap``): D:
       ``log det(I_m + J_k M⁻¹ J_kᵀ)`` (matrix determinant lemma); A / I: the decrease of
       ``tr(W M⁻¹)`` by the Woodbury identity (``W = I`` / the workspace average
       ``mean_t J_tᵀJ_t``); E: the first-order increase ``‖J_k v_min‖²`` of ``λ_min(M)``.
       ``M⁻¹`` follows by rank-``m`` Sherman–Morrison–Woodbury updates.
    3. ``exchange=True``: DETMAX exchange (Mitchell 1974): add the best candidate, drop the
       selected pose whose removal costs least, keep the swap if the exact criterion improved;
       until no swap improves (or ``max_exchanges``, default ``10·n``).

    ``start``: indices of candidates to start the exchange from instead of the greedy picks.
    Deterministic: the same candidates give the same selection (ties go to the lowest index);
    generate the candidates from a seed with :func:`candidate_poses`. With data of other sensors
    in hand (one combined fit): :func:`jaxcal.plan_blocks`, the same selection started from their
    information.
    """
    if criterion not in CRITERIA:
        raise ValueError(f"criterion must be one of {CRITERIA}, got {criterion!r}")
    t0 = time.perf_counter()
    q, space, scale, Jc, lam, W, J = _setup_rows(robot, measurement, candidates, space, prior, noise_std)
    N = q.shape[0]
    if not (1 <= n <= N):
        raise ValueError(f"cannot select {n} of {N} candidate poses")
    M0 = jnp.diag(jnp.asarray(lam))
    Jc_j, W_j = jnp.asarray(Jc), jnp.asarray(np.eye(Jc.shape[2]) if criterion == "A" else W)
    if start is None:
        sel, _ = _greedy(Jc_j, M0, W_j, jnp.ones(N, bool), n, criterion)
        method = "greedy"
    else:
        sel = jnp.asarray(np.asarray(start, int))
        method = "start"
    n_ex = 0
    if exchange:
        sel, _, it = _exchange(Jc_j, M0, W_j, sel, criterion, int(max_exchanges or 10 * n))
        n_ex = int(it)
        method += "+exchange"
    sel = np.asarray(sel)
    seconds = time.perf_counter() - t0
    return PoseSelection(q[sel], sel, criterion, method, indices_from_jacobian(J[sel], scale), space,
                         scale, n_ex, seconds, _selected_data(candidates, sel))


def _selected_data(candidates, sel):
    """The selected rows of a candidate :class:`Dataset` (their readings: labels, the bar's second
    pose), or of ``[N, 2·dof]`` bar pose pairs; ``None`` for plain joint angles."""
    if isinstance(candidates, Dataset):
        return candidates.subset(jnp.asarray(sel))
    return None


@functools.partial(jit, static_argnames=("iters",))
def _multiplicative(Jc, eps, iters: int):
    N, _, p = Jc.shape

    def body(w, _):
        M = jnp.einsum("k,kap,kaq->pq", w, Jc, Jc) + eps * jnp.eye(p, dtype=Jc.dtype)
        d = jnp.einsum("kap,pq,kaq->k", Jc, _inv(M), Jc)  # tr(J_k M(w)⁻¹ J_kᵀ)
        return w * d / jnp.sum(w * d), jnp.max(d)

    w, dmax = jax.lax.scan(body, jnp.full(N, 1.0 / N, Jc.dtype), None, length=iters)
    return w, dmax[-1]


def relaxed_design(
    robot: AbstractRobot,
    measurement: MeasurementModel,
    candidates,
    n: int,
    *,
    iters: int = 500,
    exchange: bool = False,
    space: ParameterSpace | None = None,
) -> tuple[PoseSelection, np.ndarray, float]:
    """The convex relaxation of D-optimal selection (FIGAROH's approach, solved differently).

    Relax "pick ``n`` poses" to weights ``w_k ≥ 0``, ``Σw = 1`` on the candidates and maximise
    the concave ``log det Σ_k w_k J_kᵀJ_k``. FIGAROH solves it as an SOCP (picos/cvxopt); here
    it is the classical multiplicative algorithm (Silvey, Titterington & Torsney 1978):
    ``w_k ← w_k·d_k(w)/Σ_j w_j d_j(w)`` with ``d_k = tr(J_k M(w)⁻¹ J_kᵀ)``, which increases the
    objective monotonically; by the Kiefer–Wolfowitz equivalence theorem the design is optimal
    iff ``max_k d_k = p``, and its D-efficiency is at least ``exp(1 − max_k d_k/p)``. The ``n``
    poses with the largest weights are then taken (as FIGAROH keeps the largest weights), then
    optionally refined by the DETMAX exchange of :func:`select_poses`.

    Returns:
        ``(selection, weights [N], efficiency_bound)``.
    """
    t0 = time.perf_counter()
    q, space, scale, Jc, lam, W, J = _setup_rows(robot, measurement, candidates, space, None, 0.5)
    w, dmax = _multiplicative(jnp.asarray(Jc), 1e-10, iters)
    w = np.asarray(w)
    p = Jc.shape[2]
    bound = min(1.0, float(math.exp(1.0 - float(dmax) / p)))  # ε-regularised: round-off can pass 1
    sel = np.argsort(-w, kind="stable")[:n]
    method = "relaxation"
    n_ex = 0
    if exchange:
        s, _, it = _exchange(jnp.asarray(Jc), jnp.diag(jnp.asarray(lam)), jnp.asarray(W), jnp.asarray(sel), "D", 10 * n)
        sel, n_ex, method = np.asarray(s), int(it), "relaxation+exchange"
    seconds = time.perf_counter() - t0
    sel_obj = PoseSelection(q[sel], sel, "D", method, indices_from_jacobian(J[sel], scale), space,
                            scale, n_ex, seconds, _selected_data(candidates, sel))
    return sel_obj, w, bound


# -- predicted accuracy -----------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class PredictedAccuracy:
    """Result of :func:`predicted_accuracy` (before any measurement).

    Attributes:
        test_rmse: expected RMSE (``unit``) of the calibrated model on fresh workspace poses,
            ``sqrt(mean_t E‖e_t‖²)`` with the metric's per-sample error.
        train_rmse: expected training RMSE (mm) of the fit on the planned poses (least squares,
            no prior: ``σ·sqrt(m·(1 − p/N))``).
        noise_std: σ (mm).
        names: the identifiable parameters.
        param_std: ``[p]`` predicted standard deviations of the estimates (rad / mm).
        covariance: ``[p, p]`` the covariance ``Σ``.
        n_poses: number of planned poses.
        unit: of the readings, ``test_rmse``, ``train_rmse`` and ``noise_std`` (``"px"`` for a
            camera, else ``"mm"``).
    """

    test_rmse: float
    train_rmse: float
    noise_std: float
    names: tuple[str, ...]
    units: tuple[str, ...]
    param_std: np.ndarray
    covariance: np.ndarray
    n_poses: int
    unit: str = "mm"

    def table(self) -> str:
        u = self.unit
        rows = [f"predicted test RMSE {self.test_rmse:.4f} {u} (σ = {self.noise_std:g} {u}, {self.n_poses} poses, "
                f"{len(self.names)} parameters); per-parameter σ:"]
        for name, unit, sd in zip(self.names, self.units, self.param_std):
            rows.append(f"  {name:<14} {math.degrees(sd):.4g}°" if unit == "rad" else f"  {name:<14} {sd:.4g} mm")
        return "\n".join(rows)

    def __str__(self) -> str:
        return self.table()


def _error_rows(measurement) -> slice:
    """Which residual rows enter the per-sample error of the metrics (a pose: position only)."""
    return slice(0, 3) if isinstance(measurement, Pose) else slice(0, measurement.size)


def _error_points(measurement) -> int:
    """The per-sample error is ``sqrt(Σ rows² / this)``: a camera image's error is the RMS over its
    target points (:meth:`jaxcal.Camera.sample_error`), every other model's the norm of its rows
    (:attr:`~jaxcal._sensors._measurement.MeasurementModel.error_points`)."""
    return int(measurement.error_points)


def predicted_accuracy(
    robot: AbstractRobot,
    measurement: MeasurementModel,
    q,
    noise_std: float,
    *,
    q_test=None,
    space: ParameterSpace | None = None,
    prior=None,
    key=None,
    n_test: int = 2000,
) -> PredictedAccuracy:
    """Predicted accuracy of calibrating from the poses ``q`` ``[n, dof]`` (rad), before measuring.

    ``Σ = σ²(JᵀJ + σ²·diag(1/σ_j²))⁻¹`` ``[p, p]`` (the posterior covariance) on the free set
    :func:`jaxcal.calibrate` would choose at the planned poses: the identifiable subset of
    ``space`` without a prior, every parameter the prior covers with one (``prior``:
    :class:`jaxcal.Prior`; default none, as :func:`jaxcal.calibrate`), and the expected test RMSE over the workspace
    ``sqrt(m_e·σ² + mean_t tr(J_t Σ J_tᵀ))`` over the held-out poses ``q_test`` (default
    ``n_test`` candidate poses from ``key``, :func:`candidate_poses` with its default filters),
    ``m_e`` the residual entries of the per-sample error (1 for a wire length, a plane
    distance, a sphere or a bar; 3 for a position or a pivot point; the position part of a
    pose; a camera image's ``2N`` rows divided by ``N``: the RMS reprojection error per target
    point, px, with ``noise_std`` in px). ``q`` and ``q_test`` may be candidates with readings
    (:func:`candidate_rows`: contact labels, bar pose pairs). Linearised at the nominal robot: it assumes
    Gaussian noise of σ on every residual entry, an unbiased model and small deviations
    (checked against simulated calibrations in ``tests/experiments/test_plan.py`` and
    ``benchmarks/bench_plan.py``).
    """
    q, y = candidate_rows(robot, measurement, q)
    base = ParameterSpace.for_robot(robot, measurement=measurement) if space is None else space
    space = _identifiable_space(robot, measurement, base, q, prior, y)
    J = planning_jacobian(robot, measurement, q, space, y).reshape(-1, space.n_free)
    cov = _covariance(J, noise_std, _prior_precision(space, prior))
    if q_test is None:
        q_test = candidate_poses(jax.random.key(1) if key is None else key, robot, measurement, n_test)
    Jt = planning_jacobian(robot, measurement, q_test, space)[:, _error_rows(measurement), :]
    m_e = Jt.shape[1]
    pts = _error_points(measurement)
    var = np.einsum("tap,pq,taq->t", Jt, cov, Jt)
    test = math.sqrt((m_e * noise_std**2 + float(np.mean(var))) / pts)
    N = J.shape[0]
    p_eff = float(np.trace(J.T @ J @ cov)) / noise_std**2  # = p without a prior
    train = noise_std * math.sqrt(max(measurement.size * (1.0 - p_eff / N), 0.0) / pts) \
        if m_e == measurement.size else float("nan")
    return PredictedAccuracy(test, train, float(noise_std), space.free_names, space.free_units,
                             np.sqrt(np.diag(cov)), cov, int(q.shape[0]), getattr(measurement, "unit", "mm"))


def simulate_readings(key, robot: AbstractRobot, measurement: MeasurementModel, q, noise_std: float, true_deviations=None):
    """Readings of a "true" robot at the planned poses ``q`` ``[n, dof]`` (rad) as a
    :class:`Dataset`: the truth is drawn as in :func:`jaxcal.simulate_experiment` (the paper's
    Table V magnitudes) unless given; Gaussian noise σ = ``noise_std`` mm on every reading (a
    pose: on its position). Returns ``(dataset, true_deviations)``."""
    from .._simulation._simulate import draw_deviations

    k_dev, k_noise = jax.random.split(key)
    dtype = jnp.result_type(float)
    q = jnp.asarray(q, dtype)
    truth = draw_deviations(k_dev, robot, dtype=dtype) if true_deviations is None else true_deviations
    y = measurement.predict(robot, truth, q)
    if isinstance(measurement, (CableLength, Position)):
        y = y + noise_std * jax.random.normal(k_noise, y.shape, dtype)
    else:
        y = y.at[:, :3, 3].add(noise_std * jax.random.normal(k_noise, y[:, :3, 3].shape, dtype))
    return Dataset(q, y, measurement.kind), truth


def simulated_test_rmse(robot, measurement, q, q_test, noise_std: float, n_seeds: int, *, seed: int = 0,
                        method="lm") -> np.ndarray:
    """The check of a prediction by simulation: ``n_seeds`` calibrations (``method``) from
    readings at the planned poses ``q`` of truths drawn as in :func:`simulate_readings`, each
    evaluated on fresh readings at ``q_test`` of the same truth. Returns the ``[n_seeds]`` test
    RMSEs (mm); seed ``s`` uses ``jax.random.key(seed + s)``."""
    import warnings

    from .._calibration._calibrate import calibrate

    out = []
    for s in range(int(n_seeds)):
        k1, k2 = jax.random.split(jax.random.key(seed + s))
        train, truth = simulate_readings(k1, robot, measurement, q, noise_std)
        test, _ = simulate_readings(k2, robot, measurement, q_test, noise_std, true_deviations=truth)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = calibrate(robot, measurement, train, method)
        out.append(float(res.evaluate(test).rmse))
    return np.asarray(out)


# -- how many poses ---------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class AccuracyCurve:
    """Predicted test RMSE (mm) vs number of poses: selected (greedy prefixes of one ranking)
    and random (prefixes of a random order of the candidates). See :func:`accuracy_curve`.

    Attributes:
        n: ``[k]`` numbers of poses.
        selected, random: ``[k]`` predicted test RMSE (mm).
        simulated_selected, simulated_random: ``[k]`` mean simulated test RMSE (mm) or ``None``.
        criterion: the selection criterion.
        noise_std: σ (mm).
    """

    n: np.ndarray
    selected: np.ndarray
    random: np.ndarray
    criterion: str
    noise_std: float
    simulated_selected: np.ndarray | None = None
    simulated_random: np.ndarray | None = None

    def poses_needed(self, target_rmse: float) -> int | None:
        """The smallest ``n`` of the curve whose predicted (selected) test RMSE ≤ ``target_rmse``."""
        ok = np.flatnonzero(self.selected <= target_rmse)
        return int(self.n[ok[0]]) if ok.size else None

    def plot(self, ax=None, target_rmse: float | None = None):
        """Draw the curve (matplotlib); returns the Figure."""
        from matplotlib.figure import Figure

        if ax is None:
            fig = Figure(figsize=(6.4, 4.0))
            ax = fig.add_subplot()
        else:
            fig = ax.figure
        ax.plot(self.n, self.selected, "-", color="C0", label=f"{self.criterion}-optimal (predicted)")
        ax.plot(self.n, self.random, "-", color="C1", label="random (predicted)")
        if self.simulated_selected is not None:
            ax.plot(self.n, self.simulated_selected, "o", color="C0", label=f"{self.criterion}-optimal (simulated mean)")
        if self.simulated_random is not None:
            ax.plot(self.n, self.simulated_random, "s", color="C1", mfc="none", label="random (simulated mean)")
        if target_rmse is not None:
            ax.axhline(target_rmse, color="0.5", ls="--", lw=1, label=f"target {target_rmse:.3f} mm")
        ax.axhline(self.noise_std, color="0.7", ls=":", lw=1, label=f"noise σ = {self.noise_std:g} mm")
        ax.set_xlabel("number of measured poses")
        ax.set_ylabel("test RMSE / mm")
        ax.set_xscale("log")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        return fig


def accuracy_curve(
    robot: AbstractRobot,
    measurement: MeasurementModel,
    candidates,
    ns,
    noise_std: float,
    *,
    q_test=None,
    criterion: str = "D",
    space: ParameterSpace | None = None,
    prior=None,
    key=None,
) -> AccuracyCurve:
    """Predicted test RMSE vs the number of poses ``ns`` for greedy selection from
    ``candidates`` (the first ``n`` greedy picks; no exchange, so the sets are nested) and for
    random poses (the first ``n`` of a permutation of the candidates drawn from ``key``)."""
    ns = np.asarray(sorted(int(n) for n in ns))
    sel = select_poses(robot, measurement, candidates, int(ns[-1]), criterion=criterion, exchange=False,
                       space=space, prior=prior, noise_std=noise_std)
    n_cand = candidate_rows(robot, measurement, candidates)[0].shape[0]
    order = np.asarray(jax.random.permutation(jax.random.key(0) if key is None else key, n_cand))
    if q_test is None:
        q_test = candidate_poses(jax.random.key(1), robot, measurement, 2000)
    # one Jacobian of all candidates (on the candidates' identifiable subset), rows taken per set
    J = planning_jacobian(robot, measurement, candidates, sel.space)
    Jt = planning_jacobian(robot, measurement, q_test, sel.space)[:, _error_rows(measurement), :]
    info0 = _prior_precision(sel.space, prior)
    pts = _error_points(measurement)
    f = lambda idx: _test_rmse(J[idx].reshape(-1, J.shape[2]), Jt, noise_std, info0, pts)  # noqa: E731
    return AccuracyCurve(ns, np.asarray([f(sel.index[:n]) for n in ns]), np.asarray([f(order[:n]) for n in ns]),
                         criterion, float(noise_std))


def _prior_precision(space, prior) -> np.ndarray:
    """``[p]`` prior precisions ``1/σ_j²`` (0 = no prior)."""
    from .._fit._objective import resolve_prior

    prior = resolve_prior(prior)
    if prior is None:
        return np.zeros(space.n_free)
    sd = prior.std(space)
    return np.where(np.isfinite(sd), 1.0 / sd**2, 0.0)


def _covariance(J, noise_std, prior_precision) -> np.ndarray:
    info = J.T @ J / noise_std**2 + np.diag(prior_precision)
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return np.full(info.shape, np.inf)
    return 0.5 * (cov + cov.T)


def _test_rmse(J, Jt, noise_std, prior_precision, points: int = 1) -> float:
    cov = _covariance(J, noise_std, prior_precision)
    var = np.einsum("tap,pq,taq->t", Jt, cov, Jt)
    return math.sqrt((Jt.shape[1] * noise_std**2 + float(np.mean(var))) / points)


# -- files ------------------------------------------------------------------------------------------


def save_plan_csv(path, q, kind: str, metadata=()) -> None:
    """Write planned joint angles ``q`` ``[n, dof]`` (rad; mm at the prismatic joints that an
    ``mm_joints`` metadata entry names) as a data file with empty measurement columns: once the
    readings are filled in, :func:`jaxcal.load_csv` and ``jaxcal calibrate`` read it (joint
    angles in degrees, the shortest decimals that read back to the same float)."""
    from .._datasets._dataset import joint_columns_out, mm_joints
    from .._sensors._kind import sensor_kind

    columns = sensor_kind(kind).columns
    names, cols = joint_columns_out(np.asarray(q, np.float64), mm_joints(metadata))
    lines = ["# jaxcal dataset v1", f"# kind: {kind}"] + [f"# {k}: {v}" for k, v in metadata]
    lines.append(",".join(names + list(columns)))
    blanks = "," * len(columns)
    lines += [",".join(repr(float(v)) for v in row) + blanks for row in cols]
    with open(path, "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")


def load_joint_angles(path, dof: int) -> np.ndarray:
    """Joint coordinates ``[n, dof]`` from a CSV file: columns ``q1_deg … qN_deg`` (or ``q1_rad …``),
    prismatic joints as ``q<j>_mm`` (kept in mm), read like :func:`jaxcal.load_csv` (delimiter,
    byte-order mark, case, any column order); other columns are ignored. Angles in rad."""
    from .._core._csvfile import read_table
    from .._datasets._dataset import _joint_columns, joint_values

    t = read_table(path, what="joint-angle file", row_name="row")
    cols, unit = _joint_columns(t.path, t.header, dof)
    if not t.rows:
        raise ValueError(f"{t.path}: no rows")
    q, _ = joint_values(t.path, t.floats(cols), cols, unit)
    return q
