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
(``tests/test_contact.py::test_contact_data_cannot_see_the_length_scale``). The report shows it
as one more rank deficiency (a length parameter such as ``d_2`` or ``a_2`` left out, or
depending on the others). Something must fix it: the prior toward the nominal DH lengths
(``jaxcal calibrate``'s default ``--prior``), a length held at nominal (``--fix``), a known
sphere radius (``--radius-mm``: a length reference), or distance-bar rows (:class:`DistanceBar`,
whose ``L`` is a calibrated length). With one or two planes, or points only, the base-frame
directions above are also unseen; the prior then keeps them at the nominal values.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._kinematics import check_joint_angles, fk_pose_jit, rotvec_to_matrix, tool_point_soa
from ._measurement import MeasurementModel
from ._params import Deviations, Group, layout_for
from ._precision import to_device

__all__ = ["PlaneContact", "FixedPoint", "plane_group", "point_groups", "initial_contact", "simulate_contact",
           "unobservable_directions", "contact_model", "default_setup", "dataset_labels", "CONTACT_KINDS",
           "label_metadata_key", "relabel", "DistanceBar", "simulate_distance"]

#: measurement kinds of this module and the CSV label column of each
CONTACT_KINDS = {"plane": "plane", "point": "point"}


def label_metadata_key(kind: str) -> str:
    """The Dataset metadata key holding the comma-separated label names (``plane_labels``)."""
    return f"{CONTACT_KINDS[kind]}_labels"


def _check_label(label) -> str:
    s = str(label).strip()
    if not s or any(c in s for c in "@,\n\r") or s != str(label):
        raise ValueError(f"label {label!r} must be a non-empty string without '@', ',', line breaks or "
                         "surrounding spaces")
    return s


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


def _labels_of(y, n_labels: int):
    return jnp.clip(jnp.round(y).astype(jnp.int32), 0, n_labels - 1).reshape(-1)



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

    def check_measurements(self, y, n: int) -> None:
        super().check_measurements(y, n)
        y = np.asarray(y)
        if y.size and (np.any(y != np.round(y)) or y.min() < 0 or y.max() >= len(self.labels)):
            raise ValueError(f"{self.kind} readings must be label indices 0..{len(self.labels) - 1}")


class PlaneContact(_LabelModel):
    """A probe on the tool touching one of ``K`` planes; reading: the plane's index ``[n]``.

    Residual ``[n, 1]`` (mm): ``r_i = n_k·p(q_i) − d_k`` with ``k`` = the row's plane, ``p`` the
    tool point in the base frame (nominal tool + the ``tool`` extra), ``n_k`` the unit normal
    ``exp([u_k·e_u + v_k·e_v]×)·n0_k`` and ``d_k = d0_k + plane_d@k`` (see the module docstring).
    ``sample_error`` is the signed distance (mm).

    Attributes:
        normals: ``[K, 3]`` nominal unit normals (base frame); default ``(0, 0, 1)`` each (the
            closed-form start finds the real ones: a normal can turn by up to 180°).
        offsets: ``[K]`` nominal offsets ``d0`` (mm).
        basis_u, basis_v: ``[K, 3]`` the fixed tangent bases.
        labels: the plane labels (static, index order).
    """

    normals: Float[Array, "K 3"]
    offsets: Float[Array, " K"]
    basis_u: Float[Array, "K 3"]
    basis_v: Float[Array, "K 3"]
    labels: tuple[str, ...] = eqx.field(static=True)
    kind: ClassVar[str] = "plane"
    size: ClassVar[int] = 1

    def __init__(self, labels: Sequence[str], normals=None, offsets_mm=None):
        labels = tuple(_check_label(s) for s in labels)
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
        """``plane@K`` per label."""
        return tuple(plane_group(s) for s in self.labels)

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
        p = tool_point_soa(robot, deviations, q)
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
        p = tool_point_soa(robot, deviations, q)
        n, d = self.planes(deviations, q.dtype)
        nk, dk = n[k], d[k]
        return (nk[:, 0] * p[0] + nk[:, 1] * p[1] + nk[:, 2] * p[2] - dk)[:, None]


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
    """

    centres: Float[Array, "K 3"]
    radii: Float[Array, " K"]
    labels: tuple[str, ...] = eqx.field(static=True)
    sphere: bool = eqx.field(static=True, default=False)
    estimate_radius: bool = eqx.field(static=True, default=False)
    kind: ClassVar[str] = "point"

    def __init__(self, labels: Sequence[str], centres_mm=None, radii_mm=None, estimate_radius: bool = False):
        labels = tuple(_check_label(s) for s in labels)
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
        """``point@K`` (and ``radius@K``) per label."""
        return tuple(g for s in self.labels for g in point_groups(s, self.estimate_radius))

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
        p = jnp.stack(tool_point_soa(robot, deviations, q), -1)
        c, r = self.points(deviations, q.dtype)
        dist = jnp.abs(jnp.linalg.norm(p[:, None] - c[None], axis=-1) - r)
        return jnp.argmin(jax.lax.stop_gradient(dist), axis=1).astype(q.dtype)

    def residual(self, robot, deviations, q, y):
        """``p − c_k`` ``[n, 3]`` (points) or ``‖p − c_k‖ − r_k`` ``[n, 1]`` (spheres), mm."""
        q = check_joint_angles(robot, q)
        k = _labels_of(y, len(self.labels))
        p = tool_point_soa(robot, deviations, q)
        c, r = self.points(deviations, q.dtype)
        ck = c[k]
        diff = [p[j] - ck[:, j] for j in range(3)]
        if not self.sphere:
            return jnp.stack(diff, -1)
        return (jnp.sqrt(diff[0] ** 2 + diff[1] ** 2 + diff[2] ** 2) - r[k])[:, None]


# -- data ---------------------------------------------------------------------------------------
def dataset_labels(data) -> tuple[str, ...]:
    """The label names of a contact :class:`~jaxcal.Dataset` (``plane_labels``/``point_labels``)."""
    key = label_metadata_key(data.kind)
    names = data.meta.get(key, "")
    labels = tuple(s for s in names.split(",") if s)
    if not labels:
        raise ValueError(f"{data.kind} data carry no '{key}' metadata naming the labels")
    return labels


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
    from ._simulate import sample_joint_angles

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
    from ._initialise import ExtrasEstimate, _trim

    q, y = (data.q, data.y) if hasattr(data, "q") else data
    q = jnp.asarray(q)
    dtype = q.dtype
    m = measurement
    kind = m.kind
    start = Deviations.zeros(layout_for(robot, m), dtype) if start is None else start.astype(dtype)
    est = {kind} if estimate is None else set(estimate)
    bad = est - {kind, "tool"}
    if bad:
        raise ValueError(f"cannot initialise {sorted(bad)} for {kind} data; possible: {kind}, tool")
    lab = np.asarray(_labels_of(jnp.asarray(y), len(m.labels)))
    T = np.asarray(fk_pose_jit(robot, q, start), np.float64)
    F, P = T[:, :3, :3], T[:, :3, 3]
    t0 = np.asarray(robot.tool, np.float64) + np.asarray(start.tool, np.float64)
    K = len(m.labels)

    def resid(dev):
        r = np.asarray(m.residual(robot, dev, q, jnp.asarray(y, dtype)), np.float64)
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
        dev = start.replace(tool=t - np.asarray(robot.tool, np.float64), **vals)
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
           + (f", {n_trim} row(s) left out as gross outliers)" if n_trim else ")"))
    return ExtrasEstimate(dev, before, after, n_trim, msg)


def _plane_start(m: PlaneContact, start, F, P, lab, t0, est_planes, est_tool, iterations):
    n_cur, d_cur = (np.array(a, np.float64) for a in m.planes(start))
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

    c_cur, r_cur = (np.array(a, np.float64) for a in m.points(start))
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


# -- simulation ------------------------------------------------------------------------------------
def _row_constraint(robot, dev, m, qi, k):
    """The constraint of one row, ``[m]``: signed distance / ``p − c`` / sphere distance."""
    p = jnp.stack(tool_point_soa(robot, dev, qi[None]), -1)[0]
    if m.kind == "plane":
        n, d = m.planes(dev, qi.dtype)
        return jnp.atleast_1d(n[k] @ p - d[k])
    c, r = m.points(dev, qi.dtype)
    if not m.sphere:
        return p - c[k]
    return jnp.atleast_1d(jnp.linalg.norm(p - c[k]) - r[k])


@eqx.filter_jit
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
    wanted row are moved (raise it where many fail).

    Returns:
        :class:`jaxcal.Experiment` with ``train`` / ``test`` datasets (``y``: label indices;
        metadata ``plane_labels`` / ``point_labels``).
    """
    from ._dataset import Dataset, mm_joints_metadata
    from ._simulate import DEFAULT_ANGLE_STD_DEG, DEFAULT_LENGTH_STD_MM, Experiment, draw_deviations

    m = default_setup("plane", robot) if measurement is None else measurement
    dtype = jnp.result_type(float)
    k_dev, k_q, k_noise, k_split = jax.random.split(key, 4)
    layout = layout_for(robot, m)
    if true_deviations is None:
        dh = draw_deviations(k_dev, robot, angle_std_deg=DEFAULT_ANGLE_STD_DEG if angle_std_deg is None else angle_std_deg,
                             length_std_mm=DEFAULT_LENGTH_STD_MM if length_std_mm is None else length_std_mm,
                             tool_std_mm=tool_std_mm, dtype=dtype)
        true_deviations = Deviations({g: v for g, v in dh.values.items() if g in layout.group_names}, layout, dtype)
    true_deviations = true_deviations.astype(dtype)
    K = len(m.labels)
    n_cand = n_samples * oversample
    cand = _sample_q(k_q, robot, n_cand * K)
    lab_all = jnp.arange(n_cand * K) % K
    g0 = jax.vmap(lambda qi, ki: _row_constraint(robot, true_deviations, m, qi, ki))(cand, lab_all)
    score = np.asarray(jnp.linalg.norm(g0, axis=1), np.float64)
    lab_np = np.asarray(lab_all)
    picks = []
    for k in range(K):  # per label the candidates nearest to it
        rows = np.flatnonzero(lab_np == k)
        picks.append(rows[np.argsort(score[rows])][: tries * (n_samples // K + 1)])
    order = np.stack(picks, 1).reshape(-1)  # labels in turn
    q = cand[order]
    k = lab_all[order]
    msize = m.size
    target = noise_std * jax.random.normal(k_noise, (q.shape[0], msize), dtype)
    for _ in range(iterations):
        q_new, err = _newton_step(robot, true_deviations, m, q, k, target)
        if float(jnp.max(err)) < 1e-9:
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
    perm = np.asarray(jax.random.permutation(k_split, n_samples))
    return Experiment(robot, m, true_deviations, data.subset(perm[n_test:]), data.subset(perm[:n_test]),
                      jnp.asarray(noise_std, dtype))


# -- CSV (called by jaxcal._dataset) -----------------------------------------------------------------
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
            _check_label(v)
        except ValueError as e:
            raise ValueError(f"{path}: {table.where(r, col)}: {e}") from None
    known = [s for s in meta.get(key, "").split(",") if s]
    names = list(dict.fromkeys(known + cells))
    meta = dict(meta)
    meta[key] = ",".join(names)
    return np.asarray([names.index(v) for v in cells], np.float64), meta


# -- result files (called by jaxcal._io) ------------------------------------------------------------
def contact_to_dict(m) -> dict:
    """``{"kind": "plane", "labels": [...], "normals": [[...]], "offsets_mm": [...]}`` or
    ``{"kind": "point", "labels": [...], "centres_mm": [[...]], "radii_mm": [...] | None,
    "estimate_radius": bool}``."""
    if isinstance(m, DistanceBar):
        return {"kind": "distance", "dof": m.dof}
    if isinstance(m, PlaneContact):
        return {"kind": "plane", "labels": list(m.labels), "normals": np.asarray(m.normals, np.float64).tolist(),
                "offsets_mm": np.asarray(m.offsets, np.float64).tolist()}
    return {"kind": "point", "labels": list(m.labels), "centres_mm": np.asarray(m.centres, np.float64).tolist(),
            "radii_mm": np.asarray(m.radii, np.float64).tolist() if m.sphere else None,
            "estimate_radius": bool(m.estimate_radius)}


def contact_from_dict(d: dict):
    """Inverse of :func:`contact_to_dict`."""
    if d["kind"] == "distance":
        return DistanceBar(int(d["dof"]))
    if d["kind"] == "plane":
        return PlaneContact(d["labels"], d["normals"], d["offsets_mm"])
    return FixedPoint(d["labels"], d["centres_mm"], d.get("radii_mm"), bool(d.get("estimate_radius", False)))


def relabel(data, labels: Sequence[str]):
    """``data`` (a contact :class:`~jaxcal.Dataset`) with its label indices renumbered to
    ``labels`` (a model's label order), e.g. a test file whose rows name the planes in another
    order. Labels ``data`` has but ``labels`` lacks raise."""
    from ._dataset import Dataset

    own = dataset_labels(data)
    labels = tuple(labels)
    missing = [s for s in own if s not in labels]
    if missing:
        raise ValueError(f"{data.kind} labels {missing} are not in the model (labels: {list(labels)})")
    if own == labels[: len(own)] and len(own) == len(labels):
        return data
    idx = np.asarray([labels.index(s) for s in own], np.float64)
    y = idx[np.round(np.asarray(data.y, np.float64)).astype(int)]
    meta = dict(data.metadata)
    meta[label_metadata_key(data.kind)] = ",".join(labels)
    return Dataset(data.q, jnp.asarray(y, data.q.dtype), data.kind, meta)


def save_simulated_contact(args, robot, measurement) -> None:
    """``jaxcal simulate --measurement plane|point``: :func:`simulate_contact` → ``args.out``."""
    from ._dataset import Dataset, mm_joints_metadata

    meta = {"source": "jaxcal simulate", "robot": robot.name, "seed": args.seed, "noise_std_mm": args.noise_std,
            **mm_joints_metadata(robot)}
    if measurement.kind == "distance":
        ex = simulate_distance(jax.random.key(args.seed), robot, n_samples=args.samples, noise_std=args.noise_std,
                               test_fraction=0.0)
        what = "bar lengths 150 and 300 mm"
    else:
        ex = simulate_contact(jax.random.key(args.seed), robot, measurement, n_samples=args.samples,
                              noise_std=args.noise_std, test_fraction=0.0)
        meta[label_metadata_key(measurement.kind)] = ",".join(measurement.labels)
        what = f"{len(measurement.labels)} {measurement.kind}s: {', '.join(measurement.labels)}"
        if getattr(measurement, "sphere", False):
            r = np.asarray(measurement.radii, np.float64)
            meta["radius_mm"] = ",".join(f"{v:g}" for v in r) if np.ptp(r) > 0 else f"{r[0]:g}"
            what = f"{len(measurement.labels)} spheres of radius {meta['radius_mm']} mm: {', '.join(measurement.labels)}"
    Dataset(ex.train.q, ex.train.y, measurement.kind, meta).to_csv(args.out)
    print(f"wrote {args.samples} {measurement.kind} samples of robot {robot.name} (σ = {args.noise_std} mm, "
          f"seed {args.seed}, {what}) to {args.out}")


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
    """

    dof: int = eqx.field(static=True)
    kind: ClassVar[str] = "distance"
    size: ClassVar[int] = 1

    def __init__(self, dof: int):
        self.dof = int(dof)

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
        from ._kinematics import shared_joint_trig

        q = check_joint_angles(robot, q)
        qb = qb.astype(q.dtype)
        pa = tool_point_soa(robot, deviations, q)
        with shared_joint_trig(qb):
            pb = tool_point_soa(robot, deviations, qb)
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


def _pair_constraint(robot, dev, qa, qb):
    pa = jnp.stack(tool_point_soa(robot, dev, qa[None]), -1)[0]
    pb = jnp.stack(tool_point_soa(robot, dev, qb[None]), -1)[0]
    return jnp.atleast_1d(jnp.linalg.norm(pa - pb))


@eqx.filter_jit
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
    from ._dataset import Dataset, mm_joints_metadata
    from ._simulate import DEFAULT_ANGLE_STD_DEG, DEFAULT_LENGTH_STD_MM, Experiment, draw_deviations

    m = DistanceBar(robot.dof)
    dtype = jnp.result_type(float)
    k_dev, k_a, k_b, k_noise, k_split = jax.random.split(key, 5)
    layout = layout_for(robot, m)
    if true_deviations is None:
        dh = draw_deviations(k_dev, robot, angle_std_deg=DEFAULT_ANGLE_STD_DEG if angle_std_deg is None else angle_std_deg,
                             length_std_mm=DEFAULT_LENGTH_STD_MM if length_std_mm is None else length_std_mm,
                             tool_std_mm=tool_std_mm, dtype=dtype)
        true_deviations = Deviations({g: v for g, v in dh.values.items() if g in layout.group_names}, layout, dtype)
    true_deviations = true_deviations.astype(dtype)
    n_try = tries * n_samples
    qa = _sample_q(k_a, robot, n_try)
    pool = _sample_q(k_b, robot, min(8 * n_try, 8192))
    pa = np.asarray(jnp.stack(tool_point_soa(robot, true_deviations, qa), -1))
    pp = np.asarray(jnp.stack(tool_point_soa(robot, true_deviations, pool), -1))
    L = np.resize(np.asarray(lengths_mm, np.float64), n_try)
    best = np.empty(n_try, int)
    for i in range(0, n_try, 256):  # the pool pose nearest to a bar length away, in blocks (memory)
        dist = np.sqrt(((pa[i:i + 256, None, :] - pp[None, :, :]) ** 2).sum(-1))
        best[i:i + 256] = np.argmin(np.abs(dist - L[i:i + 256, None]), axis=1)
    qb = pool[best]
    eps = noise_std * np.asarray(jax.random.normal(k_noise, (n_try,), dtype))
    target = jnp.asarray(L + eps, dtype)[:, None]
    for _ in range(iterations):
        qb_new, err = _pair_step(robot, true_deviations, qa, qb, target)
        if float(jnp.max(err)) < 1e-9:
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
    perm = np.asarray(jax.random.permutation(k_split, n_samples))
    return Experiment(robot, m, true_deviations, data.subset(perm[n_test:]), data.subset(perm[:n_test]),
                      jnp.asarray(noise_std, dtype))


# -- distance CSV (called by jaxcal._dataset) -------------------------------------------------------
def distance_columns(dof: int, unit: str = "deg") -> list[str]:
    """``q1a_<unit> … qNa_<unit>, q1b_<unit> … qNb_<unit>, distance_mm``."""
    return ([f"q{j}a_{unit}" for j in range(1, dof + 1)] + [f"q{j}b_{unit}" for j in range(1, dof + 1)]
            + ["distance_mm"])


def save_distance_csv(data, path, angle_unit: str = "deg") -> None:
    """Write distance-bar data: ``# key: value`` lines, then :func:`distance_columns`."""
    import csv
    import io
    import os

    from ._dataset import _rad_to_deg_roundtrip

    q = np.asarray(data.q, np.float64)
    y = np.asarray(data.y, np.float64)
    dof = q.shape[1]
    conv = _rad_to_deg_roundtrip if angle_unit == "deg" else (lambda a: a)
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
    import re

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
        import warnings

        warnings.warn(f"{path}: column(s) {unused} are not used; distance data uses {','.join(want)}", UserWarning,
                      stacklevel=3)
    if not t.rows:
        raise ValueError(f"{path}: no data rows")
    v = t.floats(want)
    ang = np.deg2rad(v[:, : 2 * n_dof]) if unit == "deg" else v[:, : 2 * n_dof]
    return ang[:, :n_dof], np.concatenate([ang[:, n_dof:], v[:, 2 * n_dof:]], axis=1)
