"""Marker data from several recording sessions, calibrated jointly, and held-out-session checks.

A motion-capture calibration is often recorded in several sessions: the robot (and its
kinematic errors) is the same, but each session expresses the marker positions in its own
sensor frame (the mocap system was moved, or the reference markers on the robot base were
chosen differently) and may use its own marker placement on the end effector. Sessions share a
frame or a placement by **label**: two sessions recorded with the same reference frame carry
the same frame label, two sessions with the marker at the same place the same placement label.

:class:`SessionMarkers` is the measurement model. It adds, per frame label ``F``, the extra
groups ``base_rotation@F`` (``base_rx@F, base_ry@F, base_rz@F``, rad) and ``base_translation@F``
(``base_x@F …``, mm), and per placement label ``K`` the groups ``marker_k@K`` (``marker_k_x@K
…``, mm; ``k`` = 1..N markers per row) — the single-session ``base`` and ``marker_k`` groups with
the label after ``@``. The robot's own groups are shared by every session. Labels travel with
the data: :class:`~jaxcal.Dataset` ``labels`` (per row ``(session, frame, placement)``), read
from the CSV columns ``session``, ``frame`` and ``placement`` by :func:`~jaxcal.load_csv`.

:func:`initial_sessions` starts every frame and placement in closed form (Kabsch per frame on
the nominal robot's marker points, alternating with the per-placement marker positions, as
:func:`jaxcal.initial_extras` does for one session); :func:`jaxcal.calibrate` calls it.
:func:`holdout_session` calibrates on all sessions but one (or on the sessions named in
``train=``) and evaluates the held-out one; :func:`leave_one_session_out` does it for each
session; :func:`evaluate_sessions` (``jaxcal.evaluate_result``, ``jaxcal evaluate``) checks a
session calibration on new sessions, registering their frames and placements.

Sessions may have **different marker counts** (a one-point session beside three-marker ones):
each placement has its own marker set (``SessionMarkers(markers=...)``, read from the data by
:meth:`SessionMarkers.from_dataset`) and groups only for those markers; rows carry NaN (empty CSV
cells) in the columns of markers they lack. Such readings are masked (residual exactly 0), counted
(:func:`masked_markers`, the closed-form start's message, the CLI's note) and never dropped
silently, and every statistic counts only real readings (:meth:`SessionMarkers.observed`). A NaN
in only some coordinates of a marker is an error (:func:`marker_gaps`).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._core._host_method import host_method
from .._core._params import Deviations, Group, layout_for
from .._core._precision import to_device
from .._models._kinematics import _chain, check_joint_angles, rotvec_to_matrix
from ._initialise import (
    MIN_FRAME_ROWS,
    ExtrasEstimate,
    alternate_frames_and_markers,
    marker_errors,
    tip_frames,
    trimmed_note,
)
from ._kind import PointsKind, register_kind
from ._measurement import MarkerModel, Markers, frame_from_dict, frame_to_dict, tip_to_dict, xyz_entries

__all__ = ["SessionMarkers", "frame_groups", "placement_groups", "initial_sessions", "session_labels",
    "masked_markers"]


def frame_groups(label: str) -> tuple[Group, Group]:
    """``base_rotation@label`` (rad) and ``base_translation@label`` (mm): one session frame's
    correction ``R = exp(δr)``, ``t = δt`` of ``T_sensor_base`` (nominal: identity)."""
    return (Group.vector(f"base_rotation@{label}", tuple(f"base_r{c}@{label}" for c in "xyz"), "rad"),
            Group.vector(f"base_translation@{label}", tuple(f"base_{c}@{label}" for c in "xyz"), "mm"))


def placement_groups(label: str, markers) -> tuple[Group, ...]:
    """``marker_k@label`` (mm): the marker positions of one placement in the flange frame
    (deviations from the nominal positions), for ``k`` in ``markers`` (1-based marker numbers;
    an int ``N`` means ``1..N``)."""
    ks = range(1, int(markers) + 1) if isinstance(markers, (int, np.integer)) else markers
    return tuple(Group.vector(f"marker_{k}@{label}", tuple(f"marker_{k}_{c}@{label}" for c in "xyz"), "mm")
                 for k in ks)


def masked_markers(y) -> tuple[int, int, int]:
    """``(missing, total, rows_with_missing)`` marker readings of ``y`` ``[n, N, 3]`` (see
    :func:`marker_gaps`): what :class:`SessionMarkers` masks."""
    gap = marker_gaps(y)
    return int(gap.sum()), int(gap.size), int(gap.any(axis=1).sum())


def _check_label(label, what: str) -> str:
    s = str(label).strip()
    if not s or any(c in s for c in "@,\n\r") or s != str(label):
        raise ValueError(f"{what} label {label!r} must be a non-empty string without '@', ',', line breaks "
                         "or surrounding spaces")
    return s


def _ordered(labels) -> tuple[str, ...]:
    return tuple(dict.fromkeys(labels))


def session_labels(data) -> tuple[tuple[str, str, str], ...]:
    """Per-row ``(session, frame, placement)`` labels of a :class:`~jaxcal.Dataset` (its ``labels``)."""
    labels = getattr(data, "labels", ())
    if not labels:
        raise ValueError("the data carry no session labels: give a Dataset with labels= (per row (session, frame, "
                         "placement)) or a CSV file with a 'session' and/or 'frame'/'placement' column")
    return labels


class SessionMarkers(MarkerModel):
    """``N`` markers on the end effector seen in several sessions, ``[n, N, 3]`` mm:
    ``y_ik = R_f(i)·(P_i + F_i·m_{p(i),k}) + t_f(i)`` with ``f(i)`` the frame label and ``p(i)``
    the placement label of row ``i``, ``(P_i, F_i)`` the flange origin and orientation in the base
    frame, ``m_{p,k}`` marker ``k`` of placement ``p`` in the flange frame (nominal
    ``positions_mm[p] +`` the ``marker_k@p`` deviation) and ``(R_f, t_f) = T_sensor_base`` of
    frame ``f`` (identity ``+`` the ``base_rotation@f`` / ``base_translation@f`` deviations).

    **Different marker counts.** Each placement has its own set of markers (``markers``: a
    one-point session beside three-marker ones): rows carry ``NaN`` (empty CSV cells) in the
    columns of markers their placement does not have. A missing reading (NaN in x, y and z; also
    a marker of the placement that one row did not see) is **masked**: its residual is exactly 0
    (zero weight), it is counted (:func:`masked_markers`, the closed-form start's message) and
    never dropped silently; a reading with only some coordinates NaN is an error. A placement
    has ``marker_k@K`` groups only for the markers it has, and every statistic counts only the
    real readings (:meth:`observed`): the per-row error, σ̂, the robust/outlier scale, the
    residual count of the uncertainty and the floor (:func:`jaxcal.statistical_floor` with
    ``n_train`` = real readings, ``size = 3``).

    The model carries one frame and one placement index per row, so it belongs to the rows it was
    made for: :meth:`take` gives the model of a subset of rows with the same labels and groups
    (a held-out split keeps the parameter layout). Every extra group is free by default;
    :func:`jaxcal.calibrate` starts them in closed form (:func:`initial_sessions`). The
    ``sample_error`` is the RMS over the row's real markers of the 3-D distance error (mm), as
    :class:`~jaxcal.Markers` (and :class:`~jaxcal.Camera` for undetected corners).

    Attributes:
        positions: ``[n_placements, N, 3]`` nominal marker positions per placement (mm).
        frame_index, placement_index: ``[n]`` int, per row.
        frames, placements: the label of every index (static, in order).
        markers: per placement, its 1-based marker numbers (static; default all ``1..N``).
        tip: the tip of a :class:`~jaxcal.KinematicTree` that carries the markers (static;
            ``None``: the robot's default tip); the positions are in its tip link frame.
    """

    positions: Float[Array, "P N 3"]
    frame_index: Int[Array, " n"]
    placement_index: Int[Array, " n"]
    frames: tuple[str, ...] = eqx.field(static=True)
    placements: tuple[str, ...] = eqx.field(static=True)
    markers: tuple[tuple[int, ...], ...] = eqx.field(static=True)
    tip: str | None = eqx.field(static=True, default=None)
    kind: ClassVar[str] = "markers"
    known: ClassVar[bool] = False
    row_sessions: ClassVar[bool] = True

    def __init__(self, frames: Sequence[str], placements: Sequence[str], n_markers: int = 1, positions_mm=None,
                 *, frame_labels: Sequence[str] | None = None, placement_labels: Sequence[str] | None = None,
                 markers=None, tip: str | None = None):
        """Args:
            frames, placements: ``[n]`` per-row frame and placement labels (strings).
            n_markers: markers per row (``N``).
            positions_mm: nominal marker positions in the flange frame: ``[N, 3]`` for every
                placement or ``[n_placements, N, 3]`` (default zeros; the closed-form start
                does not need a guess).
            frame_labels, placement_labels: every label of the parameter layout, in order
                (default: the labels of these rows in order of appearance); labels without rows
                here keep their groups, so a model of a held-out subset has the same layout.
            markers: the markers each placement has: ``{label: [k, ...]}`` or one sequence per
                placement label in order (1-based marker numbers ``<= N``; default every
                placement has all ``N``). :meth:`from_dataset` reads them from the data.
            tip: the tip that carries the markers (``None``: the robot's default tip).
        """
        self.tip = tip
        frames = [_check_label(f, "frame") for f in frames]
        placements = [_check_label(p, "placement") for p in placements]
        if len(frames) != len(placements):
            raise ValueError(f"{len(frames)} frame labels but {len(placements)} placement labels; one of each per row")
        fl = _ordered(frames) if frame_labels is None else tuple(_check_label(f, "frame") for f in frame_labels)
        pl = (_ordered(placements) if placement_labels is None
              else tuple(_check_label(p, "placement") for p in placement_labels))
        for what, given, known in (("frame", frames, fl), ("placement", placements, pl)):
            if len(set(known)) != len(known):
                raise ValueError(f"{what} labels repeat: {list(known)}")
            unknown = sorted(set(given) - set(known))
            if unknown:
                raise ValueError(f"unknown {what} label(s) {unknown}; the layout has {list(known)}")
        if not fl or not pl:
            raise ValueError("SessionMarkers needs at least one frame and one placement label")
        n_markers = int(n_markers)
        if n_markers < 1:
            raise ValueError(f"n_markers must be >= 1, got {n_markers}")
        pos = np.zeros((len(pl), n_markers, 3)) if positions_mm is None else np.asarray(positions_mm, np.float64)
        if pos.shape == (n_markers, 3):
            pos = np.broadcast_to(pos, (len(pl), n_markers, 3)).copy()
        if pos.shape != (len(pl), n_markers, 3) or not np.all(np.isfinite(pos)):
            raise ValueError(f"positions_mm must be finite [{n_markers}, 3] or [{len(pl)}, {n_markers}, 3] (mm), "
                             f"got shape {list(pos.shape)}")
        self.positions = to_device(pos)
        self.frames, self.placements = fl, pl
        self.markers = _placement_markers(markers, pl, n_markers)
        self.frame_index = to_device(np.asarray([fl.index(f) for f in frames], np.int32).reshape(-1))
        self.placement_index = to_device(np.asarray([pl.index(p) for p in placements], np.int32).reshape(-1))

    # -- construction -------------------------------------------------------------------
    @classmethod
    def from_dataset(cls, data, n_markers: int | None = None, positions_mm=None, **kw) -> SessionMarkers:
        """The model of a labelled marker :class:`~jaxcal.Dataset` (``data.labels``).

        Unless ``markers=`` is given, each placement has the markers with at least one reading
        in its rows (:func:`marker_gaps`): a one-point session in a three-marker file (NaN in
        marker 2's and 3's columns) gets ``marker_1@K`` only."""
        labels = session_labels(data)
        n_markers = int(np.shape(data.y)[1]) if n_markers is None else n_markers
        fr, pl = [f for _, f, _ in labels], [p for _, _, p in labels]
        if kw.get("markers") is None and np.shape(data.y)[1] == n_markers:
            seen = ~marker_gaps(data.y)
            order = _ordered(pl) if kw.get("placement_labels") is None else kw["placement_labels"]
            kw["markers"] = {p: [k + 1 for k in range(n_markers) if seen[[x == p for x in pl]][:, k].any()]
                             for p in order if p in pl}
        return cls(fr, pl, n_markers, positions_mm, **kw)

    def take(self, rows) -> SessionMarkers:
        """The model of rows ``rows`` (an index array, boolean mask or slice), same labels and layout."""
        fi = np.asarray(self.frame_index)[rows]
        pi = np.asarray(self.placement_index)[rows]
        return SessionMarkers([self.frames[i] for i in fi], [self.placements[i] for i in pi], self.n_markers,
                              np.asarray(self.positions), frame_labels=self.frames, placement_labels=self.placements,
                              markers=self.markers, tip=self.tip)

    @host_method
    def takes_extra(self, flag: str, name: str) -> bool:
        if flag == "base":  # every session frame is already free (base_rotation@F, ...)
            return False
        return super().takes_extra(flag, name)

    @host_method
    def pad_rows(self, n: int, n_to: int) -> SessionMarkers:
        """The model of the rows padded to ``n_to`` by repeating row 0 (shape buckets)."""
        if n_to == n:
            return self
        return self.take(np.concatenate([np.arange(n), np.zeros(n_to - n, int)]))

    # -- shape ----------------------------------------------------------------------------
    @property
    def n_markers(self) -> int:
        return int(self.positions.shape[1])

    @property
    def n_rows(self) -> int:
        return int(self.frame_index.shape[0])

    def extra_groups(self) -> tuple[Group, ...]:
        """``base_rotation@F, base_translation@F`` per frame label, then ``marker_k@K`` per placement."""
        return (tuple(g for f in self.frames for g in frame_groups(f))
                + tuple(g for p, ks in zip(self.placements, self.markers) for g in placement_groups(p, ks)))

    def nominal_lengths(self) -> dict[str, float]:
        return {n: v for p, rows in zip(self.placements, np.asarray(self.positions, np.float64))
                for k, row in enumerate(rows) for n, v in xyz_entries(f"marker_{k + 1}_", row, f"@{p}").items()}

    def groups_of(self, *, frame: str | None = None, placement: str | None = None) -> tuple[str, ...]:
        """Group names of a frame label and/or a placement label."""
        out: list[str] = []
        if frame is not None:
            if frame not in self.frames:
                raise ValueError(f"unknown frame label {frame!r}; labels: {list(self.frames)}")
            out += [g.name for g in frame_groups(frame)]
        if placement is not None:
            if placement not in self.placements:
                raise ValueError(f"unknown placement label {placement!r}; labels: {list(self.placements)}")
            out += [g.name for g in placement_groups(placement, self.markers[self.placements.index(placement)])]
        return tuple(out)

    @host_method
    def check_measurements(self, y, n: int) -> None:
        """``[n, N, 3]`` for the rows the model was made for; a missing marker is NaN in x, y and z
        (masked, :func:`marker_gaps`); a reading of a marker the row's placement does not have is
        an error (build the model with :meth:`from_dataset`, or name the markers)."""
        shape = tuple(np.shape(y))
        if shape != (n, *self.sample_shape):
            raise ValueError(f"markers measurements must have shape {[n, *self.sample_shape]} for {n} samples, "
                             f"got {list(shape)}")
        if n != self.n_rows:
            raise ValueError(f"SessionMarkers was made for {self.n_rows} rows but the data have {n}: build it from "
                             "the same rows (SessionMarkers.from_dataset, or .take(rows) for a subset)")
        seen = ~marker_gaps(y)
        extra = seen & ~self._has()[np.asarray(self.placement_index)]
        if extra.any():
            i, k = (int(v) for v in np.argwhere(extra)[0])
            p = self.placements[int(self.placement_index[i])]
            raise ValueError(f"row {i} (placement {p!r}) has a reading of marker {k + 1}, which placement {p!r} does "
                             f"not have (its markers: {list(self.markers[self.placements.index(p)])}); build the "
                             "model with SessionMarkers.from_dataset or name the markers (markers=)")

    def _has(self) -> np.ndarray:
        """``[n_placements, N]`` bool: the markers each placement has."""
        out = np.zeros((len(self.placements), self.n_markers), bool)
        for j, ks in enumerate(self.markers):
            out[j, np.asarray(ks, int) - 1] = True
        return out

    @host_method
    def observed(self, y) -> np.ndarray | None:
        """``[n, 3N]`` bool: the residual entries that are real readings (not a missing marker);
        ``None`` when every marker of every row is there."""
        seen = ~np.isnan(np.asarray(y, np.float64)).all(axis=-1)
        return None if seen.all() else np.repeat(seen, 3, axis=1)

    # -- model ----------------------------------------------------------------------------
    def frame_arrays(self, deviations: Deviations | None, dtype=None):
        """``(R [n_frames, 3, 3], t [n_frames, 3])``: ``T_sensor_base`` of every frame label."""
        dtype = self.positions.dtype if dtype is None else dtype
        nf = len(self.frames)
        if deviations is None:
            return jnp.broadcast_to(jnp.eye(3, dtype=dtype), (nf, 3, 3)), jnp.zeros((nf, 3), dtype)
        vals = deviations.values
        w = jnp.stack([jnp.asarray(vals[f"base_rotation@{f}"]).astype(dtype) for f in self.frames])
        t = jnp.stack([jnp.asarray(vals[f"base_translation@{f}"]).astype(dtype) for f in self.frames])
        return rotvec_to_matrix(w), t

    def marker_arrays(self, deviations: Deviations | None, dtype=None) -> Float[Array, "P N 3"]:
        """Marker positions ``[n_placements, N, 3]`` in the flange frame (nominal + deviations, mm)."""
        m = self.positions if dtype is None else self.positions.astype(dtype)
        if deviations is None:
            return m
        vals = deviations.values
        zero = jnp.zeros(3, m.dtype)
        dev = jnp.stack([jnp.stack([jnp.asarray(vals[f"marker_{k + 1}@{p}"]).astype(m.dtype) if k + 1 in ks else zero
                                    for k in range(self.n_markers)]) for p, ks in zip(self.placements, self.markers)])
        return m + dev

    def predict(self, robot, deviations, q) -> Float[Array, "n N 3"]:
        """Marker positions ``[n, N, 3]`` in each row's sensor frame (mm)."""
        q = check_joint_angles(robot, q)
        if q.shape[0] != self.n_rows:
            raise ValueError(f"SessionMarkers was made for {self.n_rows} rows, got {q.shape[0]} joint rows")
        X, Y, Z, P = _chain(robot, deviations, q, self.tip_for(robot))
        M = self.marker_arrays(deviations, q.dtype)[self.placement_index]  # [n, N, 3]
        R, t = self.frame_arrays(deviations, q.dtype)
        R, t = R[self.frame_index], t[self.frame_index]  # [n, 3, 3], [n, 3]
        out = []
        for k in range(self.n_markers):
            p = [P[c] + M[:, k, 0] * X[c] + M[:, k, 1] * Y[c] + M[:, k, 2] * Z[c] for c in range(3)]
            out.append(jnp.stack([R[:, r, 0] * p[0] + R[:, r, 1] * p[1] + R[:, r, 2] * p[2] + t[:, r]
                                  for r in range(3)], -1))
        return jnp.stack(out, axis=1)

    def residual(self, robot, deviations, q, y) -> Float[Array, "n 3N"]:
        """``predicted − measured`` (mm) ``[n, 3N]``; exactly 0 where a marker is missing (NaN)."""
        y = jnp.asarray(y)
        ok = ~jnp.isnan(y)
        r = self.predict(robot, deviations, q) - jnp.where(ok, y, 0.0)
        return jnp.where(ok, r, 0.0).reshape(q.shape[0], self.size)

    def sample_error(self, residual) -> Float[Array, " n"]:
        """RMS over the row's real markers of the 3-D distance error (mm). A missing marker has an
        exactly zero residual and is left out of the mean (as :meth:`jaxcal.Camera.sample_error`:
        a real reading whose residual is exactly 0.0 would be too, a measure-zero event with
        noisy data); with every marker present this is :class:`~jaxcal.Markers`' error."""
        r = residual.reshape(residual.shape[0], self.n_markers, 3)
        sq = jnp.sum(r * r, axis=-1)
        count = jnp.sum(sq > 0, axis=-1).astype(sq.dtype)
        return jnp.sqrt(jnp.mean(sq, axis=-1) * (self.n_markers / jnp.maximum(count, 1.0)))


def _placement_markers(markers, placements: tuple[str, ...], n_markers: int) -> tuple[tuple[int, ...], ...]:
    """``SessionMarkers(markers=...)`` as one sorted tuple of 1-based marker numbers per placement."""
    if markers is None:
        return tuple(tuple(range(1, n_markers + 1)) for _ in placements)
    if isinstance(markers, dict):
        unknown = sorted(set(markers) - set(placements))
        if unknown:
            raise ValueError(f"markers= names unknown placement label(s) {unknown}; labels: {list(placements)}")
        markers = [markers.get(p, range(1, n_markers + 1)) for p in placements]
    markers = list(markers)
    if len(markers) != len(placements):
        raise ValueError(f"markers= gives {len(markers)} marker sets for {len(placements)} placements")
    out = []
    for p, ks in zip(placements, markers):
        ks = tuple(sorted({int(k) for k in ks}))
        if not ks or ks[0] < 1 or ks[-1] > n_markers:
            raise ValueError(f"placement {p!r}: markers must be a non-empty set of numbers 1..{n_markers}, got {list(ks)}")
        out.append(ks)
    return tuple(out)


# -- closed-form start --------------------------------------------------------------------------
def initial_sessions(robot, measurement: SessionMarkers, data, *, start: Deviations | None = None,
                     frames: Sequence[str] | None = None, placements: Sequence[str] | None = None,
                     iterations: int = 500, trim: bool = True):
    """Closed-form start of the session frames and marker placements on the (nominal) robot.

    Each frame by Kabsch on its rows' marker points, each placement's markers by the mean over
    its rows of ``F_iᵀ(R_iᵀ(y_ik − t_i) − P_i)``, alternating until nothing moves (the frames
    first from the marker centroids); then once more without rows beyond 5 robust σ.

    Args:
        robot, measurement: nominal robot, the session model of the data's rows.
        data: ``(q, y)`` or a :class:`~jaxcal.Dataset` of those rows.
        start: deviations to start from (default nominal); its robot part gives the flange poses.
        frames, placements: labels to estimate (default: every label with rows); the others
            keep ``start``'s values.
        iterations: alternation steps at most.

    Returns:
        :class:`jaxcal.ExtrasEstimate` (deviations, RMS before/after, trimmed rows, message).

    Raises:
        ValueError: a label to estimate has no rows, or a frame to estimate has fewer than
            3 rows, or a placement to estimate is seen only in frames that are also estimated
            and has no rows at all.
    """

    q, y = (data.q, data.y) if hasattr(data, "q") else data
    q = jnp.asarray(q)
    dtype = q.dtype
    m = measurement
    start = Deviations.zeros(layout_for(robot, m), dtype) if start is None else start.astype(dtype)
    Y = np.asarray(y, np.float64)
    fi, pi = np.asarray(m.frame_index), np.asarray(m.placement_index)
    if Y.shape[0] != fi.shape[0]:
        raise ValueError(f"SessionMarkers was made for {fi.shape[0]} rows but the data have {Y.shape[0]}")
    est_f = [f for f in m.frames if np.any(fi == m.frames.index(f))] if frames is None else list(frames)
    est_p = [p for p in m.placements if np.any(pi == m.placements.index(p))] if placements is None else list(placements)
    for f in est_f:
        if f not in m.frames:
            raise ValueError(f"unknown frame label {f!r}; labels: {list(m.frames)}")
        rows = int(np.sum(fi == m.frames.index(f)))
        if rows < MIN_FRAME_ROWS:
            raise ValueError(f"frame {f!r} has {rows} row(s): its own sensor frame (6 parameters) needs at least "
                             f"{MIN_FRAME_ROWS} rows; give more rows or share the frame label with another session")
    for p in est_p:
        if p not in m.placements:
            raise ValueError(f"unknown placement label {p!r}; labels: {list(m.placements)}")
        if not np.any(pi == m.placements.index(p)):
            raise ValueError(f"placement {p!r} has no rows: its marker positions cannot be estimated")
    T = tip_frames(robot, m, q, start)
    F, P = T[:, :3, :3], T[:, :3, 3]
    M = np.array(m.marker_arrays(start, dtype), np.float64)  # [Pn, N, 3]
    R_all, t_all = (np.array(a, np.float64) for a in m.frame_arrays(start, dtype))
    fidx = [m.frames.index(f) for f in est_f]
    pidx = [m.placements.index(p) for p in est_p]
    before = float(np.sqrt(np.mean(marker_errors(F, P, Y, fi, pi, R_all, t_all, M) ** 2)))
    R_all, t_all, M, keep = alternate_frames_and_markers(F, P, Y, fi, pi, R_all, t_all, M, fidx, pidx,
                                                         iterations=iterations, trim=trim)
    from .._core._rotvec import matrix_to_rotvec

    vals = {}
    for j in fidx:
        f = m.frames[j]
        vals[f"base_rotation@{f}"] = to_device(matrix_to_rotvec(R_all[j]), dtype)
        vals[f"base_translation@{f}"] = to_device(t_all[j], dtype)
    M0 = np.asarray(m.positions, np.float64)
    for j in pidx:
        for k in m.markers[j]:
            vals[f"marker_{k}@{m.placements[j]}"] = to_device(M[j, k - 1] - M0[j, k - 1], dtype)
    dev = start.replace(**vals)
    after = float(np.sqrt(np.mean(marker_errors(F, P, Y, fi, pi, R_all, t_all, M) ** 2)))
    n_trim = int((~keep).sum())
    n_miss, n_all, n_rows = masked_markers(Y)
    msg = (f"extras from the data: {len(fidx)} session frame(s) ({', '.join(est_f) or '-'}) and {len(pidx)} marker "
           f"placement(s) ({', '.join(est_p) or '-'}) in closed form (RMS residual of the robot {before:.2f} → "
           f"{after:.2f} mm" + trimmed_note(n_trim) + ")"
           + (f"; {n_miss} of {n_all} marker readings missing (NaN: markers a placement does not have, or not seen) "
              f"in {n_rows} row(s): masked (zero weight), not dropped" if n_miss else ""))
    return ExtrasEstimate(dev, before, after, n_trim, msg)


def marker_gaps(y) -> np.ndarray:
    """``[n, N]`` bool: the marker readings of ``y`` ``[n, N, 3]`` that are missing (NaN in all
    three coordinates: a marker the session does not have, or one not seen in that row).

    Raises:
        ValueError: a reading with only some coordinates NaN (a partial point is a broken file,
            not a missing marker), ±inf, or a row without any marker reading.
    """
    Y = np.asarray(y, np.float64)
    if Y.ndim != 3 or Y.shape[2] != 3:
        raise ValueError(f"marker readings must be [n, N, 3] (mm), got shape {list(Y.shape)}")
    if np.isinf(Y).any():
        raise ValueError("marker readings contain ±inf; a missing marker is NaN in x, y and z (empty CSV cells)")
    nan = np.isnan(Y)
    gap = nan.all(axis=-1)
    part = nan.any(axis=-1) & ~gap
    if part.any():
        i, k = (int(v) for v in np.argwhere(part)[0])
        raise ValueError(f"marker readings: {int(part.sum())} reading(s) have only some of x, y, z missing (first: "
                         f"row {i}, marker {k + 1}); a missing marker is NaN in all three coordinates, a partial "
                         "point is an error in the data")
    empty = gap.all(axis=1)
    if empty.any():
        raise ValueError(f"marker readings: {int(empty.sum())} row(s) have no marker reading at all (rows "
                         f"{np.flatnonzero(empty)[:10].tolist()}, 0-based); remove them")
    return gap


# -- the data-file form of marker data -----------------------------------------------------------
_MARKER = re.compile(r"marker_(\d+)_([xyz])_mm")
#: CSV columns of session labels (marker data of several sessions; text, not numbers)
LABEL_COLUMNS = ("session", "frame", "placement")


def marker_columns(n_markers: int) -> list[str]:
    """CSV columns of ``n_markers`` marker positions in the sensor frame (mm)."""
    return [f"marker_{k}_{c}_mm" for k in range(1, n_markers + 1) for c in "xyz"]


@register_kind
class MarkersKind(PointsKind):
    """Motion-capture marker data (:class:`~jaxcal.Markers`, :class:`SessionMarkers`): columns
    ``marker_k_x_mm, marker_k_y_mm, marker_k_z_mm`` for k = 1..N (N from the file; empty cells:
    a marker missing, masked), readings ``[n, N, 3]`` mm in the sensor frame; optional text columns
    ``session``, ``frame``, ``placement`` (:attr:`jaxcal.Dataset.labels`)."""

    name = "markers"
    session_labels = True
    plannable = False
    counts_markers = True
    pattern = _MARKER
    number_group, width = 1, 3
    columns_word, count_word = "marker", "marker(s)"
    expected_hint = "marker_1_x_mm, marker_1_y_mm, marker_1_z_mm, marker_2_x_mm, ..."

    def point_columns(self, n_points):
        return marker_columns(n_points)

    def check_options(self, estimate, options):
        super().check_options(estimate, options)
        if "tool" in estimate:
            raise ValueError("--estimate tool does not apply to marker data: the marker positions are the tool")

    def required_extras(self, estimate, *, sessions=False, **_):
        estimate = set(estimate)
        if "base" in estimate or sessions:  # sessions: every frame is estimated
            return estimate, []
        return estimate | {"base"}, [
            "marker data: the motion-capture frame (base extras) and the marker positions on the flange are estimated "
            "(closed-form Kabsch start from the data, then the joint fit)"]

    def model_to_dict(self, model):
        """:class:`~jaxcal.Markers`: positions, ``known`` and the sensor frame; a
        :class:`SessionMarkers` adds ``"sessions"`` (its labels, each placement's marker numbers and
        the training rows' indices) and per-placement ``positions_mm`` ``[P, N, 3]``."""
        positions = np.asarray(model.positions, np.float64).tolist()
        if isinstance(model, SessionMarkers):
            return {"kind": "markers", "positions_mm": positions,
                    "sessions": {"frames": list(model.frames), "placements": list(model.placements),
                                 "markers": [list(k) for k in model.markers],
                                 "frame_index": np.asarray(model.frame_index).tolist(),
                                 "placement_index": np.asarray(model.placement_index).tolist()}} | tip_to_dict(model)
        return ({"kind": "markers", "positions_mm": positions, "known": bool(model.known)} | frame_to_dict(model)
                | tip_to_dict(model))

    def model_from_dict(self, d):
        if "sessions" not in d:
            return Markers(to_device(np.asarray(d["positions_mm"], np.float64)), known=bool(d.get("known", False)),
                           **frame_from_dict(d), tip=d.get("tip"))
        se = d["sessions"]
        fr, pl = se["frames"], se["placements"]
        return SessionMarkers([fr[i] for i in se["frame_index"]], [pl[i] for i in se["placement_index"]],
                              len(d["positions_mm"][0]), np.asarray(d["positions_mm"], np.float64),
                              frame_labels=fr, placement_labels=pl, markers=se["markers"], tip=d.get("tip"))

    def default_model(self, robot, *, data=None, anchor_mm=None, n_markers=None):
        # marker positions on the flange unknown: they start from the data (closed form) and are calibrated
        self.refuse_anchor(anchor_mm)
        n = int(np.shape(data.y)[1]) if n_markers is None else int(n_markers)
        return Markers(np.zeros((n, 3)))

    def setup(self, data, robot, estimate, options):
        self.check_options(estimate, options)
        estimate, notes = self.required_extras(estimate, sessions=bool(data.labels))
        if not data.labels:
            return self.default_model(robot, data=data), estimate, notes
        # marker data of several sessions: one frame / placement per label
        measurement = SessionMarkers.from_dataset(data)
        n_miss, n_all, n_rows = masked_markers(data.y)
        places = ", ".join(f"{p} ({len(k)})" for p, k in zip(measurement.placements, measurement.markers))
        notes.append(f"{len(dict.fromkeys(s for s, _, _ in data.labels))} recording sessions: frames "
                     f"{', '.join(measurement.frames)}; placements (markers) {places}; shared robot errors"
                     + (f"; {n_miss} of {n_all} marker readings missing (empty cells) in {n_rows} row(s): masked "
                        "(zero weight), not dropped" if n_miss else ""))
        return measurement, estimate, notes

    def label_columns(self, path, header):
        return [c for c in LABEL_COLUMNS if c in header]

    def readings(self, values, path, table, meta):
        header = table.header
        cols = self.label_columns(path, header)
        y, meta, _ = super().readings(values, path, table, meta)  # NaN: a marker the session does not have
        if not cols:
            return y, meta, ()
        cells = {c: [row[header.index(c)].strip() for row in table.rows] for c in cols}
        for c, vals_c in cells.items():
            empty = [r for r, v in enumerate(vals_c) if not v]
            if empty:
                raise ValueError(f"{path}: {table.where(empty[0], c)}: empty label ({len(empty)} row(s) without a {c})")
        fr = cells.get("frame") or cells.get("session")
        pl = cells.get("placement") or cells.get("session")
        if fr is None or pl is None:
            raise ValueError(f"{path}: give a 'session' column, or both 'frame' and 'placement' (have {cols})")
        se = cells.get("session") or [f"{fr[r]}/{pl[r]}" for r in range(len(table.rows))]
        return y, meta, tuple(zip(se, fr, pl))

    def write_values(self, data):
        y = np.asarray(data.y, np.float64)
        text = list(LABEL_COLUMNS) if data.labels else []
        cells = [list(lab) for lab in data.labels] if data.labels else [[] for _ in range(y.shape[0])]
        return marker_columns(y.shape[1]), y.reshape(y.shape[0], -1), text, cells

    def checked_readings(self, y, n, dof):
        if y.ndim != 3 or y.shape[0] != n or y.shape[2] != 3 or y.shape[1] < 1:
            raise ValueError(f"markers measurements must have shape [{n}, N, 3] (N >= 1 markers), got {list(y.shape)}")
        if np.isnan(y).any():  # a missing marker (NaN x, y, z): masked by SessionMarkers, refused by Markers
            marker_gaps(y)  # partial points, ±inf, rows without any marker: errors
            y = np.where(np.isnan(y), 0.0, y)
        return y

