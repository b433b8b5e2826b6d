"""Saving and loading results: calibration results as JSON, sweeps from their output directory.

A calibration result file (``jaxcal calibrate --out result.json``, :func:`save_result`) is a
JSON object holding everything needed to use the calibration again: the nominal robot, the
measurement model, the free parameters, the calibrated deviations (rad, mm), the calibrated DH
table (degrees, mm), the history, the status, metrics and the identifiability report.
:func:`load_result` turns it back into a :class:`~jaxcal.CalibrationResult` whose ``predict``,
``evaluate`` and ``dh_table`` work as on the original (the RBF network of ``"rbfnn"`` included).

A sweep's output directory is read back by :func:`jaxcal._experiments._sweep_results.load_sweep` (beside the
sweep's results; ``jaxcal._experiments._sweep_chunks`` writes the chunk files).
"""

from __future__ import annotations

import json
import pathlib
from typing import Any

import numpy as np

from .._core._csvfile import _decode, number_list, read_table
from .._core._json import from_json_number, to_jsonable
from .._core._metrics import Metrics
from .._core._params import Deviations, ParameterSpace, layout_for
from .._core._precision import to_device
from .._fit._diagnostics import Uncertainty
from .._fit._prior import Prior, prior_from_dict, prior_to_dict
from .._fit._result import CalibrationResult, Status
from .._models._abstract import AbstractRobot
from .._models._nongeometric import nongeometric_from_dict
from .._models._robot import DHRobot
from .._models._tree import KinematicTree
from .._sensors._measurement import MeasurementModel

__all__ = [
    "RESULT_FORMAT",
    "robot_to_dict",
    "robot_from_dict",
    "measurement_to_dict",
    "measurement_from_dict",
    "result_to_dict",
    "save_result",
    "load_result",
    "load_result_dict",
    "load_robot_csv",
    "load_tree_csv",
    "save_robot_csv",
    "result_data_file",
    "file_identity",
]

#: ``"format"`` entry of calibration result files.
RESULT_FORMAT = "jaxcal-calibration-result/1"


# -- models -------------------------------------------------------------------------------------


def robot_to_dict(robot) -> dict:
    """JSON-friendly robot (:meth:`~jaxcal._models._abstract.AbstractRobot.to_dict`): a DH table in
    degrees/mm, limits in degrees, tool point in mm; a :class:`~jaxcal.SerialChain` its URDF text
    with base/tip links; each with its non-geometric models."""
    return robot.to_dict()


def robot_from_dict(d: dict) -> AbstractRobot:
    """Inverse of :func:`robot_to_dict` (values within rounding of deg↔rad)."""
    if d.get("type") == "serial_chain":
        from .._models._urdf import chain_from_dict

        return nongeometric_from_dict(chain_from_dict(d), d.get("nongeometric"))
    if d.get("type") == "kinematic_tree":
        from .._models._urdf import tree_from_dict

        return nongeometric_from_dict(tree_from_dict(d), d.get("nongeometric"))
    robot = DHRobot.from_degrees(
        alpha_deg=d["alpha_deg"], a_mm=d["a_mm"], d_mm=d["d_mm"], theta_deg=d["theta_deg"],
        q_min_deg=d.get("q_min_deg"), q_max_deg=d.get("q_max_deg"), tool_mm=d.get("tool_mm", (0, 0, 0)),
        beta_deg=d.get("beta_deg"), convention=d.get("convention", "standard"),
        beta_joints=d.get("beta_joints", ()), name=d.get("name", "robot"),
    )
    return nongeometric_from_dict(robot, d.get("nongeometric"))  # compliance / harmonic models


_DH_COLUMNS = ("alpha_deg", "a_mm", "d_mm", "theta_deg")
#: accepted names of the joint-limit columns, before ``_deg``/``_rad``.
_LIMIT_NAMES = {"q_min": ("q_min", "qmin", "min", "lower", "q_lower"),
                "q_max": ("q_max", "qmax", "max", "upper", "q_upper")}
#: every accepted DH-file column: name -> (quantity, unit).
_DH_FILE_COLUMNS = {"a_mm": ("a", "mm"), "d_mm": ("d", "mm"), "joint": ("joint", "")} | {
    f"{name}_{unit}": (quantity, unit)
    for quantity, names in {"alpha": ("alpha",), "theta": ("theta",), "beta": ("beta",), **_LIMIT_NAMES}.items()
    for name in names
    for unit in ("deg", "rad")
}
_DH_ACCEPTED = (
    "alpha_deg, a_mm, d_mm, theta_deg (or alpha_rad, theta_rad); optional: beta_deg (or beta_rad), "
    "a joint-limit pair " + ", ".join(f"{lo}_deg/{hi}_deg" for lo, hi in zip(*_LIMIT_NAMES.values()))
    + " (each also *_rad), joint (1..N)"
)


def _tool_mm(path, text: str) -> tuple[float, float, float]:
    """``# tool_mm: x,y,z`` (or ``x;y;z``, where numbers may have decimal commas)."""
    sep = ";" if ";" in text else ","
    try:
        parts = [float(p.replace(",", ".") if sep == ";" else p) for p in text.split(sep)]
    except ValueError:
        parts = []
    if len(parts) != 3:
        raise ValueError(f"{path}: '# tool_mm: {text}' needs 3 numbers separated by ',' (or ';' with decimal commas)")
    return tuple(parts)


#: the DH-table file's ``# convention:`` values (case-insensitive) and the convention each names
_CONVENTION_NAMES = {"standard": "standard", "dh": "standard", "modified": "modified", "craig": "modified"}
#: the ``# key: value`` settings a DH-table file may carry
_DH_FILE_SETTINGS = ("name", "tool_mm", "convention")


def _convention(path, text: str) -> str:
    """``# convention: standard|modified`` (``dh``/``craig`` as synonyms) → the robot's convention."""
    value = text.strip().lower()
    if value not in _CONVENTION_NAMES:
        raise ValueError(f"{path}: '# convention: {text.strip()}' must be standard (or dh) or modified (or craig): "
                         "standard DH puts row i's alpha_i, a_i after joint i, modified (Craig) DH holds "
                         "alpha_(i-1), a_(i-1) in row i")
    return _CONVENTION_NAMES[value]


def _dh_file_columns(t, path) -> dict[str, np.ndarray]:
    """The DH-table columns of ``t`` by quantity (``alpha``, ``a``, ``d``, ``theta``, optional ``q_min``,
    ``q_max``, ``beta``, ``joint``), angles in degrees, checked as :func:`load_robot_csv` says."""
    unknown = [h for h in t.header if h not in _DH_FILE_COLUMNS]
    if unknown:
        raise ValueError(f"{path}: unknown DH table column(s) {unknown}; accepted: {_DH_ACCEPTED}")
    named: dict[str, list[str]] = {}
    for h in t.header:
        named.setdefault(_DH_FILE_COLUMNS[h][0], []).append(h)
    twice = [cols for cols in named.values() if len(cols) > 1]
    if twice:
        raise ValueError(f"{path}: columns {twice[0]} give the same quantity; keep one")
    missing = [c for c in _DH_COLUMNS if _DH_FILE_COLUMNS[c][0] not in named]
    if missing:
        raise ValueError(f"{path}: DH table lacks column(s) {missing}; header must include {','.join(_DH_COLUMNS)}"
                         " (angles may be *_rad)")
    if ("q_min" in named) != ("q_max" in named):
        have, lack = ("q_min", "q_max") if "q_min" in named else ("q_max", "q_min")
        raise ValueError(f"{path}: joint limit column {named[have][0]} needs its partner "
                         f"({'/'.join(n + '_deg' for n in _LIMIT_NAMES[lack])} or *_rad)")
    if not t.rows:
        raise ValueError(f"{path}: DH table has no joint rows")
    values = t.floats(t.header)
    cols = {}
    for k, h in enumerate(t.header):
        quantity, unit = _DH_FILE_COLUMNS[h]
        cols[quantity] = np.rad2deg(values[:, k]) if unit == "rad" else values[:, k]
    if "joint" in cols and not np.array_equal(cols["joint"], np.arange(1, len(t.rows) + 1)):
        raise ValueError(f"{path}: the joint column must number the rows 1..{len(t.rows)}, "
                         f"got {cols['joint'].tolist()}")
    return cols


def load_robot_csv(path, *, delimiter: str | None = None) -> DHRobot | KinematicTree:
    """A robot from a DH table file (lengths in mm, angles in degrees or radians); a file with
    ``# branch:`` lines is a kinematic tree, one DH table per branch (:func:`load_tree_csv`).

    Layout: optional ``# name: NAME``, ``# tool_mm: x,y,z`` (tool point in the flange frame, mm;
    default the flange origin) and ``# convention: standard|modified`` comment lines, a header
    row, then one row per joint::

        # name: hsr_jr680
        # convention: standard
        alpha_deg,a_mm,d_mm,theta_deg,q_min_deg,q_max_deg
        -90,250,653.5,0,-170,170
        ...

    ``# convention``: ``standard`` (Denavit–Hartenberg; also ``dh``; the default) or ``modified``
    (Craig's convention, in which many vendors publish their arms; also ``craig``): row ``i``
    then holds Craig's ``α_{i-1}, a_{i-1}`` with ``θ_i, d_i`` (:class:`jaxcal.DHRobot`). Any other
    ``# key: value`` line is an error naming the settings a DH table file takes (a free comment
    without a colon is fine), so a setting is never ignored silently.

    Columns, in any order, names stripped and case-insensitive:

    * required: ``alpha_deg`` (or ``alpha_rad``), ``a_mm``, ``d_mm``, ``theta_deg`` (or
      ``theta_rad``);
    * joint limits, both or neither (default ±180°): ``q_min_deg/q_max_deg``, or the synonyms
      ``qmin_deg/qmax_deg``, ``min_deg/max_deg``, ``lower_deg/upper_deg``,
      ``q_lower_deg/q_upper_deg``, each also in radians (``q_min_rad``, ``lower_rad``, ...);
    * ``beta_deg`` (or ``beta_rad``): nominal Hayati β; the joints where it is nonzero become
      the robot's ``beta_joints`` (to estimate β at a joint whose nominal β is 0, use
      ``robot.with_hayati(j)``);
    * ``joint``: joint numbers, checked to be 1, 2, ..., N.

    Any other column is an error (never dropped silently), as is a quantity given twice (e.g.
    ``q_min_deg`` and ``lower_deg``). The file may have a UTF-8 byte-order mark and use ``,``,
    ``;`` or tab as delimiter (recognised from the header, or ``delimiter=``); in ``;`` files
    numbers may use decimal commas. Errors name the file, the joint row, its line and column.
    """
    t = read_table(path, delimiter=delimiter, what="DH table file", row_name="joint row")
    path = t.path
    meta = {k.lower(): v for k, v in t.meta.items()}
    if "branch" in meta:  # one DH table per branch: a kinematic tree
        return load_tree_csv(path, delimiter=delimiter)
    if (other := [k for k in meta if k not in _DH_FILE_SETTINGS]):
        raise ValueError(f"{path}: '# {other[0]}: ...' is not a DH table file setting; the settings are "
                         + ", ".join(f"'# {k}:'" for k in _DH_FILE_SETTINGS) + " (a comment line without a colon "
                         "is free text)")
    convention = _convention(path, meta["convention"]) if "convention" in meta else "standard"
    cols = _dh_file_columns(t, path)
    beta = cols.get("beta")
    return DHRobot.from_degrees(
        alpha_deg=cols["alpha"], a_mm=cols["a"], d_mm=cols["d"], theta_deg=cols["theta"],
        q_min_deg=cols.get("q_min"), q_max_deg=cols.get("q_max"), beta_deg=beta,
        beta_joints=() if beta is None else (np.flatnonzero(beta) + 1).tolist(),
        tool_mm=_tool_mm(path, meta["tool_mm"]) if "tool_mm" in meta else (0.0, 0.0, 0.0),
        name=meta.get("name", pathlib.Path(path).stem), convention=convention,
    )


#: the ``# key: value`` settings a DH tree file may carry (``# branch:`` once per branch)
_TREE_FILE_SETTINGS = ("name", "convention", "branch")
#: the ``# branch:`` line's ``key=value`` words
_BRANCH_KEYS = ("parent", "tip", "tool_mm")
_BRANCH_FORM = "'# branch: NAME parent=root|PARENT@ROW [tip=TIP] [tool_mm=x,y,z]'"
#: a DH tree file's ``type`` column: a joint row (empty cell too) or a fixed row
_ROW_TYPES = {"": "revolute", "revolute": "revolute", "joint": "revolute", "fixed": "fixed"}


def _branch_lines(path: str) -> list[tuple[int, str]]:
    """``(line number, text after 'branch:')`` of each ``# branch:`` line, in file order."""
    out = []
    for number, line in enumerate(_decode(path).splitlines(), start=1):
        s = line.strip()
        if s.startswith("#") and ":" in s:
            key, value = s[1:].split(":", 1)
            if key.strip().lower() == "branch":
                out.append((number, value.strip()))
    return out


def _parse_branch(path, number: int, text: str) -> dict:
    """``{"name", "parent" (None: the root), "row" (1-based), "tip", "tool", "where", "line"}`` of one
    ``# branch:`` line (``where`` names it in errors)."""
    where = f"{path}: line {number} ('# branch: {text}')"
    words = text.split()
    if not words or "=" in words[0]:
        raise ValueError(f"{where}: a branch line starts with the branch's name: {_BRANCH_FORM}")
    opts: dict[str, str] = {}
    for w in words[1:]:
        key, eq, value = w.partition("=")
        key = key.lower()
        if not eq or key not in _BRANCH_KEYS or not value:
            raise ValueError(f"{where}: {w!r} is not one of parent=..., tip=..., tool_mm=...; the form is "
                             f"{_BRANCH_FORM}")
        if key in opts:
            raise ValueError(f"{where}: {key}= is given twice")
        opts[key] = value
    if "parent" not in opts:
        raise ValueError(f"{where}: says no parent= (parent=root for a branch on the base, parent=BRANCH@ROW for "
                         "one hanging from joint row ROW of an earlier branch)")
    parent, row = None, None
    if opts["parent"].lower() != "root":
        parent, at, r = opts["parent"].rpartition("@")
        if not at or not parent or not r.isdigit() or int(r) < 1:
            raise ValueError(f"{where}: parent={opts['parent']} must be parent=root or parent=BRANCH@ROW (ROW the "
                             "parent branch's row number, from 1)")
        row = int(r)
    if "tool_mm" in opts and "tip" not in opts:
        raise ValueError(f"{where}: tool_mm= needs tip=NAME (the tool point of that tip)")
    tool = (0.0, 0.0, 0.0) if "tool_mm" not in opts else tuple(
        number_list(opts["tool_mm"], 3, f"{where}: tool_mm="))
    return {"name": words[0], "parent": parent, "row": row, "tip": opts.get("tip"), "tool": tool, "where": where,
            "line": number}


def load_tree_csv(path, *, delimiter: str | None = None) -> KinematicTree:
    """A kinematic tree from a DH tree file: one standard DH table per branch, each after a
    ``# branch:`` line that names the branch, its parent and its tip (lengths mm, angles degrees
    or radians; :func:`load_robot_csv` reads such a file too).

    Layout: the DH table file's (one header row, the columns of :func:`load_robot_csv` but
    ``joint`` and ``beta``, optional ``# name:`` and ``# convention: standard`` lines), with the
    joint rows grouped by branch::

        # name: two_arms
        alpha_deg,a_mm,d_mm,theta_deg,q_min_deg,q_max_deg,type
        # branch: torso parent=root
        0,0,500,0,-170,170,
        # branch: left parent=torso@1 tip=left_tool tool_mm=0,0,120
        90,0,500,0,,,
        -90,300,0,0,-90,90,
        # branch: right parent=torso@1 tip=right_tool
        -90,0,500,0,,,
        90,300,0,0,-90,90,

    ``# branch: NAME parent=root|PARENT@ROW [tip=TIP] [tool_mm=x,y,z]``:

    * ``parent=root``: the branch's rows are a DH chain from the base frame.
    * ``parent=PARENT@ROW``: the branch hangs from the joint of row ``ROW`` (from 1) of the
      branch ``PARENT``, defined above. Its **first row is that joint again**, as this branch's
      DH table has it: the same joint (one reading, one set of error parameters), whose row may
      hold other ``d, θ, a, α`` than the parent's (``Tz(d)·Rz(θ)`` commutes with the joint's
      rotation; a torso axis whose arms leave it at ±15° is one joint with two rows). Its limit
      cells may be empty (they are the parent's) and must otherwise equal the parent's.
      So the branch, written as one DH chain, is its parent's rows before ``ROW`` (recursively)
      followed by its own rows.
    * ``tip=TIP``: the branch ends at a tip (the frame after its last row's ``Tx(a)·Rx(α)``);
      ``tool_mm=x,y,z``: that tip's tool point in its frame (mm, default its origin). A branch
      without a tip must carry other branches.

    Optional ``type`` column: ``revolute`` (or empty) for a joint, ``fixed`` for a row without a
    joint reading (its ``Rz(θ)·Tz(d)·Tx(a)·Rx(α)`` is a fixed transform, e.g. a camera frame
    after the last joint; its limit cells may be empty). Only revolute joints and standard DH.

    Joints are numbered in file order (parents' rows before their children's, a repeated first
    row not counted again) and named ``BRANCH_joint_K`` (``K`` the row number in the branch),
    their links ``BRANCH_link_K``; tips in file order, the first the default tip; the base link is
    ``base``.

    Raises:
        ValueError: naming the file and line: a row before the first ``# branch:`` line, a branch
            without rows or defined twice, a parent not defined above, a row number out of range
            or on a fixed row, a repeated first row that is fixed or has other limits, a tip name
            repeated, a modified-DH file, ``joint``/``beta`` columns, what :func:`load_robot_csv`
            refuses in the columns, or what :meth:`~jaxcal.KinematicTree.build` refuses.
    """
    from dataclasses import replace

    from .._models._dh_tree import TreeSpec, dh_head, dh_row, dh_tail

    t = read_table(path, delimiter=delimiter, what="DH tree file", row_name="joint row")
    path = t.path
    meta = {k.lower(): v for k, v in t.meta.items()}
    if (other := [k for k in meta if k not in _TREE_FILE_SETTINGS]):
        raise ValueError(f"{path}: '# {other[0]}: ...' is not a DH tree file setting; the settings are "
                         + ", ".join(f"'# {k}:'" for k in _TREE_FILE_SETTINGS))
    if "convention" in meta and _convention(path, meta["convention"]) != "standard":
        raise ValueError(f"{path}: a DH tree file holds standard DH rows; '# convention: {meta['convention']}' is "
                         "not read for trees (rewrite the rows in standard DH)")
    if (bad := [h for h in t.header if _DH_FILE_COLUMNS.get(h, ("",))[0] in ("joint", "beta")]):
        raise ValueError(f"{path}: column(s) {bad} are not read in a DH tree file (joints are named after their "
                         "branch; Hayati beta rows are for single chains)")
    types = ["revolute"] * len(t.rows)
    if "type" in t.header:
        k = t.header.index("type")
        for r, cells in enumerate(t.rows):
            value = cells[k].strip().lower()
            if value not in _ROW_TYPES:
                raise ValueError(f"{path}: {t.where(r, 'type')}: {cells[k]!r} is not a row type (revolute or empty: "
                                 "a joint; fixed: a fixed transform)")
            types[r] = _ROW_TYPES[value]
        keep = [i for i in range(len(t.header)) if i != k]
        t = replace(t, header=tuple(t.header[i] for i in keep), rows=[[c[i] for i in keep] for c in t.rows])
    branches = [_parse_branch(path, n, text) for n, text in _branch_lines(path)]
    if not branches:
        raise ValueError(f"{path}: a DH tree file has a {_BRANCH_FORM} line before each branch's rows")
    # each row's branch: the last '# branch:' line above it
    of_row = [int(np.searchsorted([b["line"] for b in branches], line)) - 1 for line in t.lines]
    if t.rows and of_row[0] < 0:
        raise ValueError(f"{path}: {t.where(0)} comes before the first '# branch:' line: every row belongs to a "
                         "branch")
    first = {r for r in range(len(t.rows)) if r == 0 or of_row[r] != of_row[r - 1]}
    inherit = [types[r] == "fixed" or (r in first and branches[of_row[r]]["parent"] is not None)
               for r in range(len(t.rows))]
    blank = np.zeros(len(t.rows), bool)
    limit_cols = [i for i, h in enumerate(t.header) if _DH_FILE_COLUMNS.get(h, ("",))[0] in ("q_min", "q_max")]
    if limit_cols:  # empty limit cells of fixed and repeated rows: no value to read
        rows = [list(c) for c in t.rows]
        for r, cells in enumerate(rows):
            if inherit[r] and all(not cells[i].strip() for i in limit_cols):
                blank[r] = True
                for i in limit_cols:
                    cells[i] = "0"
        t = replace(t, rows=rows)
    cols = _dh_file_columns(t, path)
    lo = cols.get("q_min", np.full(len(t.rows), -180.0))
    hi = cols.get("q_max", np.full(len(t.rows), 180.0))

    spec = TreeSpec()
    done: dict[str, list] = {}  # branch -> per row (joint index or None, (d, θ) in its origin, limits)
    tips: dict[str, str] = {}
    for b, br in enumerate(branches):
        rows = [r for r in range(len(t.rows)) if of_row[r] == b]
        name, where = br["name"], br["where"]
        if name in done:
            raise ValueError(f"{where}: branch {name!r} is defined twice")
        if not rows:
            raise ValueError(f"{where}: branch {name!r} has no rows")
        entries = []
        if br["parent"] is None:
            joint, prev, own = -1, np.eye(4), rows
        else:
            parent, k = br["parent"], br["row"]
            if parent not in done:
                raise ValueError(f"{where}: parent branch {parent!r} is not defined above (defined: "
                                 f"{', '.join(done) or 'none'}); a branch comes after its parent")
            if k > len(done[parent]):
                raise ValueError(f"{where}: {parent}@{k}: branch {parent!r} has {len(done[parent])} rows")
            joint, (pd, ptheta), lim = done[parent][k - 1]
            if joint is None:
                raise ValueError(f"{where}: {parent}@{k} is a fixed row; a branch hangs from a joint")
            r = rows[0]
            if types[r] == "fixed":
                raise ValueError(f"{path}: {t.where(r)}: the first row of branch {name!r} is joint {parent}@{k} "
                                 "again (as this branch's DH table has it), not a fixed row")
            if not blank[r] and not np.allclose((lo[r], hi[r]), lim, rtol=0, atol=1e-9):
                raise ValueError(f"{path}: {t.where(r)}: the first row of branch {name!r} is joint {parent}@{k} "
                                 f"again; its limits {lo[r]:g}..{hi[r]:g} deg differ from the parent's "
                                 f"{lim[0]:g}..{lim[1]:g} (leave the cells empty)")
            # the joint's origin holds the parent's Tz(d)·Rz(θ); this branch's own row opens it
            prev = np.linalg.inv(dh_head(pd, ptheta)) @ dh_head(cols["d"][r], cols["theta"][r]) @ dh_tail(
                cols["a"][r], cols["alpha"][r])
            entries.append((joint, (pd, ptheta), lim))
            own = rows[1:]
        for r in own:
            a, d, alpha, theta = cols["a"][r], cols["d"][r], cols["alpha"][r], cols["theta"][r]
            if types[r] == "fixed":
                prev = prev @ dh_row(a, d, alpha, theta)
                entries.append((None, None, None))
                continue
            kk = len(entries) + 1
            joint = spec.joint(joint, prev @ dh_head(d, theta), f"{name}_joint_{kk}", f"{name}_link_{kk}",
                               (lo[r], hi[r]))
            prev = dh_tail(a, alpha)
            entries.append((joint, (d, theta), (lo[r], hi[r])))
        done[name] = entries
        tip = br["tip"]
        if tip is not None:
            if tip in tips:
                raise ValueError(f"{where}: tip {tip!r} is already the tip of branch {tips[tip]!r}")
            if joint < 0:
                raise ValueError(f"{where}: tip {tip!r} is on no joint (branch {name!r} has only fixed rows on "
                                 "the root)")
            tips[tip] = name
            spec.tip(tip, joint, prev, br["tool"])
    if not tips:
        raise ValueError(f"{path}: no branch names a tip (tip=NAME on its '# branch:' line)")
    try:
        return spec.build(meta.get("name", pathlib.Path(path).stem), "base", None)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None


def save_robot_csv(robot: DHRobot, path) -> None:
    """Write ``robot``'s nominal DH table in the layout of :func:`load_robot_csv` (standard or
    modified DH, with its ``# convention:`` line)."""
    if robot.beta_joints:
        raise ValueError("the DH table file format holds DH tables without Hayati beta joints only "
                         "(save the robot with the calibration result's JSON instead)")
    d = robot_to_dict(robot)
    lines = [f"# name: {robot.name}", f"# convention: {robot.convention}",
             "# tool_mm: " + ",".join(repr(v) for v in d["tool_mm"]), ",".join(_DH_COLUMNS + ("q_min_deg", "q_max_deg"))]
    for j in range(robot.dof):
        lines.append(",".join(repr(float(d[c][j])) for c in _DH_COLUMNS + ("q_min_deg", "q_max_deg")))
    pathlib.Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def measurement_to_dict(m: MeasurementModel) -> dict:
    """``{"kind": "cable", "anchor_mm": [x, y, z]}``, ``{"kind": "position", "rotation": R,
    "translation_mm": t}``, ``{"kind": "pose", "orientation_scale": s, ...}`` or ``{"kind": "markers",
    "positions_mm": [[x, y, z], ...], "known": bool, ...}`` (``R`` the nominal
    ``[3, 3]`` sensor-from-base rotation, ``t`` mm); a :class:`~jaxcal.SessionMarkers` adds
    ``"sessions": {"frames", "placements", "markers", "frame_index", "placement_index"}`` (its
    labels, each placement's marker numbers and the training rows' indices) and per-placement
    ``positions_mm`` ``[P, N, 3]``."""
    from .._sensors._kind import sensor_kind

    try:
        kind = sensor_kind(str(getattr(m, "kind", "")))
    except ValueError:
        raise TypeError(f"cannot serialise measurement model {type(m).__name__}") from None
    return kind.model_to_dict(m)


def measurement_from_dict(d: dict) -> MeasurementModel:
    """Inverse of :func:`measurement_to_dict`."""
    from .._sensors._kind import sensor_kind

    return sensor_kind(str(d.get("kind")), "measurement kind").model_from_dict(d)


def _extra_to_dict(extra) -> dict | None:
    """Method state worth keeping (the RBF network); ``None`` otherwise."""
    if extra is None:  # most methods (not importing the RBF network's module for them)
        return None
    from ..methods import RBFNetwork

    if isinstance(extra, RBFNetwork):
        return {"type": "RBFNetwork", "fields": {f: np.asarray(getattr(extra, f)).tolist() for f in extra._fields}}
    return None


def _extra_from_dict(d: dict | None):
    if not d:
        return None, None
    if d.get("type") == "RBFNetwork":
        from ..methods import RBFNetwork, RBFNetworkMethod

        net = RBFNetwork(**{f: to_device(np.asarray(v)) for f, v in d["fields"].items()})
        return net, RBFNetworkMethod().predictor()
    raise ValueError(f"unknown saved method state {d.get('type')!r}")


# -- calibration results ----------------------------------------------------------------------


def result_to_dict(result: CalibrationResult, **info: Any) -> dict:
    """Everything in ``result`` as JSON-friendly data, plus ``info`` entries (e.g.
    ``test_metrics_mm=``, ``before_metrics_mm=``, ``settings=``) stored under their names.

    Units: angles in the DH table in degrees, lengths in mm; ``deviations`` and
    ``free_parameters`` in rad (angles) and mm (lengths), as :meth:`CalibrationResult.to_dict`.
    """
    out = {"format": RESULT_FORMAT}
    out |= result.to_dict()
    out["history_rmse_mm"] = [float(v) for v in np.asarray(result.history)]
    out["robot"] = robot_to_dict(result.robot)
    out["measurement"] = measurement_to_dict(result.measurement)
    out["free_names"] = list(result.space.free_names)
    if result.robot.dh_rows_deg() is not None:  # a robot described by a DH table
        out["calibrated_dh_table"] = {
            "columns": ["alpha_deg", "a_mm", "d_mm", "theta_deg"],
            "rows": np.asarray(result.dh_table()).tolist(),
        }
    if result.prior is not None:  # the prior itself (its description is under "prior"): a fleet prior divides it out
        out["prior_spec"] = prior_to_dict(result.prior)
    ident = getattr(result, "identifiability", None)
    if ident is not None:
        out["identifiability"] = ident.to_dict()
    extra = _extra_to_dict(result.extra)
    if extra is not None:
        out["method_state"] = extra
    for k, v in info.items():
        out[k] = v._asdict() if isinstance(v, Metrics) else v
    return to_jsonable(out)


def save_result(result: CalibrationResult, path, **info: Any) -> None:
    """Write ``result`` (and ``info``, see :func:`result_to_dict`) as JSON to ``path``."""
    text = json.dumps(result_to_dict(result, **info), indent=1, allow_nan=False)
    pathlib.Path(path).write_text(text + "\n", encoding="utf-8")


def load_result_dict(path) -> dict:
    """The raw JSON object of a result file (checked to be a jaxcal result)."""
    try:
        d = json.loads(pathlib.Path(path).read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise ValueError(f"{path} is not a JSON file: {e}") from None
    if not isinstance(d, dict) or not str(d.get("format", "")).startswith("jaxcal-calibration-result/"):
        raise ValueError(f"{path} is not a jaxcal calibration result (no 'format': {RESULT_FORMAT!r} entry)")
    return d


def result_data_file(path, d: dict) -> pathlib.Path | None:
    """The data file a result (raw dict ``d`` of the file at ``path``) was calibrated on, as found
    now: ``settings.data`` as given to ``jaxcal calibrate`` (relative to the working directory), else
    relative to the result's folder; ``None`` when the result names no single file or it is gone."""
    name = (d.get("settings") or {}).get("data")
    if not isinstance(name, str) or not name:
        return None
    given = pathlib.Path(name)
    for cand in (given, pathlib.Path(path).parent / given):
        if cand.is_file():
            return cand
    return None


def file_identity(path, digits: int = 12) -> str:
    """``"NAME (sha256 0123456789ab…)"``: a file's name and the first ``digits`` hex digits of the
    SHA-256 of its bytes (what the report prints to tell input files apart)."""
    import hashlib

    p = pathlib.Path(path)
    return f"{p.name} (sha256 {hashlib.sha256(p.read_bytes()).hexdigest()[:digits]}…)"


def load_result(path) -> CalibrationResult:
    """Read a result file written by :func:`save_result` (or ``jaxcal calibrate --out``).

    The returned :class:`~jaxcal.CalibrationResult` predicts and evaluates like the original;
    ``compile_time_s``/``wall_time_s`` are the saved values; the prior it was calibrated under
    is restored when the file has it (``"prior_spec"``: a fleet prior divides it out). The identifiability report is kept
    as its dict under ``result.identifiability`` (``None`` if absent); the uncertainty (posterior
    σ and covariance of the free parameters, σ̂) is restored as ``result.uncertainty`` when the
    file has it (what :meth:`~jaxcal.CalibrationResult.prediction_std` and the expected RMSE of
    :func:`jaxcal.evaluate_result` need); the saved diagnostics stay in the file
    (``load_result_dict``).
    """
    return result_from_dict(load_result_dict(path), path)


def result_from_dict(d: dict, path="result") -> CalibrationResult:
    """:func:`load_result` of a result's JSON object ``d`` (``path`` names it in errors)."""
    robot = robot_from_dict(d["robot"])
    measurement = measurement_from_dict(d["measurement"])
    layout = layout_for(robot, measurement)
    names = layout.names
    dev = dict(d["deviations"])
    for n in names:  # files written before the sensor-frame extras / a chain's tip errors existed
        if n.startswith(("base_", "tip_")) and n not in dev:
            dev[n] = 0.0
    missing = [n for n in names if n not in dev]
    if missing:
        raise ValueError(f"{path}: deviations lack {missing}")
    deviations = Deviations.unravel(to_device(np.asarray([dev[n] for n in names], np.float64)), layout)
    space = ParameterSpace.from_names(layout, d["free_names"])
    extra, predictor = _extra_from_dict(d.get("method_state"))
    tm = d.get("train_metrics_mm", {})
    result = CalibrationResult(
        method=d["method"],
        deviations=deviations,
        x=np.asarray([d["free_parameters"][n] for n in space.free_names], np.float64),
        space=space,
        robot=robot,
        measurement=measurement,
        history=np.asarray([from_json_number(v) for v in d.get("history_rmse_mm", [])], np.float64),
        n_iterations=int(d["n_iterations"]),
        iterations_to_converge=int(d["iterations_to_converge"]),
        status=Status[str(d["status"]).upper()],
        train_metrics=Metrics(*(from_json_number(tm.get(f)) for f in Metrics._fields)),
        wall_time_s=from_json_number(d.get("wall_time_s")),
        compile_time_s=from_json_number(d.get("compile_time_s")),
        hyperparameters=dict(d.get("hyperparameters", {})),
        extra=extra,
        predictor=predictor,
        prior=prior_from_dict(d["prior_spec"], Prior, str(path)) if d.get("prior_spec") else None,
        loss=str(d.get("loss") or "linear"),
        loss_scale_mm=d.get("loss_scale_mm"),
    )
    object.__setattr__(result, "identifiability", d.get("identifiability"))
    object.__setattr__(result, "uncertainty", Uncertainty.from_dict(d.get("uncertainty"), space.free_names,
                                                                    space.free_units))
    return result
