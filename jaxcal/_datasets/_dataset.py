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

from .._core._csvfile import rad_to_deg_roundtrip, read_table
from .._sensors._contact import dataset_labels, label_metadata_key
from .._sensors._kind import kind_names, sensor_kind, sensor_kinds

__all__ = ["Dataset", "load_csv", "save_csv", "relabel", "joint_columns_out", "joint_values", "mm_joints",
    "mm_joints_metadata", "MM_JOINTS"]


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
        spec = sensor_kind(kind)
        self.kind = kind
        items = metadata.items() if isinstance(metadata, Mapping) else metadata
        self.metadata = tuple((str(k), str(v)) for k, v in items)
        self.labels = _session_labels(labels, int(np.shape(q)[0]), spec)
        if _is_tracer(q) or _is_tracer(y):
            self.q, self.y = q, y
            return
        q = jnp.asarray(q)
        if not jnp.issubdtype(q.dtype, jnp.floating):
            q = q.astype(jnp.result_type(float))
        y = jnp.asarray(y, dtype=q.dtype)
        _validate(np.asarray(q), np.asarray(y), spec, mm_joints(self.metadata))
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


def _session_labels(labels, n: int, kind) -> tuple[tuple[str, str, str], ...]:
    """Per-row ``(session, frame, placement)``; a row given as one string means all three."""
    if labels is None or len(labels) == 0:
        return ()
    if not kind.session_labels:
        raise ValueError(f"session labels apply to marker data, not {kind.name!r}")
    out = []
    for r, lab in enumerate(labels):
        lab = (lab,) * 3 if isinstance(lab, str) else tuple(lab)
        if len(lab) != 3 or not all(isinstance(v, str) and v.strip() for v in lab):
            raise ValueError(f"row {r}: session labels must be (session, frame, placement) non-empty strings, got {lab!r}")
        out.append(tuple(v.strip() for v in lab))
    if len(out) != n:
        raise ValueError(f"{len(out)} session label rows for {n} data rows")
    return tuple(out)


def _validate(q: np.ndarray, y: np.ndarray, kind, mm: tuple[int, ...] = ()) -> None:
    """Shapes, NaN/inf and the degrees check of a data set's ``q`` and ``y`` (``kind``: its
    :class:`~jaxcal._sensors._kind.SensorKind`, which checks the readings' shape and masks)."""
    if q.ndim != 2 or q.shape[1] < 1:
        raise ValueError(f"joint angles must have shape [n, dof], got {list(q.shape)}")
    n = q.shape[0]
    y = kind.checked_readings(y, n, q.shape[1])
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


# -- CSV ------------------------------------------------------------------------------------
def save_csv(data: Dataset, path, *, angle_unit: str = "deg") -> None:
    """Write ``data`` as CSV: ``# key: value`` metadata lines, then a header row.

    Columns: ``q1_deg … qN_deg`` (or ``q1_rad …`` with ``angle_unit="rad"``), then the value
    columns of the data's kind (``length_mm``; ``x_mm,y_mm,z_mm``; poses add a rotation vector
    ``rx_deg,ry_deg,rz_deg``; markers ``marker_1_x_mm,marker_1_y_mm,marker_1_z_mm,marker_2_x_mm…``).
    Numbers are written as the shortest decimal that reads back
    to the same float64. Radian files round-trip exactly; degree files give joint angles
    within 1 ulp of the originals (float64 deg↔rad conversion cannot be exact for every
    value), and data loaded from a degree file saves back to the identical file.
    """
    if angle_unit not in ("deg", "rad"):
        raise ValueError(f"angle_unit must be 'deg' or 'rad', got {angle_unit!r}")
    kind = sensor_kind(data.kind)
    if kind.own_table:
        return kind.write_file(data, path, angle_unit)
    qnames, qcols = joint_columns_out(np.asarray(data.q, dtype=np.float64), mm_joints(data.metadata), angle_unit)
    value_cols, vals, text_cols, text = kind.write_values(data)
    header = qnames + value_cols
    buf = io.StringIO()
    buf.write("# jaxcal dataset v1\n")
    buf.write(f"# kind: {data.kind}\n")
    for k, v in data.metadata:
        if k != "kind":
            buf.write(f"# {k}: {v}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header + text_cols)
    for r, row in enumerate(np.concatenate([qcols, vals], axis=1)):
        # NaN (a camera corner not detected) is written as an empty cell
        w.writerow([repr(float(x)) if x == x else "" for x in row] + text[r])
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
    cols = rad_to_deg_roundtrip(q) if angle_unit == "deg" else q.copy()
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
    * the measurement columns of the data's kind: ``length_mm`` (cable); ``x_mm,y_mm,z_mm``
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
    t = read_table(path, delimiter=delimiter, what="data file", row_name="data row")
    path, header, meta = t.path, t.header, dict(t.meta)
    meta_kind = next((k for k in meta if k.lower() == "kind"), None)
    if kind is not None and meta_kind is not None and meta[meta_kind].strip().lower() != kind:
        asked = kind_from or f"--measurement {kind} / kind={kind!r}"
        raise ValueError(f"{path}: the file says '# {meta_kind}: {meta[meta_kind]}' but {kind} data were asked for "
                         f"({asked}); " + ("use a file of that kind" if kind_from else "ask for the file's kind")
                         + f", or correct its '# {meta_kind}:' line")
    if meta_kind is not None:
        kind = kind or meta[meta_kind].strip().lower()
        meta.pop(meta_kind)
    if kind is None:  # recognised from the columns, in the registry's order
        spec = next((k for k in sensor_kinds() if k.found_in(header)), None)
        if spec is None:
            _joint_columns(path, header, dof)  # a file without joint columns is told so first
            raise ValueError(f"{path}: no measurement columns found; expected one of "
                             + "; ".join(f"{k.name}: {k.column_hint()}" for k in sensor_kinds() if k.column_hint())
                             + f"; header: {list(header)}")
    else:
        try:
            spec = sensor_kind(kind)
        except ValueError:
            raise ValueError(f"{path}: unknown measurement kind {kind!r}; expected one of {list(kind_names())}") from None
    dt = dtype or jnp.result_type(float)
    if spec.own_table:
        q, y = spec.read_table(path, t, meta, dof)
        return Dataset(jnp.asarray(q, dt), jnp.asarray(y, dt), spec.name, meta)
    qcols, unit = _joint_columns(path, header, dof)
    value_cols = spec.value_columns(path, header, n_markers)
    missing = [c for c in value_cols if c not in header]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing} for {spec.name} data; header: {list(header)}")
    used = qcols + value_cols
    label_cols = spec.label_columns(path, header)
    unused = [h for h in header if h not in used and h not in label_cols]
    if unused:
        odd = [h for h in unused if h not in _BOOKKEEPING]
        book = [h for h in unused if h in _BOOKKEEPING]
        named = " and ".join(
            part for part in (odd and f"unknown column(s) {odd}", book and f"bookkeeping column(s) {book}") if part
        )
        msg = f"{path}: {named} are not used; {spec.name} data uses {','.join(used)}"
        if strict:
            raise ValueError(msg + " (strict=True)")
        warnings.warn(msg + " (strict=True makes this an error)", UserWarning, stacklevel=2)
    if not t.rows:
        raise ValueError(f"{path}: no data rows")
    q, mm = joint_values(path, t.floats(qcols), qcols, unit)
    if mm:
        meta[MM_JOINTS] = ",".join(str(j + 1) for j in mm)
    y, meta, labels = spec.readings(spec.read_values(t, value_cols), path, t, meta)
    return Dataset(jnp.asarray(q, dt), jnp.asarray(y, dt), spec.name, meta, labels)


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


