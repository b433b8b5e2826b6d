"""Starting values for the sensor's unknowns, from the data, before the kinematic fit.

Real setups do not know where the draw-wire leaves its housing (the anchor), the cable's zero
offset, where a laser tracker stands relative to the robot base, nor exactly where the wire or
the target is attached to the flange (the tool point); a first guess can be 500 mm off, and local
solvers started there land in nonsense. With the nominal robot (plus the DH
part of ``start``) the flange frames ``(P_i, F_i)`` (origin ``[3]`` mm, rotation ``[3, 3]``) are
known to a few mm, so the sensor unknowns follow in closed form. ``t`` is the tool point in the
flange frame (nominal + ``tool`` deviation, mm) and ``p_i = P_i + F_i t`` the tool points:

* **Draw-wire** (``L_i = ‖p_i − c‖ + o``): multilateration. Squaring ``L_i − o = ‖p_i − c‖``
  gives equations linear in ``(c, o, k = o² − ‖c‖²)``:
  ``‖p_i‖² − L_i² = 2 p_i·c − 2 L_i o + k`` (without an offset: ``o = 0``, unknowns ``c, k``),
  solved by least squares, then refined by Gauss–Newton on the true distances. Points of a
  narrow session lie close to a surface, where the linear solution is poorly determined across
  it and the distance equations have a mirror solution; the refinement starts from the linear
  solution, its mirror image through the points' best-fit plane and the user's guess, and keeps
  the best fit (ties: nearest the guess).
  **With the tool point** (``L_i = ‖P_i + F_i t − c‖ + o``, not linear in ``t``): multilateration
  with ``t`` at its guess ``t₀``, then Levenberg–Marquardt on ``(c, o, t)`` (7 unknowns, those
  estimated) with the derivatives ``∂L_i/∂c = −u_i``, ``∂L_i/∂o = 1``, ``∂L_i/∂t = F_iᵀu_i``
  (``u_i`` the unit wire direction), minimising ``Σ r_i² + w‖t − t₀‖²`` with
  ``w = σ̂²/σ_t²`` (σ̂ the RMS residual, σ_t = :data:`TOOL_PRIOR_STD_MM`): a weak Gaussian prior
  toward the guess that only holds directions the data barely see (a session whose flange
  barely turns cannot tell the tool from the anchor). The result is never worse (RMS) than the
  multilateration start.
* **Position sensors** (``y_i = R p_i + b``, ``(R, b) = T_sensor_base``): the rigid transform by
  Kabsch/Horn (SVD of the cross-covariance of centred point sets; Horn, 1987; Kabsch, 1976).
  **With the tool point** (``y_i = R(P_i + F_i t) + b``): the one-marker case of the markers
  start below (:func:`alternate_frames_and_markers`): Kabsch for ``(R, b)`` given ``t``,
  ``t = mean_i F_iᵀ(Rᵀ(y_i − b) − P_i)`` given the frame (exact least squares: ``F_i``, ``R``
  orthonormal), alternating until nothing moves; with a known frame only the latter, once.
* **Pose sensors** (``T_sensor_tool,i = [R F_i, R(P_i + F_i t) + b]``): the rotation from the
  rotation readings, the chordal L2 mean ``R = argmin Σ‖R − R_y,i F_iᵀ‖_F² = Π_SO(3)(Σ R_y,i F_iᵀ)``
  (SVD projection); then ``(t, b)`` from the positions by one linear least-squares solve of
  ``F_i t + b' = Rᵀy_i − P_i`` (``b' = Rᵀb``, 6 unknowns; the same weak prior on ``t``). Without
  the tool: ``b' = mean_i(Rᵀy_i − P_i − F_i t₀)``; with a known frame: ``t = mean_i F_iᵀ(Rᵀ(y_i − b) − P_i)``.
* **Markers** (``y_ik = R (P_i + F_i m_k) + t``, flange frames ``(P_i, F_i)`` of the nominal
  robot): the sensor frame by Kabsch on the marker centroids (``m̄`` from the guessed layout),
  then alternating least squares: each marker's flange-frame position given the frame
  (``m_k = mean_i F_iᵀ(Rᵀ(y_ik − t) − P_i)``, exact because ``F_i`` is orthonormal) and the
  frame by Kabsch on every marker point given the positions, until nothing moves. (The marker
  positions are the tool: the ``tool`` extras do not apply.)

Each is refit once without the samples whose residual exceeds 5 robust standard deviations
(gross outliers must not move the start; the calibration itself reports them).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .._core._buckets import LeanJit, pad_model_rows
from .._core._metrics import robust_scale
from .._core._params import Deviations
from .._core._precision import to_device, uncommitted
from .._core._xla import jit

__all__ = ["ExtrasEstimate", "multilaterate", "wire_with_tool", "kabsch", "project_rotation",
    "pose_from_markers"]


#: σ (mm) of the weak prior toward the guessed tool point in the draw-wire and pose starts: it
#: holds only the directions the data barely see (bias ``w/(s² + w)`` along a direction with
#: singular value ``s``, ``w = σ̂²/σ_t²``; with σ̂ = 1 mm, w = 1.6e-5).
TOOL_PRIOR_STD_MM = 250.0


class ExtrasEstimate(NamedTuple):
    """Result of :func:`initial_extras`.

    Attributes:
        deviations: the start: ``start`` (or nominal) with the estimated extras filled in.
        rmse_before, rmse_after: RMS residual (mm) of the nominal robot with the guessed and with
            the estimated extras.
        n_trimmed: samples left out of the final closed-form fit as gross outliers.
        message: one line for logs and the CLI.
    """

    deviations: Deviations
    rmse_before: float
    rmse_after: float
    n_trimmed: int
    message: str


#: the measurement model's residual and per-sample error, compiled once per shape (host-side use)
def _residual_of(measurement, robot, deviations, q, y):
    return measurement.residual(robot, deviations, q, y)


_residual = jit(_residual_of)
_sample_error = jit(lambda measurement, r: measurement.sample_error(r))
#: the residual program of host-side checks: one per (models, row bucket), every deviations
_residual_rows = LeanJit(_residual_of, maxsize=16)


def residual_rows(measurement, robot, deviations: Deviations, q, y, *, pad: bool = True) -> np.ndarray:
    """``measurement.residual`` of ``robot + deviations`` as NumPy ``[n, m]`` (mm), from one compiled
    program per models and shape bucket whatever the deviations (the closed-form starts' RMS, the
    calibration's robust scales and outlier scans, an evaluation's per-row errors): the rows are
    padded to their bucket (``pad=False``: as given, rows a caller padded itself) and the deviations
    taken as uncommitted host values (``jax.jit`` compiles per placement too)."""
    n = int(q.shape[0])
    if pad:
        measurement, q, y, _ = pad_model_rows(measurement, q, y)
    q = to_device(q)
    return np.asarray(_residual_rows(measurement, robot, uncommitted(deviations), q, to_device(y, q.dtype)))[:n]


def has_plain_row_error(measurement) -> bool:
    """Whether ``measurement``'s per-row error (:meth:`~jaxcal.MeasurementModel.sample_error`) is the
    plain one of its residual block, which :func:`plain_row_errors` takes on the host: the signed
    entry of a length, the Euclidean norm of a position, a pose's position part (not, e.g., the RMS
    over a marker set)."""
    from ._measurement import MeasurementModel, Pose

    return type(measurement).sample_error in (MeasurementModel.sample_error, Pose.sample_error)


def plain_row_errors(measurement, r) -> np.ndarray:
    """The per-row error ``[n]`` of residual blocks ``r`` ``[n, m]`` (NumPy) for a model whose
    :meth:`~jaxcal.MeasurementModel.sample_error` is the plain one: the signed entry of a length,
    the Euclidean norm of a pose's position part, else of the whole block."""
    r = np.asarray(r, np.float64)
    if measurement.size == 1:
        return r[:, 0].copy()
    return np.linalg.norm(r[:, :3] if measurement.kind == "pose" else r, axis=1)


def row_errors(measurement, r) -> np.ndarray:
    """The per-row errors ``[n]`` (NumPy) of residual blocks ``r`` ``[n, m]``: :func:`plain_row_errors`
    where the model's error is the plain one, else its
    :meth:`~jaxcal.MeasurementModel.sample_error` compiled once per model and shape (op by op
    outside ``jit`` it runs as a handful of small programs)."""
    if has_plain_row_error(measurement):
        return plain_row_errors(measurement, r)
    return np.asarray(_sample_error(measurement, to_device(r)), np.float64)


def tip_frames(robot, measurement, q, start: Deviations | None) -> np.ndarray:
    """``T_base_link`` ``[n, 4, 4]`` (mm) of the link frame ``measurement`` sees at ``q`` (the flange,
    or the link of its ``tip`` on a :class:`~jaxcal.KinematicTree`), robot at ``start``: the
    frames the closed-form starts work from (one compiled program per tip and shape bucket)."""
    from .._models._kinematics import fk_pose_jit

    return np.asarray(fk_pose_jit(robot, q, start, tip=measurement.tip_for(robot)), np.float64)


def tool_guess(robot, measurement, start: Deviations) -> tuple[np.ndarray, np.ndarray]:
    """``(nominal, guess)`` ``[3]`` mm of the tool point ``measurement`` sees, in its link frame:
    the robot's nominal tool point of that tip and it plus ``start``'s deviation of the model's
    :attr:`~jaxcal.MeasurementModel.tool_group`."""
    tip = measurement.tip_for(robot)
    tools = getattr(robot, "tools", None)  # a tree's, sliced on the host (a slice of a JAX array is a program)
    nominal = (np.asarray(robot.tool if tip is None else robot.tool_of(tip), np.float64) if tools is None
               else np.asarray(tools, np.float64)[robot.tip_index(tip)])
    return nominal, nominal + np.asarray(start.values[measurement.tool_group], np.float64)


def with_tool(dev: Deviations, robot, measurement, tool) -> Deviations:
    """``dev`` with the model's tool group set so that its tool point is ``tool`` ``[3]`` mm."""
    nominal, _ = tool_guess(robot, measurement, dev)
    return dev.replace(**{measurement.tool_group: np.asarray(tool, np.float64) - nominal})


#: Rows whose closed-form-start residual is beyond this many robust σ are left out of the start.
TRIM_ROBUST_SIGMAS = 5.0


def trimmed_note(n_trim: int, what: str = "row") -> str:
    """The words a closed-form start's message ends with for the ``n_trim`` rows (``what``: "row",
    "sample") :func:`_trim` left out of it: on clean data these are the nominal robot's largest
    errors, not bad readings, and the calibration keeps every one ("" for none)."""
    if not n_trim:
        return ""
    return (f", {n_trim} {what}(s) beyond {TRIM_ROBUST_SIGMAS:g} robust σ left out of this start only: the nominal "
            "robot's largest errors or gross outliers; the calibration keeps them and judges outliers after its fit")


def _trim(res: np.ndarray, k: float = TRIM_ROBUST_SIGMAS) -> np.ndarray:
    s = robust_scale(res)
    if not (s > 0 and math.isfinite(s)):
        return np.ones(res.shape, bool)
    return np.abs(res - np.median(res)) <= k * s


def multilaterate(points, lengths, *, offset: bool = True, guess=None, iterations: int = 50):
    """Anchor ``c`` [3] (mm) and cable offset ``o`` (mm) with ``lengths ≈ ‖points − c‖ + o``.

    Args:
        points: ``[n, 3]`` tool points (mm), ``lengths``: ``[n]`` wire readings (mm).
        offset: estimate ``o`` (else ``o = 0``).
        guess: ``[3]`` anchor guess (tie-break and an extra start); default the linear solution.

    Returns:
        ``(c [3], o, rms)`` with ``rms`` the RMS residual of the fit (mm).
    """
    P = np.asarray(points, np.float64)
    L = np.asarray(lengths, np.float64)
    n = P.shape[0]
    need = 6 if offset else 5
    if n < need:
        raise ValueError(f"multilateration needs at least {need} samples, got {n}")
    b = np.sum(P * P, axis=1) - L * L
    cols = [2 * P] + ([-2 * L[:, None]] if offset else []) + [np.ones((n, 1))]
    A = np.concatenate(cols, axis=1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c_lin, o_lin = sol[:3], (sol[3] if offset else 0.0)

    def residual(c, o):
        return np.linalg.norm(P - c, axis=1) + o - L

    def refine(c, o):
        c, o = c.astype(np.float64).copy(), float(o)
        lam = 1e-3
        r = residual(c, o)
        for _ in range(iterations):
            d = P - c
            dist = np.maximum(np.linalg.norm(d, axis=1), 1e-9)
            J = -d / dist[:, None]
            if offset:
                J = np.concatenate([J, np.ones((n, 1))], axis=1)
            H = J.T @ J
            g = J.T @ r
            step = np.linalg.lstsq(H + lam * np.diag(np.diag(H) + 1e-12), -g, rcond=None)[0]
            c_new = c + step[:3]
            o_new = o + (step[3] if offset else 0.0)
            r_new = residual(c_new, o_new)
            if np.sum(r_new**2) < np.sum(r**2):
                c, o, r, lam = c_new, o_new, r_new, lam / 10
                if np.linalg.norm(step) < 1e-9 * (1 + np.linalg.norm(c)):
                    break
            else:
                lam *= 10
                if lam > 1e12:
                    break
        return c, o, float(np.sqrt(np.mean(r**2)))

    starts = [(c_lin, o_lin)]
    # mirror of the linear solution through the points' best-fit plane
    centre = P.mean(axis=0)
    _, _, Vt = np.linalg.svd(P - centre, full_matrices=False)
    normal = Vt[-1]
    starts.append((c_lin - 2 * np.dot(c_lin - centre, normal) * normal, o_lin))
    if guess is not None:
        g = np.asarray(guess, np.float64)
        starts.append((g, float(np.median(L - np.linalg.norm(P - g, axis=1))) if offset else 0.0))
    fits = [refine(c, o) for c, o in starts if np.all(np.isfinite(c)) and np.isfinite(o)]
    best = min(f[2] for f in fits)
    close = [f for f in fits if f[2] <= best * (1 + 1e-6) + 1e-9]
    ref = np.asarray(guess, np.float64) if guess is not None else c_lin
    c, o, rms = min(close, key=lambda f: np.linalg.norm(f[0] - ref))
    return c, o, rms


def kabsch(source, target):
    """Rigid transform ``(R [3,3], t [3])`` minimising ``Σ‖R·source_i + t − target_i‖²``
    (Kabsch, 1976; Horn, 1987), proper rotation (det = +1)."""
    S = np.asarray(source, np.float64)
    T = np.asarray(target, np.float64)
    if S.shape[0] < 3:
        raise ValueError(f"a rigid transform needs at least 3 points, got {S.shape[0]}")
    cs, ct = S.mean(axis=0), T.mean(axis=0)
    H = (S - cs).T @ (T - ct)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ D @ U.T
    return R, ct - R @ cs


def pose_from_markers(markers, layout_mm, *, min_markers: int = 3):
    """Poses ``T_sensor_body`` ``[..., 4, 4]`` (mm) from measured marker positions by Kabsch.

    Args:
        markers: ``[..., N, 3]`` marker positions measured in the sensor frame (mm); rows
            with NaN (a marker not seen) are left out of that pose's fit.
        layout_mm: ``[N, 3]`` the markers' known positions in the body (e.g. flange) frame (mm).
        min_markers: markers needed per pose (at least 3, not collinear).

    Returns:
        ``[..., 4, 4]`` ``T`` with ``markers_k ≈ R·layout_k + t``, the least-squares rigid fit
        (proper rotation). The result can go to :class:`~jaxcal.Pose` as ``T_sensor_flange``
        (a robot whose tool point is zero, or the pose model's tool extras).

    Raises:
        ValueError: wrong shapes, fewer than ``min_markers`` finite markers in a pose, or
            collinear markers (no unique rotation).
    """
    Y = np.asarray(markers, np.float64)
    L = np.asarray(layout_mm, np.float64)
    if L.ndim != 2 or L.shape[1] != 3:
        raise ValueError(f"layout_mm must be [N, 3] (mm), got shape {list(L.shape)}")
    if Y.ndim < 2 or Y.shape[-2:] != L.shape:
        raise ValueError(f"markers must be [..., {L.shape[0]}, 3] to match the layout, got shape {list(Y.shape)}")
    if min_markers < 3:
        raise ValueError("a pose needs at least 3 markers")
    batch = Y.shape[:-2]
    Yf = Y.reshape(-1, *L.shape)
    out = np.zeros((Yf.shape[0], 4, 4))
    out[:, 3, 3] = 1.0
    for i, y in enumerate(Yf):
        ok = np.isfinite(y).all(axis=1)
        if ok.sum() < min_markers:
            raise ValueError(f"pose {i}: {int(ok.sum())} finite markers, need {min_markers}")
        s = np.linalg.svd(L[ok] - L[ok].mean(axis=0), compute_uv=False)
        if s[1] <= 1e-9 * max(s[0], 1.0):
            raise ValueError(f"pose {i}: the markers used are collinear; the rotation about their line is unknown")
        R, t = kabsch(L[ok], y[ok])
        out[i, :3, :3], out[i, :3, 3] = R, t
    return out.reshape(*batch, 4, 4)


#: a sensor frame of its own needs this many rows (Kabsch: 3 non-collinear points)
MIN_FRAME_ROWS = 3


def marker_errors(F, P, Y, fi, pi, R, t, M) -> np.ndarray:
    """Per-row RMS marker distance error (mm) of rows seen in frames ``(R [nf, 3, 3], t [nf, 3])``
    (row ``i`` in frame ``fi[i]``) with marker placements ``M [np, N, 3]`` (row ``i``: ``pi[i]``),
    flange frames ``F [n, 3, 3]``, ``P [n, 3]`` and readings ``Y [n, N, 3]``."""
    pts = P[:, None, :] + np.einsum("nij,nkj->nki", F, M[pi])
    pred = np.einsum("nij,nkj->nki", R[fi], pts) + t[fi][:, None, :]
    sq = np.sum((pred - Y) ** 2, axis=-1)
    if np.isnan(sq).any():  # missing markers (NaN readings, SessionMarkers): the mean over the real ones
        return np.sqrt(np.nanmean(sq, axis=-1))
    return np.sqrt(np.mean(sq, axis=-1))


def alternate_frames_and_markers(F, P, Y, fi, pi, R, t, M, est_f, est_p, *, iterations: int, trim: bool = True):
    """Sensor frames and marker positions in closed form, given the flange frames (the marker
    start of :func:`initial_extras` and, per session, of :func:`jaxcal.initial_sessions`).

    The frames ``est_f`` (indices into ``R [nf, 3, 3]``, ``t [nf, 3]``) first by Kabsch on the
    marker centroids, then alternating least squares: each placement ``est_p`` (index into
    ``M [np, N, 3]``) as ``m_k = mean_i F_iᵀ(R_iᵀ(y_ik − t_i) − P_i)`` (exact: ``F_i``, ``R_i``
    orthonormal) and each frame by Kabsch on all its marker points, until nothing moves; then
    once more without rows beyond 5 robust σ (``trim``; a frame keeps at least
    :data:`MIN_FRAME_ROWS` rows). Row ``i`` is seen in frame ``fi[i]`` with placement ``pi[i]``.
    A missing marker (NaN in ``Y``) is left out of every mean and fit (centroids over each
    row's real markers; a marker position from the rows that saw it).
    Returns ``(R, t, M, keep [n])`` (copies; ``keep``: rows used).
    """
    R, t, M = np.array(R, np.float64), np.array(t, np.float64), np.array(M, np.float64)
    keep = np.ones(Y.shape[0], bool)
    seen = ~np.isnan(Y).any(axis=-1)  # [n, N]: False for a missing marker (SessionMarkers masks it)
    gaps = not seen.all()

    def points(rows):  # marker points in the base frame [r, N, 3]
        return P[rows][:, None, :] + np.einsum("nij,nkj->nki", F[rows], M[pi[rows]])

    def centroid(v, rows):  # [r, 3]: mean over each row's real markers
        if not gaps:
            return v.mean(axis=1)
        w = seen[rows][..., None]
        return np.where(w, v, 0.0).sum(axis=1) / w.sum(axis=1)

    for _ in range(2):
        for j in est_f:  # frames from the marker centroids first
            rows = np.flatnonzero((fi == j) & keep)
            R[j], t[j] = kabsch(centroid(points(rows), rows), centroid(Y[rows], rows))
        for _ in range(iterations):
            old = (M.copy(), R.copy(), t.copy())
            for j in est_p:
                rows = np.flatnonzero((pi == j) & keep)
                if rows.size:
                    local = np.einsum("nji,nkj->nki", R[fi[rows]], Y[rows] - t[fi[rows]][:, None, :])
                    m_rows = np.einsum("nji,nkj->nki", F[rows], local - P[rows][:, None, :])
                    if not gaps:
                        M[j] = m_rows.mean(axis=0)
                    else:  # each marker from the rows that saw it; a marker no row saw keeps its value
                        w = seen[rows][..., None]
                        cnt = w.sum(axis=0)
                        M[j] = np.where(cnt > 0, np.where(w, m_rows, 0.0).sum(axis=0) / np.maximum(cnt, 1), M[j])
            for j in est_f:
                rows = np.flatnonzero((fi == j) & keep)
                ok = seen[rows].reshape(-1)
                R[j], t[j] = kabsch(points(rows).reshape(-1, 3)[ok], Y[rows].reshape(-1, 3)[ok])
            if (np.abs(M - old[0]).max() < 1e-9 and np.abs(R - old[1]).max() < 1e-12
                    and np.abs(t - old[2]).max() < 1e-9):
                break
        if not trim:
            break
        new_keep = _trim(marker_errors(F, P, Y, fi, pi, R, t, M))
        for j in est_f:  # never trim a frame below its minimum
            if np.sum(new_keep & (fi == j)) < MIN_FRAME_ROWS:
                new_keep |= fi == j
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return R, t, M, keep


def project_rotation(M) -> np.ndarray:
    """The rotation nearest ``M`` ``[..., 3, 3]`` in the Frobenius norm (``U diag(1, 1, ±1) Vᵀ`` of
    its SVD, det = +1), each of a stack: ``argmin_R Σ‖R − A_i‖_F²`` is the projection of ``Σ A_i``
    (chordal L2 mean)."""
    U, _, Vt = np.linalg.svd(np.asarray(M, np.float64))
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.ones(d.shape + (3,))
    D[..., 2] = np.where(d == 0, 1.0, d)
    return (U * D[..., None, :]) @ Vt


def _prior_weight(sse: float, n_entries: int, prior_std: float) -> float:
    """``w = σ̂²/σ_t²`` of the weak prior on the tool point (σ̂² = mean square residual entry)."""
    return max(sse / max(n_entries, 1), 1e-12) / prior_std**2


def wire_with_tool(P, F, lengths, anchor, offset, tool, *, anchor_free: bool = True, offset_free: bool = True,
                   guess=None, prior_std: float = TOOL_PRIOR_STD_MM, iterations: int = 100):
    """Anchor ``c`` [3], cable offset ``o`` and tool point ``t`` [3] (flange frame, mm) with
    ``lengths_i ≈ ‖P_i + F_i t − c‖ + o``, by Levenberg–Marquardt from ``(anchor, offset, tool)``.

    Args:
        P: ``[n, 3]`` flange origins (mm), ``F``: ``[n, 3, 3]`` flange rotations, ``lengths``: ``[n]`` mm.
        anchor, offset, tool: the start (e.g. multilateration with the guessed tool point).
        anchor_free, offset_free: estimate ``c`` / ``o`` (else kept); ``t`` is always estimated.
        guess: ``[3]`` the tool point the weak prior pulls toward (default ``tool``):
            minimises ``Σ r_i² + w‖t − guess‖²``, ``w = σ̂²/prior_std²`` (σ̂ the RMS residual,
            updated once), so directions of ``t`` the data barely see stay at the guess.

    Returns:
        ``(c, o, t, rms)``; never a worse RMS residual than the start (else the start itself).
    """
    P, F, L = (np.asarray(a, np.float64) for a in (P, F, lengths))
    c, o, t = np.array(anchor, np.float64), float(offset), np.array(tool, np.float64)
    g = t.copy() if guess is None else np.asarray(guess, np.float64)
    n = L.shape[0]

    def res(c, o, t):
        return np.linalg.norm(P + F @ t - c, axis=1) + o - L

    def split(x):
        i = 0
        cc, oo = c_fix, o_fix
        if anchor_free:
            cc, i = x[:3], 3
        if offset_free:
            oo, i = x[i], i + 1
        return cc, oo, x[i:]

    c_fix, o_fix = c, o
    x = np.concatenate(([c] if anchor_free else []) + ([[o]] if offset_free else []) + [t])
    k = x.size - 3  # the tool block starts here
    r = res(c, o, t)
    sse_start = float(r @ r)
    w = _prior_weight(sse_start, n, prior_std)
    for _ in range(3):  # LM for this prior weight, then σ̂ (and w) from the fit
        lam = 1e-3
        cc, oo, tt = split(x)
        r = res(cc, oo, tt)
        f = float(r @ r) + w * float((tt - g) @ (tt - g))
        for _ in range(iterations):
            d = P + F @ tt - cc
            u = d / np.maximum(np.linalg.norm(d, axis=1), 1e-9)[:, None]
            cols = ([-u] if anchor_free else []) + ([np.ones((n, 1))] if offset_free else [])
            J = np.concatenate(cols + [np.einsum("nji,nj->ni", F, u)], axis=1)  # ∂r/∂t = F_iᵀu_i
            H = J.T @ J
            H[k:, k:] += w * np.eye(3)
            grad = J.T @ r
            grad[k:] += w * (tt - g)
            step = np.linalg.lstsq(H + lam * np.diag(np.diag(H) + 1e-12), -grad, rcond=None)[0]
            xn = x + step
            cn, on, tn = split(xn)
            rn = res(cn, on, tn)
            fn = float(rn @ rn) + w * float((tn - g) @ (tn - g))
            if fn < f:
                done = f - fn <= 1e-14 * f or np.linalg.norm(step) < 1e-10 * (1.0 + np.linalg.norm(x))
                x, r, f, lam, (cc, oo, tt) = xn, rn, fn, lam / 10, (cn, on, tn)
                if done:
                    break
            else:
                lam *= 10
                if lam > 1e12:
                    break
        w_new = _prior_weight(float(r @ r), n, prior_std)
        if abs(w_new - w) <= 0.1 * w:
            break
        w = w_new
    cc, oo, tt = split(x)
    r = res(cc, oo, tt)
    if not (np.all(np.isfinite(x)) and float(r @ r) <= sse_start):
        return c, o, t, math.sqrt(sse_start / n)
    return np.array(cc, np.float64), float(oo), tt, math.sqrt(float(r @ r) / n)
