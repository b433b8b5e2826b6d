"""Delimited text files as spreadsheets and instruments write them, for the data and DH-table
readers: encoding and byte-order mark, delimiter, comment and metadata lines, case-insensitive
column names, and numbers whose errors name the file, the row, the line and the column.

Nothing here drops data silently: a cell that is not a number, a row of the wrong length, a
duplicated or nameless column with values is an error; what is skipped (blank lines, ``#``
comment lines, rows and trailing columns with no text at all) holds no data.
"""

from __future__ import annotations

import codecs
import csv
import math
import os
from dataclasses import dataclass

import numpy as np

__all__ = ["DELIMITERS", "Table", "gap_floats", "rad_to_deg_roundtrip", "read_table"]

#: delimiters recognised from the header line when none is given.
DELIMITERS = (",", ";", "\t")
_NAMES = {",": "','", ";": "';'", "\t": "tab"}


@dataclass(frozen=True)
class Table:
    """The text of one delimited file, split into cells (nothing converted yet).

    Attributes:
        path: the file path, as it starts every error message.
        meta: ``# key: value`` comment lines, keys and values stripped (case kept).
        header: column names, stripped and lower-case, in file order.
        rows: one list of cell texts per data row, each as long as ``header``.
        lines: the 1-based file line number of each data row.
        delimiter: the delimiter used (given or recognised).
        row_name: how errors call a row, e.g. ``"data row"`` (numbered from 1).
    """

    path: str
    meta: dict[str, str]
    header: tuple[str, ...]
    rows: list[list[str]]
    lines: list[int]
    delimiter: str
    row_name: str

    @property
    def decimal_comma(self) -> bool:
        """Whether numbers may be written with a decimal comma (``;``-delimited files only)."""
        return self.delimiter == ";"

    def where(self, r: int, column: str | None = None) -> str:
        """``"data row 3 (line 7), column q2_deg"`` for row index ``r`` (0-based)."""
        at = f"{self.row_name} {r + 1} (line {self.lines[r]})"
        return at if column is None else f"{at}, column {column}"

    def floats(self, columns) -> np.ndarray:
        """``[n_rows, len(columns)]`` float64 values of the named columns (header names).

        Raises:
            ValueError: an empty cell or one that is not a number (naming the row, line,
                column and text), or NaN/inf cells (counting the rows, naming the first).
        """
        idx = [self.header.index(c) for c in columns]
        out = np.empty((len(self.rows), len(idx)))
        comma = self.decimal_comma
        for r, row in enumerate(self.rows):
            for k, i in enumerate(idx):
                text = row[i].strip()
                try:
                    if not text or "_" in text:  # float() would read "1_000" as 1000
                        raise ValueError
                    out[r, k] = float(text.replace(",", ".") if comma else text)
                except ValueError:
                    what = "empty field" if not text else f"{row[i]!r} is not a number"
                    hint = "" if comma or "," not in text else " (decimal commas are read only in ';'-delimited files)"
                    raise ValueError(f"{self.path}: {self.where(r, columns[k])}: {what}{hint}") from None
        bad = np.flatnonzero(~np.isfinite(out).all(axis=1))
        if bad.size:
            r = int(bad[0])
            k = int(np.flatnonzero(~np.isfinite(out[r]))[0])
            raise ValueError(
                f"{self.path}: {bad.size} row(s) contain NaN/inf ({self.row_name}s {(bad + 1)[:10].tolist()}"
                f"{'...' if bad.size > 10 else ''}); first at {self.where(r, columns[k])}: {self.rows[r][idx[k]]!r}; "
                "remove or fix them — nothing is dropped silently"
            )
        return out


def number_list(text: str, n: int, what: str) -> list[float]:
    """The ``n`` finite numbers of a comma-separated text such as a metadata line's value
    (``"1200, 0, 300"``; ``;`` separates too); ``what`` names the text in the error.

    Raises:
        ValueError: a part is not a number, or there are not ``n`` finite numbers.
    """
    parts = [p for p in text.replace(";", ",").split(",") if p.strip()]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"{what} must be {n} comma-separated numbers, got {text!r}") from None
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"{what} must be {n} finite comma-separated numbers, got {text!r}")
    return vals


def _decode(path: str) -> str:
    with open(path, "rb") as f:
        raw = f.read()
    if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        return raw.decode("utf-16")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise ValueError(
            f"{path}: not UTF-8 text (byte 0x{raw[e.start]:02x} on line {line}); "
            "save it as UTF-8 (Excel: 'CSV UTF-8')"
        ) from None


def _sniff(path: str, header_line: str) -> str:
    counts = {d: header_line.count(d) for d in DELIMITERS}
    best = max(counts.values())
    found = [d for d in DELIMITERS if counts[d] == best]
    if best and len(found) > 1:
        raise ValueError(
            f"{path}: cannot tell the delimiter from the header line (as many of "
            f"{' and '.join(_NAMES[d] for d in found)}); give the delimiter (load_csv's delimiter argument)"
        )
    return found[0]


def read_table(path, *, delimiter: str | None = None, what: str = "file", row_name: str = "row") -> Table:
    """Read a delimited text file into a :class:`Table`.

    * Encoding: UTF-8, with or without a byte-order mark (Excel's "CSV UTF-8"); UTF-16 with
      a byte-order mark (Excel's "Unicode text"). Anything else is refused.
    * Lines: blank lines and lines starting with ``#`` are skipped anywhere; a ``#`` line
      holding ``:`` is also metadata (``# key: value``). The first other line is the header.
    * Delimiter: ``delimiter`` if given, otherwise the most frequent of ``,``, ``;`` and tab
      in the header line (a tie is an error; a header without any is one column).
    * Header: names are stripped and lower-cased; duplicates are an error. Columns with an
      empty name are dropped when all their cells are empty (trailing separators), and an
      error otherwise. Rows whose cells are all empty are skipped; a row with another number
      of cells than the header is an error, except for extra empty cells at its end and
      left-out cells of trailing nameless columns.

    Args:
        path: the file.
        delimiter: one character, or ``None`` to recognise it.
        what: the kind of file, for the not-found message (``"data file"``).
        row_name: how errors call a data row (``"data row"``).

    Raises:
        FileNotFoundError: no such file.
        ValueError: undecodable text, no header, an ambiguous delimiter, bad rows/columns.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"{what} not found: {path}")
    if delimiter is not None and (not isinstance(delimiter, str) or len(delimiter) != 1):
        raise ValueError(f"delimiter must be one character (e.g. ',', ';', '\\t'), got {delimiter!r}")
    meta: dict[str, str] = {}
    header_line, body = None, []
    for number, line in enumerate(_decode(path).splitlines(), start=1):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            if ":" in s:
                k, v = s[1:].split(":", 1)
                meta[k.strip()] = v.strip()
            continue
        if header_line is None:
            header_line = line
        else:
            body.append((number, line))
    if header_line is None:
        raise ValueError(f"{path}: no header row found")
    if delimiter is None:
        delimiter = _sniff(path, header_line)
    parse = lambda line: next(csv.reader([line], delimiter=delimiter))  # noqa: E731
    header = [h.strip().lower() for h in parse(header_line)]
    width = len(header)
    rows, lines = [], []
    for number, line in body:
        cells = parse(line)
        if not any(c.strip() for c in cells):
            continue
        while len(cells) > width and not cells[-1].strip():
            cells.pop()
        if len(cells) < width and not any(header[len(cells):]):  # cells of trailing nameless columns left out
            cells += [""] * (width - len(cells))
        if len(cells) != width:
            raise ValueError(
                f"{path}: {row_name} {len(rows) + 1} (line {number}) has {len(cells)} fields, "
                f"the header has {width} (delimiter {_NAMES.get(delimiter, repr(delimiter))})"
            )
        rows.append(cells)
        lines.append(number)
    nameless = [i for i, h in enumerate(header) if not h]
    for i in nameless:
        r = next((r for r, cells in enumerate(rows) if cells[i].strip()), None)
        if r is not None:
            raise ValueError(f"{path}: column {i + 1} has no name but holds {rows[r][i]!r} at {row_name} {r + 1} "
                             f"(line {lines[r]})")
    if nameless:
        keep = [i for i in range(width) if header[i]]
        header = [header[i] for i in keep]
        rows = [[cells[i] for i in keep] for cells in rows]
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise ValueError(f"{path}: duplicate column(s) {dup} (names are compared ignoring case and spaces)")
    return Table(path, meta, tuple(header), rows, lines, delimiter, row_name)


def rad_to_deg_roundtrip(q: np.ndarray) -> np.ndarray:
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


def gap_floats(t: Table, columns, width: int) -> np.ndarray:
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
