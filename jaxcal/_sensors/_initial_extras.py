"""The closed-form start of a measurement model's extras (anchor, frames, tool, markers, planes,
camera): :func:`initial_extras` picks the model's own start; the geometry it uses lives in
:mod:`._initialise` and the models' modules.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from .._core._params import Deviations, layout_for
from .._core._rotvec import matrix_to_rotvec, rotvec_to_matrix
from .._models._abstract import AbstractRobot
from ._initialise import (
    MIN_FRAME_ROWS,
    TOOL_PRIOR_STD_MM,
    ExtrasEstimate,
    _prior_weight,
    _residual,
    _sample_error,
    _trim,
    alternate_frames_and_markers,
    has_plain_row_error,
    kabsch,
    multilaterate,
    plain_row_errors,
    project_rotation,
    residual_rows,
    tip_frames,
    tool_guess,
    trimmed_note,
    wire_with_tool,
    with_tool,
)
from ._measurement import CableLength, Markers, MeasurementModel, Pose, Position

__all__ = ["initial_extras"]


def _pose_start(P, F, Ym, R0, b0, t0, est_base: bool, est_tool: bool, prior_std: float = TOOL_PRIOR_STD_MM):
    """``(R, b, t, keep)`` of a :class:`Pose` sensor (``T_sensor_base = (R, b)``) and tool point
    ``t`` from pose readings ``Ym [n, 4, 4]`` and flange frames ``(P [n, 3], F [n, 3, 3])``: the
    rotation as the chordal mean of ``R_y,i F_iᵀ``, then ``(t, b' = Rᵀb)`` by least squares on
    ``F_i t + b' = Rᵀy_i − P_i`` (weak prior toward ``t0``); refit once without gross outliers."""
    Rm, pm = Ym[:, :3, :3], Ym[:, :3, 3]
    n = P.shape[0]
    keep = np.ones(n, bool)
    R, b, t = R0, b0, t0
    for _ in range(2):
        if est_base:
            R = project_rotation(np.einsum("nij,nkj->ik", Rm[keep], F[keep]))
        z = pm @ R - P  # Rᵀy_i − P_i
        if est_base and est_tool:
            A = np.concatenate([F[keep], np.broadcast_to(np.eye(3), F[keep].shape)], axis=2).reshape(-1, 6)
            rhs = z[keep].reshape(-1)
            sol = np.linalg.lstsq(A, rhs, rcond=None)[0]
            w = _prior_weight(float(np.sum((A @ sol - rhs) ** 2)), rhs.size, prior_std)
            H = A.T @ A
            H[:3, :3] += w * np.eye(3)
            sol = np.linalg.solve(H, A.T @ rhs + np.concatenate([w * t0, np.zeros(3)]))
            t, bl = sol[:3], sol[3:]
        elif est_base:
            bl = np.mean(z[keep] - F[keep] @ t0, axis=0)
        else:
            bl = R.T @ b0
            if est_tool:
                t = np.einsum("nji,nj->i", F[keep], z[keep] - bl) / keep.sum()
        b = R @ bl
        pos_err = np.linalg.norm((P + F @ t) @ R.T + b - pm, axis=1)
        E = np.einsum("nji,jk,nkl->nil", Rm, R, F)  # R_yᵀ R F_i
        ang_err = np.arccos(np.clip((np.trace(E, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0))
        new_keep = _trim(pos_err) & (_trim(ang_err) if est_base else True)
        if new_keep.sum() < MIN_FRAME_ROWS or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    return R, b, t, keep


def _position_start(P, F, Y, R0, b0, t0, est_base: bool, est_tool: bool, iterations: int = 1000):
    """``(R, b, t, keep)`` of a :class:`Position` sensor and tool point: the one-marker case of
    :func:`alternate_frames_and_markers` (Kabsch for the frame, ``t = mean_i F_iᵀ(Rᵀ(y_i − b) − P_i)``)."""
    zero = np.zeros(Y.shape[0], int)
    R, b, M, keep = alternate_frames_and_markers(F, P, Y[:, None, :], zero, zero, R0[None], b0[None],
                                                 t0[None, None, :], [0] if est_base else [],
                                                 [0] if est_tool else [], iterations=iterations)
    return R[0], b[0], M[0, 0], keep


def _tool_message(t, t0) -> str:
    return (f"tool point ({', '.join(f'{v:.1f}' for v in t)}) mm in the flange frame, "
            f"{np.linalg.norm(t - t0):.1f} mm from the guess")


def _markers_start(measurement: Markers, robot, q, Y, start, est_base: bool, est_markers: bool, iterations=100):
    """``(R, t, M [N, 3], keep)``: one sensor frame and the marker layout of a :class:`Markers`
    model (:func:`alternate_frames_and_markers` with one frame and one placement)."""
    T = tip_frames(robot, measurement, q, start)
    R = rotvec_to_matrix(start.base_rotation) @ np.asarray(measurement.rotation, np.float64)
    t = np.asarray(measurement.translation, np.float64) + np.asarray(start.base_translation, np.float64)
    M = np.asarray(measurement.marker_points(start), np.float64)
    zero = np.zeros(Y.shape[0], int)
    R, t, M, keep = alternate_frames_and_markers(T[:, :3, :3], T[:, :3, 3], Y, zero, zero, R[None], t[None], M[None],
                                                 [0] if est_base else [], [0] if est_markers else [],
                                                 iterations=iterations)
    return R[0], t[0], M[0], keep


def initial_extras(
    robot: AbstractRobot,
    measurement: MeasurementModel,
    data,
    *,
    estimate=None,
    start: Deviations | None = None,
) -> ExtrasEstimate:
    """Closed-form starting values for the sensor extras from the data and the nominal robot.

    Args:
        robot, measurement: nominal models (the measurement's anchor / frame is the user's guess).
        data: a :class:`~jaxcal.Dataset` or ``(q [n, dof] rad, y)``.
        estimate: which extras to initialise: for draw-wire data ``"anchor"`` and/or
            ``"cable_offset"`` (default both), for position/pose data ``"base"`` (default), and
            ``"tool"`` (the tool point in the flange frame, jointly with the others; only when
            named: :func:`jaxcal.calibrate` names it when the tool is estimated).
        start: deviations to start from (default nominal); its DH part is used for the flange
            frames and kept, its extras are the guess; the estimated extras are replaced.

    Returns:
        :class:`ExtrasEstimate` (the new start, RMS residual before/after, trimmed samples).
    """
    from ._sessions import SessionMarkers, initial_sessions

    if isinstance(measurement, SessionMarkers):  # per-session frames and marker placements
        est = set(measurement.initialisable if estimate is None else estimate)
        bad = est - set(measurement.initialisable)
        if bad:
            raise ValueError(f"cannot initialise {sorted(bad)} for session marker data; possible: base, markers")
        return initial_sessions(robot, measurement, data, start=start, frames=None if "base" in est else [],
                                placements=None if "markers" in est else [])
    if measurement.kind in ("plane", "point"):  # contact models (jaxcal._sensors._contact)
        from ._contact import initial_contact

        return initial_contact(robot, measurement, data, estimate=estimate, start=start)
    q, y = (data.q, data.y) if hasattr(data, "q") else data
    if measurement.kind == "camera":  # per-image PnP + Park–Martin hand-eye (jaxcal._sensors._camera)
        from ._camera import initial_camera_extras

        return initial_camera_extras(robot, measurement, q, y, estimate=estimate, start=start)
    q = jnp.asarray(q)
    dtype = q.dtype
    start = Deviations.zeros(layout_for(robot, measurement), dtype) if start is None else start.astype(dtype)
    kind = measurement.kind
    if estimate is None:  # the tool point only when asked for (it is often known)
        estimate = tuple(e for e in measurement.initialisable if e != "tool")
        if kind == "markers" and measurement.known:
            estimate = ("base",)
    estimate = set(estimate)
    if kind == "markers" and measurement.known and "markers" in estimate:
        raise ValueError("the marker positions are known (Markers(known=True)): only 'base' can be initialised")
    bad = estimate - set(measurement.initialisable)
    if bad:
        raise ValueError(f"cannot initialise {sorted(bad)} for {kind} data; possible: {list(measurement.initialisable)}")
    est_tool = "tool" in estimate
    tool0 = tool_guess(robot, measurement, start)[1]  # flange (tip link) frame, mm
    P = Pl = Fl = None  # tool points; flange origins and rotations (base frame)
    if kind != "markers":
        # the flange frames (one compiled program for every kind and estimate, shared with the
        # other closed-form starts), the tool points from them
        T = tip_frames(robot, measurement, q, start)
        Fl, Pl = T[:, :3, :3], T[:, :3, 3]
        P = Pl + Fl @ tool0
    Y = np.asarray(y, np.float64)

    def rms(dev):
        if has_plain_row_error(measurement):  # the residual program of the calibration's host-side checks
            e = plain_row_errors(measurement, residual_rows(measurement, robot, dev, q, y))
        else:  # a marker set's RMS over its markers
            e = np.asarray(_sample_error(measurement, _residual(measurement, robot, dev, q, jnp.asarray(y))), np.float64)
        return float(np.sqrt(np.mean(e**2)))

    before = rms(start)
    tool = tool0
    if isinstance(measurement, CableLength):
        anchor0 = np.asarray(measurement.anchor, np.float64) + np.asarray(start.anchor, np.float64)
        offset0 = float(start.cable_offset)
        est_anchor, est_offset = "anchor" in estimate, "cable_offset" in estimate
        keep = np.ones(P.shape[0], bool)
        for _ in range(2):
            if est_anchor:  # multilateration with the tool point at its guess
                c, o, _ = multilaterate(P[keep], Y[keep] - (0.0 if est_offset else offset0), offset=est_offset,
                                        guess=anchor0)
                o = o if est_offset else offset0
            else:
                c = anchor0
                o = float(np.median(Y[keep] - np.linalg.norm(P[keep] - c, axis=1))) if est_offset else offset0
            if est_tool:  # then (c, o, t) jointly
                c, o, tool, _ = wire_with_tool(Pl[keep], Fl[keep], Y[keep], c, o, tool0, anchor_free=est_anchor,
                                               offset_free=est_offset)
                res = np.linalg.norm(Pl + Fl @ tool - c, axis=1) + o - Y
            else:
                res = np.linalg.norm(P - c, axis=1) + o - Y
            new_keep = _trim(res)
            if np.array_equal(new_keep, keep):
                break
            keep = new_keep
        dev = start.replace(anchor=jnp.asarray(c - np.asarray(measurement.anchor, np.float64), dtype),
                            cable_offset=jnp.asarray(o, dtype))
        what = []
        if est_anchor:
            what.append(f"anchor ({', '.join(f'{v:.1f}' for v in c)}) mm, {np.linalg.norm(c - anchor0):.1f} mm "
                        "from the guess")
        if est_offset:
            what.append(f"cable offset {o:+.2f} mm")
    elif isinstance(measurement, (Position, Pose)):
        est_base = "base" in estimate
        R0 = np.asarray(measurement.rotation, np.float64)
        t0 = np.asarray(measurement.translation, np.float64)
        R_guess = rotvec_to_matrix(start.base_rotation) @ R0
        b_guess = t0 + np.asarray(start.base_translation, np.float64)
        if kind == "pose":
            R, t, tool, keep = _pose_start(Pl, Fl, Y, R_guess, b_guess, tool0, est_base, est_tool)
        elif est_tool:
            R, t, tool, keep = _position_start(Pl, Fl, Y, R_guess, b_guess, tool0, est_base, est_tool)
        else:  # the frame alone: Kabsch on the tool points
            keep = np.ones(P.shape[0], bool)
            for _ in range(2):
                R, t = kabsch(P[keep], Y[keep])
                new_keep = _trim(np.linalg.norm(P @ R.T + t - Y, axis=1))
                if np.array_equal(new_keep, keep):
                    break
                keep = new_keep
        dev, what = start, []
        if est_base:
            dev = dev.replace(base_rotation=jnp.asarray(matrix_to_rotvec(R @ R0.T), dtype),
                              base_translation=jnp.asarray(t - t0, dtype))
            angle = math.degrees(float(np.linalg.norm(matrix_to_rotvec(R @ R_guess.T))))
            what.append(f"sensor frame: base origin at ({', '.join(f'{v:.1f}' for v in t)}) mm in the sensor frame, "
                        f"rotated {angle:.2f}° from the guess")
    elif isinstance(measurement, Markers):
        est_base, est_markers = "base" in estimate, "markers" in estimate
        R, t, M, keep = _markers_start(measurement, robot, q, Y, start, est_base, est_markers)
        R0 = np.asarray(measurement.rotation, np.float64)
        t0 = np.asarray(measurement.translation, np.float64)
        dev = start
        what = []
        if est_base:
            dev = dev.replace(base_rotation=jnp.asarray(matrix_to_rotvec(R @ R0.T), dtype),
                              base_translation=jnp.asarray(t - t0, dtype))
            what.append(f"sensor frame: base origin at ({', '.join(f'{v:.1f}' for v in t)}) mm in the sensor frame")
        if est_markers:
            M0 = np.asarray(measurement.positions, np.float64)
            dev = dev.replace(**{f"marker_{k + 1}": jnp.asarray(M[k] - M0[k], dtype) for k in range(M.shape[0])})
            what.append(f"{M.shape[0]} marker position(s) in the flange frame, up to "
                        f"{np.linalg.norm(M - M0, axis=1).max():.1f} mm from the guess")
    else:  # pragma: no cover - every model is handled above
        raise TypeError(f"no initialisation for {type(measurement).__name__}")
    if est_tool:
        dev = with_tool(dev, robot, measurement, tool)
        what.append(_tool_message(tool, tool0))
    after = rms(dev)
    n_trim = int((~keep).sum())
    msg = ("extras from the data: " + "; ".join(what) + f" (RMS residual of the nominal robot {before:.2f} → "
           f"{after:.2f} mm" + trimmed_note(n_trim, "sample") + ")")
    return ExtrasEstimate(dev, before, after, n_trim, msg)
