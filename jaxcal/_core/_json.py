"""Conversion of results, settings and hyperparameters to JSON-ready Python values (one
definition for result files, sweep settings and fingerprints, and report summaries)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np


def to_jsonable(v, *, nonfinite: str = "string"):
    """``v`` with mappings → dicts (string keys), sequences and arrays (NumPy or JAX) → lists,
    NumPy scalars → Python scalars; anything else JSON cannot hold → its ``repr``.

    Args:
        nonfinite: how non-finite floats are written: ``"string"`` (NaN → ``null``, ±inf →
            ``"inf"`` / ``"-inf"``, so a reader can restore them), ``"null"`` (all → ``null``),
            or ``"keep"`` (left as floats: Python's ``json`` then writes ``NaN``/``Infinity``,
            which is not strict JSON; for hashing only).
    """
    if nonfinite not in ("string", "null", "keep"):
        raise ValueError(f"nonfinite must be 'string', 'null' or 'keep', got {nonfinite!r}")
    return _convert(v, nonfinite)


def from_json_number(v) -> float:
    """A number written by :func:`to_jsonable` back to float: ``null`` → NaN, ``"inf"``/``"-inf"``
    → ±inf."""
    return math.nan if v is None else float(v)


def _convert(v, nonfinite):
    if isinstance(v, Mapping):
        return {str(k): _convert(x, nonfinite) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_convert(x, nonfinite) for x in v]
    if hasattr(v, "__array__") and hasattr(v, "shape") and hasattr(v, "dtype"):  # NumPy / JAX arrays
        return _convert(np.asarray(v).tolist(), nonfinite)
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        v = float(v)
        if math.isfinite(v) or nonfinite == "keep":
            return v
        if nonfinite == "null" or math.isnan(v):
            return None
        return "inf" if v > 0 else "-inf"
    if v is None or isinstance(v, str):
        return v
    return repr(v)
