"""One self-contained HTML page for a calibration result, a combined result or an evaluation (``jaxcal
report X.json --html``).

The page holds everything a person needs to judge a calibration: a summary (data, model, method,
objective, status, warnings), the before/after tables, a residual histogram, the residuals
against each joint, the error over the workspace, the parameter table with posterior σ and a
correlation heat map, the identifiability report and the outlier rows. Figures are matplotlib
PNGs inlined as base64 (:mod:`jaxcal.plots`), so the file needs no network and no other file; the
markup is well-formed XHTML-compatible HTML5 (a test parses it as XML) and the layout is one
column of at most 60 em, so nothing scrolls sideways.
"""

from __future__ import annotations

import base64
import datetime
import html
import io
import json
import math
import pathlib

import numpy as np

__all__ = ["write_html", "html_report", "combined_html_report"]

_CSS = """
body { font-family: system-ui, -apple-system, 'Segoe UI', sans-serif; margin: 0 auto; max-width: 60em;
       padding: 1em; color: #222; line-height: 1.4; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; border-bottom: 1px solid #ccc; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.9em; max-width: 100%; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.5em; text-align: right; overflow-wrap: break-word; }
th, td:not(.l) { white-space: nowrap; }
th { background: #f2f2f2; } td.l, th.l { text-align: left; }
img { max-width: 100%; height: auto; display: block; margin: 0.5em 0; }
.warn { color: #8a4b00; } .bad { color: #b00020; font-weight: bold; } .ok { color: #1b5e20; font-weight: bold; }
.small { font-size: 0.85em; color: #555; } code { overflow-wrap: anywhere; }
"""


def _e(x) -> str:
    return html.escape(str(x), quote=True)


def _num(v, digits: int = 4) -> str:
    if v is None:
        return "—"
    v = float(v)
    if not math.isfinite(v):
        return str(v)
    return f"{v:.{digits}g}" if abs(v) >= 1e4 or (v != 0 and abs(v) < 1e-3) else f"{v:.{digits}f}"


def _table(headers, rows, left: int = 1) -> str:
    """An HTML table; the first ``left`` columns left-aligned; ``headers`` ``None``: no header row.
    Headers and numbers do not wrap; left-aligned text wraps between words."""
    out = ["<table>"] if headers is None else [
        "<table><tr>" + "".join(f'<th class="l">{_e(h)}</th>' if i < left else f"<th>{_e(h)}</th>"
                                for i, h in enumerate(headers)) + "</tr>"]
    for r in rows:
        out.append("<tr>" + "".join(f'<td class="l">{_e(c)}</td>' if i < left else f"<td>{_e(c)}</td>"
                                    for i, c in enumerate(r)) + "</tr>")
    return "".join(out) + "</table>"


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return f'<img alt="figure" src="data:image/png;base64,{data}"/>'


def _metrics_table(metrics: dict, unit: str = "mm") -> str:
    rows = [[name, _num(m.get("rmse")), _num(m.get("mean")), _num(m.get("max"))] for name, m in metrics.items()]
    return _table(["data", f"RMSE / {unit}", f"MEAN / {unit}", f"MAX / {unit}"], rows)


def _points(robot_dict, q_deg, tip: str | None = None) -> np.ndarray | None:
    """Tool points of the nominal robot at ``q_deg`` (mm, base frame; ``tip``: a kinematic tree's
    tip, default its default tip), or None if the model cannot."""
    try:
        from .._calibration._evaluate import joints_from_file_units
        from .._calibration._io import robot_from_dict
        from .._core._precision import to_device
        from .._models._kinematics import fk_position_jit

        robot = robot_from_dict(robot_dict)
        q = joints_from_file_units(robot, q_deg)  # degrees (mm at prismatic joints) → rad
        return fk_position_jit(robot, to_device(q), tool=True, tip=tip)  # one compiled program, not ~40 small ones
    except Exception:  # noqa: BLE001 - a figure is optional; the page says it is missing
        return None


def _verdicts(d: dict):
    """The result's verdicts (:class:`~jaxcal._fit._verdicts.Verdicts`), or ``None`` in a file
    written before they were saved."""
    from .._fit._verdicts import Verdicts

    return Verdicts.from_dict((d.get("diagnostics") or {}).get("verdicts"))


def _set_by_prior(d: dict) -> set[str]:
    """Names of the free parameters the prior rather than the data holds in a result dict: their
    verdict (:func:`_verdicts`), as the command line marks them with †; in an older file, the
    diagnostics' weak parameters; none without a prior."""
    v = _verdicts(d)
    if v is not None:
        return set(v.by_prior)
    return set((d.get("diagnostics") or {}).get("weak_parameters") or []) if d.get("prior") else set()


def _marks_legend(by_prior: set[str]) -> str:
    """The legend of † (held by the prior) and * (not calibrated), as ``jaxcal calibrate`` prints it."""
    from .._fit._verdicts import HELD_MARK, PRIOR_MARK

    return "; ".join(([PRIOR_MARK] if by_prior else []) + [HELD_MARK])


def _evidence(d: dict) -> str | None:
    """The prior's scale the evidence chose (``--prior evidence``), with its uncertainty, or ``None``."""
    from .._fit._evidence import EvidenceScales

    ev = EvidenceScales.from_dict(d.get("prior_evidence"))
    return None if ev is None else ev.describe()


def _fixed(v) -> str:
    """A value in ° or mm at the tables' precision (4 decimals; one that rounds to zero as
    ``0.0000``, not ``-7.435e-09``)."""
    return f"{round(float(v), 4) + 0.0:.4f}" if math.isfinite(float(v)) else str(v)


def _parameters(d: dict, labels: dict | None = None) -> str:
    """Parameter table (Δ ± σ in ° / mm; angles wrapped to (−180°, 180°]; † set by the prior) and
    the correlation heat map of a result dict; ``labels``: ``{name: where it acts}`` for a column
    of them (a kinematic tree's branch and joint, :meth:`~jaxcal.KinematicTree.entry_labels`)."""
    from .._core._trig import wrap_angle_deg
    from ..plots import correlation_heatmap

    free = d.get("free_parameters", {})
    units = d.get("units", {})
    unc = d.get("uncertainty") or {}
    std = unc.get("std", {})
    by_prior = _set_by_prior(d)
    rows = []
    for n, v in free.items():
        u = units.get(n, "")
        f = math.degrees if u == "rad" else (lambda x: x)
        s = std.get(n)
        value = float(wrap_angle_deg(f(v))) if u == "rad" else v
        rows.append([n + ("†" if n in by_prior else "")] + ([labels.get(n, "")] if labels else [])
                    + ["°" if u == "rad" else u,
                     _fixed(value) if u in ("rad", "mm") else _num(value),
                     "—" if s is None else _num(f(s), 3),
                     "" if s in (None, 0) or not math.isfinite(s) else f"{abs(v) / s:.1f}"])
    parts = [f"<p>{len(free)} calibrated parameters: deviation Δ from the nominal value (sensor extras: from the "
             "guess) and one posterior standard deviation σ"
             + (f"; residual σ̂ {_num(unc.get('noise_std_mm'))} mm" if unc.get("noise_std_mm") is not None else "")
             + (f"; {len(by_prior & set(free))} of them (†) held by the prior rather than determined by the data: their values "
                "are the prior's, not results" if by_prior & set(free) else "")
             + ".</p>", _table(["parameter"] + (["branch / joint"] if labels else []) + ["unit", "Δ", "σ", "|Δ|/σ"],
                               rows, left=2 if labels else 1)]
    dh = d.get("calibrated_dh_table")
    if dh:
        groups = [c.split("_")[0] for c in dh["columns"]]  # alpha_deg → alpha

        def cell(g, j, v):
            name = f"{g}_{j + 1}"
            return _fixed(v) + ("†" if name in by_prior else "" if name in free else "*")

        parts.append("<p>Calibrated DH table (angles in (−180°, 180°]):</p>" + _table(
            ["joint", *dh["columns"]], [[j + 1, *(cell(g, j, v) for g, v in zip(groups, r))]
                                        for j, r in enumerate(dh["rows"])])
            + f'<p class="small">{_e(_marks_legend(by_prior))}</p>')
    cov = unc.get("covariance")
    if cov and len(std) > 1:
        parts.append(_png(correlation_heatmap(cov, list(std))))
    return "".join(parts)


def _identifiability(ident: dict | None, verdicts=None) -> str:
    """The identifiability section: the rank, each candidate's verdict (``verdicts``, as
    ``jaxcal calibrate`` prints it; an older file: the rank test's subset) and what the
    parameters left out act like."""
    if not ident:
        return "<p>No identifiability report in this file.</p>"
    deps = ident.get("dependencies", {})
    covered = set(ident.get("prior_covered", []))

    def rows(names):
        return [[n, " ".join(f"{c:+.4g}·{m}" for c, m in deps.get(n, [])) or "no effect on the measurements"]
                for n in names]

    head = ["parameter", "a change δ acts like (coefficient · parameter · δ; angles in rad, lengths in mm)"]
    out = [f"<p>Identification Jacobian rank {ident.get('rank')} of {ident.get('n_free')} candidate parameters "
           f"(column-scaled, rtol {ident.get('rtol')}); condition number of the identifiable subset "
           f"{_num(ident.get('condition_number'), 3)}.</p>"]
    if verdicts is not None:
        from .._fit._verdicts import DATA, HELD, PRIOR, prior_lines

        names = list(ident.get("identifiable", [])) + list(ident.get("unidentifiable", []))
        names = [n for n in verdicts.verdict if n in set(names)]  # the space's order
        of = {n: verdicts.verdict[n] for n in names}
        out.append(f"<p>Determined by the data: {_e(', '.join(n for n in names if of[n] == DATA) or 'none')}</p>")
        out += [f"<p>{_e(line[0].upper() + line[1:])}</p>" for line in prior_lines(verdicts, names)]
        held = [n for n in names if of[n] == HELD]
        if held:
            out.append(f"<p>Not calibrated (*), held at their start value: {_e(', '.join(held))}</p>")
        left = [n for n in ident.get("unidentifiable", []) if of.get(n) in (PRIOR, HELD)]
        if left:
            out.append("<p>What the parameters the data cannot tell apart act like:</p>" + _table(head, rows(left), left=2))
        return "".join(out)
    out.append(f"<p>Identifiable from the data (calibrated): {_e(', '.join(ident.get('identifiable', [])))}</p>")
    # as the text report: under a prior (MAP) the prior sets these directions; only the rest is held
    by_prior = [n for n in ident.get("unidentifiable", []) if n in covered]
    held = [n for n in ident.get("unidentifiable", []) if n not in covered]
    if by_prior:
        out.append("<p>Not identifiable from the data alone, estimated under the prior (maximum a posteriori: "
                   "the prior sets these directions); a change acts like:</p>" + _table(head, rows(by_prior), left=2))
    if held:
        out.append("<p>Not identifiable" + (" and without a prior" if covered else "")
                   + " (held at their start value); a change acts like:</p>" + _table(head, rows(held), left=2))
    return "".join(out)


def _outliers(parts_rows: dict, flagged: dict) -> str:
    """Outlier rows per part: ``flagged`` ``{part: [1-based data rows]}``."""
    out = []
    for part, rows in flagged.items():
        if not rows:
            continue
        info = parts_rows.get(part)
        table = []
        for r in rows:
            if info is not None and r in info["row"]:
                i = info["row"].index(r)
                table.append([part, r, _num(info["before_mm"][i]), _num(info["after_mm"][i]),
                              ", ".join(f"{v:.1f}" for v in info["q_deg"][i])])
            else:
                table.append([part, r, "", "", ""])
        out.append(_table(["data", "row (1-based)", "before / mm", "after / mm", "joints / °"], table, left=1))
    return "".join(out) or "<p>No outlier row after calibration.</p>"


def _figures(parts_rows: dict, robot_dict: dict, heading: str = "h2", tip: str | None = None) -> str:
    """The residual histogram, the residuals against each joint and the error over the workspace of
    ``parts_rows`` (``{part: {"row", "q_deg", "before_mm", "after_mm"}}``), under ``heading`` s;
    ``tip``: the tree tip whose tool points the workspace figure places the errors at."""
    from ..plots import (
        WORKSPACE_COLOUR_QUANTILE,
        residual_histogram,
        residuals_vs_joints,
        workspace_colour_max,
        workspace_errors,
    )

    if not parts_rows:
        return "<p>This file holds no per-row residuals (written before they were saved); re-run the command.</p>"
    arr = {k: (np.asarray(v["before_mm"], np.float64), np.asarray(v["after_mm"], np.float64),
               np.asarray(v["q_deg"], np.float64)) for k, v in parts_rows.items() if v["row"]}
    # histogram and workspace colours: error sizes (a draw-wire's per-row error is signed)
    out = [f"<{heading}>Residuals</{heading}>", _png(residual_histogram({k: (np.abs(b), np.abs(a)) for k, (b, a, _) in arr.items()})),
           _png(residuals_vs_joints({k: (q, a) for k, (_, a, q) in arr.items()},
                                    joint_names=robot_dict.get("joint_names")))]
    q = np.concatenate([q for _, _, q in arr.values()])
    e = np.abs(np.concatenate([a for _, a, _ in arr.values()]))
    pts = _points(robot_dict, q, tip)
    out.append(f"<{heading}>Error over the workspace</{heading}>")
    if pts is None:
        out.append("<p>The tool points of this robot model could not be computed.</p>")
    else:
        out.append(_png(workspace_errors(pts, e)) + f'<p class="small">The colour scale is clipped at the '
                   f"{100 * WORKSPACE_COLOUR_QUANTILE:g}th percentile of the errors ({_num(workspace_colour_max(e))} "
                   "mm): larger errors take the top colour.</p>")
    return "".join(out)


def _summary(items) -> str:
    return _table(None, [[k, v] for k, v in items if v not in (None, "")], left=2)


def _warnings(ws) -> str:
    if not ws:
        return '<p class="ok">No warnings.</p>'
    return "<ul>" + "".join(f'<li class="warn">{_e(w)}</li>' for w in ws) + "</ul>"


def _provenance(source: str, inputs, created: str | None) -> str:
    """The line under the title: jaxcal's version, when the page was made and what it was made from
    (``inputs``: :func:`~jaxcal._calibration._io.file_identity` strings)."""
    from .. import __version__

    made = f"jaxcal {__version__} report" + (f", made {created}" if created else "")
    files = "; ".join(inputs) if inputs else source
    return f'<p class="small">{_e(made)}, of <code>{_e(files)}</code></p>'


def html_report(d: dict, *, source: str = "", result: dict | None = None, inputs=(), created: str | None = None
                ) -> str:
    """The page for a result dict (``jaxcal calibrate --out``) or an evaluation dict (``jaxcal evaluate
    --out``; ``result``: the calibration it checks, when available, for its parameter sections).
    ``inputs``: the files it was made from, as ``"name (sha256 …)"`` (:func:`write_html` gives the
    JSON file and the data file(s) it names, where found); ``created``: when (a date and time)."""
    fmt = str(d.get("format", ""))
    is_eval = fmt.startswith("jaxcal-evaluation/")
    robot = d.get("robot", {})
    meas = d.get("measurement", {})
    model = f"{robot.get('name', '?')} ({'URDF chain' if robot.get('type') == 'serial_chain' else 'DH table'}), " \
            f"{meas.get('kind', '?')} measurements"
    title = ("Evaluation of a calibration on new data" if is_eval else "Calibration report") + f": {robot.get('name', '')}"
    body = [f"<h1>{_e(title)}</h1>", _provenance(source, inputs, created), "<h2>Summary</h2>"]
    unit = d.get("unit") or ("px" if meas.get("kind") == "camera" else "mm")  # the errors' unit
    if is_eval:
        m = d["metrics_mm"]
        verdict = (f'<p class="bad">The calibrated robot predicts these data WORSE than the nominal robot '
                   f'(RMSE {_num(m["after"]["rmse"])} vs {_num(m["before"]["rmse"])} {unit}).</p>' if d.get("worse") else
                   f'<p class="ok">The calibrated robot predicts these data with {_num(m["after"]["rmse"])} {unit} RMSE, '
                   f'the nominal robot with {_num(m["before"]["rmse"])} {unit}.</p>')
        exp = d.get("expected_rmse_mm")
        if exp is not None:
            from .._calibration._evaluate import EXPECTED_FACTOR

            verdict += (f'<p class="bad">{_num(m["after"]["rmse"])} {unit} is more than {EXPECTED_FACTOR:g}× the {_num(exp)} {unit} the '
                        "calibration expects of itself here (its σ̂ and parameter uncertainty at these poses): "
                        "has the set-up changed since, or do these poses lie outside the calibrated workspace?</p>"
                        if d.get("worse_than_expected") else
                        f'<p class="ok">The calibration expected {_num(exp)} {unit} here (its σ̂ and parameter '
                        "uncertainty at these poses).</p>")
        body += [verdict, _summary([("calibration", d.get("result")), ("new data", f"{d.get('data')}: "
                                                                                     f"{d.get('n_samples')} rows"),
                                    ("model", model), ("method", f"{d.get('method')} ({d.get('status')})"),
                                    ("objective", d.get("objective")),
                                    ("sensor extras", d.get("extras", {}).get("message"))])]
        labels = {"raw_nominal": "raw nominal (guessed extras, nothing estimated)",
                  "before": "before: nominal robot, extras from the data",
                  "after": "after: calibrated robot, extras "
                           + {"registered": "re-registered", "result": "from the result",
                              "none": "(no set-up extras to register)"}.get(d.get("extras", {}).get("source"), "")}
        order = [k for k in ("raw_nominal", "before", "after") if k in m]
        body += ["<h2>Before / after</h2>", _metrics_table({labels[k]: m[k] for k in order}, unit)]
        parts_rows = {"new data": d["rows"]} if d.get("rows") else {}
        flagged = {"new data": d.get("outlier_rows", [])}
        res_d = result or {}
        warnings_ = (res_d.get("diagnostics") or {}).get("warnings", [])
    else:
        s = d.get("settings", {})
        res_d = d
        diag = d.get("diagnostics") or {}
        warnings_ = diag.get("warnings", [])
        if s.get("outlier_rows_after"):  # the diagnostics count training rows from 0; the page uses data rows
            rows_txt = ", ".join(map(str, s["outlier_rows_after"][:20]))
            warnings_ = [f"{len(s['outlier_rows_after'])} outlier row(s) at data rows {rows_txt} (see Outlier rows)"
                         if w.startswith("training data: ") and " outlier row" in w else w for w in warnings_]
        data = s.get("data", "")
        if s.get("combined"):  # one block of `jaxcal calibrate --combine`
            data = (f"{data}: {s.get('n_samples')} rows, every one trains (one block of a combined fit of "
                    f"{', '.join(s['combined'])}: no held-out rows)")
        elif s:
            data = f"{data}: {s.get('n_samples')} rows → {s.get('n_train')} train, {s.get('n_test')} test" + (
                f" (test file {s['test_file']})" if s.get("test_file") else f" (random split, seed {s.get('seed')})")
        status = f"{d.get('status')} — {d.get('message')}; {'plausible' if d.get('plausible') else 'IMPLAUSIBLE'}"
        body += [_summary([("data", data), ("model", model), ("method", f"{d.get('method')}, {d.get('n_iterations')} "
                                                                         "iterations"),
                           ("objective", s.get("objective") or f"{d.get('loss')} loss; {d.get('prior') or 'no prior'}"),
                           ("prior scale", _evidence(d)),
                           ("status", status), ("sensor extras", diag.get("extras")),
                           ("test-file extras", (d.get("test_extras") or {}).get("message"))])]
        body += ["<h2>Before / after</h2>",
                 _metrics_table(d.get("metrics_mm") or {"train, after": d.get("train_metrics_mm", {})}, unit),
                 '<p class="small">before = the nominal robot with the sensor extras estimated from the data '
                 "(closed-form start); raw nominal = the guessed extras, nothing estimated.</p>"]
        parts_rows = d.get("rows") or {}
        flagged = {"train": s.get("outlier_rows_after", [])}
    body += ["<h2>Warnings</h2>", _warnings(warnings_)]
    body.append(_figures(parts_rows, robot))
    if res_d:
        body += ["<h2>Parameters</h2>", _parameters(res_d), "<h2>Identifiability</h2>",
                 _identifiability(res_d.get("identifiability"), _verdicts(res_d))]
    else:
        body.append("<p>The calibration result file was not found: no parameter sections.</p>")
    body += ["<h2>Outlier rows</h2>", '<p class="small">Rows whose residual after calibration is an outlier in '
             "their own robust σ̂ (1.4826·MAD), at the threshold clean Gaussian rows of the file cross with the "
             "chance --outlier-rate (1 % by default; data-row numbers, 1-based).</p>", _outliers(parts_rows, flagged)]
    return _page(title, body)


def _page(title: str, body) -> str:
    """One self-contained HTML page: the head (title, the style sheet) and the ``body`` pieces."""
    return ('<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"/>'
            '<meta name="viewport" content="width=device-width, initial-scale=1"/>'
            f"<title>{_e(title)}</title><style>{_CSS}</style></head><body>"
            + "".join(body) + "</body></html>\n")


def _restricted(d: dict, names, *, table: bool = True, heatmap: bool = True) -> dict:
    """A result dict with only ``names`` among its free parameters (their σ and covariance too),
    for a parameter section of some of them: without the DH table (``table``), the correlation
    heat map (``heatmap``) and the residual σ̂ (the caller states whose)."""
    names = set(names)
    unc = dict(d.get("uncertainty") or {})
    std = unc.get("std", {})
    order = list(std)
    idx = [i for i, n in enumerate(order) if n in names]
    unc["std"] = {order[i]: std[order[i]] for i in idx}
    cov = unc.get("covariance")
    unc["covariance"] = [[cov[i][j] for j in idx] for i in idx] if cov and heatmap else None
    unc.pop("noise_std_mm", None)
    out = dict(d, free_parameters={n: v for n, v in d.get("free_parameters", {}).items() if n in names},
               uncertainty=unc)
    if not table:
        out.pop("calibrated_dh_table", None)
    return out


def _robot_names(robot_dict: dict) -> tuple[set[str] | None, dict]:
    """The robot's own parameter names (its error groups) and their table labels
    (:meth:`~jaxcal.KinematicTree.entry_labels`; ``{}`` for a DH table or a chain), or ``(None, {})``
    if the model cannot be read."""
    try:
        from .._calibration._io import robot_from_dict

        robot = robot_from_dict(robot_dict)
        return {n for g in robot.error_groups() for n in g.names}, robot.entry_labels()
    except Exception:  # noqa: BLE001 - the page then shows every parameter together
        return None, {}


def combined_html_report(d: dict, *, source: str = "", inputs=(), created: str | None = None) -> str:
    """The page for a combined result (``jaxcal calibrate --combine``'s ``combined.json``,
    :func:`jaxcal.save_combined_result`): the blocks' statistics (σ used and σ̂ against the noise each
    file states), the warnings, the calibrated robot (parameters ± σ with the verdicts' marks, the
    DH table), which block sees what, the relations, and per block its before/after table, its
    extras and its residual figures (where the file holds per-row errors: ``jaxcal calibrate
    --combine`` writes them). What the file cannot show, the page says."""
    from .._calibration._blocks import _stats_from_dict
    from .._fit._diagnostics import Checks
    from .._sensors._blocks import Relations

    blocks = [b for b in d.get("blocks", []) if isinstance(b, dict)]
    data_blocks = [b for b in blocks if "result" in b]
    first = data_blocks[0]["result"] if data_blocks else {}
    robot = first.get("robot", {})
    name = d.get("robot") if isinstance(d.get("robot"), str) else robot.get("name", "")
    kind = {"serial_chain": "URDF chain", "kinematic_tree": "URDF tree"}.get(robot.get("type"), "DH table")
    title = f"Combined calibration report: {name}"
    s = d.get("settings") or {}
    body = [f"<h1>{_e(title)}</h1>", _provenance(source, inputs, created), "<h2>Summary</h2>"]
    files = [((b.get("result") or {}).get("settings") or {}).get("data") for b in data_blocks]
    body.append(_summary([
        ("blocks", "; ".join(f"{b['name']}: {b.get('n_samples')} {b.get('kind')} rows"
                             + (f" from {f}" if f else "") for b, f in zip(data_blocks, files))),
        ("model", f"{name} ({kind})"),
        ("method", f"{d.get('method')} ({d.get('status')}), {d.get('variance_rounds')} fit(s) with re-estimated σ"),
        ("objective", f"{s.get('loss') or first.get('loss')} loss; prior {s.get('prior') or first.get('prior') or 'none'}"),
        ("relations", s.get("relations") or (f"{len(d['relations'])} relations" if d.get("relations") else "none")),
        ("whitened train RMSE", f"{_num((d.get('train_metrics_whitened') or {}).get('rmse'))} (1 at the floor)")]))
    body.append('<p class="small">Every row of every block trains: the numbers below are training numbers. This file '
                "holds no held-out data; check a block on new rows with <code>jaxcal evaluate BLOCK.json NEW.csv</code> "
                "(the block result files beside this one).</p>")
    # the blocks' statistics: σ used, σ̂, the noise the file states
    stats = [_stats_from_dict(b) for b in blocks]
    factor = Checks.noise_warn_factor
    rows = []
    for st in stats:
        ratio = st.sigma_hat / st.sigma_stated if st.sigma_stated else None
        rows.append([st.name, st.kind, st.n_samples, st.n_residuals, st.unit,
                     f"{_num(st.sigma)} ({'given' if st.sigma_given else 'estimated'})", _num(st.sigma_hat),
                     "—" if st.sigma_stated is None else _num(st.sigma_stated),
                     "—" if ratio is None else f"{ratio:.2f}", f"{st.redundancy:.1f}",
                     _num(st.rmse), _num(st.mean), _num(st.max)])
    body += ["<h2>Blocks</h2>", _table(["block", "kind", "rows", "residuals", "unit", "σ used", "σ̂", "stated noise",
                                        "σ̂ / stated", "redundancy", "RMSE", "MEAN", "MAX"], rows, left=2),
             '<p class="small">Each block in its own unit. σ used: what its residuals were divided by in the final fit; '
             "σ̂ = √(RSS / redundancy), the variance-component estimate; stated noise: the file's "
             f"<code># noise_std_mm:</code> / <code># noise_std_px:</code> line (σ̂ at {factor:g}× it or more is warned "
             "about); RMSE, MEAN, MAX of the per-row errors after the fit (relations: whitened, σ = 1).</p>"]
    warned = [w for w in (st.noise_warning(factor=factor) for st in stats) if w is not None]
    warned += [w for w in (first.get("diagnostics") or {}).get("warnings", []) if w not in warned]
    body += ["<h2>Warnings</h2>", _warnings(warned)]
    own, labels = _robot_names(robot)
    body.append("<h2>Calibrated robot</h2>")
    if first:
        body.append(_parameters(first if own is None else _restricted(first, own), labels))
    else:
        body.append("<p>This file holds no block result: no robot parameters to show.</p>")
    lines = d.get("who_sees_what") or []
    body += ["<h2>Which block sees what</h2>",
             "<ul>" + "".join(f"<li>{_e(ln)}</li>" for ln in lines) + "</ul>" if lines else
             "<p>No who-sees-what lines in this file.</p>"]
    rel = d.get("relations") or []
    body.append("<h2>Relations</h2>")
    if rel:
        rel_stats = next((st for st in stats if st.kind == Relations.kind), None)
        body.append(_table(["relation", "between", "known value", "std"], [
            [r.get("kind"), " – ".join(str(v) for k, v in r.items() if isinstance(v, str) and k != "kind"),
             ", ".join(_num(v) for k, v in r.items() if isinstance(v, (int, float)) and "std" not in k),
             ", ".join(_num(v) for k, v in r.items() if "std" in k)] for r in rel], left=2)
            + ("" if rel_stats is None else f'<p class="small">Their whitened RMS after the fit: {_num(rel_stats.rms)} '
               "(1: each relation off by its std).</p>"))
    else:
        body.append("<p>No known relations between the blocks.</p>")
    for b in data_blocks:
        r = b["result"]
        st = _stats_from_dict(b)
        src = (r.get("settings") or {}).get("data")
        body.append(f"<h2>Block {_e(b['name'])}: {_e(b.get('kind'))} data" + (f" from {_e(src)}" if src else "")
                    + "</h2>")
        metrics = r.get("metrics_mm") or {"train, after": {"rmse": st.rmse, "mean": st.mean, "max": st.max}}
        body.append(_metrics_table(metrics, st.unit)
                    + '<p class="small">Training rows (every row trains). before = the nominal robot with the block\'s '
                    "sensor extras estimated from its data (closed-form start); raw nominal = the guessed extras, nothing "
                    "estimated" + ("" if r.get("metrics_mm") else "; this file holds the fit's numbers only, no "
                                   "before/after") + ".</p>")
        extras = [n for n in r.get("free_parameters", {}) if own is not None and n not in own]
        if extras:
            body.append("<h3>Estimated extras</h3>" + _parameters(_restricted(r, extras, table=False, heatmap=False)))
        body.append(_figures(r.get("rows") or {}, robot, heading="h3", tip=(r.get("measurement") or {}).get("tip")))
    return _page(title, body)


def write_html(source, out) -> pathlib.Path:
    """Write the report page of the JSON file ``source`` (a calibration result, a combined result
    of ``jaxcal calibrate --combine``: :func:`combined_html_report`, or an evaluation) to ``out``;
    returns the path."""
    src = pathlib.Path(source)
    d = json.loads(src.read_text(encoding="utf-8"))
    fmt = str(d.get("format", "")) if isinstance(d, dict) else ""
    from .._calibration._io import file_identity, result_data_file

    created = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    if fmt.startswith("jaxcal-combined/"):  # `jaxcal calibrate --combine`'s combined.json
        inputs = [f"combined result {file_identity(src)}"]
        for b in d.get("blocks", []):
            data = result_data_file(src, b.get("result") or {})
            if data is not None:
                inputs.append(f"{b['name']} data {file_identity(data)}")
        page = combined_html_report(d, source=src.name, inputs=inputs, created=created)
    elif not (fmt.startswith("jaxcal-calibration-result/") or fmt.startswith("jaxcal-evaluation/")):
        raise ValueError(f"{src} is neither a jaxcal calibration result, a combined result nor an evaluation (no "
                         "matching 'format')")
    else:
        page = _single_page(src, d, fmt, created)
    p = pathlib.Path(out)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(page, encoding="utf-8")
    return p


def _single_page(src: pathlib.Path, d: dict, fmt: str, created: str) -> str:
    """:func:`html_report` of a result or evaluation file ``src`` (its dict ``d``), with the files it
    was made from (the data file; an evaluation's calibration and new data)."""
    from .._calibration._io import file_identity, result_data_file

    result = None
    inputs = [f"{'evaluation' if fmt.startswith('jaxcal-evaluation/') else 'result'} {file_identity(src)}"]
    if fmt.startswith("jaxcal-evaluation/"):
        for cand in ((pathlib.Path(d["result"]), src.parent / pathlib.Path(d["result"]).name) if d.get("result") else ()):
            if cand.exists():
                result = json.loads(cand.read_text(encoding="utf-8"))
                inputs.append(f"calibration {file_identity(cand)}")
                break
        new_data = pathlib.Path(str(d.get("data", "")))
        if d.get("data") and new_data.is_file():
            inputs.append(f"new data {file_identity(new_data)}")
    else:
        data = result_data_file(src, d)
        if data is not None:
            inputs.append(f"data {file_identity(data)}")
    return html_report(d, source=src.name, result=result, inputs=inputs, created=created)
