"""One self-contained HTML page for a calibration result or an evaluation (``jaxcal report X.json --html``).

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

__all__ = ["write_html", "html_report"]

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


def _points(robot_dict, q_deg) -> np.ndarray | None:
    """Tool points of the nominal robot at ``q_deg`` (mm, base frame), or None if the model cannot."""
    try:
        from .._calibration._evaluate import joints_from_file_units
        from .._calibration._io import robot_from_dict
        from .._core._precision import to_device
        from .._models._kinematics import fk_position_jit

        robot = robot_from_dict(robot_dict)
        q = joints_from_file_units(robot, q_deg)  # degrees (mm at prismatic joints) → rad
        return fk_position_jit(robot, to_device(q), tool=True)  # one compiled program, not ~40 small ones
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


def _parameters(d: dict) -> str:
    """Parameter table (Δ ± σ in ° / mm; angles wrapped to (−180°, 180°]; † set by the prior) and
    the correlation heat map of a result dict."""
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
        rows.append([n + ("†" if n in by_prior else ""), "°" if u == "rad" else u,
                     _fixed(value) if u in ("rad", "mm") else _num(value),
                     "—" if s is None else _num(f(s), 3),
                     "" if s in (None, 0) or not math.isfinite(s) else f"{abs(v) / s:.1f}"])
    parts = [f"<p>{len(free)} calibrated parameters: deviation Δ from the nominal value (sensor extras: from the "
             "guess) and one posterior standard deviation σ"
             + (f"; residual σ̂ {_num(unc.get('noise_std_mm'))} mm" if unc.get("noise_std_mm") is not None else "")
             + (f"; {len(by_prior)} of them (†) held by the prior rather than determined by the data: their values "
                "are the prior's, not results" if by_prior else "")
             + ".</p>", _table(["parameter", "unit", "Δ", "σ", "|Δ|/σ"], rows)]
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
    return "".join(out) or "<p>No row exceeds 5 robust σ after calibration.</p>"


def _figures(parts_rows: dict, robot_dict: dict) -> str:
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
    out = ["<h2>Residuals</h2>", _png(residual_histogram({k: (np.abs(b), np.abs(a)) for k, (b, a, _) in arr.items()})),
           _png(residuals_vs_joints({k: (q, a) for k, (_, a, q) in arr.items()},
                                    joint_names=robot_dict.get("joint_names")))]
    q = np.concatenate([q for _, _, q in arr.values()])
    e = np.abs(np.concatenate([a for _, a, _ in arr.values()]))
    pts = _points(robot_dict, q)
    out.append("<h2>Error over the workspace</h2>")
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
            warnings_ = [f"{len(s['outlier_rows_after'])} outlier sample(s) at data rows {rows_txt} (1-based; see "
                         "Outlier rows)" if "outlier sample(s)" in w else w for w in warnings_]
        data = s.get("data", "")
        if s:
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
    body += ["<h2>Outlier rows</h2>", '<p class="small">Rows whose residual after calibration exceeds 5 robust '
             "standard deviations (data-row numbers, 1-based).</p>", _outliers(parts_rows, flagged)]
    return ('<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"/>'
            '<meta name="viewport" content="width=device-width, initial-scale=1"/>'
            f"<title>{_e(title)}</title><style>{_CSS}</style></head><body>"
            + "".join(body) + "</body></html>\n")


def write_html(source, out) -> pathlib.Path:
    """Write the report page of the JSON file ``source`` (a calibration result or an evaluation)
    to ``out``; returns the path."""
    src = pathlib.Path(source)
    d = json.loads(src.read_text(encoding="utf-8"))
    fmt = str(d.get("format", "")) if isinstance(d, dict) else ""
    if fmt.startswith("jaxcal-combined/"):  # the summary of `jaxcal calibrate --combine`
        blocks = [str(src.parent / f"{b['name']}.json") for b in d.get("blocks", []) if b.get("kind") != "relations"
                  and (src.parent / f"{b['name']}.json").exists()]
        raise ValueError(f"{src} is the summary of a combined fit (jaxcal calibrate --combine), whose report has "
                         "no page of its own yet: report one of its blocks' results"
                         + (f" ({', '.join(blocks)})" if blocks else "") + "; the summary's block table is what "
                         "the calibrate command printed")
    if not (fmt.startswith("jaxcal-calibration-result/") or fmt.startswith("jaxcal-evaluation/")):
        raise ValueError(f"{src} is neither a jaxcal calibration result nor an evaluation (no matching 'format')")
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
    created = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    page = html_report(d, source=src.name, result=result, inputs=inputs, created=created)
    p = pathlib.Path(out)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(page, encoding="utf-8")
    return p
