"""Measured data: joint angles plus sensor readings, with CSV I/O and reproducible splits."""

from __future__ import annotations

import csv
import io
import math
import os
import warnings
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

__all__ = ["Dataset", "load_csv", "save_csv", "KINDS"]

#: measurement kinds and their value columns in CSV files.
KINDS: dict[str, tuple[str, ...]] = {
    "cable": ("length_mm",),
    "position": ("x_mm", "y_mm", "z_mm"),
    "pose": ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg"),
}
_SAMPLE_SHAPE = {"cable": (), "position": (3,), "pose": (4, 4)}
#: |q| beyond this (rad) cannot be a joint angle of a real robot: it looks like degrees.
_MAX_RAD = 4 * math.pi


def _is_tracer(x) -> bool:
    return isinstance(x, jax.core.Tracer)


class Dataset(eqx.Module):
    """Joint angles and the matching measurements of one calibration data set.

    A pytree (``q`` and ``y`` are leaves), so datasets can be built inside ``jit``/``vmap``.

    Attributes:
        q: ``[n, dof]`` joint angles (rad).
        y: measurements: ``[n]`` wire lengths (mm) for ``kind="cable"``, ``[n, 3]`` positions
            (mm) for ``"position"``, ``[n, 4, 4]`` poses for ``"pose"``.
        kind: ``"cable"``, ``"position"`` or ``"pose"`` (static).
        metadata: ``((key, value), ...)`` strings kept with the data and in CSV headers (static).
    """

    q: Float[Array, "n dof"]
    y: Array
    kind: str = eqx.field(static=True)
    metadata: tuple[tuple[str, str], ...] = eqx.field(static=True, default=())

    def __init__(self, q, y, kind: str = "cable", metadata: Mapping | tuple = ()):
        if kind not in KINDS:
            raise ValueError(f"unknown measurement kind {kind!r}; expected one of {list(KINDS)}")
        self.kind = kind
        items = metadata.items() if isinstance(metadata, Mapping) else metadata
        self.metadata = tuple((str(k), str(v)) for k, v in items)
        if _is_tracer(q) or _is_tracer(y):
            self.q, self.y = q, y
            return
        q = jnp.asarray(q)
        if not jnp.issubdtype(q.dtype, jnp.floating):
            q = q.astype(jnp.result_type(float))
        y = jnp.asarray(y, dtype=q.dtype)
        _validate(np.asarray(q), np.asarray(y), kind)
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
        return Dataset(self.q[index], self.y[index], self.kind, self.metadata)

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


def _validate(q: np.ndarray, y: np.ndarray, kind: str) -> None:
    if q.ndim != 2 or q.shape[1] < 1:
        raise ValueError(f"joint angles must have shape [n, dof], got {list(q.shape)}")
    n = q.shape[0]
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
    if n and np.abs(q).max() > _MAX_RAD:
        raise ValueError(
            f"joint angles up to {np.abs(q).max():.1f} rad were given where radians are expected; "
            "they look like degrees (convert with np.deg2rad, or use *_deg columns in CSV)"
        )


# -- rotation vector <-> matrix (pose files) ------------------------------------------------
def _rotvec_to_matrix(w: np.ndarray) -> np.ndarray:
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
    ``rx_deg,ry_deg,rz_deg``). Numbers are written as the shortest decimal that reads back
    to the same float64. Radian files round-trip exactly; degree files give joint angles
    within 1 ulp of the originals (float64 deg↔rad conversion cannot be exact for every
    value), and data loaded from a degree file saves back to the identical file.
    """
    if angle_unit not in ("deg", "rad"):
        raise ValueError(f"angle_unit must be 'deg' or 'rad', got {angle_unit!r}")
    q = np.asarray(data.q, dtype=np.float64)
    qcols = _rad_to_deg_roundtrip(q) if angle_unit == "deg" else q
    y = np.asarray(data.y, dtype=np.float64)
    if data.kind == "cable":
        vals = y[:, None]
    elif data.kind == "position":
        vals = y
    else:
        vals = np.concatenate([y[:, :3, 3], np.rad2deg(_matrix_to_rotvec(y[:, :3, :3]))], axis=1)
    header = [f"q{j + 1}_{angle_unit}" for j in range(data.dof)] + list(KINDS[data.kind])
    buf = io.StringIO()
    buf.write("# jaxcal dataset v1\n")
    buf.write(f"# kind: {data.kind}\n")
    for k, v in data.metadata:
        if k != "kind":
            buf.write(f"# {k}: {v}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for row in np.concatenate([qcols, vals], axis=1):
        w.writerow([repr(float(x)) for x in row])
    with open(os.fspath(path), "w", encoding="utf-8") as f:
        f.write(buf.getvalue())


def load_csv(path, *, kind: str | None = None, dof: int | None = None, dtype=None) -> Dataset:
    """Read a CSV data file (see :func:`save_csv` for the layout) into a :class:`Dataset`.

    Args:
        path: file path.
        kind: expected measurement kind; by default taken from the ``# kind:`` line or from
            the value columns present.
        dof: expected number of joints (e.g. ``robot.dof``); a mismatch raises.
        dtype: array dtype (default: JAX's default float).

    Raises:
        ValueError: missing/unknown columns, mixed angle units, wrong joint count, empty file,
            unparsable or NaN/inf values (with row numbers), or radian columns whose values
            look like degrees.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"data file not found: {path}")
    meta: dict[str, str] = {}
    with open(path, encoding="utf-8") as f:
        lines = f.read().splitlines()
    body = []
    for line in lines:
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            if ":" in s:
                k, v = s[1:].split(":", 1)
                meta[k.strip()] = v.strip()
            continue
        body.append(line)
    if not body:
        raise ValueError(f"{path}: no header row found")
    rows = list(csv.reader(body))
    header = [h.strip() for h in rows[0]]
    qcols = [h for h in header if h.startswith("q") and (h.endswith("_deg") or h.endswith("_rad"))]
    if not qcols:
        raise ValueError(f"{path}: no joint-angle columns (expected q1_deg, q2_deg, ... or q1_rad, ...); header: {header}")
    units = {h.rsplit("_", 1)[1] for h in qcols}
    if len(units) != 1:
        raise ValueError(f"{path}: joint-angle columns mix degrees and radians: {qcols}")
    unit = units.pop()
    n_joints = len(qcols)
    expected_q = [f"q{j + 1}_{unit}" for j in range(n_joints)]
    if qcols != expected_q:
        raise ValueError(f"{path}: joint-angle columns must be {expected_q} in order, got {qcols}")
    if dof is not None and n_joints != dof:
        raise ValueError(f"{path}: file has {n_joints} joint-angle columns but the robot has {dof} joints")
    if kind is None:
        kind = meta.get("kind")
    if kind is None:
        kind = next((k for k in ("pose", "position", "cable") if all(c in header for c in KINDS[k])), None)
        if kind is None:
            raise ValueError(
                f"{path}: no measurement columns found; expected one of "
                + "; ".join(f"{k}: {','.join(c)}" for k, c in KINDS.items())
            )
    if kind not in KINDS:
        raise ValueError(f"{path}: unknown measurement kind {kind!r}; expected one of {list(KINDS)}")
    missing = [c for c in KINDS[kind] if c not in header]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing} for {kind} data; header: {header}")
    extra = [h for h in header if h not in qcols and h not in KINDS[kind]]
    if extra:
        warnings.warn(f"{path}: ignoring unknown column(s) {extra}", stacklevel=2)
    idx = [header.index(c) for c in expected_q + list(KINDS[kind])]
    table = np.empty((len(rows) - 1, len(idx)))
    for r, row in enumerate(rows[1:]):
        if len(row) != len(header):
            raise ValueError(f"{path}: data row {r + 1} has {len(row)} fields, header has {len(header)}")
        try:
            table[r] = [float(row[i]) for i in idx]
        except ValueError as e:
            raise ValueError(f"{path}: data row {r + 1}: {e}") from None
    if table.shape[0] == 0:
        raise ValueError(f"{path}: no data rows")
    bad = np.flatnonzero(~np.isfinite(table).all(axis=1))
    if bad.size:
        raise ValueError(
            f"{path}: {bad.size} row(s) contain NaN/inf (data rows {(bad + 1)[:10].tolist()}); "
            "remove or fix them — nothing is dropped silently"
        )
    qv = table[:, :n_joints]
    if unit == "rad" and np.abs(qv).max() > _MAX_RAD:
        raise ValueError(
            f"{path}: columns are declared in radians (q*_rad) but hold values up to "
            f"{np.abs(qv).max():.1f}; they look like degrees — rename the columns to q*_deg"
        )
    q = np.deg2rad(qv) if unit == "deg" else qv
    vals = table[:, n_joints:]
    if kind == "cable":
        y = vals[:, 0]
    elif kind == "position":
        y = vals
    else:
        y = np.zeros((vals.shape[0], 4, 4))
        y[:, :3, :3] = _rotvec_to_matrix(np.deg2rad(vals[:, 3:6]))
        y[:, :3, 3] = vals[:, :3]
        y[:, 3, 3] = 1.0
    meta.pop("kind", None)
    meta.pop("jaxcal dataset v1", None)
    dt = dtype or jnp.result_type(float)
    return Dataset(jnp.asarray(q, dt), jnp.asarray(y, dt), kind, meta)
