"""Session hold-outs: calibrate on some measurement sessions, check on another with its frame
registered again (:func:`holdout_session`, :func:`leave_one_session_out`).
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from .._calibration._evaluate import _errors, _register
from .._fit._objective import MEASURED_DEFAULTS, describe_objective
from .._sensors._sessions import SessionMarkers, _ordered, initial_sessions, session_labels

__all__ = ["SessionHoldout", "holdout_session", "leave_one_session_out"]


class SessionHoldout(NamedTuple):
    """One held-out session (:func:`holdout_session`).

    Attributes:
        session: the held-out session label; rows: its row indices in the data.
        frame, placement: its labels; frame_seen / placement_seen: whether the training
            sessions use them (then predicted directly, else registered on the held-out rows).
        registered: the groups fitted on the held-out rows with the robot fixed (``()`` when
            every label was seen in training).
        before_rmse, after_rmse: held-out marker RMSE (mm) with the nominal robot and with the
            calibrated robot (each with its frames/markers: from training, or registered).
        before_errors, after_errors: ``[rows]`` per-row errors (mm).
        train_before_rmse, train_after_rmse: training RMSE (mm), nominal (+ closed-form
            extras) and calibrated.
        result: the training :class:`~jaxcal.CalibrationResult`.
        objective: one line naming the training objective (the measured-data defaults, or not).
    """

    session: str
    rows: np.ndarray
    frame: str
    placement: str
    frame_seen: bool
    placement_seen: bool
    registered: tuple[str, ...]
    before_rmse: float
    after_rmse: float
    before_errors: np.ndarray
    after_errors: np.ndarray
    train_before_rmse: float
    train_after_rmse: float
    result: object
    objective: str = ""


def _rms(e) -> float:
    e = np.asarray(e, np.float64)
    return float(np.sqrt(np.mean(e * e))) if e.size else float("nan")


def holdout_session(robot, data, session: str, *, train=None, n_markers: int | None = None, positions_mm=None,
                    prior=MEASURED_DEFAULTS["prior"], loss: str = MEASURED_DEFAULTS["loss"],
                    **calibrate_kw) -> SessionHoldout:
    """Calibrate on other sessions (``train``: a list of session labels; default every session
    but ``session``) and evaluate on ``session``'s rows.

    Training: :func:`jaxcal.calibrate` with :class:`SessionMarkers` on the other sessions'
    rows (shared robot errors, the identifiable subset by QR, each frame/placement started in
    closed form; labels that occur only in the held-out session stay fixed), with ``prior`` and
    ``loss`` (default: :data:`jaxcal.MEASURED_DEFAULTS`, the defaults for measured data — the
    default prior and the Huber loss, as ``calibrate(..., objective="measured")`` and the CLI).

    Held-out rows: a frame or placement label the training sessions use is predicted with its
    trained value; a label only the held-out session has is **registered** on the held-out rows
    with the robot fixed (closed form, then LM on those groups only — the standard registration
    of a new sensor set-up; it never touches the kinematics). ``registered`` says which.
    "before" does the same with the nominal robot (frames/markers in closed form on the
    training rows, new labels registered on the held-out rows).

    Args:
        robot: nominal robot. data: a labelled marker :class:`~jaxcal.Dataset`.
        session: the session label to hold out.
        n_markers, positions_mm: as :meth:`SessionMarkers.from_dataset`.
        **calibrate_kw: more :func:`jaxcal.calibrate` arguments (``fix=``, ``checks=`` ...).
    """
    from .._calibration._calibrate import calibrate

    labels = session_labels(data)
    sessions = _ordered(s for s, _, _ in labels)
    if session not in sessions:
        raise ValueError(f"unknown session {session!r}; sessions: {list(sessions)}")
    full = SessionMarkers.from_dataset(data, n_markers, positions_mm)
    if train is None:
        chosen = [s for s in sessions if s != session]
    else:
        chosen = [train] if isinstance(train, str) else list(train)
        unknown = [s for s in chosen if s not in sessions]
        if unknown:
            raise ValueError(f"unknown training session(s) {unknown}; sessions: {list(sessions)}")
        if session in chosen:
            raise ValueError(f"session {session!r} is held out; it cannot also be a training session")
    test = np.flatnonzero([s == session for s, _, _ in labels])
    train = np.flatnonzero([s in chosen for s, _, _ in labels])
    if train.size == 0:
        raise ValueError("holding out the only session leaves no training data")
    q, y = np.asarray(data.q), np.asarray(data.y)
    m_tr, m_te = full.take(train), full.take(test)
    frame, placement = labels[test[0]][1], labels[test[0]][2]
    if any((f, p) != (frame, placement) for _, f, p in (labels[i] for i in test)):
        raise ValueError(f"session {session!r} mixes frame/placement labels; one session has one of each")
    tr_frames = {labels[i][1] for i in train}
    tr_places = {labels[i][2] for i in train}
    absent = [g for f in full.frames if f not in tr_frames for g in full.groups_of(frame=f)]
    absent += [g for p in full.placements if p not in tr_places for g in full.groups_of(placement=p)]
    fix = list(calibrate_kw.pop("fix", ()) or ())
    fix = ([fix] if isinstance(fix, str) else fix) + absent
    nominal = initial_sessions(robot, m_tr, (q[train], y[train])).deviations
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate(robot, m_tr, (jnp.asarray(q[train]), jnp.asarray(y[train])), "lm", prior=prior, loss=loss,
                        fix=fix or (), start=nominal, **calibrate_kw)
    frame_seen, placement_seen = frame in tr_frames, placement in tr_places
    new_f = [] if frame_seen else [frame]
    new_p = [] if placement_seen else [placement]
    groups = tuple(full.groups_of(frame=new_f[0]) if new_f else ()) + tuple(
        full.groups_of(placement=new_p[0]) if new_p else ())
    dev_b = _register(robot, m_te, q[test], y[test], nominal, groups, new_f, new_p)
    dev_a = _register(robot, m_te, q[test], y[test], res.deviations, groups, new_f, new_p)
    eb = _errors(robot, m_te, dev_b, q[test], y[test])
    ea = _errors(robot, m_te, dev_a, q[test], y[test])
    return SessionHoldout(
        session, test, frame, placement, frame_seen, placement_seen, groups, _rms(eb), _rms(ea), eb, ea,
        _rms(_errors(robot, m_tr, nominal, q[train], y[train])),
        _rms(_errors(robot, m_tr, res.deviations, q[train], y[train])), res, describe_objective(prior, loss))


def leave_one_session_out(robot, data, **kw) -> tuple[list[SessionHoldout], float, float]:
    """:func:`holdout_session` for every session of ``data`` (same keywords; by default the
    objective :data:`jaxcal.MEASURED_DEFAULTS`); returns ``(per session, pooled
    before RMSE, pooled after RMSE)`` — pooled over every held-out row (mm)."""
    sessions = _ordered(s for s, _, _ in session_labels(data))
    if len(sessions) < 2:
        raise ValueError(f"leave-one-session-out needs at least 2 sessions, got {list(sessions)}")
    out = [holdout_session(robot, data, s, **kw) for s in sessions]
    before = _rms(np.concatenate([h.before_errors for h in out]))
    after = _rms(np.concatenate([h.after_errors for h in out]))
    return out, before, after
