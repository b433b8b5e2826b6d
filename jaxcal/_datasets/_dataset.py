"""Measured data: joint angles plus sensor readings, with CSV I/O and reproducible splits."""

from __future__ import annotations

import csv
import io
import math
import os
import re
import warnings
from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._csvfile import read_table

__all__ = ["Dataset", "load_csv", "save_csv", "KINDS", "marker_columns", "CONTACT_KINDS",
    "label_metadata_key", "dataset_labels", "contact_label_cells", "contact_labels_from_cells", "relabel",
    "distance_columns", "save_distance_csv", "load_distance_table", "camera_columns", "marker_gaps"]

#: measurement kinds and their value columns in CSV files.
KINDS: dict[str, tuple[str, ...]] = {
    "cable": ("length_mm",),
    "position": ("x_mm", "y_mm", "z_mm"),
    "pose": ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg"),
    "markers": (),  # marker_1_x_mm, marker_1_y_mm, marker_1_z_mm, marker_2_x_mm, ... (N from the file)
    "camera": (),  # u_1_px, v_1_px, u_2_px, ... (N target points from the file; empty = not detected)
    "plane": (),  # a text column `plane` (jaxcal._sensors._contact): y = the label's index
    "point": (),  # a text column `point` (jaxcal._sensors._contact): y = the label's index
    "distance": ("distance_mm",),  # q1a_deg…, q1b_deg…, distance_mm (jaxcal._sensors._contact.DistanceBar)
}
_SAMPLE_SHAPE = {"cable": (), "position": (3,), "pose": (4, 4), "plane": (), "point": ()}
_MARKER = re.compile(r"marker_(\d+)_([xyz])_mm")
_CAMERA = re.compile(r"([uv])_(\d+)_px")


def marker_columns(n_markers: int) -> list[str]:
    """CSV columns of ``n_markers`` marker positions in the sensor frame (mm)."""
    return [f"marker_{k}_{c}_mm" for k in range(1, n_markers + 1) for c in "xyz"]
#: |q| beyond this (rad) cannot be a joint angle of a real robot: it looks like degrees.
_MAX_RAD = 4 * math.pi


#: metadata key listing the 1-based joints whose positions are lengths in mm (prismatic joints),
#: e.g. ``"1"``: they are exempt from the degrees check and written as ``q1_mm`` columns.
MM_JOINTS = "mm_joints"


def mm_joints(metadata) -> tuple[int, ...]:
    """The 0-based prismatic (mm) joints named by a dataset's ``mm_joints`` metadata."""
    items = metadata.items() if isinstance(metadata, Mapping) else metadata
    text = dict(items).get(MM_JOINTS, "")
    return tuple(int(v) - 1 for v in str(text).replace(";", ",").split(",") if v.strip())


def mm_joints_metadata(robot) -> dict[str, str]:
    """``{"mm_joints": "1,…"}`` for a robot with prismatic joints (a :class:`~jaxcal.SerialChain`), else ``{}``."""
    prism = [j + 1 for j, p in enumerate(getattr(robot, "prismatic", ())) if p]
    return {MM_JOINTS: ",".join(map(str, prism))} if prism else {}


def _is_tracer(x) -> bool:
    return isinstance(x, jax.core.Tracer)


class Dataset(eqx.Module):
    """Joint angles and the matching measurements of one calibration data set.

    A pytree (``q`` and ``y`` are leaves), so datasets can be built inside ``jit``/``vmap``.

    Attributes:
        q: ``[n, dof]`` joint angles (rad; mm for the prismatic joints listed in the
            ``mm_joints`` metadata, e.g. ``"1"``).
        y: measurements: ``[n]`` wire lengths (mm) for ``kind="cable"``, ``[n, 3]`` positions
            (mm) for ``"position"``, ``[n, 4, 4]`` poses for ``"pose"``, ``[n, N, 3]`` marker
            positions (mm, sensor frame) for ``"markers"``, ``[n, N, 2]`` image points (px) of
            ``N`` target points for ``"camera"`` (NaN: not detected, masked; see
            :class:`jaxcal.Camera`; for ``"markers"`` NaN in x, y and z is a missing marker,
            masked by :class:`jaxcal.SessionMarkers`); ``[n]`` label indices for ``"plane"`` / ``"point"`` (names in
            the ``plane_labels`` / ``point_labels`` metadata) and ``[n, dof + 1]`` (pose b in rad,
            bar length in mm) for ``"distance"`` (see the contact sensors how-to).
        kind: ``"cable"``, ``"position"``, ``"pose"``, ``"markers"``, ``"camera"``, ``"plane"``,
            ``"point"`` or ``"distance"`` (static).
        metadata: ``((key, value), ...)`` strings kept with the data and in CSV headers (static).
        labels: per-row ``(session, frame, placement)`` labels of marker data recorded in
            several sessions (static; ``()`` = one session). See :class:`jaxcal.SessionMarkers`;
            CSV columns ``session``, ``frame``, ``placement``.
    """

    q: Float[Array, "n dof"]
    y: Array
    kind: str = eqx.field(static=True)
    metadata: tuple[tuple[str, str], ...] = eqx.field(static=True, default=())
    labels: tuple[tuple[str, str, str], ...] = eqx.field(static=True, default=())

    def __init__(self, q, y, kind: str = "cable", metadata: Mapping | tuple = (), labels=()):
        if kind not in KINDS:
            raise ValueError(f"unknown measurement kind {kind!r}; expected one of {list(KINDS)}")
        self.kind = kind
        items = metadata.items() if isinstance(metadata, Mapping) else metadata
        self.metadata = tuple((str(k), str(v)) for k, v in items)
        self.labels = _session_labels(labels, int(np.shape(q)[0]), kind)
        if _is_tracer(q) or _is_tracer(y):
            self.q, self.y = q, y
            return
        q = jnp.asarray(q)
        if not jnp.issubdtype(q.dtype, jnp.floating):
            q = q.astype(jnp.result_type(float))
        y = jnp.asarray(y, dtype=q.dtype)
        _validate(np.asarray(q), np.asarray(y), kind, mm_joints(self.metadata))
        self.q, self.y = q, y

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.q.shape[0])

    @property
    def dof(self) -> int:
        return int(self.q.shape[1])

    @property
    def meta(self) -> dict[str, str]:
        return dict(self.metadata)

    def subset(self, index) -> Dataset:
        """The samples at ``index`` (an integer array or slice)."""
        traced = any(isinstance(v, jax.core.Tracer) for v in (self.q, self.y, index))
        if not traced:
            index = index if isinstance(index, slice) else np.asarray(index)
        labels = tuple(self.labels[int(i)] for i in np.arange(self.n)[index]) if self.labels else ()
        if traced:
            return Dataset(self.q[index], self.y[index], self.kind, self.metadata, labels)
        # on the host: NumPy indexing, then device_put (jnp indexing runs small compiled programs)
        return Dataset(jax.device_put(np.asarray(self.q)[index]), jax.device_put(np.asarray(self.y)[index]),
                       self.kind, self.metadata, labels)

    def split(self, key: Array, test_fraction: float = 0.2) -> tuple[Dataset, Dataset]:
        """Random train/test split from a ``jax.random`` key (same key ⇒ same split)."""
        if not (0.0 <= test_fraction < 1.0):
            raise ValueError(f"test_fraction must be in [0, 1), got {test_fraction}")
        n_test = int(round(self.n * test_fraction))
        perm = jax.random.permutation(key, self.n)
        return self.subset(perm[n_test:]), self.subset(perm[:n_test])

    def to_csv(self, path, *, angle_unit: str = "deg") -> None:
        """Write a CSV file; see :func:`save_csv`."""
        save_csv(self, path, angle_unit=angle_unit)

    @classmethod
    def from_csv(cls, path, **kwargs) -> Dataset:
        """Read a CSV file; see :func:`load_csv`."""
        return load_csv(path, **kwargs)


#: CSV columns of session labels (marker data of several sessions; text, not numbers)
LABEL_COLUMNS = ("session", "frame", "placement")


def _session_labels(labels, n: int, kind: str) -> tuple[tuple[str, str, str], ...]:
    """Per-row ``(session, frame, placement)``; a row given as one string means all three."""
    if labels is None or len(labels) == 0:
        return ()
    if kind != "markers":
        raise ValueError(f"session labels apply to marker data, not {kind!r}")
    out = []
    for r, lab in enumerate(labels):
        lab = (lab,) * 3 if isinstance(lab, str) else tuple(lab)
        if len(lab) != 3 or not all(isinstance(v, str) and v.strip() for v in lab):
            raise ValueError(f"row {r}: session labels must be (session, frame, placement) non-empty strings, got {lab!r}")
        out.append(tuple(v.strip() for v in lab))
    if len(out) != n:
        raise ValueError(f"{len(out)} session label rows for {n} data rows")
    return tuple(out)


def _validate(q: np.ndarray, y: np.ndarray, kind: str, mm: tuple[int, ...] = ()) -> None:
    if q.ndim != 2 or q.shape[1] < 1:
        raise ValueError(f"joint angles must have shape [n, dof], got {list(q.shape)}")
    n = q.shape[0]
    if kind == "camera":
        if y.ndim != 3 or y.shape[0] != n or y.shape[2] != 2 or y.shape[1] < 1:
            raise ValueError(f"camera measurements must have shape [{n}, N, 2] (u, v px of N target points), "
                             f"got {list(y.shape)}")
        if np.isinf(y).any():
            raise ValueError("camera measurements contain ±inf; a corner that was not detected is NaN (an empty "
                             "CSV cell)")
        y = np.where(np.isnan(y), 0.0, y)  # NaN = not detected: masked by the camera model, not an error
    elif kind == "distance":  # y = [pose b (rad), bar length (mm)]
        if y.ndim != 2 or y.shape != (n, q.shape[1] + 1):
            raise ValueError(f"distance readings must have shape [{n}, {q.shape[1] + 1}] (pose b, length), "
                             f"got {list(y.shape)}")
    elif kind == "markers":
        if y.ndim != 3 or y.shape[0] != n or y.shape[2] != 3 or y.shape[1] < 1:
            raise ValueError(f"markers measurements must have shape [{n}, N, 3] (N >= 1 markers), got {list(y.shape)}")
        if np.isnan(y).any():  # a missing marker (NaN x, y, z): masked by SessionMarkers, refused by Markers

            marker_gaps(y)  # partial points, ±inf, rows without any marker: errors
            y = np.where(np.isnan(y), 0.0, y)
    else:
        want = (n, *_SAMPLE_SHAPE[kind])
        if y.shape != want:
            raise ValueError(f"{kind} measurements must have shape {list(want)}, got {list(y.shape)}")
    bad_q = ~np.isfinite(q).all(axis=1)
    bad_y = ~np.isfinite(y.reshape(n, -1)).all(axis=1) if n else np.zeros(0, bool)
    if bad_q.any() or bad_y.any():
        rows = np.flatnonzero(bad_q | bad_y)
        raise ValueError(
            f"data contain NaN/inf in {rows.size} sample(s) (rows {rows[:10].tolist()}"
            f"{'...' if rows.size > 10 else ''}); remove or fix them — nothing is dropped silently"
        )
    ang = np.delete(q, [j for j in mm if j < q.shape[1]], axis=1) if mm else q
    if n and ang.size and np.abs(ang).max() > _MAX_RAD:
        raise ValueError(
            f"joint angles up to {np.abs(ang).max():.1f} rad were given where radians are expected; "
            "they look like degrees (convert with np.deg2rad, or use *_deg columns in CSV)"
        )


# -- rotation vector <-> matrix (pose files) ------------------------------------------------
def _rotvec_to_matrix(w) -> np.ndarray:
    """``[..., 3, 3]`` rotation matrices of rotation vectors ``w`` ``[..., 3]`` (rad; Rodrigues),
    in NumPy: host-side callers (pose files, closed-form starts, a camera's pose fit) run no
    device program per call."""
    w = np.asarray(w, np.float64)
    th = np.linalg.norm(w, axis=-1, keepdims=True)
    k = np.where(th > 0, w / np.where(th > 0, th, 1.0), 0.0)
    K = np.zeros(w.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    K = K - np.swapaxes(K, -1, -2)
    th = th[..., None]
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * (K @ K)


def _matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    c = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    th = np.arccos(c)
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    s = np.sin(th)
    small = s < 1e-9
    factor = np.where(small, 0.5, th / (2 * np.where(small, 1.0, s)))
    return v * factor[..., None]


# -- CSV ------------------------------------------------------------------------------------
def _rad_to_deg_roundtrip(q: np.ndarray) -> np.ndarray:
    """Degrees ``d`` near ``rad2deg(q)`` with ``deg2rad(d) == q`` wherever such a float exists
    (a neighbour within two ulps), so that data loaded from a degree file saves back to the
    identical file."""
    d = np.rad2deg(q)
    for k in (1, 2):
        bad = np.deg2rad(d) != q
        if not bad.any():
            break
        for direction in (np.inf, -np.inf):
            c = d.copy()
            for _ in range(k):
                c = np.nextafter(c, direction)
            d = np.where(bad & (np.deg2rad(c) == q), c, d)
            bad = np.deg2rad(d) != q
    return d


def save_csv(data: Dataset, path, *, angle_unit: str = "deg") -> None:
    """Write ``data`` as CSV: ``# key: value`` metadata lines, then a header row.

    Columns: ``q1_deg … qN_deg`` (or ``q1_rad …`` with ``angle_unit="rad"``), then the value
    columns of :data:`KINDS` (``length_mm``; ``x_mm,y_mm,z_mm``; poses add a rotation vector
    ``rx_deg,ry_deg,rz_deg``; markers ``marker_1_x_mm,marker_1_y_mm,marker_1_z_mm,marker_2_x_mm…``).
    Numbers are written as the shortest decimal that reads back
    to the same float64. Radian files round-trip exactly; degree files give joint angles
    within 1 ulp of the originals (float64 deg↔rad conversion cannot be exact for every
    value), and data loaded from a degree file saves back to the identical file.
    """
    if angle_unit not in ("deg", "rad"):
        raise ValueError(f"angle_unit must be 'deg' or 'rad', got {angle_unit!r}")
    if data.kind == "distance":

        return save_distance_csv(data, path, angle_unit)
    qnames, qcols = joint_columns_out(np.asarray(data.q, dtype=np.float64), mm_joints(data.metadata), angle_unit)
    y = np.asarray(data.y, dtype=np.float64)
    if data.kind == "cable":
        vals = y[:, None]
    elif data.kind == "position":
        vals = y
    elif data.kind in ("markers", "camera"):
        vals = y.reshape(y.shape[0], -1)
    elif data.kind in CONTACT_KINDS:
        vals = np.zeros((y.shape[0], 0))
    else:
        vals = np.concatenate([y[:, :3, 3], np.rad2deg(_matrix_to_rotvec(y[:, :3, :3]))], axis=1)
    value_cols = marker_columns(y.shape[1]) if data.kind == "markers" else list(KINDS[data.kind])
    if data.kind == "camera":

        value_cols = camera_columns(y.shape[1])
    header = qnames + value_cols
    buf = io.StringIO()
    buf.write("# jaxcal dataset v1\n")
    buf.write(f"# kind: {data.kind}\n")
    for k, v in data.metadata:
        if k != "kind":
            buf.write(f"# {k}: {v}\n")
    w = csv.writer(buf, lineterminator="\n")
    contact = contact_label_cells(data) if data.kind in CONTACT_KINDS else None
    w.writerow(header + (list(LABEL_COLUMNS) if data.labels else []) + ([CONTACT_KINDS[data.kind]] if contact else []))
    for r, row in enumerate(np.concatenate([qcols, vals], axis=1)):
        # NaN (a camera corner not detected) is written as an empty cell
        w.writerow([repr(float(x)) if x == x else "" for x in row] + (list(data.labels[r]) if data.labels else [])
                   + ([contact[r]] if contact else []))
    with open(os.fspath(path), "w", encoding="utf-8") as f:
        f.write(buf.getvalue())


#: columns that data files often carry for bookkeeping; not used, still named in the warning.
_BOOKKEEPING = ("index", "row", "sample", "id", "time", "time_s", "timestamp")
_JOINT = re.compile(r"q(\d+)_(deg|rad|mm)")


def _joint_columns(path: str, header, dof: int | None) -> tuple[list[str], str]:
    """The joint-angle column names ordered by joint number, and their unit."""
    found = {h: _JOINT.fullmatch(h) for h in header}
    found = {h: (int(m[1]), m[2]) for h, m in found.items() if m}
    if not found:
        raise ValueError(f"{path}: no joint-angle columns (expected q1_deg, q2_deg, ... or q1_rad, ...); "
                         f"header: {list(header)}")
    units = {u for _, u in found.values()} - {"mm"}  # mm: prismatic joints, next to deg or rad columns
    if len(units) > 1:
        raise ValueError(f"{path}: joint-angle columns mix degrees and radians: {list(found)}")
    unit = units.pop() if units else "rad"
    by_joint: dict[int, list[str]] = {}
    for h, (j, _) in found.items():
        by_joint.setdefault(j, []).append(h)
    twice = [names for names in by_joint.values() if len(names) > 1]
    if twice:
        raise ValueError(f"{path}: joint-angle columns {twice[0]} name the same joint")
    n = max(by_joint)
    missing = [f"q{j}_{unit}" for j in range(1, n + 1) if j not in by_joint]
    if missing or 0 in by_joint:
        # a misspelt joint column (q1_dg, Q1_deg, q1 deg) is what the user will look for
        near = [h for h in header if h not in found and re.match(r"\s*q\s*\d+", h, re.IGNORECASE)]
        raise ValueError(
            f"{path}: joint-angle columns must be numbered 1..N without gaps; "
            + (f"missing {missing}" if missing else "found q0") + f" (have {list(found)})"
            + (f"; found {near}, not a joint-angle column name (qN_deg, qN_rad, or qN_mm for a prismatic joint)"
               if near else "")
        )
    if dof is not None and n != dof:
        raise ValueError(f"{path}: file has {n} joint-angle columns but the robot has {dof} joints")
    return [by_joint[j][0] for j in range(1, n + 1)], unit


def joint_columns_out(q: np.ndarray, mm, angle_unit: str = "deg") -> tuple[list[str], np.ndarray]:
    """Inverse of :func:`joint_values`: the joint column names (``q<j>_deg``/``q<j>_rad``, and
    ``q<j>_mm`` for the 0-based prismatic joints ``mm``) and their values ``[n, dof]`` — degrees
    as the shortest decimals that read back to the same radians, mm as they are."""
    cols = _rad_to_deg_roundtrip(q) if angle_unit == "deg" else q.copy()
    for j in mm:
        cols[:, j] = q[:, j]
    return [f"q{j + 1}_{'mm' if j in mm else angle_unit}" for j in range(q.shape[1])], cols


def joint_values(path: str, values: np.ndarray, qcols: list[str], unit: str) -> tuple[np.ndarray, list[int]]:
    """Joint columns ``[n, dof]`` as read (``qcols`` from :func:`_joint_columns`) → radians, with
    ``q<j>_mm`` columns (prismatic joints) kept in mm. Returns ``(q, mm)``, ``mm`` the 0-based
    indices of the mm columns. Radian columns holding values beyond ``_MAX_RAD`` raise (they
    look like degrees)."""
    mm = [j for j, c in enumerate(qcols) if c.endswith("_mm")]
    ang = np.delete(values, mm, axis=1)
    if unit == "rad" and ang.size and np.abs(ang).max() > _MAX_RAD:
        raise ValueError(
            f"{path}: columns are declared in radians (q*_rad) but hold values up to "
            f"{np.abs(ang).max():.1f}; they look like degrees — rename the columns to q*_deg"
        )
    q = np.deg2rad(values) if unit == "deg" else values.copy()
    q[:, mm] = values[:, mm]
    return q, mm


def load_csv(
    path, *, kind: str | None = None, dof: int | None = None, dtype=None, delimiter: str | None = None,
    strict: bool = False, n_markers: int | None = None, kind_from: str | None = None,
) -> Dataset:
    """Read a CSV data file into a :class:`Dataset`, as :func:`save_csv` or a spreadsheet writes it.

    Columns, matched by name in any order (names are stripped and case-insensitive):

    * joint angles ``q1_deg … qN_deg`` or ``q1_rad … qN_rad`` (one unit for all), numbered
      1..N without gaps or duplicates;
    * the measurement columns of :data:`KINDS`: ``length_mm`` (cable); ``x_mm,y_mm,z_mm``
      (position); poses add a rotation vector ``rx_deg,ry_deg,rz_deg``; marker data
      ``marker_k_x_mm,marker_k_y_mm,marker_k_z_mm`` for k = 1..N (sensor frame, mm; every
      marker of 1..N must have all three columns);
    * marker data of several sessions (:class:`jaxcal.SessionMarkers`): text columns
      ``session`` (the recording session), ``frame`` (its sensor-frame label) and
      ``placement`` (its marker-placement label); a missing ``frame`` or ``placement`` column
      takes the ``session`` label, a missing ``session`` column the ``frame/placement`` pair;
      they become :attr:`Dataset.labels`;
    * any other column is not used: a ``UserWarning`` names it (``strict=True``: an error).
      Bookkeeping columns (``index``, ``row``, ``sample``, ``id``, ``time``, ``time_s``,
      ``timestamp``) are named in the warning too.

    File format: UTF-8 with or without a byte-order mark (Excel's "CSV UTF-8"), or UTF-16 with
    one; delimiter ``,``, ``;`` or tab, recognised from the header line (or ``delimiter=``).
    In ``;``-delimited files numbers may use a decimal comma (``1,5``); elsewhere a comma in
    a number is an error. Blank lines and ``#`` lines are skipped anywhere; ``# key: value``
    lines are kept as metadata (``# kind: cable`` gives the kind). Rows whose cells are all
    empty and trailing nameless empty columns (spreadsheet exports) are skipped. Nothing else
    is dropped: a bad cell is an error naming the data row (1-based), its file line, the
    column and the text.

    Args:
        path: file path.
        kind: expected measurement kind; by default taken from the ``# kind:`` line or from
            the value columns present. A ``kind`` that contradicts the file's ``# kind:`` line
            raises.
        dof: expected number of joints (e.g. ``robot.dof``); a mismatch raises.
        dtype: array dtype (default: JAX's default float).
        delimiter: the column delimiter (one character); default: recognised from the header.
        strict: raise instead of warning when a column is not used.
        n_markers: expected number of markers (marker data); a mismatch raises.
        kind_from: where ``kind`` comes from, for the error when the file's ``# kind:`` line
            contradicts it (default: the ``--measurement`` option / the ``kind`` argument; ``jaxcal
            evaluate`` names the result file, whose kind it takes).

    Raises:
        FileNotFoundError: no such file.
        ValueError: missing/unknown columns, mixed angle units, gaps in the joint numbering,
            wrong joint count, empty file, unparsable or NaN/inf values (naming row, line and
            column), radian columns whose values look like degrees, or a ``kind`` other than the
            file's ``# kind:`` line.
    """
    n_markers_expected = n_markers
    t = read_table(path, delimiter=delimiter, what="data file", row_name="data row")
    path, header, meta = t.path, t.header, dict(t.meta)
    meta_kind = next((k for k in meta if k.lower() == "kind"), None)
    if kind is not None and meta_kind is not None and meta[meta_kind].strip().lower() != kind:
        asked = kind_from or f"--measurement {kind} / kind={kind!r}"
        raise ValueError(f"{path}: the file says '# {meta_kind}: {meta[meta_kind]}' but {kind} data were asked for "
                         f"({asked}); " + ("use a file of that kind" if kind_from else "ask for the file's kind")
                         + f", or correct its '# {meta_kind}:' line")
    if kind == "distance" or (kind is None and "distance_mm" in header):  # two poses per row (jaxcal._sensors._contact)

        if meta_kind is not None:
            meta.pop(meta_kind)
        qa, yd = load_distance_table(path, t, meta, dof)
        dt = dtype or jnp.result_type(float)
        return Dataset(jnp.asarray(qa, dt), jnp.asarray(yd, dt), "distance", meta)
    qcols, unit = _joint_columns(path, header, dof)
    if kind is None and meta_kind is not None:
        kind = meta[meta_kind].lower()
    markers_found = {h: _MARKER.fullmatch(h) for h in header}
    markers_found = {h: (int(m[1]), m[2]) for h, m in markers_found.items() if m}
    if kind is None and markers_found:
        kind = "markers"
    camera_found = {m for m in (_CAMERA.fullmatch(h) for h in header) if m}
    if kind is None and camera_found:
        kind = "camera"
    if kind is None:
        kind = next((k for k, col in CONTACT_KINDS.items() if col in header), None)
    if kind is None:
        kind = next((k for k in ("pose", "position", "cable") if all(c in header for c in KINDS[k])), None)
        if kind is None:
            raise ValueError(
                f"{path}: no measurement columns found; expected one of "
                + "; ".join(f"{k}: {','.join(c or ('marker_1_x_mm', 'marker_1_y_mm', '...'))}" for k, c in KINDS.items())
                + f"; header: {list(header)}"
            )
    if kind not in KINDS:
        raise ValueError(f"{path}: unknown measurement kind {kind!r}; expected one of {list(KINDS)}")
    value_cols = list(KINDS[kind])
    if kind == "markers":
        if not markers_found:
            raise ValueError(f"{path}: no marker columns (expected marker_1_x_mm, marker_1_y_mm, marker_1_z_mm, "
                             f"marker_2_x_mm, ...); header: {list(header)}")
        n_markers = max(k for k, _ in markers_found.values())
        if n_markers_expected is not None and n_markers != n_markers_expected:
            raise ValueError(f"{path}: file has {n_markers} marker(s) but {n_markers_expected} were expected")
        value_cols = marker_columns(n_markers)
    elif n_markers_expected is not None and kind != "camera":
        raise ValueError(f"{path}: n_markers applies to marker (and camera) data, not {kind!r}")
    if kind == "camera":  # u_k_px, v_k_px for k = 1..N (N from the file, or n_markers = target points)

        if not camera_found:
            raise ValueError(f"{path}: no image-point columns (expected u_1_px, v_1_px, u_2_px, ...); "
                             f"header: {list(header)}")
        n_pts = max(int(m[2]) for m in camera_found)
        if n_markers_expected is not None and n_pts != n_markers_expected:
            raise ValueError(f"{path}: file has {n_pts} target point(s) but {n_markers_expected} were expected")
        value_cols = camera_columns(n_pts)
    missing = [c for c in value_cols if c not in header]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing} for {kind} data; header: {list(header)}")
    used = qcols + value_cols
    label_cols = [c for c in LABEL_COLUMNS if c in header] if kind == "markers" else []
    if kind in CONTACT_KINDS:
        label_cols = [CONTACT_KINDS[kind]]
        if label_cols[0] not in header:
            raise ValueError(f"{path}: {kind} data need a text column {label_cols[0]!r} naming each row's "
                             f"{label_cols[0]}; header: {list(header)}")
    unused = [h for h in header if h not in used and h not in label_cols]
    if unused:
        odd = [h for h in unused if h not in _BOOKKEEPING]
        book = [h for h in unused if h in _BOOKKEEPING]
        named = " and ".join(
            part for part in (odd and f"unknown column(s) {odd}", book and f"bookkeeping column(s) {book}") if part
        )
        msg = f"{path}: {named} are not used; {kind} data uses {','.join(used)}"
        if strict:
            raise ValueError(msg + " (strict=True)")
        warnings.warn(msg + " (strict=True makes this an error)", UserWarning, stacklevel=2)
    if not t.rows:
        raise ValueError(f"{path}: no data rows")
    n_joints = len(qcols)
    if kind == "camera":  # empty cells (corners not detected) → NaN, masked by the camera model
        table = np.concatenate([t.floats(qcols), _gap_cells(t, value_cols, 2)], axis=1)
    elif kind == "markers":  # empty cells (a marker the session does not have) → NaN, masked by SessionMarkers
        table = np.concatenate([t.floats(qcols), _gap_cells(t, value_cols, 3)], axis=1)
    else:
        table = t.floats(used)
    q, mm = joint_values(path, table[:, :n_joints], qcols, unit)
    if mm:
        meta[MM_JOINTS] = ",".join(str(j + 1) for j in mm)
    vals = table[:, n_joints:]
    if kind == "cable":
        y = vals[:, 0]
    elif kind == "position":
        y = vals
    elif kind == "markers":
        y = vals.reshape(vals.shape[0], -1, 3)
    elif kind == "camera":
        y = vals.reshape(vals.shape[0], -1, 2)
    elif kind in CONTACT_KINDS:
        y, meta = contact_labels_from_cells(path, t, header, kind, meta)
        label_cols = []
    else:
        y = np.zeros((vals.shape[0], 4, 4))
        y[:, :3, :3] = _rotvec_to_matrix(np.deg2rad(vals[:, 3:6]))
        y[:, :3, 3] = vals[:, :3]
        y[:, 3, 3] = 1.0
    labels = ()
    if label_cols:
        cells = {c: [row[header.index(c)].strip() for row in t.rows] for c in label_cols}
        for c, vals_c in cells.items():
            empty = [r for r, v in enumerate(vals_c) if not v]
            if empty:
                raise ValueError(f"{path}: {t.where(empty[0], c)}: empty label ({len(empty)} row(s) without a {c})")
        n_rows = len(t.rows)
        fr = cells.get("frame") or cells.get("session")
        pl = cells.get("placement") or cells.get("session")
        if fr is None or pl is None:
            raise ValueError(f"{path}: give a 'session' column, or both 'frame' and 'placement' (have {label_cols})")
        se = cells.get("session") or [f"{fr[r]}/{pl[r]}" for r in range(n_rows)]
        labels = tuple(zip(se, fr, pl))
    if meta_kind is not None:
        meta.pop(meta_kind)
    dt = dtype or jnp.result_type(float)
    return Dataset(jnp.asarray(q, dt), jnp.asarray(y, dt), kind, meta, labels)


def _gap_cells(t, columns, width: int) -> np.ndarray:
    """``[n_rows, len(columns)]`` readings of a file whose points may be missing: an empty cell is
    NaN; the ``width`` columns of one point (``u, v`` of a camera corner: a corner not detected;
    ``x, y, z`` of a marker: a marker the session does not have, or not seen) must be empty
    together; other text that is not a number, NaN/inf text, is an error naming row, line and
    column."""
    what = "corner was not detected" if width == 2 else "marker is missing"
    idx = [t.header.index(c) for c in columns]
    out = np.full((len(t.rows), len(idx)), np.nan)
    for r, row in enumerate(t.rows):
        for k, i in enumerate(idx):
            text = row[i].strip()
            if not text:
                continue
            try:
                if "_" in text:
                    raise ValueError
                v = float(text.replace(",", ".") if t.decimal_comma else text)
            except ValueError:
                raise ValueError(f"{t.path}: {t.where(r, columns[k])}: {row[i]!r} is not a number") from None
            if not math.isfinite(v):
                raise ValueError(f"{t.path}: {t.where(r, columns[k])}: {row[i]!r}; leave the cell empty where a "
                                 f"{what}")
            out[r, k] = v
        gap = np.isnan(out[r].reshape(-1, width))
        odd = np.flatnonzero(gap.any(axis=1) & ~gap.all(axis=1))
        if odd.size:
            cols = columns[odd[0] * width:(odd[0] + 1) * width]
            name = "point" if width == 2 else "marker"
            raise ValueError(f"{t.path}: {t.where(r)}: {name} {odd[0] + 1} has only some of {', '.join(cols)} "
                             f"(leave {'both' if width == 2 else 'all three'} empty where a {what})")
    return out


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
            _check_label(v)
        except ValueError as e:
            raise ValueError(f"{path}: {table.where(r, col)}: {e}") from None
    known = [s for s in meta.get(key, "").split(",") if s]
    names = list(dict.fromkeys(known + cells))
    meta = dict(meta)
    meta[key] = ",".join(names)
    return np.asarray([names.index(v) for v in cells], np.float64), meta


def relabel(data, labels: Sequence[str]):
    """``data`` (a contact :class:`~jaxcal.Dataset`) with its label indices renumbered to
    ``labels`` (a model's label order), e.g. a test file whose rows name the planes in another
    order. Labels ``data`` has but ``labels`` lacks raise."""

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


def distance_columns(dof: int, unit: str = "deg") -> list[str]:
    """``q1a_<unit> … qNa_<unit>, q1b_<unit> … qNb_<unit>, distance_mm``."""
    return ([f"q{j}a_{unit}" for j in range(1, dof + 1)] + [f"q{j}b_{unit}" for j in range(1, dof + 1)]
            + ["distance_mm"])


def save_distance_csv(data, path, angle_unit: str = "deg") -> None:
    """Write distance-bar data: ``# key: value`` lines, then :func:`distance_columns`."""
    import csv
    import io
    import os


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


def camera_columns(n_points: int) -> list[str]:
    """CSV columns of ``n_points`` target points' image coordinates: ``u_1_px, v_1_px, u_2_px…``."""
    return [f"{c}_{k}_px" for k in range(1, n_points + 1) for c in "uv"]


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
