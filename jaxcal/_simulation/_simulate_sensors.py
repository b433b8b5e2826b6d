"""Simulated data of the contact, distance-bar and camera models (true set-up, poses that satisfy
the constraint, noise), as :class:`~jaxcal.Experiment` splits.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._core._buckets import pad_rows
from .._core._params import Deviations, layout_for
from .._core._xla import filter_jit
from .._models._kinematics import tool_point_soa
from .._sensors._camera import Camera, _log, _predict_jit, _setup_frames, default_camera
from .._sensors._contact import DistanceBar, _sample_q, default_setup, label_metadata_key

__all__ = ["simulate_contact", "simulate_distance", "simulate_camera"]



def _true_deviations(k_dev, robot, layout, true_deviations, angle_std_deg, length_std_mm, tool_std_mm, dtype):
    """The simulated robot's deviations: the given ones, or drawn (the experiment's defaults where a
    std is ``None``) and restricted to the model's parameter groups."""
    from ._simulate import DEFAULT_ANGLE_STD_DEG, DEFAULT_LENGTH_STD_MM

    if true_deviations is None:
        true_deviations = _draw_true(k_dev, robot, layout,
                                     DEFAULT_ANGLE_STD_DEG if angle_std_deg is None else angle_std_deg,
                                     DEFAULT_LENGTH_STD_MM if length_std_mm is None else length_std_mm,
                                     tool_std_mm, dtype)
    return true_deviations.astype(dtype)


@filter_jit
def _draw_true(k_dev, robot, layout, angle_std_deg, length_std_mm, tool_std_mm, dtype):
    """:func:`~jaxcal.draw_deviations` restricted to ``layout``'s groups, one compiled program
    (a jitted wrapper made at module level: one made per call was traced again every call)."""
    from ._simulate import draw_deviations

    dh = draw_deviations(k_dev, robot, angle_std_deg=angle_std_deg, length_std_mm=length_std_mm,
                         tool_std_mm=tool_std_mm, dtype=dtype)
    return Deviations({g: v for g, v in dh.values.items() if g in layout.group_names}, layout, dtype)


#: rows per call of the programs that score candidate rows (constraint values, tool points): the
#: rows are padded to a multiple of it, so each compiles once per model, not once per number of
#: samples; their values are bit-identical to one call over all rows. (Not the Newton steps: in
#: blocks, their results differ in the last bit from one call over all rows.)
_CHUNK = 2048


def _chunked(fn, q, labels=None):
    """``fn(q_block[, labels_block])`` ``[n, ...]`` over the rows in blocks of :data:`_CHUNK`, the
    last one padded (:func:`~jaxcal._core._buckets.pad_rows`), concatenated on the host (NumPy)."""
    q = np.asarray(q)
    labels = None if labels is None else np.asarray(labels)
    if q.shape[0] == 0:
        return np.asarray(fn(q) if labels is None else fn(q, labels))
    outs = []
    for i in range(0, q.shape[0], _CHUNK):
        qc = q[i:i + _CHUNK]
        lc = None if labels is None else labels[i:i + _CHUNK]
        m = qc.shape[0]
        qp, lp, _ = pad_rows(qc, lc, _CHUNK, host=True)
        outs.append(np.asarray(fn(qp) if labels is None else fn(qp, lp))[:m])
    return np.concatenate(outs, axis=0)


@filter_jit
def _split(key, n: int):
    return tuple(jax.random.split(key, n))


@filter_jit
def _normal(key, shape, dtype):
    """``N(0, 1)`` draws of ``shape`` (scaled by σ on the host: scaled inside the program, one
    value in ~1000 came out one bit different from the former eager product)."""
    return jax.random.normal(key, shape, dtype)


@filter_jit
def _permutation(key, n: int):
    return jax.random.permutation(key, n)


@filter_jit
def _sample_q_jit(key, robot, n: int):
    return _sample_q(key, robot, n)


def _row_constraint(robot, dev, m, qi, k):
    """The constraint of one row, ``[m]``: signed distance / ``p − c`` / sphere distance."""
    p = jnp.stack(tool_point_soa(robot, dev, qi[None]), -1)[0]
    return m.gap(dev, p, k, qi.dtype)


@filter_jit
def _candidates(robot, key, n: int, n_labels: int):
    """``n`` random joint-angle rows ``[n, dof]`` and their labels in turn ``[n]`` (one program for
    every model with that many labels); their distances to the labels' constraints: :func:`_scores`
    (in blocks of rows, one program per model)."""
    q = _sample_q(key, robot, n)
    return q, jnp.arange(n) % n_labels


@filter_jit
def _scores(robot, dev, m, q, labels):
    """Each row's distance to its label's constraint ``[n]``, in one compiled program (op by op,
    this was hundreds of small programs)."""
    g = jax.vmap(lambda qi, ki: _row_constraint(robot, dev, m, qi, ki))(q, labels)
    return jnp.linalg.norm(g, axis=1)


@filter_jit
def _tool_points(robot, dev, q):
    """Tool points ``[n, 3]`` (mm) of the rows ``q``, compiled."""
    return jnp.stack(tool_point_soa(robot, dev, q), -1)


@filter_jit
def _newton_step(robot, dev, m, q, k, target):
    g = jax.vmap(lambda qi, ki: _row_constraint(robot, dev, m, qi, ki))(q, k)
    J = jax.vmap(jax.jacfwd(lambda qi, ki: _row_constraint(robot, dev, m, qi, ki)))(q, k)  # [n, m, dof]
    e = g - target
    JJt = jnp.einsum("nij,nkj->nik", J, J) + 1e-9 * jnp.eye(J.shape[1])
    step = jnp.einsum("nji,nj->ni", J, jnp.linalg.solve(JJt, e[..., None])[..., 0])
    return q - step, jnp.max(jnp.abs(e), axis=1)


def simulate_contact(key, robot, measurement=None, *, n_samples: int = 300, noise_std: float = 0.05,
                     test_fraction: float = 0.2, true_deviations: Deviations | None = None,
                     angle_std_deg: float | None = None, length_std_mm: float | None = None,
                     tool_std_mm: float = 2.0, oversample: int = 6, iterations: int = 30, tries: int = 2):
    """A simulated contact experiment (:class:`jaxcal.Experiment`).

    The true robot is the nominal one with random DH deviations (:func:`jaxcal.draw_deviations`)
    and a tool-point deviation of σ ``tool_std_mm``; the true planes / points are the
    ``measurement``'s nominal ones (default :func:`default_setup`). Rows get labels in turn;
    random joint angles nearest to their plane / point are moved onto it by minimum-norm Newton
    steps on the true robot, to a constraint value drawn from the noise (plane: a signed distance
    ``~ N(0, σ²)``; point: ``p − c ~ N(0, σ²I₃)``; sphere: ``‖p − c‖ − r ~ N(0, σ²)``), so the
    statistical floor is :func:`jaxcal.statistical_floor` with ``size`` = the model's residual
    size. Rows that leave the joint limits or do not converge are not used; ``tries`` rows per
    wanted row are moved (raise it where many fail). The drawn tool deviation is this
    simulation's own: ``jaxcal simulate`` passes the seed's set-up shared by every kind instead
    (:func:`~jaxcal._simulation._simulate_files.plane_file`, ``point_file``).

    Returns:
        :class:`jaxcal.Experiment` with ``train`` / ``test`` datasets (``y``: label indices;
        metadata ``plane_labels`` / ``point_labels``).
    """
    from .._datasets._dataset import Dataset, mm_joints_metadata
    from ._simulate import Experiment

    m = default_setup("plane", robot) if measurement is None else measurement
    dtype = jnp.result_type(float)
    k_dev, k_q, k_noise, k_split = _split(key, 4)
    layout = layout_for(robot, m)
    true_deviations = _true_deviations(k_dev, robot, layout, true_deviations, angle_std_deg, length_std_mm,
                                       tool_std_mm, dtype)
    K = len(m.labels)
    n_cand = n_samples * oversample
    cand, lab_all = _candidates(robot, k_q, n_cand * K, K)
    score = np.asarray(_chunked(lambda qc, lc: _scores(robot, true_deviations, m, qc, lc), cand, lab_all), np.float64)
    lab_np = np.asarray(lab_all)
    picks = []
    for k in range(K):  # per label the candidates nearest to it
        rows = np.flatnonzero(lab_np == k)
        picks.append(rows[np.argsort(score[rows])][: tries * (n_samples // K + 1)])
    order = np.stack(picks, 1).reshape(-1)  # labels in turn
    q = np.asarray(cand)[order]  # on the host: jnp indexing compiles a program per shape
    k = lab_np[order]
    msize = m.size
    target = noise_std * np.asarray(_normal(k_noise, (q.shape[0], msize), dtype))
    for _ in range(iterations):
        q_new, err = _newton_step(robot, true_deviations, m, q, k, target)  # all rows at once: blocks change the last bit
        if float(np.max(np.asarray(err))) < 1e-9:
            break
        q = q_new
    qn, errn = np.asarray(q), np.asarray(err)
    lo, hi = np.asarray(robot.q_min), np.asarray(robot.q_max)
    ok = (errn < 1e-6) & np.all((qn >= lo) & (qn <= hi), axis=1)
    idx = np.flatnonzero(ok)[:n_samples]
    if idx.size < n_samples:
        raise ValueError(f"simulate_contact: only {idx.size} of {n_samples} rows reached their contact inside the "
                         "joint limits; raise tries")
    meta = {"source": "simulate_contact", "robot": robot.name, label_metadata_key(m.kind): ",".join(m.labels),
            "noise_std_mm": str(noise_std), **mm_joints_metadata(robot)}
    data = Dataset(jnp.asarray(qn[idx], dtype), jnp.asarray(np.asarray(k)[idx], dtype), m.kind, meta)
    n_test = int(round(n_samples * test_fraction))
    perm = np.asarray(_permutation(k_split, n_samples))
    return Experiment(robot, m, true_deviations, data.subset(perm[n_test:]), data.subset(perm[:n_test]),
                      jnp.asarray(noise_std, dtype))


def _pair_constraint(robot, dev, qa, qb):
    pa = jnp.stack(tool_point_soa(robot, dev, qa[None]), -1)[0]
    pb = jnp.stack(tool_point_soa(robot, dev, qb[None]), -1)[0]
    return jnp.atleast_1d(jnp.linalg.norm(pa - pb))


@filter_jit
def _pair_step(robot, dev, qa, qb, target):
    g = jax.vmap(lambda a, b: _pair_constraint(robot, dev, a, b))(qa, qb)
    J = jax.vmap(jax.jacfwd(lambda b, a: _pair_constraint(robot, dev, a, b)))(qb, qa)  # [n, 1, dof]
    e = (g - target)[:, 0]
    step = J[:, 0] * (e / (jnp.sum(J[:, 0] ** 2, axis=1) + 1e-12))[:, None]
    return qb - step, jnp.abs(e)


def simulate_distance(key, robot, *, n_samples: int = 300, noise_std: float = 0.05, lengths_mm=(150.0, 300.0),
                      test_fraction: float = 0.2, true_deviations: Deviations | None = None,
                      angle_std_deg: float | None = None, length_std_mm: float | None = None,
                      tool_std_mm: float = 2.0, iterations: int = 30, tries: int = 2):
    """A simulated distance-bar experiment (:class:`jaxcal.Experiment`, model :class:`DistanceBar`).

    Pose *a* random within the joint limits (tool point above the base plane); pose *b* the random
    pose whose tool point is nearest to a bar length from *a*'s (lengths ``lengths_mm`` in turn),
    then moved by minimum-norm Newton steps on the true robot until the distance is ``L + ε``,
    ``ε ~ N(0, σ²)``; the reading holds ``L`` (the noise is in the bar's reading). Rows that
    leave the joint limits or do not converge are not used (``tries`` pairs are tried per wanted
    row)."""
    from .._datasets._dataset import Dataset, mm_joints_metadata
    from ._simulate import Experiment

    m = DistanceBar(robot.dof)
    dtype = jnp.result_type(float)
    k_dev, k_a, k_b, k_noise, k_split = _split(key, 5)
    layout = layout_for(robot, m)
    true_deviations = _true_deviations(k_dev, robot, layout, true_deviations, angle_std_deg, length_std_mm,
                                       tool_std_mm, dtype)
    n_try = tries * n_samples
    qa = np.asarray(_sample_q_jit(k_a, robot, n_try))
    pool = np.asarray(_sample_q_jit(k_b, robot, min(8 * n_try, 8192)))
    pa = _chunked(lambda qc: _tool_points(robot, true_deviations, qc), qa)
    pp = _chunked(lambda qc: _tool_points(robot, true_deviations, qc), pool)
    L = np.resize(np.asarray(lengths_mm, np.float64), n_try)
    best = np.empty(n_try, int)
    for i in range(0, n_try, 256):  # the pool pose nearest to a bar length away, in blocks (memory)
        dist = np.sqrt(((pa[i:i + 256, None, :] - pp[None, :, :]) ** 2).sum(-1))
        best[i:i + 256] = np.argmin(np.abs(dist - L[i:i + 256, None]), axis=1)
    qb = pool[best]
    eps = noise_std * np.asarray(_normal(k_noise, (n_try,), dtype))
    target = np.asarray(L + eps, dtype)[:, None]
    for _ in range(iterations):
        qb_new, err = _pair_step(robot, true_deviations, qa, qb, target)  # all rows at once (as above)
        if float(np.max(np.asarray(err))) < 1e-9:
            break
        qb = qb_new
    qa_n, qb_n, errn = np.asarray(qa), np.asarray(qb), np.asarray(err)
    lo, hi = np.asarray(robot.q_min), np.asarray(robot.q_max)
    ok = (errn < 1e-6) & np.all((qb_n >= lo) & (qb_n <= hi), axis=1) & (pa[:, 2] > 0)
    idx = np.flatnonzero(ok)[:n_samples]
    if idx.size < n_samples:
        raise ValueError(f"simulate_distance: only {idx.size} of {n_samples} pose pairs converged inside the limits")
    y = np.concatenate([qb_n[idx], L[idx, None]], axis=1)
    meta = {"source": "simulate_distance", "robot": robot.name, "noise_std_mm": str(noise_std),
            **mm_joints_metadata(robot)}
    data = Dataset(jnp.asarray(qa_n[idx], dtype), jnp.asarray(y, dtype), "distance", meta)
    n_test = int(round(n_samples * test_fraction))
    perm = np.asarray(_permutation(k_split, n_samples))
    return Experiment(robot, m, true_deviations, data.subset(perm[n_test:]), data.subset(perm[:n_test]),
                      jnp.asarray(noise_std, dtype))


def simulate_camera(key, robot, camera: Camera | None = None, *, n_views: int = 30, noise_px: float = 0.3,
                    true_deviations: Deviations | None = None, missing: float = 0.0, distance_mm: float = 450.0,
                    joint_spread_deg=(8.0, 8.0, 8.0, 25.0, 25.0, 25.0), home=None, oversample: int = 40):
    """Simulated camera calibration data: ``(q [n, dof] rad, y [n, N, 2] px, camera, truth)``.

    The true robot is nominal + ``true_deviations`` (default :func:`~jaxcal.draw_deviations`:
    0.2°, 0.6 mm). Views are joint angles around ``home`` (default the middle of the joint
    ranges) spread uniformly by ``joint_spread_deg`` (per joint, ± degrees; the last value repeats),
    kept when every target point lies in front of the camera and inside the image (the target in
    view). The true set-up: eye-in-hand, a camera 60 mm off the flange axis looking along the
    flange z axis, and the target ``distance_mm`` in front of the camera at ``home``; eye-to-hand,
    the target 60 mm off the flange, the camera ``distance_mm`` from it looking at it at ``home``;
    tip to tip (self-observation on a :class:`~jaxcal.KinematicTree`: the camera on ``camera.tip``,
    a head, the target on ``camera.target_tip``, a hand), the camera's optical centre 27 mm off tip
    A's link origin and the target's centre 44 mm off tip B's, camera and target facing each other
    at ``home`` (``distance_mm`` is not used: the tips' distance is the robot's; choose a ``home``
    with the hand in front of the head, and a ``joint_spread_deg`` per joint of the tree). Both
    tips' frames come from the tree's frame kernel, so every joint on either path, shared or not,
    moves the images as the model says.
    The true hand-eye/target poses are returned in ``truth`` and written into the deviations of
    the returned ``camera`` model's groups relative to its nominal (identity) frames.

    Args:
        key: ``jax.random`` key. camera: model to simulate (default: eye-in-hand, a 9×6
            checkerboard of 20 mm squares, 1280×1024 px, f = 1000 px, mild distortion); its
            hand-eye and target frames are replaced by the true ones above.
        noise_px: Gaussian σ per image coordinate (px). missing: fraction of corners made NaN
            (not detected) at random.

    Returns:
        ``(q, y, camera, truth)`` with ``truth`` the true :class:`~jaxcal.Deviations` (DH + the
        camera groups relative to ``camera``'s nominal frames).
    """
    from ._simulate import draw_deviations

    rng = np.random.default_rng(np.asarray(jax.random.key_data(key)).ravel().tolist())
    camera = default_camera("eye_in_hand") if camera is None else camera
    if camera.image_size is None:
        raise ValueError("simulate_camera needs the camera's image_size to keep the target in view")
    dtype = jnp.result_type(float)
    layout = layout_for(robot, camera)
    if true_deviations is None:
        true_deviations = draw_deviations(jax.random.fold_in(key, 1), robot, dtype=dtype)
    base = {g: v for g, v in true_deviations.values.items() if g in layout.group_names}
    truth = Deviations(base, layout, dtype=dtype)
    lo, hi = np.asarray(robot.q_min, np.float64), np.asarray(robot.q_max, np.float64)
    home = (lo + hi) / 2 if home is None else np.asarray(home, np.float64)
    X, B = _setup_frames(robot, camera, truth, home, distance_mm)
    truth = truth.replace(
        handeye_rotation=_log(X[:3, :3] @ np.asarray(camera.handeye_rotation, np.float64).T),
        handeye_translation=X[:3, 3] - np.asarray(camera.handeye_translation, np.float64),
        target_rotation=_log(B[:3, :3] @ np.asarray(camera.target_rotation, np.float64).T),
        target_translation=B[:3, 3] - np.asarray(camera.target_translation, np.float64))
    spread = np.deg2rad(np.resize(np.asarray(joint_spread_deg, np.float64), robot.dof))
    n_cand = n_views * oversample
    cand = home + rng.uniform(-1, 1, (n_cand, robot.dof)) * spread
    cand = np.clip(cand, lo, hi)
    y_true, pz = (np.asarray(a, np.float64) for a in _predict_jit(camera, robot, truth, jnp.asarray(cand, dtype)))
    w, h = camera.image_size
    ok = (pz > 1.0).all(axis=1) & (y_true[..., 0] >= 0).all(axis=1) & (y_true[..., 0] <= w).all(axis=1) \
        & (y_true[..., 1] >= 0).all(axis=1) & (y_true[..., 1] <= h).all(axis=1)
    idx = np.flatnonzero(ok)
    if idx.size < n_views:
        raise ValueError(f"simulate_camera: only {idx.size} of {n_cand} candidate poses see the whole target; "
                         "lower joint_spread_deg, raise oversample or distance_mm")
    idx = idx[:n_views]
    q = cand[idx]
    y = y_true[idx] + noise_px * rng.standard_normal(y_true[idx].shape)
    if missing > 0:
        drop = rng.random(y.shape[:2]) < missing
        y[drop] = np.nan
    return jnp.asarray(q, dtype), jnp.asarray(y, dtype), camera, truth
