"""Calibration without a tracker: a probe touching planes, a tool tip pivoting on fixed points,
a distance bar.

Three cheap set-ups (issue 23). Two are measurement models whose reading is a **label**, not a
number (the third, :class:`DistanceBar`, reads a second pose and a length; see its docstring):

* :class:`PlaneContact` (kind ``"plane"``): the tool tip (a touch probe, a dial indicator at
  zero) touches one of ``K`` planes (a table, the faces of a calibration cube). Row ``i`` says
  which plane it touched; the residual is the signed distance of the predicted tool point to
  that plane, ``r_i = n_k·p(q_i) − d_k`` (mm).
* :class:`FixedPoint` (kind ``"point"``): the tool tip is put on one of ``K`` fixed points in
  different orientations (pivoting; residual ``p(q_i) − c_k``, ``[n, 3]`` mm), or, with
  ``radii``, a ball on the flange touches one of ``K`` fixed spheres (residual
  ``‖p(q_i) − c_k‖ − r_k``, ``[n, 1]`` mm; ``r_k`` = sphere radius + ball radius).

The reading ``y`` is ``[n]``: the 0-based index of the row's plane / point label (a float
holding an integer, so that :class:`~jaxcal.Dataset` keeps one array type); the label names
travel in the Dataset metadata (``plane_labels`` / ``point_labels``) and in CSV files as a text
column ``plane`` / ``point``. ``predict`` returns the label of the nearest plane / point, i.e.
the reading a perfect contact would give, so that code that asks a model for readings at
poses (identifiability at poses, pose planning) sees a consistent data set.

Extras (one group per label, named with ``@label`` like the session groups; all free by
default, started in closed form by :func:`initial_contact`, which :func:`jaxcal.calibrate`
calls through :func:`jaxcal.initial_extras`):

* ``plane@K`` = ``plane_u@K, plane_v@K`` (rad) and ``plane_d@K`` (mm). The normal is the
  nominal normal ``n0`` turned by the rotation vector ``u·e_u + v·e_v``
  (``n = exp([u·e_u + v·e_v]×)·n0``, with ``e_u, e_v`` a fixed orthonormal basis of the plane
  ``⊥ n0``): a minimal, singularity-free (up to a 180° turn) two-angle parametrisation of a unit
  vector; the plane is ``{x : n·x = d0 + plane_d}`` in the robot base frame.
* ``point@K`` = ``point_x@K, point_y@K, point_z@K`` (mm, base frame, deviation from the
  nominal centre) and, with ``estimate_radius=True``, ``radius@K`` (mm).
* The tool point is the standard ``tool`` extra (``tool_x/y/z``, flange frame).

What contact data cannot see (no sensor frame: the planes and points are expressed in the robot
base frame, so a base-frame error is absorbed by them): with one plane, moving the robot
parallel to the plane (2 translations) and turning it about the plane normal (1 rotation) change
no reading; two non-parallel planes leave the translation along their intersection line; three
planes with independent normals see every rigid motion of the robot relative to the planes.
:func:`unobservable_directions` says so for a given set of normals; the identification Jacobian
(:func:`jaxcal.identifiability`) shows it as unidentifiable robot parameters (e.g. ``theta_1``
with one horizontal plane) or dependencies between ``d_1`` and a plane offset. A fixed point
sees all three translations of the tool point, so pivot data with one point identify what
position data in the base frame identify, less the base translation (absorbed by the centre).

Nor can plane or point data see the robot's **length scale**: multiplying every length of the
set-up by the same factor — the DH lengths ``a_i``, ``d_i``, the tool point, the plane offsets
``d_k`` (or the point centres, and unknown sphere radii) — keeps every contact a contact, so that
direction is in the null space of the identification Jacobian whatever the poses
(``tests/sensors/test_contact.py::test_contact_data_cannot_see_the_length_scale``). The report shows it
as one more rank deficiency (a length parameter such as ``d_2`` or ``a_2`` left out, or
depending on the others). Something must fix it: the prior toward the nominal DH lengths
(``jaxcal calibrate``'s default ``--prior``), a length held at nominal (``--fix``), a known
sphere radius (``--radius-mm``: a length reference), or distance-bar rows (:class:`DistanceBar`,
whose ``L`` is a calibrated length). With one or two planes, or points only, the base-frame
directions above are also unseen; the prior then keeps them at the nominal values.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
import warnings
from collections.abc import Sequence
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core._csvfile import rad_to_deg_roundtrip
from .._core._host_method import host_method
from .._core._params import Deviations, Group, layout_for
from .._core._precision import to_device
from .._core._xla import jit
from .._models._kinematics import check_joint_angles, rotvec_to_matrix, tool_point_soa
from ._kind import SensorKind, check_label, register_kind
from ._measurement import MeasurementModel, tip_groups, tip_to_dict, xyz_entries

__all__ = ["PlaneContact", "FixedPoint", "plane_group", "point_groups", "initial_contact",
    "unobservable_directions", "contact_model", "default_setup", "DistanceBar", "length_reference_note"]


def plane_group(label: str) -> Group:
    """``plane@label``: ``plane_u@label, plane_v@label`` (rad, the normal's turn) and
    ``plane_d@label`` (mm, the offset's deviation)."""
    return Group(f"plane@{label}", (f"plane_u@{label}", f"plane_v@{label}", f"plane_d@{label}"),
                 ("rad", "rad", "mm"), "extra", (3,))


def point_groups(label: str, radius: bool = False) -> tuple[Group, ...]:
    """``point@label`` (``point_x/y/z@label``, mm) and, with ``radius``, ``radius@label`` (mm)."""
    g = (Group.vector(f"point@{label}", tuple(f"point_{c}@{label}" for c in "xyz"), "mm"),)
    return g + ((Group(f"radius@{label}", (f"radius@{label}",), ("mm",), "extra", ()),) if radius else ())


def _tangent_basis(n0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[K, 3]`` orthonormal ``e_u, e_v`` with ``(e_u, e_v, n0)`` right-handed, per normal."""
    eu, ev = [], []
    for n in n0:
        a = np.eye(3)[int(np.argmin(np.abs(n)))]
        u = np.cross(a, n)
        u /= np.linalg.norm(u)
        eu.append(u)
        ev.append(np.cross(n, u))
    return np.asarray(eu), np.asarray(ev)


def _labels_of(y, n_labels: int, xp=jnp):
    """The label index ``[n]`` (int32) of readings ``y``, rounded and clipped to ``0..n_labels-1``
    (``xp=np``: the same on the host, no JAX program)."""
    return xp.clip(xp.round(y).astype(xp.int32), 0, n_labels - 1).reshape(-1)


def _per_label(deviations: Deviations, group: str, labels, dtype) -> Array:
    """The per-label groups ``group@label`` of ``deviations`` stacked in ``labels`` order ``[K, ...]``."""
    vals = deviations.values
    return jnp.stack([jnp.asarray(vals[f"{group}@{s}"]).astype(dtype) for s in labels])

class _LabelModel(MeasurementModel):
    """Shared by the contact models: the reading is a label index ``[n]``."""

    sample_shape: ClassVar[tuple[int, ...]] = ()

    @property
    def jacobian_free_of_data(self) -> bool:
        # the readings are labels: the Jacobian depends on them, and the right one is the one at the
        # measured labels. Where readings are given, jaxcal then uses them (not the prediction)
        # for the start Jacobian, which is what a contact model needs.
        return True

    @host_method
    def check_measurements(self, y, n: int) -> None:
        super().check_measurements(y, n)
        y = np.asarray(y)
        if y.size and (np.any(y != np.round(y)) or y.min() < 0 or y.max() >= len(self.labels)):
            raise ValueError(f"{self.kind} readings must be label indices 0..{len(self.labels) - 1}")


class PlaneContact(_LabelModel):
    """A probe on the tool touching one of ``K`` planes; reading: the plane's index ``[n]``.

    Residual ``[n, 1]`` (mm): ``r_i = n_k·p(q_i) − d_k`` with ``k`` = the row's plane, ``p`` the
    tool point in the base frame (nominal tool + the ``tool`` extra), ``n_k`` the unit normal
    ``exp([u_k·e_u + v_k·e_v]×)·n0_k`` (``u_k, v_k`` the extras ``plane_u@k, plane_v@k`` in rad,
    ``e_u, e_v`` a fixed orthonormal basis ``⊥ n0_k``: two angles, singularity-free up to a 180°
    turn) and ``d_k = d0_k + plane_d@k`` (mm), all in the robot base frame; the extras are free by
    default and started in closed form by :func:`jaxcal.calibrate`. ``sample_error`` is the signed
    distance (mm). The planes absorb a base-frame error: one plane leaves 2 translations and the
    rotation about its normal unseen, two non-parallel planes the translation along their
    intersection line; three planes with independent normals see every rigid motion.

    Attributes:
        normals: ``[K, 3]`` nominal unit normals (base frame); default ``(0, 0, 1)`` each (the
            closed-form start finds the real ones: a normal can turn by up to 180°).
        offsets: ``[K]`` nominal offsets ``d0`` (mm).
        basis_u, basis_v: ``[K, 3]`` the fixed tangent bases.
        labels: the plane labels (static, index order).
        tip: the tip of a :class:`~jaxcal.KinematicTree` that carries the probe (static; ``None``:
            the robot's default tip); another tip's tool point is the ``tool@<tip>`` group.
    """

    normals: Float[Array, "K 3"]
    offsets: Float[Array, " K"]
    basis_u: Float[Array, "K 3"]
    basis_v: Float[Array, "K 3"]
    labels: tuple[str, ...] = eqx.field(static=True)
    tip: str | None = eqx.field(static=True, default=None)
    kind: ClassVar[str] = "plane"
    initialisable: ClassVar[tuple[str, ...]] = ("plane", "tool")
    size: ClassVar[int] = 1

    def __init__(self, labels: Sequence[str], normals=None, offsets_mm=None, tip: str | None = None):
        self.tip = tip
        labels = tuple(check_label(s) for s in labels)
        if not labels or len(set(labels)) != len(labels):
            raise ValueError(f"PlaneContact needs distinct plane labels, got {list(labels)}")
        K = len(labels)
        n0 = np.tile([0.0, 0.0, 1.0], (K, 1)) if normals is None else np.asarray(normals, np.float64)
        d0 = np.zeros(K) if offsets_mm is None else np.asarray(offsets_mm, np.float64).reshape(-1)
        if n0.shape != (K, 3) or d0.shape != (K,) or not (np.all(np.isfinite(n0)) and np.all(np.isfinite(d0))):
            raise ValueError(f"normals must be finite [{K}, 3] and offsets_mm [{K}]")
        nn = np.linalg.norm(n0, axis=1, keepdims=True)
        if np.any(nn < 1e-9):
            raise ValueError("plane normals must be non-zero")
        n0 = n0 / nn
        eu, ev = _tangent_basis(n0)
        self.normals, self.offsets = to_device(n0), to_device(d0)
        self.basis_u, self.basis_v = to_device(eu), to_device(ev)
        self.labels = labels

    @classmethod
    def from_dataset(cls, data, **kw) -> PlaneContact:
        """The model of a plane-contact :class:`~jaxcal.Dataset` (its ``plane_labels`` metadata)."""
        return cls(dataset_labels(data), **kw)

    def extra_groups(self) -> tuple[Group, ...]:
        """``plane@K`` per label (and ``tool@<tip>`` for a tip other than the default one)."""
        return tuple(plane_group(s) for s in self.labels) + tip_groups(self.tip)

    def nominal_lengths(self) -> dict[str, float]:
        return {f"plane_d@{s}": float(v) for s, v in zip(self.labels, np.asarray(self.offsets, np.float64))}

    def planes(self, deviations: Deviations | None, dtype=None):
        """``(n [K, 3], d [K])``: the planes' unit normals and offsets (mm), base frame."""
        dtype = self.normals.dtype if dtype is None else dtype
        n0, d0 = self.normals.astype(dtype), self.offsets.astype(dtype)
        if deviations is None:
            return n0, d0
        dev = _per_label(deviations, "plane", self.labels, dtype)  # [K, 3]
        w = dev[:, :1] * self.basis_u.astype(dtype) + dev[:, 1:2] * self.basis_v.astype(dtype)
        n = jnp.einsum("kij,kj->ki", rotvec_to_matrix(w), n0)
        return n, d0 + dev[:, 2]

    def distances(self, robot, deviations, q) -> Float[Array, "n K"]:
        """Signed distance ``[n, K]`` (mm) of every row's tool point to every plane."""
        q = check_joint_angles(robot, q)
        p = tool_point_soa(robot, deviations, q, tip=self.tip_for(robot))
        n, d = self.planes(deviations, q.dtype)
        return jnp.stack([n[k, 0] * p[0] + n[k, 1] * p[1] + n[k, 2] * p[2] - d[k] for k in range(len(self.labels))],
                         axis=-1)

    def predict(self, robot, deviations, q) -> Float[Array, " n"]:
        """The index of the nearest plane ``[n]`` (the reading of a perfect contact)."""
        return jnp.argmin(jnp.abs(jax.lax.stop_gradient(self.distances(robot, deviations, q))), axis=1).astype(
            jnp.asarray(q).dtype)

    def residual(self, robot, deviations, q, y) -> Float[Array, "n 1"]:
        """Signed distance to the row's plane, ``[n, 1]`` (mm)."""
        q = check_joint_angles(robot, q)
        k = _labels_of(y, len(self.labels))
        p = tool_point_soa(robot, deviations, q, tip=self.tip_for(robot))
        n, d = self.planes(deviations, q.dtype)
        nk, dk = n[k], d[k]
        return (nk[:, 0] * p[0] + nk[:, 1] * p[1] + nk[:, 2] * p[2] - dk)[:, None]

    def gap(self, deviations, p, k, dtype) -> Float[Array, " 1"]:
        """The contact constraint of one tool point ``p`` ``[3]`` (mm) on plane ``k``: its signed
        distance ``[1]`` (mm; zero at contact). The simulation moves poses onto it."""
        n, d = self.planes(deviations, dtype)
        return jnp.atleast_1d(n[k] @ p - d[k])


class FixedPoint(_LabelModel):
    """The tool tip on one of ``K`` fixed points (pivoting) or a flange ball on one of ``K`` fixed
    spheres; reading: the point's index ``[n]``.

    Points (``radii=None``): residual ``[n, 3]`` = ``p(q_i) − c_k`` (mm), sample error its norm
    (the 3-D distance to the point). Spheres (``radii`` given): residual ``[n, 1]`` =
    ``‖p(q_i) − c_k‖ − r_k`` (mm, signed), ``r_k`` the nominal radius (sphere + ball) plus the
    ``radius@k`` extra when ``estimate_radius``. ``c_k`` = nominal centre + ``point@k`` (base
    frame, mm); ``p`` the tool point (the ball centre).

    Attributes:
        centres: ``[K, 3]`` nominal centres (mm; default zeros: the closed form finds them).
        radii: ``[K]`` nominal radii (mm; zeros for points).
        labels: the point labels (static); sphere, estimate_radius: static flags.
        tip: the tip of a :class:`~jaxcal.KinematicTree` that carries the tool tip or ball
            (static; ``None``: the robot's default tip); another tip's tool point is the
            ``tool@<tip>`` group.
    """

    centres: Float[Array, "K 3"]
    radii: Float[Array, " K"]
    labels: tuple[str, ...] = eqx.field(static=True)
    sphere: bool = eqx.field(static=True, default=False)
    estimate_radius: bool = eqx.field(static=True, default=False)
    tip: str | None = eqx.field(static=True, default=None)
    kind: ClassVar[str] = "point"
    initialisable: ClassVar[tuple[str, ...]] = ("point", "tool")

    def __init__(self, labels: Sequence[str], centres_mm=None, radii_mm=None, estimate_radius: bool = False,
                 tip: str | None = None):
        self.tip = tip
        labels = tuple(check_label(s) for s in labels)
        if not labels or len(set(labels)) != len(labels):
            raise ValueError(f"FixedPoint needs distinct point labels, got {list(labels)}")
        K = len(labels)
        c = np.zeros((K, 3)) if centres_mm is None else np.asarray(centres_mm, np.float64)
        self.sphere = radii_mm is not None or bool(estimate_radius)
        r = np.zeros(K) if radii_mm is None else np.broadcast_to(np.asarray(radii_mm, np.float64), (K,)).copy()
        if c.shape != (K, 3) or not (np.all(np.isfinite(c)) and np.all(np.isfinite(r))) or np.any(r < 0):
            raise ValueError(f"centres_mm must be finite [{K}, 3] and radii_mm finite, non-negative [{K}]")
        self.centres, self.radii = to_device(c), to_device(r)
        self.labels = labels
        self.estimate_radius = bool(estimate_radius)

    @classmethod
    def from_dataset(cls, data, **kw) -> FixedPoint:
        """The model of a fixed-point :class:`~jaxcal.Dataset` (its ``point_labels`` metadata)."""
        return cls(dataset_labels(data), **kw)

    @property
    def size(self) -> int:  # type: ignore[override]
        return 1 if self.sphere else 3

    def extra_groups(self) -> tuple[Group, ...]:
        """``point@K`` (and ``radius@K``) per label (and ``tool@<tip>`` for a tip other than the
        default one)."""
        return tuple(g for s in self.labels for g in point_groups(s, self.estimate_radius)) + tip_groups(self.tip)

    def nominal_lengths(self) -> dict[str, float]:
        out: dict[str, float] = {}
        for s, c, r in zip(self.labels, np.asarray(self.centres, np.float64), np.asarray(self.radii, np.float64)):
            out |= xyz_entries("point_", c, f"@{s}") | {f"radius@{s}": float(r)}
        return out

    def points(self, deviations: Deviations | None, dtype=None):
        """``(c [K, 3], r [K])``: centres and radii (mm)."""
        dtype = self.centres.dtype if dtype is None else dtype
        c, r = self.centres.astype(dtype), self.radii.astype(dtype)
        if deviations is None:
            return c, r
        c = c + _per_label(deviations, "point", self.labels, dtype)
        if self.estimate_radius:
            r = r + _per_label(deviations, "radius", self.labels, dtype)
        return c, r

    def predict(self, robot, deviations, q) -> Float[Array, " n"]:
        """The index of the nearest point / sphere surface ``[n]``."""
        q = check_joint_angles(robot, q)
        p = jnp.stack(tool_point_soa(robot, deviations, q, tip=self.tip_for(robot)), -1)
        c, r = self.points(deviations, q.dtype)
        dist = jnp.abs(jnp.linalg.norm(p[:, None] - c[None], axis=-1) - r)
        return jnp.argmin(jax.lax.stop_gradient(dist), axis=1).astype(q.dtype)

    def residual(self, robot, deviations, q, y):
        """``p − c_k`` ``[n, 3]`` (points) or ``‖p − c_k‖ − r_k`` ``[n, 1]`` (spheres), mm."""
        q = check_joint_angles(robot, q)
        k = _labels_of(y, len(self.labels))
        p = tool_point_soa(robot, deviations, q, tip=self.tip_for(robot))
        c, r = self.points(deviations, q.dtype)
        ck = c[k]
        diff = [p[j] - ck[:, j] for j in range(3)]
        if not self.sphere:
            return jnp.stack(diff, -1)
        return (jnp.sqrt(diff[0] ** 2 + diff[1] ** 2 + diff[2] ** 2) - r[k])[:, None]

    def gap(self, deviations, p, k, dtype):
        """The contact constraint of one tool point ``p`` ``[3]`` (mm) on point ``k``: ``p − c_k``
        ``[3]`` (points) or ``‖p − c_k‖ − r_k`` ``[1]`` (spheres), mm; zero at contact."""
        c, r = self.points(deviations, dtype)
        if not self.sphere:
            return p - c[k]
        return jnp.atleast_1d(jnp.linalg.norm(p - c[k]) - r[k])


# -- data ---------------------------------------------------------------------------------------


def length_reference_note(kind: str, *, known_radius: bool = False) -> str:
    """What fixes the robot's length scale under ``kind`` contact data (``"plane"``, ``"point"``),
    in words for the command line: planes and pivot points (or spheres of unknown radius) have no
    length reference, so the prior or a fixed length sets the scale; a ``known_radius`` sphere is
    one, but weak (scaling every length by ``1 + ε`` moves a residual ``‖p − c‖ − r`` by only
    ``ε·r``), so the prior still holds most of it."""
    if kind == "point" and known_radius:
        return ("the known sphere radius is the data's only length reference, and a weak one: the prior (or a "
                "--fix'ed length) still holds most of the robot's scale")
    return "contact data have no length reference, so the prior (or a --fix'ed length) sets the robot's scale"


def contact_model(kind: str, robot, data=None):
    """The model the command line uses: from ``data``'s labels with unknown planes / points (the
    closed-form start finds them), or without data the simulation set-up of
    :func:`default_setup`."""
    if kind == "distance":
        return DistanceBar(robot.dof)
    if data is not None:
        return PlaneContact.from_dataset(data) if kind == "plane" else FixedPoint.from_dataset(data)
    return default_setup(kind, robot)


def default_setup(kind: str, robot):
    """A simulated set-up inside the robot's reach: for ``"plane"`` three planes through the middle
    of the workspace (a table tilted 5°, two walls 60° apart), for ``"point"`` two pivot points
    400 mm apart."""
    q = np.asarray(_sample_q(jax.random.key(0), robot, 4096), np.float64)
    p = np.asarray(jnp.stack(tool_point_soa(robot, None, jnp.asarray(q)), -1), np.float64)
    p = p[p[:, 2] > 0] if np.sum(p[:, 2] > 0) > 100 else p
    mid = np.median(p, axis=0)
    if kind == "plane":
        t = math.radians(5.0)
        n = np.array([[math.sin(t), 0.0, math.cos(t)], [1.0, 0.0, 0.15], [0.5, math.sqrt(3) / 2, 0.1]])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return PlaneContact(("table", "wall_a", "wall_b"), n, n @ mid)
    if kind == "point":
        return FixedPoint(("p1", "p2"), np.stack([mid - [0, 200, 0], mid + [0, 200, 0]]))
    raise ValueError(f"unknown contact kind {kind!r}; expected one of {list(CONTACT_KINDS)}")


def _sample_q(key, robot, n):
    from .._models._robot import sample_joint_angles

    return sample_joint_angles(key, robot, n)


# -- closed-form start ----------------------------------------------------------------------------
def _fit_plane(pts: np.ndarray, n_ref: np.ndarray) -> tuple[np.ndarray, float]:
    c = pts.mean(axis=0)
    n = np.linalg.svd(pts - c, full_matrices=False)[2][-1]
    n = n if n @ n_ref >= 0 else -n
    return n, float(n @ c)


def _turn(n0: np.ndarray, n: np.ndarray, eu: np.ndarray, ev: np.ndarray) -> tuple[float, float]:
    """``(u, v)`` with ``exp([u·e_u + v·e_v]×)·n0 = n`` (both unit, ``n0·n > −1``)."""
    axis = np.cross(n0, n)
    s, c = np.linalg.norm(axis), float(n0 @ n)
    if s < 1e-15:
        return 0.0, 0.0
    w = axis / s * math.atan2(s, c)
    return float(w @ eu), float(w @ ev)


def initial_contact(robot, measurement, data, *, estimate=None, start: Deviations | None = None,
                    iterations: int = 20):
    """Closed-form start of the planes / points (and the tool point) on the nominal robot.

    Planes: per label an SVD plane fit of the tool points ``P_i + F_i·t`` (normal: the singular
    vector of the smallest singular value, signed toward the nominal normal), then with
    ``"tool"`` the tool ``t`` and the offsets ``d_k`` by linear least squares
    (``n_k·F_i·t − d_k = −n_k·P_i``, normals fixed), alternating until nothing moves. The tool
    needs three planes with independent normals and varied orientations; otherwise it stays.
    Points: the linear pivot calibration ``[F_i, −I][t; c_k] = −P_i`` over every row at once
    (without ``"tool"``: ``c_k`` = the mean tool point of its rows); spheres: an algebraic sphere
    fit per label, then Gauss–Newton on ``‖P_i + F_i t − c_k‖ − r_k``. Then once more without
    rows beyond 5 robust σ.

    Args:
        robot, measurement: nominal robot, the contact model.
        data: a :class:`~jaxcal.Dataset` or ``(q [n, dof] rad, y [n] label indices)``.
        estimate: ``"plane"``/``"point"`` and/or ``"tool"`` (default: the planes / points).
        start: deviations to start from (its robot part gives the flange poses).

    Returns:
        :class:`jaxcal.ExtrasEstimate`.
    """
    from ._initialise import ExtrasEstimate, _trim, residual_rows, tip_frames, tool_guess, trimmed_note, with_tool

    q, y = (data.q, data.y) if hasattr(data, "q") else data
    q = to_device(q)
    dtype = q.dtype
    m = measurement
    kind = m.kind
    start = Deviations.zeros(layout_for(robot, m), dtype) if start is None else start.astype(dtype)
    est = {kind} if estimate is None else set(estimate)
    bad = est - {kind, "tool"}
    if bad:
        raise ValueError(f"cannot initialise {sorted(bad)} for {kind} data; possible: {kind}, tool")
    lab = _labels_of(np.asarray(y), len(m.labels), np)
    T = tip_frames(robot, m, q, start)
    F, P = T[:, :3, :3], T[:, :3, 3]
    t0 = tool_guess(robot, m, start)[1]
    K = len(m.labels)

    def resid(dev):  # the residual program of the calibration's host-side checks
        r = residual_rows(m, robot, dev, q, y)
        return np.linalg.norm(r, axis=1) if r.shape[1] > 1 else r[:, 0]

    before = float(np.sqrt(np.mean(resid(start) ** 2)))
    keep = np.ones(len(lab), bool)
    vals: dict = {}
    for _pass in range(2):
        if kind == "plane":
            t, vals = _plane_start(m, start, F[keep], P[keep], lab[keep], t0, kind in est, "tool" in est,
                                   iterations)
        else:
            t, vals = _point_start(m, start, F[keep], P[keep], lab[keep], t0, kind in est, "tool" in est,
                                   iterations)
        dev = with_tool(start.replace(**vals), robot, m, t)
        r = resid(dev)
        new_keep = _trim(r)
        if _pass or new_keep.all() or np.array_equal(new_keep, keep):
            break
        for k in range(K):  # never drop a whole label
            if not np.any(new_keep & (lab == k)):
                new_keep |= lab == k
        keep = new_keep
    after = float(np.sqrt(np.mean(r**2)))
    n_trim = int((~keep).sum())
    what = "planes" if kind == "plane" else ("spheres" if m.sphere else "points")
    msg = (f"extras from the data: {K} {what} ({', '.join(m.labels)})" + (" and the tool point" if "tool" in est else "")
           + f" in closed form (RMS residual of the robot {before:.2f} → {after:.2f} mm"
           + trimmed_note(n_trim) + ")")
    return ExtrasEstimate(dev, before, after, n_trim, msg)


#: the planes ``(n, d)`` or points ``(c, r)`` of a contact model at some deviations, for the
#: closed-form starts: one compiled program (op by op, a dozen small ones)
_geometry = jit(lambda m, dev: m.planes(dev) if m.kind == "plane" else m.points(dev))


def _plane_start(m: PlaneContact, start, F, P, lab, t0, est_planes, est_tool, iterations):
    n_cur, d_cur = (np.array(a, np.float64) for a in _geometry(m, start))
    t = t0.copy()
    K = len(m.labels)
    for _ in range(iterations):
        p = P + F @ t
        if est_planes:
            for k in range(K):
                rows = lab == k
                if rows.sum() >= 3:
                    n_cur[k], d_cur[k] = _fit_plane(p[rows], n_cur[k])
        if not est_tool:
            break
        # linear LS in (t, d_k [only when planes estimated]) with the normals fixed
        nk = n_cur[lab]  # [n, 3]
        A_t = np.einsum("ni,nij->nj", nk, F)
        rhs = d_cur[lab] - np.einsum("ni,ni->n", nk, P)
        if est_planes:
            A = np.concatenate([A_t, -np.eye(K)[lab]], axis=1)
            rhs = -np.einsum("ni,ni->n", nk, P)
        else:
            A = A_t
        s = np.linalg.svd(A, compute_uv=False)
        if s[-1] < 1e-6 * s[0]:
            break  # the tool is not seen by these planes: keep it
        sol = np.linalg.lstsq(A, rhs, rcond=None)[0]
        t_new = sol[:3]
        if est_planes:
            d_cur = sol[3:]
        moved = np.linalg.norm(t_new - t)
        t = t_new
        if moved < 1e-9:
            break
    vals = {}
    if est_planes:
        n0, d0 = np.asarray(m.normals, np.float64), np.asarray(m.offsets, np.float64)
        eu, ev = np.asarray(m.basis_u, np.float64), np.asarray(m.basis_v, np.float64)
        for k, s in enumerate(m.labels):
            u, v = _turn(n0[k], n_cur[k], eu[k], ev[k])
            vals[f"plane@{s}"] = np.array([u, v, d_cur[k] - d0[k]])
    return t, vals


def _point_start(m: FixedPoint, start, F, P, lab, t0, est_points, est_tool, iterations):
    from ._initialise import _trim

    c_cur, r_cur = (np.array(a, np.float64) for a in _geometry(m, start))
    K = len(m.labels)
    t = t0.copy()
    n = len(lab)
    if not m.sphere:
        if est_points and est_tool:
            A = np.zeros((3 * n, 3 + 3 * K))
            A[:, :3] = F.reshape(3 * n, 3)
            for i, k in enumerate(lab):
                A[3 * i:3 * i + 3, 3 + 3 * k:6 + 3 * k] = -np.eye(3)
            s = np.linalg.svd(A, compute_uv=False)
            if s[-1] > 1e-6 * s[0]:
                sol = np.linalg.lstsq(A, -P.reshape(-1), rcond=None)[0]
                t, c_cur = sol[:3], sol[3:].reshape(K, 3)
            else:
                est_tool = False
        if est_points and not est_tool:
            p = P + F @ t
            for k in range(K):
                if np.any(lab == k):
                    c_cur[k] = p[lab == k].mean(axis=0)
        elif est_tool and not est_points:
            A = F.reshape(3 * n, 3)
            t = np.linalg.lstsq(A, (c_cur[lab] - P).reshape(-1), rcond=None)[0]
    else:
        p = P + F @ t
        if est_points:
            for k in range(K):
                rows = lab == k
                if rows.sum() >= 4:
                    x = p[rows]
                    use = np.ones(len(x), bool)
                    for _ in range(3):  # algebraic fit, then again without rows beyond 5 robust σ
                        A = np.concatenate([2 * x, np.ones((len(x), 1))], axis=1)
                        sol = np.linalg.lstsq(A[use], np.sum(x * x, axis=1)[use], rcond=None)[0]
                        rad = math.sqrt(max(sol[3] + sol[:3] @ sol[:3], 0.0))
                        new_use = _trim(np.linalg.norm(x - sol[:3], axis=1) - rad)
                        if new_use.sum() < 4 or np.array_equal(new_use, use):
                            break
                        use = new_use
                    c_cur[k] = sol[:3]
                    if m.estimate_radius:
                        r_cur[k] = rad
        # Gauss–Newton on everything asked for
        for _ in range(iterations):
            p = P + F @ t
            diff = p - c_cur[lab]
            dist = np.linalg.norm(diff, axis=1)
            u = diff / np.where(dist > 0, dist, 1.0)[:, None]
            r = dist - r_cur[lab]
            cols = []
            if est_tool:
                cols.append(np.einsum("ni,nij->nj", u, F))
            if est_points:
                Jc = np.zeros((n, 3 * K))
                for k in range(K):
                    Jc[lab == k, 3 * k:3 * k + 3] = -u[lab == k]
                cols.append(Jc)
                if m.estimate_radius:
                    cols.append(-np.eye(K)[lab])
            if not cols:
                break
            J = np.concatenate(cols, axis=1)
            use = _trim(r)  # Gauss–Newton without the rows beyond 5 robust σ (a wrong label is ~100 mm off)
            step = np.linalg.lstsq(J[use], -r[use], rcond=None)[0]
            i = 0
            if est_tool:
                t = t + step[:3]
                i = 3
            if est_points:
                c_cur = c_cur + step[i:i + 3 * K].reshape(K, 3)
                i += 3 * K
                if m.estimate_radius:
                    r_cur = r_cur + step[i:i + K]
            if np.linalg.norm(step) < 1e-10:
                break
    vals = {}
    if est_points:
        c0, r0 = np.asarray(m.centres, np.float64), np.asarray(m.radii, np.float64)
        for k, s in enumerate(m.labels):
            vals[f"point@{s}"] = c_cur[k] - c0[k]
            if m.estimate_radius:
                vals[f"radius@{s}"] = np.asarray(r_cur[k] - r0[k])
    return t, vals


# -- what the planes cannot see --------------------------------------------------------------------
def unobservable_directions(normals, *, tol_deg: float = 1.0) -> list[str]:
    """The rigid motions of the robot relative to planes with these unit normals (``[K, 3]``, base
    frame) that change no signed distance, in words; ``[]`` when the planes see them all.

    One normal direction (one plane, or parallel planes): translations along the plane (2) and
    the rotation about the normal; two: the translation along their intersection line; three
    independent: none. Normals within ``tol_deg`` of each other count as parallel."""
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    s = np.linalg.svd(n, compute_uv=False) if len(n) else np.zeros(0)
    tol = math.sin(math.radians(tol_deg))
    rank = int(np.sum(s > tol * max(s[0], 1e-300))) if len(s) else 0
    if rank >= 3:
        return []
    if rank == 2:
        line = np.cross(*[v for v in np.linalg.svd(n)[2][:2]])
        return [f"translation along the planes' intersection line (direction {np.round(line, 3).tolist()})"]
    if rank == 1:
        v = np.linalg.svd(n)[2]
        return [f"translation along the plane (directions {np.round(v[1], 3).tolist()} and "
                f"{np.round(v[2], 3).tolist()})", f"rotation about the plane normal {np.round(v[0], 3).tolist()}"]
    return ["every rigid motion (no planes)"]


# -- result files (called by jaxcal._calibration._io) ------------------------------------------------------------
def contact_to_dict(m) -> dict:
    """``{"kind": "plane", "labels": [...], "normals": [[...]], "offsets_mm": [...]}`` or
    ``{"kind": "point", "labels": [...], "centres_mm": [[...]], "radii_mm": [...] | None,
    "estimate_radius": bool}``."""
    if isinstance(m, DistanceBar):
        return {"kind": "distance", "dof": m.dof} | tip_to_dict(m)
    if isinstance(m, PlaneContact):
        return {"kind": "plane", "labels": list(m.labels), "normals": np.asarray(m.normals, np.float64).tolist(),
                "offsets_mm": np.asarray(m.offsets, np.float64).tolist()} | tip_to_dict(m)
    return {"kind": "point", "labels": list(m.labels), "centres_mm": np.asarray(m.centres, np.float64).tolist(),
            "radii_mm": np.asarray(m.radii, np.float64).tolist() if m.sphere else None,
            "estimate_radius": bool(m.estimate_radius)} | tip_to_dict(m)


def contact_from_dict(d: dict):
    """Inverse of :func:`contact_to_dict` (``"tip"``: the tip the probe is on, absent for the
    robot's default tip)."""
    tip = d.get("tip")
    if d["kind"] == "distance":
        return DistanceBar(int(d["dof"]), tip=tip)
    if d["kind"] == "plane":
        return PlaneContact(d["labels"], d["normals"], d["offsets_mm"], tip=tip)
    return FixedPoint(d["labels"], d["centres_mm"], d.get("radii_mm"), bool(d.get("estimate_radius", False)), tip=tip)


# -- distance bar / ballbar ------------------------------------------------------------------------
class DistanceBar(MeasurementModel):
    """Two poses per row whose tool points are a known distance apart (a calibrated bar with two
    nests, a double ball bar): kind ``"distance"``.

    ``q`` ``[n, dof]`` is pose *a*; the reading ``y`` ``[n, dof + 1]`` is pose *b* (rad) and the
    bar length ``L`` (mm). Residual ``[n, 1]`` (mm): ``‖p(q_a) − p(q_b)‖ − L``, ``p`` the tool
    point (nominal tool + the ``tool`` extra). The model adds no extra groups (a bar length that
    is not known exactly would be one more: ``L`` is taken as calibrated here).

    Distance data can never see the robot's base frame: a rigid motion of the whole robot
    (3 translations, 3 rotations) changes no distance, so ``d_1``, ``theta_1`` and every other
    base-frame direction are unidentifiable (the report lists them) and the calibrated robot is
    only defined up to where its base is; its *length scale*, unlike plane or point contact, is
    seen (``L`` is a length reference). ``predict`` pairs each row with the next one (the last
    with the first) and returns ``[q_next, ‖p(q) − p(q_next)‖]``: readings of a bar between
    consecutive poses, for code that asks a model for readings at poses.

    Attributes:
        dof: joints of the robot (static; sets the reading's shape).
        tip: the tip of a :class:`~jaxcal.KinematicTree` that carries the bar's ball (static;
            ``None``: the robot's default tip); another tip's tool point is the ``tool@<tip>``
            group.
    """

    dof: int = eqx.field(static=True)
    tip: str | None = eqx.field(static=True, default=None)
    kind: ClassVar[str] = "distance"
    size: ClassVar[int] = 1

    def __init__(self, dof: int, tip: str | None = None):
        self.dof = int(dof)
        self.tip = tip

    def extra_groups(self) -> tuple[Group, ...]:
        """``tool@<tip>`` for a tip other than the default one, else none."""
        return tip_groups(self.tip)

    @property
    def sample_shape(self) -> tuple[int, ...]:  # type: ignore[override]
        return (self.dof + 1,)

    @property
    def jacobian_free_of_data(self) -> bool:
        return True  # pose b lives in the readings: use the measured ones where they are given

    def _ends(self, robot, deviations, q, qb):
        # two kinematics passes, not one on the stacked rows: the pass at ``q`` (the problem's own
        # joint angles) takes the shared cos/sin of the solve (:func:`shared_joint_trig`), and the
        # pass at ``qb`` gets its own block, so that ``jacfwd`` does not recompute cos/sin of the
        # readings per Jacobian column (3.2-3.6x the position model's Jacobian time when stacked)
        from .._models._kinematics import shared_joint_trig

        q = check_joint_angles(robot, q)
        qb = qb.astype(q.dtype)
        tip = self.tip_for(robot)
        pa = tool_point_soa(robot, deviations, q, tip=tip)
        with shared_joint_trig(qb):
            pb = tool_point_soa(robot, deviations, qb, tip=tip)
        return pa, pb

    def predict(self, robot, deviations, q) -> Float[Array, "n dof1"]:
        """``[n, dof + 1]``: the next row's joint angles and the distance to its tool point (mm)."""
        q = check_joint_angles(robot, q)
        qb = jnp.roll(q, -1, axis=0)
        pa, pb = self._ends(robot, deviations, q, qb)
        d = jnp.sqrt(sum((pa[k] - pb[k]) ** 2 for k in range(3)))
        return jnp.concatenate([qb, d[:, None]], axis=1)

    def residual(self, robot, deviations, q, y) -> Float[Array, "n 1"]:
        """``‖p(q_a) − p(q_b)‖ − L`` ``[n, 1]`` (mm)."""
        y = jnp.asarray(y)
        pa, pb = self._ends(robot, deviations, q, y[:, : self.dof])
        return (jnp.sqrt(sum((pa[k] - pb[k]) ** 2 for k in range(3))) - y[:, self.dof].astype(pa[0].dtype))[:, None]


# -- the data-file form of contact data ------------------------------------------------------------
#: the contact kinds and the CSV label column of each
CONTACT_KINDS = {"plane": "plane", "point": "point"}


def label_metadata_key(kind: str) -> str:
    """The Dataset metadata key holding the comma-separated label names (``plane_labels``)."""
    return f"{CONTACT_KINDS[kind]}_labels"


def dataset_labels(data) -> tuple[str, ...]:
    """The label names of a contact :class:`~jaxcal.Dataset` (``plane_labels``/``point_labels``)."""
    key = label_metadata_key(data.kind)
    names = data.meta.get(key, "")
    labels = tuple(s for s in names.split(",") if s)
    if not labels:
        raise ValueError(f"{data.kind} data carry no '{key}' metadata naming the labels")
    return labels


def contact_label_cells(data) -> list[str]:
    """The label text of every row of a contact :class:`~jaxcal.Dataset` (for its CSV column)."""
    labels = dataset_labels(data)
    return [labels[int(i)] for i in np.round(np.asarray(data.y, np.float64)).astype(int)]


def contact_labels_from_cells(path, table, header, kind: str, meta: dict):
    """``(y [n] label indices, metadata with the label names)`` from a CSV file's ``plane`` /
    ``point`` text column. Labels are numbered in the order of the file's ``# plane_labels:``
    line when there is one (labels missing from it are appended), else in order of appearance."""
    col = CONTACT_KINDS[kind]
    key = label_metadata_key(kind)
    j = header.index(col)
    cells = [row[j].strip() for row in table.rows]
    empty = [r for r, v in enumerate(cells) if not v]
    if empty:
        raise ValueError(f"{path}: {table.where(empty[0], col)}: empty label ({len(empty)} row(s) without a {col})")
    for r, v in enumerate(cells):
        try:
            check_label(v)
        except ValueError as e:
            raise ValueError(f"{path}: {table.where(r, col)}: {e}") from None
    known = [s for s in meta.get(key, "").split(",") if s]
    names = list(dict.fromkeys(known + cells))
    meta = dict(meta)
    meta[key] = ",".join(names)
    return np.asarray([names.index(v) for v in cells], np.float64), meta


class _ContactKind(SensorKind):
    """The contact kinds' plain-data form (:func:`contact_to_dict`, :func:`contact_from_dict`)."""

    def model_to_dict(self, model):
        return contact_to_dict(model)

    def model_from_dict(self, d):
        return contact_from_dict(d)


class _LabelledContactKind(_ContactKind):
    """Contact data whose rows name what the probe touched: a text column (``plane`` / ``point``)
    and no value column; readings ``[n]`` label indices, the names in the ``<column>_labels``
    metadata (:func:`dataset_labels`)."""

    labelled = True
    planner = "jaxcal._experiments._plan:contact_candidates"

    def found_in(self, header) -> bool:
        return CONTACT_KINDS[self.name] in header

    def column_hint(self) -> str:
        return f"a text column {CONTACT_KINDS[self.name]!r}"

    def label_columns(self, path, header):
        col = CONTACT_KINDS[self.name]
        if col not in header:
            raise ValueError(f"{path}: {self.name} data need a text column {col!r} naming each row's "
                             f"{col}; header: {list(header)}")
        return [col]

    def readings(self, values, path, table, meta):
        y, meta = contact_labels_from_cells(path, table, table.header, self.name, meta)
        return y, meta, ()

    def write_values(self, data):
        n = int(np.shape(data.y)[0])
        return [], np.zeros((n, 0)), [CONTACT_KINDS[self.name]], [[c] for c in contact_label_cells(data)]

    def sample_shape(self, dof):
        return ()

    def check_options(self, estimate, options):
        if "base" in estimate:
            raise ValueError(f"--estimate base does not apply to {self.name} data: the {self.name}s are "
                             "in the robot base frame and carry any base-frame error")
        super().check_options(estimate, options)

    def required_extras(self, estimate, *, sphere=False, estimate_radius=False, radius_mm=None, **_):
        estimate, notes = set(estimate), []
        if sphere:
            notes.append("point data as spheres: residual = distance to the centre minus the radius, "
                         + ("radius unknown: estimated per point (sphere fit to the data, then the joint fit)"
                            if estimate_radius else "radius " + ("known" if radius_mm is None else f"{radius_mm:g} mm (known)")))
        if "tool" not in estimate:
            estimate.add("tool")
            notes.append(f"{self.name} data: the {self.name}s and the tool point are estimated "
                         "(closed-form start from the data, then the joint fit); "
                         + length_reference_note(self.name, known_radius=sphere and not estimate_radius))
        return estimate, notes

    def default_model(self, robot, *, data=None, anchor_mm=None, n_markers=None):
        self.refuse_anchor(anchor_mm)
        return contact_model(self.name, robot, data)

    def plan_lines(self, model):
        lines = {f"{self.name}_labels": ",".join(model.labels)}
        if getattr(model, "sphere", False):
            lines["radius_mm"] = f"{float(np.asarray(model.radii)[0]):g}"
        return lines


@register_kind
class PlaneKind(_LabelledContactKind):
    """Plane-contact data (:class:`PlaneContact`): a text column ``plane`` naming the touched plane."""

    name = "plane"
    simulator = "jaxcal._simulation._simulate_files:plane_file"
    plan_next = ("touch the plane each row names and record the joint angles there (the planned ones are the nominal "
                 "robot's)")


@register_kind
class PointKind(_LabelledContactKind):
    """Fixed-point (or sphere) contact data (:class:`FixedPoint`): a text column ``point``; spheres
    with a radius given (``--radius-mm``, the file's ``# radius_mm:`` line) or estimated."""

    name = "point"
    simulator = "jaxcal._simulation._simulate_files:point_file"
    plan_next = ("put the tool tip on the point each row names (or the ball on the sphere) and record the joint angles "
                 "there")

    def check_options(self, estimate, options):
        if "base" in estimate:
            raise ValueError("--estimate base does not apply to point data: the points are "
                             "in the robot base frame and carry any base-frame error")
        self.check_estimate_names(estimate)
        self.refuse_anchor(options.anchor_mm)

    def setup(self, data, robot, estimate, options):
        from .._core._csvfile import number_list

        self.check_options(estimate, options)
        sphere = options.radius_mm is not None or options.estimate_radius or "radius_mm" in data.meta
        radius = options.radius_mm
        if sphere and radius is None and "radius_mm" in data.meta:
            radius = number_list(data.meta["radius_mm"], 1, "the file's radius_mm")[0]
        estimate, notes = self.required_extras(estimate, sphere=sphere, estimate_radius=options.estimate_radius,
                                               radius_mm=radius)
        model = self.default_model(robot, data=data)
        return (self.spheres(model, radius, options.estimate_radius) if sphere else model), estimate, notes

    def spheres(self, model, radius_mm, estimate_radius):
        """The point model as spheres of radius ``radius_mm`` (mm; the start where ``estimate_radius``).

        Raises:
            ValueError: the radius is negative or not finite.
        """
        r = 0.0 if radius_mm is None else float(radius_mm)
        if not (math.isfinite(r) and r >= 0):
            raise ValueError(f"--radius-mm must be a finite number >= 0 (mm), got {radius_mm}")
        return FixedPoint(model.labels, model.centres, radii_mm=r, estimate_radius=estimate_radius, tip=model.tip)


def distance_columns(dof: int, unit: str = "deg") -> list[str]:
    """``q1a_<unit> … qNa_<unit>, q1b_<unit> … qNb_<unit>, distance_mm``."""
    return ([f"q{j}a_{unit}" for j in range(1, dof + 1)] + [f"q{j}b_{unit}" for j in range(1, dof + 1)]
            + ["distance_mm"])


def save_distance_csv(data, path, angle_unit: str = "deg") -> None:
    """Write distance-bar data: ``# key: value`` lines, then :func:`distance_columns`."""
    q = np.asarray(data.q, np.float64)
    y = np.asarray(data.y, np.float64)
    dof = q.shape[1]
    conv = rad_to_deg_roundtrip if angle_unit == "deg" else (lambda a: a)
    buf = io.StringIO()
    buf.write("# jaxcal dataset v1\n# kind: distance\n")
    for k, v in data.metadata:
        if k != "kind":
            buf.write(f"# {k}: {v}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(distance_columns(dof, angle_unit))
    for row in np.concatenate([conv(q), conv(y[:, :dof]), y[:, dof:]], axis=1):
        w.writerow([repr(float(x)) for x in row])
    with open(os.fspath(path), "w", encoding="utf-8") as f:
        f.write(buf.getvalue())


def load_distance_table(path, t, meta: dict, dof: int | None):
    """``(q_a [n, dof] rad, y [n, dof + 1])`` from a read table with :func:`distance_columns`."""
    cols = {h: re.fullmatch(r"q(\d+)([ab])_(deg|rad)", h) for h in t.header}
    cols = {h: mt for h, mt in cols.items() if mt}
    units = {mt[3] for mt in cols.values()}
    if len(units) != 1:
        raise ValueError(f"{path}: distance data need q1a_deg … qNa_deg and q1b_deg … qNb_deg (one angle unit); "
                         f"header: {list(t.header)}")
    unit = units.pop()
    n_dof = max(int(mt[1]) for mt in cols.values())
    if dof is not None and n_dof != dof:
        raise ValueError(f"{path}: file has {n_dof} joints per pose but the robot has {dof} joints")
    want = distance_columns(n_dof, unit)
    missing = [c for c in want if c not in t.header]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing} for distance data; header: {list(t.header)}")
    unused = [h for h in t.header if h not in want]
    if unused:
        warnings.warn(f"{path}: column(s) {unused} are not used; distance data uses {','.join(want)}", UserWarning,
                      stacklevel=3)
    if not t.rows:
        raise ValueError(f"{path}: no data rows")
    v = t.floats(want)
    ang = np.deg2rad(v[:, : 2 * n_dof]) if unit == "deg" else v[:, : 2 * n_dof]
    return ang[:, :n_dof], np.concatenate([ang[:, n_dof:], v[:, 2 * n_dof:]], axis=1)


@register_kind
class DistanceKind(_ContactKind):
    """Distance-bar data (:class:`DistanceBar`): two poses per row, ``q1a_deg … qNa_deg, q1b_deg …
    qNb_deg, distance_mm`` (:func:`distance_columns`); readings ``[n, dof + 1]`` (pose b in rad,
    the bar length in mm), ``q`` is pose a. The file has its own joint columns, so the kind reads
    and writes the whole table (:attr:`own_table`)."""

    name = "distance"
    columns = ("distance_mm",)
    own_table = True
    simulator = "jaxcal._simulation._simulate_files:distance_file"
    planner = "jaxcal._experiments._plan:distance_candidates"
    plan_next = ("place the bar between each row's two poses (bar length: distance_mm) and record both poses' joint "
                 "angles")

    def check_options(self, estimate, options):
        if "base" in estimate:
            raise ValueError("--estimate base does not apply to distance data: distances never see the base frame")
        super().check_options(estimate, options)

    def required_extras(self, estimate, **_):
        estimate = set(estimate)
        if "tool" in estimate:
            return estimate, []
        return estimate | {"tool"}, [
            "distance data: the tool point is estimated (from its nominal value); distances never see the robot's "
            "base frame (d_1, theta_1 and the base's position and orientation stay at nominal or are set by the prior)"]

    def default_model(self, robot, *, data=None, anchor_mm=None, n_markers=None):
        self.refuse_anchor(anchor_mm)
        return DistanceBar(robot.dof)

    def read_table(self, path, table, meta: dict, dof: int | None):
        return load_distance_table(path, table, meta, dof)

    def write_file(self, data, path, angle_unit: str) -> None:
        save_distance_csv(data, path, angle_unit)

    def sample_shape(self, dof):
        return (dof + 1,)

    def checked_readings(self, y, n, dof):
        if y.ndim != 2 or y.shape != (n, dof + 1):
            raise ValueError(f"distance readings must have shape [{n}, {dof + 1}] (pose b, length), "
                             f"got {list(y.shape)}")
        return y

