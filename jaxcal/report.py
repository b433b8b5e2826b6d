"""The paper's tables from a sweep: Table III (accuracy), IV (iterations, time), V (DH table).

Every table comes as plain text (terminal), Markdown, and rows of numbers (CSV / JSON):
:func:`accuracy_table`, :func:`convergence_table`, :func:`dh_table`, :func:`grid_table`, and
:func:`write_report` writes them all to a directory.

Conventions: ``mean ± std`` over the sweep's seeds (sample standard deviation, ``ddof=1``);
accuracy on each trial's held-out test split (mm); the paper's numbers are shown beside ours
for orientation only (its data are not ours: a real HSR-JR680 and an unstated sensor noise).
"""

from __future__ import annotations

import csv
import io
import json
import math
import pathlib
from collections.abc import Sequence

import numpy as np

from ._core._json import to_jsonable
from ._core._metrics import format_table
from ._experiments._sweep_results import PAPER_METHODS, SweepResult, _mean_std
from ._fit._result import Status

__all__ = [
    "PAPER_TABLE_III",
    "PAPER_TABLE_IV",
    "paper_label",
    "pm",
    "accuracy_rows",
    "accuracy_table",
    "convergence_rows",
    "convergence_table",
    "dh_rows",
    "dh_table",
    "grid_rows",
    "grid_table",
    "rows_to_csv",
    "write_report",
]

#: The paper's Table III (mm): model → (RMSE, MEAN, MAX) means (stds omitted).
PAPER_TABLE_III: dict[str, tuple[float, float, float]] = {
    "BC": (4.56, 4.45, 5.81),
    "ga": (0.839, 0.739, 1.635),
    "ekf": (1.385, 1.288, 2.623),
    "bso": (0.826, 0.713, 1.586),
    "lm": (0.682, 0.590, 1.163),
    "iwoa": (0.653, 0.562, 1.032),
    "rbfnn": (0.679, 0.588, 1.125),
    "adam": (0.756, 0.662, 1.336),
    "adamodw": (0.646, 0.552, 1.011),
}

#: The paper's Table IV: method → (iterations to converge in RMSE, time to converge / s).
PAPER_TABLE_IV: dict[str, tuple[int, float]] = {
    "ga": (58, 35.3), "ekf": (13, 11.6), "bso": (82, 20.9), "lm": (60, 33.1),
    "iwoa": (68, 32.0), "rbfnn": (22, 46.3), "adam": (15, 16.1), "adamodw": (10, 10.3),
}

_METRIC_NAMES = ("rmse", "mean", "max")


def paper_label(method: str) -> str:
    """``"M4"`` for ``"lm"`` etc. (Table II numbering), ``""`` for methods not in the paper."""
    return f"M{PAPER_METHODS.index(method) + 1}" if method in PAPER_METHODS else ""


def pm(mean: float, std: float, digits: int = 4) -> str:
    """``"0.6460 ± 1.2e-02"``: the paper's ``mean±std`` style (std in scientific notation)."""
    if mean is None or not math.isfinite(mean):
        return "—"
    if std is None or not math.isfinite(std):
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} ± {std:.1e}"


def _ms(a) -> tuple[float, float]:
    """Mean ± std over the finite entries."""
    a = np.asarray(a, np.float64)
    return _mean_std(a[np.isfinite(a)])


# -- Table III ------------------------------------------------------------------------------------


def accuracy_rows(result: SweepResult) -> list[dict]:
    """Rows of Table III: BC, each run, the statistical floor and the oracle (numbers)."""
    rows = []

    def add(model, method, metrics, note=""):
        row = {"model": model, "method": method}
        for f in _METRIC_NAMES:
            m, s = _ms(getattr(metrics, f)) if metrics is not None else (math.nan, math.nan)
            row[f"{f}_mean_mm"], row[f"{f}_std_mm"] = m, s
        paper = PAPER_TABLE_III.get(model if model == "BC" else method)
        for f, v in zip(_METRIC_NAMES, paper or (math.nan,) * 3):
            row[f"paper_{f}_mm"] = v
        row["note"] = note
        rows.append(row)

    add("BC", "nominal model", result.before, "before calibration")
    for r in result:
        add(paper_label(r.method) if r.grid_point is None else "", r.label, r.test)
    if result.floor is not None:
        f = result.floor.test
        row = {"model": "floor", "method": "σ√(1+p/(n−p−1))"}
        row |= {"rmse_mean_mm": f, "rmse_std_mm": math.nan,
                # Gaussian errors: E|e| = σ_e √(2/π)
                "mean_mean_mm": f * math.sqrt(2 / math.pi), "mean_std_mm": math.nan,
                "max_mean_mm": math.nan, "max_std_mm": math.nan}
        row |= {f"paper_{k}_mm": math.nan for k in _METRIC_NAMES}
        row["note"] = (f"statistical floor, σ = {result.settings.get('noise_std')} mm, p = {result.space.n_free}, "
                       f"n = {result.settings.get('n_train')}")
        rows.append(row)
    if np.any(np.isfinite(np.asarray(result.oracle.rmse, np.float64))):
        add("oracle", "true model", result.oracle, "the true robot on the same test data")
    return rows


def accuracy_table(result: SweepResult, *, markdown: bool = False, paper: bool = True) -> str:
    """Table III analogue: RMSE/MEAN/MAX (mm) on held-out data, mean ± std over seeds."""
    headers = ["Model", "Method", "RMSE/mm", "MEAN/mm", "MAX/mm"] + (["paper RMSE/mm"] if paper else [])
    rows = []
    for r in accuracy_rows(result):
        cells = [r["model"], r["method"]] + [pm(r[f"{f}_mean_mm"], r[f"{f}_std_mm"]) for f in _METRIC_NAMES]
        if paper:
            cells.append("—" if math.isnan(r["paper_rmse_mm"]) else f"{r['paper_rmse_mm']:g}")
        rows.append(cells)
    n = result.n_seeds
    title = (f"Table III. Calibration accuracy on held-out data, mean ± std over {n} seed(s) "
             f"({result.settings.get('n_test')} test samples per seed)")
    notes = [
        "BC: nominal model before calibration. floor: expected RMSE of an exact least-squares fit on fresh "
        "poses (MEAN floor = RMSE floor·√(2/π)). oracle: the true robot on the same test data.",
        "RMSE is the standard root mean square of the errors (the paper prints a garbled formula).",
    ]
    if paper:
        notes.append("paper: Chen & Li's Table III (a real robot, unknown sensor noise; for orientation only).")
    return _with_notes(format_table(rows, headers, markdown=markdown, title=title), notes, markdown)


def _with_notes(table: str, notes: Sequence[str], markdown: bool) -> str:
    if not notes:
        return table
    sep = "\n\n" if markdown else "\n"
    return table + sep + "\n".join(("" if markdown else "  ") + n for n in notes)


# -- Table IV -------------------------------------------------------------------------------------


def convergence_rows(result: SweepResult) -> list[dict]:
    """Rows of Table IV (numbers): iterations to converge, iterations run, time per trial, the
    estimated time to converge, compile time and status counts."""
    rows = []
    for r in result:
        its = _ms(r.iterations_to_converge)
        run = _ms(r.n_iterations)
        t = _ms(r.time_per_trial_s)
        tc = _ms(r.time_to_converge_s)
        codes, counts = np.unique(r.status, return_counts=True)
        paper = PAPER_TABLE_IV.get(r.method) if r.grid_point is None else None
        rows.append({
            "model": paper_label(r.method) if r.grid_point is None else "",
            "method": r.label,
            "iterations_to_converge_mean": its[0], "iterations_to_converge_std": its[1],
            "iterations_run_mean": run[0], "iterations_run_std": run[1],
            "time_per_trial_s_mean": t[0], "time_per_trial_s_std": t[1],
            "time_to_converge_s_mean": tc[0], "time_to_converge_s_std": tc[1],
            "compile_time_s": r.compile_time_s,
            "status": ", ".join(f"{int(k)} {Status(int(c)).name.lower()}" for c, k in zip(codes, counts)),
            "paper_iterations": paper[0] if paper else math.nan,
            "paper_time_s": paper[1] if paper else math.nan,
        })
    return rows


def _pm_g(mean, std, fmt=".1f"):
    if not math.isfinite(mean):
        return "—"
    return f"{mean:{fmt}} ± {std:{fmt}}"


def convergence_table(result: SweepResult, *, markdown: bool = False, paper: bool = True) -> str:
    """Table IV analogue: iterations to converge in RMSE and time, mean ± std over seeds."""
    headers = ["Model", "Method", "Iterations (RMSE)", "Iterations run", "Time/trial (s)", "Time (RMSE) (s)",
               "Compile (s)", "Status"] + (["paper its", "paper time/s"] if paper else [])
    rows = []
    for r in convergence_rows(result):
        cells = [
            r["model"], r["method"],
            _pm_g(r["iterations_to_converge_mean"], r["iterations_to_converge_std"]),
            _pm_g(r["iterations_run_mean"], r["iterations_run_std"]),
            _time_pm(r["time_per_trial_s_mean"], r["time_per_trial_s_std"]),
            _time_pm(r["time_to_converge_s_mean"], r["time_to_converge_s_std"]),
            f"{r['compile_time_s']:.1f}",
            r["status"],
        ]
        if paper:
            cells += ["—" if math.isnan(r["paper_iterations"]) else str(int(r["paper_iterations"])),
                      "—" if math.isnan(r["paper_time_s"]) else f"{r['paper_time_s']:g}"]
        rows.append(cells)
    dev = result.settings.get("n_devices", 1)
    title = f"Table IV. Iterations and time, mean ± std over {result.n_seeds} seed(s)"
    notes = [
        "Iterations (RMSE): first iteration after which the training RMSE stays within 1 % of its final value.",
        f"Time/trial: wall time of a chunk of trials / chunk size ({result.settings.get('per_device_batch')} "
        f"per device, {dev} device(s), {batching_label(result)}; compilation excluded). "
        + ("A vmapped LM chunk runs until its slowest trial converges. " if batching_label(result) == "vmap" else "")
        + "Time (RMSE) = Time/trial × Iterations (RMSE) / Iterations run.",
    ]
    if paper:
        notes.append("paper: Chen & Li's Table IV (seconds on their machine; not comparable to compiled JAX runs).")
    return _with_notes(format_table(rows, headers, markdown=markdown, title=title), notes, markdown)


def batching_label(result: SweepResult) -> str:
    """How the sweep ran each chunk of trials: ``"lax.map"`` or ``"vmap"``."""
    return "lax.map" if result.settings.get("batching") == "map" else "vmap"


def _time_pm(m, s):
    if not math.isfinite(m):
        return "—"
    if s == 0:  # every trial in one chunk: one wall time shared by all, no spread to show
        return f"{m:#.3g}"
    return f"{m:#.3g} ± {s:.1g}"


# -- Table V --------------------------------------------------------------------------------------


def _default_method(result: SweepResult, method: str | None) -> str:
    if method is not None:
        result[method]  # noqa: B018 - raises a clear KeyError
        return method
    for cand in ("adamodw", *result.labels):
        if cand in result.runs:
            return cand
    raise ValueError("the sweep has no runs")


def dh_rows(result: SweepResult, method: str | None = None, trial: int = 0) -> list[dict]:
    """Per-parameter rows of Table V for run ``method`` (default AdaModW) in ``trial``: nominal,
    true (simulation only), calibrated value, error = calibrated − true, and whether it was free.
    For a generic chain the rows are its per-joint corrections (deviations from the URDF origins,
    nominal 0)."""
    label = _default_method(result, method)
    cal = result.deviations(label, trial)
    true = result.true_deviation(trial)
    robot = result.robot
    free = set(result.space.free_names)
    if robot.dh_rows_deg() is None:  # not a DH table (a generic chain): its per-joint corrections
        return _chain_rows(robot, cal, true, free)
    rows = []
    groups = [("alpha", "deg"), ("a", "mm"), ("d", "mm"), ("theta", "deg")]
    if robot.beta_joints:
        groups.append(("beta", "deg"))
    for g, unit in groups:
        nom = np.asarray(getattr(robot, g), np.float64)
        c = nom + np.asarray(getattr(cal, g), np.float64)
        t = nom + np.asarray(getattr(true, g), np.float64) if true is not None else np.full_like(nom, np.nan)
        conv = np.rad2deg if unit == "deg" else (lambda v: v)
        for j in range(robot.dof):
            name = f"{g}_{j + 1}"
            if g == "beta" and (j + 1) not in robot.beta_joints:
                continue
            rows.append({
                "parameter": name, "unit": unit, "nominal": float(conv(nom[j])), "true": float(conv(t[j])),
                "calibrated": float(conv(c[j])), "error": float(conv(c[j] - t[j])), "free": name in free,
            })
    return rows


def dh_table(result: SweepResult, method: str | None = None, trial: int = 0, *, markdown: bool = False) -> str:
    """Table V analogue: the calibrated DH table (paper layout: joint × α/°, a/mm, d/mm, θ/°),
    then each parameter's nominal, true and calibrated value and error (calibrated − true). For a
    generic chain: joint × calibrated corrections (offset, dx, dy, dz, drx, dry, drz), then the
    same per-parameter comparison."""
    label = _default_method(result, method)
    rows = dh_rows(result, label, trial)
    if result.robot.dh_rows_deg() is None:  # not a DH table: a generic chain's corrections
        return _chain_table(result, label, trial, rows, markdown)
    by = {r["parameter"]: r for r in rows}
    dof = result.robot.dof
    layout = [[str(j + 1)] + [f"{by[f'{g}_{j + 1}']['calibrated']:.4f}" + ("" if by[f"{g}_{j + 1}"]["free"] else "*")
                              for g in ("alpha", "a", "d", "theta")] for j in range(dof)]
    t1 = format_table(layout, ["Joint i", "α_i/°", "a_i/mm", "d_i/mm", "θ_i/°"], markdown=markdown,
                      title=f"Table V. DH parameters after {label} calibration (trial {trial})")
    has_true = any(math.isfinite(r["true"]) for r in rows)
    headers = ["Parameter", "Unit", "Nominal", "True", "Calibrated", "Error (cal − true)", "Free"]
    detail = [[r["parameter"], r["unit"], f"{r['nominal']:.4f}", f"{r['true']:.4f}" if has_true else "—",
               f"{r['calibrated']:.4f}", f"{r['error']:+.4f}" if has_true else "—", "yes" if r["free"] else "no*"]
              for r in rows]
    t2 = format_table(detail, headers, markdown=markdown, title="Per-parameter comparison")
    notes = [
        "* not identifiable from these measurements (see the identifiability report): fixed at the nominal value. "
        "Its true deviation is absorbed by identifiable parameters (d2 and d3 act only as d2 + d3 when axes 2 and "
        "3 are parallel, d2 is kept; θ5 takes up Δa5 as −Δa5/L and d5 takes up Δα5 as L·Δα5, L the distance from "
        "joint 5 to the tool point; jaxcal.KEEP_PREFERENCE says which is kept), so those show errors too: large "
        "individual errors there do "
        "not mean a worse fit — the predicted measurements are the same.",
    ]
    sep = "\n\n"
    return _with_notes(t1 + sep + t2, notes, markdown)


def _chain_rows(robot, cal, true, free) -> list[dict]:
    """Table V rows of a generic chain (:class:`~jaxcal.SerialChain`): every per-joint correction
    (offset, dx, dy, dz, drx, dry; drz at prismatic joints) and the tip's (tip_dx … tip_drz) as a
    deviation from the URDF origin, so
    ``nominal`` is 0; angles in degrees, lengths (and prismatic offsets) in mm."""
    from ._models._chain import correction_entries

    truth = {} if true is None else {n: v for n, v, _ in correction_entries(robot, true)}
    return [{"parameter": n, "unit": u, "nominal": 0.0, "true": truth.get(n, math.nan), "calibrated": v,
             "error": v - truth.get(n, math.nan), "free": n in free} for n, v, u in correction_entries(robot, cal)]


def _chain_table(result: SweepResult, label: str, trial: int, rows: list[dict], markdown: bool) -> str:
    """Table V for a generic chain: joint × calibrated corrections (a last row for the tip
    transform), then per-parameter details."""
    from ._models._chain import GEOMETRIC_GROUPS, TIP_GROUPS

    robot = result.robot
    by = {r["parameter"]: r for r in rows}
    groups = [g for g, _ in GEOMETRIC_GROUPS]
    cell = lambda n: "" if n not in by else f"{by[n]['calibrated']:+.4f}" + ("" if by[n]["free"] else "*")  # noqa: E731
    layout = [[f"{j + 1} {robot.joint_names[j]}"] + [cell(f"{g}_{j + 1}") for g in groups] for j in range(robot.dof)]
    layout.append([f"tip → {robot.tip}", ""] + [cell(n) for _, names, _ in TIP_GROUPS for n in names])
    t1 = format_table(layout, ["Joint", "offset/° (mm)", "dx/mm", "dy/mm", "dz/mm", "drx/°", "dry/°", "drz/°"],
                      markdown=markdown, title=f"Table V. Joint corrections of {robot.name} ({robot.base} → {robot.tip}) "
                                               f"after {label} calibration (trial {trial}; deviations from the URDF origins)")
    has_true = any(math.isfinite(r["true"]) for r in rows)
    headers = ["Parameter", "Unit", "True", "Calibrated", "Error (cal − true)", "Free"]
    detail = [[r["parameter"], r["unit"], f"{r['true']:+.4f}" if has_true else "—", f"{r['calibrated']:+.4f}",
               f"{r['error']:+.4f}" if has_true else "—", "yes" if r["free"] else "no*"] for r in rows]
    t2 = format_table(detail, headers, markdown=markdown, title="Per-parameter comparison")
    notes = ["* not calibrated (not identifiable from these measurements, or fixed): kept at 0. A chain's six errors "
             "per joint are deliberately redundant; the identifiable subset absorbs the others' true deviations, so "
             "individual errors can be large while the predicted measurements are the same."]
    return _with_notes(t1 + "\n\n" + t2, notes, markdown)


# -- hyperparameter grids -------------------------------------------------------------------------


def grid_rows(result: SweepResult, method: str | None = None) -> list[dict]:
    """One row per grid point (runs with a ``grid_point``; of ``method`` if given)."""
    rows = []
    for r in result:
        if r.grid_point is None or (method is not None and r.method != method):
            continue
        row = {"method": r.method, **r.grid_point}
        for f in _METRIC_NAMES:
            row[f"test_{f}_mean_mm"], row[f"test_{f}_std_mm"] = _ms(getattr(r.test, f))
        row["train_rmse_mean_mm"], row["train_rmse_std_mm"] = _ms(r.train.rmse)
        row["iterations_to_converge_mean"], row["iterations_to_converge_std"] = _ms(r.iterations_to_converge)
        row["diverged"] = int(np.sum(r.status == int(Status.DIVERGED)))
        rows.append(row)
    return rows


def grid_table(result: SweepResult, method: str | None = None, *, markdown: bool = False) -> str:
    """Hyperparameter grid (ablation): test RMSE/MAX, training RMSE and iterations to converge
    per grid point, mean ± std over seeds."""
    rows = grid_rows(result, method)
    if not rows:
        raise ValueError("the sweep has no grid runs" + (f" of {method!r}" if method else ""))
    keys = [k for k in rows[0] if k not in ("method",) and not k.startswith(("test_", "train_", "iterations_",
                                                                                "diverged"))]
    headers = ["Method", *keys, "test RMSE/mm", "test MAX/mm", "train RMSE/mm", "Iterations (RMSE)", "Diverged"]
    cells = [[r["method"], *(f"{r[k]:g}" if isinstance(r[k], float) else str(r[k]) for k in keys),
              pm(r["test_rmse_mean_mm"], r["test_rmse_std_mm"]), pm(r["test_max_mean_mm"], r["test_max_std_mm"]),
              pm(r["train_rmse_mean_mm"], r["train_rmse_std_mm"]),
              _pm_g(r["iterations_to_converge_mean"], r["iterations_to_converge_std"]), str(r["diverged"])]
             for r in rows]
    title = f"Hyperparameter grid, mean ± std over {result.n_seeds} seed(s)"
    floor = result.floor
    notes = [f"statistical floor (test RMSE): {floor.test:.4f} mm"] if floor is not None else []
    return _with_notes(format_table(cells, headers, markdown=markdown, title=title), notes, markdown)


# -- files ----------------------------------------------------------------------------------------


def rows_to_csv(rows: Sequence[dict]) -> str:
    """CSV text of a list of row dicts (NaN written as empty cells)."""
    if not rows:
        return ""
    buf = io.StringIO()
    fields = list(rows[0])
    for r in rows[1:]:
        fields += [k for k in r if k not in fields]
    w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in r.items()})
    return buf.getvalue()


def write_report(result: SweepResult, out_dir, *, dh_method: str | None = None, trial: int = 0) -> dict[str, pathlib.Path]:
    """Write Tables III, IV, V (and the grid table if there are grid runs) as ``.txt``, ``.md``
    and ``.csv``, the whole summary as ``summary.json``, and ``report.md`` with every table.

    Returns ``{name: path}`` of the files written.
    """
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, pathlib.Path] = {}
    tables = [
        ("table3_accuracy", accuracy_table, accuracy_rows, {}),
        ("table4_convergence", convergence_table, convergence_rows, {}),
        ("table5_dh", dh_table, dh_rows, {"method": dh_method, "trial": trial}),
    ]
    if any(r.grid_point is not None for r in result):
        tables.append(("grid", grid_table, grid_rows, {}))
    md_parts, rows_by = [], {}
    for name, fmt, rows_fn, kw in tables:
        txt, md, rows = fmt(result, **kw), fmt(result, markdown=True, **kw), rows_fn(result, **kw)
        rows_by[name] = rows
        for ext, text in (("txt", txt), ("md", md), ("csv", rows_to_csv(rows))):
            p = out / f"{name}.{ext}"
            p.write_text(text + ("\n" if not text.endswith("\n") else ""), encoding="utf-8")
            files[f"{name}.{ext}"] = p
        md_parts.append(md)
    summary = {
        "summary": result.summary(),
        "table3_accuracy": rows_by["table3_accuracy"],
        "table4_convergence": rows_by["table4_convergence"],
        "table5_dh": rows_by["table5_dh"],
        "settings": result.settings,
    }
    p = out / "summary.json"
    p.write_text(json.dumps(to_jsonable(summary, nonfinite="null"), indent=1, default=repr) + "\n", encoding="utf-8")
    files["summary.json"] = p
    p = out / "report.md"
    p.write_text("\n\n".join(md_parts) + "\n", encoding="utf-8")
    files["report.md"] = p
    return files
