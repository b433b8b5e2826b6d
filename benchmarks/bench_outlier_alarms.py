"""Outlier alarms on clean and on planted data, through the command line (issue 53).

For every sensor kind ``jaxcal simulate`` writes for the HSR-JR680 (cable, position, pose, camera,
plane, point, distance) and two combined set-ups (plane + distance bar, position + fixed point),
20 seeds each: ``jaxcal simulate`` writes the files (modest row counts), ``jaxcal calibrate``
fits them (one file: its 20 % random test split scanned too; combined: ``--combine``, every row
trains) and we count the runs with any outlier warning (``jaxcal: warning: …: N outlier row…``)
on clean data. Then one row of one file gets a 10σ error (σ the file's simulated noise) and we
check that a warning names that file and that 1-based data row. The default false-alarm rate is
1 % per file (``--outlier-rate``), so a combined run of two files has about 2 % per run.

How a row gets its 10σ error: a reading file (cable length, position x, pose x, distance, a
camera image's first corner u) has 10σ added to that reading; a contact file (plane, point) has
no reading, so the row's joint readings are moved by the minimum-norm step that moves its first
residual entry by 10σ under the clean fit (a probe that slipped).

Everything runs in one process (``jaxcal.cli.main``), so compiled programs are reused across
seeds. Writes ``benchmarks/results/outlier_alarms_cpu.md``.

    PYTHONPATH=. python benchmarks/bench_outlier_alarms.py [--seeds 20]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import os
import pathlib
import re
import sys
import tempfile
import time

import numpy as np

OUT = pathlib.Path(__file__).resolve().parent / "results" / "outlier_alarms_cpu.md"

#: (name, files: ((kind, rows, extra simulate flags), ...))
SETUPS = (
    ("cable", (("cable", 200, ()),)),
    ("position", (("position", 200, ()),)),
    ("pose", (("pose", 200, ()),)),
    ("camera", (("camera", 20, ()),)),
    ("plane", (("plane", 200, ("--noise-std", "0.05")),)),
    ("point", (("point", 200, ("--noise-std", "0.05")),)),
    ("distance", (("distance", 200, ("--noise-std", "0.05")),)),
    ("plane + distance", (("plane", 300, ("--noise-std", "0.05")), ("distance", 150, ("--noise-std", "0.05")))),
    ("position + point", (("position", 200, ()), ("point", 200, ()))),
)

#: the reading column that gets the planted error
READING = {"cable": "length_mm", "position": "x_mm", "pose": "x_mm", "distance": "distance_mm", "camera": "u_1_px"}


def _run(argv) -> tuple[int, str, str]:
    from jaxcal.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main(argv)
        except SystemExit as e:  # argparse
            rc = int(e.code or 0)
    return rc, out.getvalue(), err.getvalue()


def _read(path):
    lines = pathlib.Path(path).read_text().splitlines()
    head = next(i for i, ln in enumerate(lines) if ln and not ln.startswith("#"))
    return lines[:head], list(csv.reader(lines[head:]))


def _write(path, comments, rows) -> None:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    pathlib.Path(path).write_text("\n".join(comments) + "\n" + buf.getvalue())


def _noise(comments) -> float:
    for c in comments:
        m = re.match(r"#\s*noise_std_(mm|px):\s*([0-9.eE+-]+)", c)
        if m:
            return float(m.group(2))
    raise ValueError("no noise line")


def _plant_reading(path, kind, row) -> None:
    comments, rows = _read(path)
    col = rows[0].index(READING[kind])
    rows[row][col] = repr(float(rows[row][col]) + 10.0 * _noise(comments))
    _write(path, comments, rows)


def _plant_contact(path, result_path, row) -> None:
    """Move row ``row``'s (1-based) joints so that its first residual entry under the fit moves by 10σ."""
    import jax
    import jax.numpy as jnp

    from jaxcal import load_csv
    from jaxcal._calibration._io import load_result

    res = load_result(result_path)
    data = load_csv(path)
    comments, rows = _read(path)
    q = jnp.asarray(data.q[row - 1: row])
    y = jnp.asarray(data.y[row - 1: row])
    g = np.asarray(jax.jacfwd(lambda qq: res.measurement.residual(res.robot, res.deviations, qq, y)[0, 0])(q))[0]
    dq = 10.0 * _noise(comments) * g / np.dot(g, g)  # rad
    for j in range(g.size):
        rows[row][j] = repr(float(rows[row][j]) + float(np.degrees(dq[j])))
    _write(path, comments, rows)


def _flagged(err: str) -> list[tuple[str, list[int]]]:
    """(file, rows) of every outlier warning in ``err``: ``…: N outlier rows at data rows 3, 17: …``,
    or for a reading of several points ``…: N outlier corners … at data row 12 (corner 31: …), data
    row 40 (…), above …``."""
    out = []
    for ln in err.splitlines():
        m = re.match(r"jaxcal: warning: (.+?)(?:, (?:training|test) rows)?: \d+ outlier rows? at data rows? ([0-9, …]+):",
                     ln)
        if m:
            out.append((m.group(1), [int(v) for v in re.findall(r"\d+", m.group(2))]))
            continue
        m = re.match(r"jaxcal: warning: (.+?)(?:, (?:training|test) rows)?: \d+ outlier \w+ .*?at (data row .*?), above ",
                     ln)
        if m:
            out.append((m.group(1), [int(v) for v in re.findall(r"data row (\d+)", m.group(2))]))
    return out


def one(name, files, seed, tmp) -> dict:
    d = pathlib.Path(tmp) / f"{name.replace(' + ', '_')}_{seed}"
    d.mkdir(parents=True, exist_ok=True)
    paths = []
    for kind, n, extra in files:
        p = d / f"{kind}.csv"
        rc, _, err = _run(["simulate", "--measurement", kind, "--samples", str(n), "--seed", str(seed), *extra,
                           "--out", str(p)])
        assert rc == 0, err
        paths.append(p)
    combined = len(paths) > 1
    outdir = d / "fit"
    argv = (["calibrate", *map(str, paths), "--robot", "hsr_jr680", "--combine", "--out-dir", str(outdir)]
            if combined else ["calibrate", str(paths[0]), "--robot", "hsr_jr680", "--out", str(d / "fit.json")])
    t = time.perf_counter()
    rc, _, err = _run(argv)
    clean_s = time.perf_counter() - t
    clean = _flagged(err)
    # the planted row: a random file and row of this seed
    rng = np.random.default_rng(seed)
    b = int(rng.integers(len(paths)))
    kind, n, _ = files[b]
    row = int(rng.integers(1, n + 1))
    if kind in READING:
        _plant_reading(paths[b], kind, row)
    else:
        _plant_contact(paths[b], outdir / f"{paths[b].stem}.json" if combined else d / "fit.json", row)
    rc2, _, err2 = _run(argv)
    planted = _flagged(err2)
    named = any(pathlib.Path(f) == paths[b] and row in rows for f, rows in planted)
    return {"rc": (rc, rc2), "clean": clean, "planted": planted, "named": named, "row": (paths[b].name, row),
            "clean_s": clean_s, "extra": [x for x in planted if not (pathlib.Path(x[0]) == paths[b] and row in x[1])]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--only", default=None, help="comma-separated set-up names")
    args = ap.parse_args()
    os.environ.setdefault("JAX_ENABLE_X64", "1")
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
    from _common import machine

    t0 = time.perf_counter()
    load0 = os.getloadavg()[0]
    rows = []
    only = None if args.only is None else set(args.only.split(","))
    with tempfile.TemporaryDirectory() as tmp:
        for name, files in SETUPS:
            if only is not None and name not in only:
                continue
            runs = [one(name, files, seed, tmp) for seed in range(args.seeds)]
            alarms = sum(bool(r["clean"]) for r in runs)
            named = sum(r["named"] for r in runs)
            extra = sum(bool(r["extra"]) for r in runs)
            failed = sum(any(c not in (0, 1) for c in r["rc"]) for r in runs)  # 1: implausible, still judged
            where = "; ".join(f"seed {s}: " + ", ".join(f"{pathlib.Path(f).name} {rr}" for f, rr in r["clean"])
                              for s, r in enumerate(runs) if r["clean"]) or "–"
            desc = " + ".join(f"{k} {n}" for k, n, _ in files)
            rows.append(f"| {name} | {desc} | {args.seeds} | {alarms} ({100 * alarms / args.seeds:.0f} %) | "
                        f"{named} / {args.seeds} | {extra} | {failed} | {np.median([r['clean_s'] for r in runs]):.1f} | {where} |")
            print(rows[-1], flush=True)
    lines = ["# Outlier alarms on clean and planted simulated data (issue 53)", "",
             f"Machine: {machine()}; load average {load0:.2f} at the start, {os.getloadavg()[0]:.2f} at the end; "
             f"{time.perf_counter() - t0:.0f} s in all. `PYTHONPATH=. python benchmarks/bench_outlier_alarms.py`.",
             "",
             "Each run: `jaxcal simulate` (seed = run), `jaxcal calibrate` (one file: default prior and loss, its "
             "20 % test split scanned too; combined: `--combine`), then again with one random row of one file "
             "carrying a 10σ error (σ the file's simulated noise: added to a reading; contact rows: joints moved "
             "so that the row's residual moves by 10σ). Default `--outlier-rate 0.01` per file, so a run of two "
             "files may alarm in about 2 % of clean runs. A reading of several points (a camera image's corners) "
             "is judged per point (half the file's rate, over its detected points) and as a whole row (the other "
             "half). No marker set-up: `jaxcal simulate` writes no marker files (marker-shaped rows are checked "
             "in NumPy by `tests/fit/test_outlier_threshold.py`).", "",
             "| set-up | files (rows) | runs | clean runs with an outlier warning | planted row named (file and row) "
             "| planted runs with another row named too | runs that ended in an error | median clean run / s | "
             "clean alarms (seed: file [rows]) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |", *rows]
    OUT.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
