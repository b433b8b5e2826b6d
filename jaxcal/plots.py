"""The paper's figures from a sweep (matplotlib; needs the ``plot`` extra).

* :func:`fig2_accuracy` — Fig. 2: RMSE / MEAN / MAX per method on held-out data, bars with
  ± std error bars over seeds, the statistical floor and the oracle as reference lines.
* :func:`fig3_training` — Fig. 3: training RMSE vs iteration (log–log-ish axes; mean over seeds
  with the min–max range over seeds shaded), in two panels as in the paper, and time per trial.
* :func:`fig4_positioning` — Fig. 4: errors at 30 random test points of one trial per method,
  dashed lines at each method's mean.
* :func:`grid_figure` — test RMSE over a two-axis hyperparameter grid (the ablation).
* :func:`save_figures` — all of them as PNG and PDF.

One calibration (the figures of the HTML page of ``jaxcal report RESULT.json --html``):
:func:`residual_histogram`, :func:`residuals_vs_joints`, :func:`workspace_errors`,
:func:`correlation_heatmap`.

Figures are built on :class:`matplotlib.figure.Figure` directly (no ``pyplot`` state, no GUI):
saving uses the Agg renderer whatever backend is active, so this works headless and in
notebooks (``display(fig)``) alike.
"""

from __future__ import annotations

import math
import pathlib
from collections.abc import Sequence

import numpy as np

from ._experiments._sweep_results import PAPER_METHODS, SweepResult, SweepRun
from .report import batching_label, paper_label

__all__ = ["fig2_accuracy", "fig3_training", "fig4_positioning", "grid_figure", "save_figures", "method_color",
           "residual_histogram", "residuals_vs_joints", "workspace_errors", "correlation_heatmap"]

_OTHER_COLORS = ("#17becf", "#bcbd22", "#7f7f7f", "#8c564b", "#e377c2")


def _figure(figsize):
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, layout="constrained")


def method_color(method: str, index: int = 0) -> str:
    """A fixed colour per paper method (AdaModW red), others from a spare palette."""
    palette = {
        "ga": "#1f77b4", "ekf": "#ff7f0e", "bso": "#2ca02c", "lm": "#9467bd",
        "iwoa": "#8c564b", "rbfnn": "#e377c2", "adam": "#17becf", "adamodw": "#d62728",
        "gn": "#7f7f7f", "adamod": "#bcbd22", "adamw": "#393b79",
    }
    return palette.get(method, _OTHER_COLORS[index % len(_OTHER_COLORS)])


def _tick(run: SweepRun) -> str:
    m = paper_label(run.method) if run.grid_point is None else ""
    name = run.label.upper() if run.label in PAPER_METHODS else run.label
    name = {"ADAMODW": "AdaModW", "ADAM": "Adam", "RBFNN": "RBFNN", "IWOA": "IWOA"}.get(name, name)
    return f"{m}\n{name}" if m else name


def _runs(result: SweepResult, methods: Sequence[str] | None) -> list[SweepRun]:
    if methods is None:
        return list(result)
    return [result[m] for m in methods]


def _save(fig, path) -> None:
    if path is None:
        return
    p = pathlib.Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p, dpi=150)


def fig2_accuracy(result: SweepResult, path=None, *, methods: Sequence[str] | None = None):
    """Fig. 2: test RMSE, MEAN and MAX (mm) per method, mean ± std over seeds.

    The bars start at zero, so their heights compare honestly (the good methods differ by a few
    tenths of a percent, less than the ± std error bars; the values are printed above the bars;
    the nominal model, an order of magnitude worse, is printed in the title instead of drawn).
    Dashed line: statistical floor (RMSE, and √(2/π)× it for MEAN); dotted line: the true model
    (oracle) on the same test data.
    """
    runs = _runs(result, methods)
    fig = _figure((max(12.0, 1.75 * len(runs) + 1.5), 4.2))
    axes = fig.subplots(1, 3)
    x = np.arange(len(runs))
    floor = result.floor.test if result.floor is not None else None
    for ax, f, name, letter in zip(axes, ("rmse", "mean", "max"), ("RMSE", "MEAN", "MAX"), "abc"):
        means = np.array([np.nanmean(getattr(r.test, f)) for r in runs])
        stds = np.array([np.nanstd(getattr(r.test, f), ddof=1) if r.n_seeds > 1 else 0.0 for r in runs])
        colors = [method_color(r.method, i) for i, r in enumerate(runs)]
        ax.bar(x, means, yerr=stds, color=colors, capsize=4, edgecolor="black", linewidth=0.5, zorder=2)
        ref = []
        if floor is not None and f in ("rmse", "mean"):
            fv = floor if f == "rmse" else floor * math.sqrt(2 / math.pi)
            ax.axhline(fv, color="black", ls="--", lw=1, label=f"statistical floor {fv:.3f}", zorder=3)
            ref.append(fv)
        oracle = np.asarray(getattr(result.oracle, f), np.float64)
        if np.any(np.isfinite(oracle)):
            ov = float(np.nanmean(oracle))
            ax.axhline(ov, color="dimgray", ls=":", lw=1.2, label=f"true model {ov:.3f}", zorder=3)
            ref.append(ov)
        hi = max(float(np.nanmax(means + stds)), *ref)
        ax.set_ylim(0.0, 1.3 * hi)  # bars from zero; headroom for the values and the legend
        for xi, m, sd in zip(x, means, stds):  # the value above the error bar
            ax.text(xi, m + sd + 0.02 * hi, f"{m:.3f}", ha="center", va="bottom", fontsize=7, rotation=90,
                    bbox={"facecolor": "white", "edgecolor": "none", "pad": 1.0, "alpha": 0.85}, zorder=4)
        ax.set_xticks(x, [_tick(r) for r in runs], fontsize=8)
        bc = float(np.nanmean(getattr(result.before, f)))
        ax.set_title(f"({letter}) {name} on test data (BC: {bc:.2f} mm)", fontsize=10)
        ax.set_ylabel(f"{name} / mm")
        ax.grid(axis="y", alpha=0.3, zorder=0)
        if ref:
            ax.legend(fontsize=7, loc="upper left", ncol=2)
    fig.suptitle(f"Calibration accuracy, mean ± std over {result.n_seeds} seed(s)", fontsize=11)
    _save(fig, path)
    return fig


def _plain_ticks(axis) -> None:
    """Tick labels as plain numbers (0.5, 2, 0.01) instead of 5×10⁻¹ on log axes."""
    from matplotlib.ticker import FuncFormatter

    def minor(v, _):
        if v <= 0:
            return ""
        lead = round(v / 10 ** math.floor(math.log10(v) + 1e-9))
        return f"{v:g}" if lead in (2, 5) else ""

    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(FuncFormatter(minor))


def _split_halves(runs: list[SweepRun]) -> tuple[list[SweepRun], list[SweepRun]]:
    """The paper's panels: (M1, M2, M4, M6) and (M3, M5, M7, M8) when present, else halves."""
    names = [r.method for r in runs]
    first = {"ga", "ekf", "lm", "rbfnn", "gn"}
    if any(n in PAPER_METHODS for n in names):
        a = [r for r in runs if r.method in first]
        b = [r for r in runs if r.method not in first]
        if a and b:
            return a, b
    h = math.ceil(len(runs) / 2)
    return runs[:h], runs[h:]


_LINESTYLES = ("-", "--", "-.", (0, (6, 1.5)))
_MARKERS = ("o", "s", "^", "D")


def _curve_panel(ax, runs: list[SweepRun], floor, letter: str):
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    for i, r in enumerate(runs):
        h = np.asarray(r.history, np.float64)
        if h.shape[1] < 2:
            continue
        T = int(np.max(r.n_iterations)) + 1
        h = h[:, :T]
        it = np.arange(T)
        mean = np.nanmean(h, axis=0)
        c = method_color(r.method, i)
        lab = f"{_tick(r).replace(chr(10), ' ')} (→ {mean[-1]:.3f})"
        # curves that coincide (LM, EKF and the RBF network all reach the floor in 1-5 steps)
        # stay visible: the first drawn is the widest with the largest hollow marker, later ones
        # are thinner with smaller markers on top (concentric), each with its own dash
        every = None if T <= 12 else np.unique(np.geomspace(1, T - 1, 8).astype(int))
        ax.plot(it, mean, color=c, lw=max(2.4 - 0.35 * i, 1.3), ls=_LINESTYLES[i % len(_LINESTYLES)], label=lab,
                marker=_MARKERS[i % len(_MARKERS)], markevery=every, ms=max(10 - 2.2 * i, 3.5),
                mfc="none" if i < len(runs) - 1 else c, mew=1.3, zorder=3 + i)
        lo, hi = np.nanmin(h, axis=0), np.nanmax(h, axis=0)
        ax.fill_between(it, lo, hi, color=c, alpha=0.12, lw=0)
        its = float(np.mean(r.iterations_to_converge))
        ax.plot([its], [np.interp(its, it, mean)], marker="v", color=c, ms=7, mec="black", mew=0.5, ls="none",
                zorder=10)
        if getattr(r, "stage_ends", None) is not None:  # staged method ("ga>lm"): where the stages switch
            for b in np.mean(np.asarray(r.stage_ends, np.float64)[:, :-1], axis=0):
                ax.axvline(b, color=c, ls=":", lw=1.2, alpha=0.9)
    if floor is not None:
        ax.axhline(floor, color="black", ls="--", lw=1, label=f"floor (train) {floor:.3f}")
    handles, labels = ax.get_legend_handles_labels()
    handles += [Patch(color="gray", alpha=0.25, lw=0),
                Line2D([], [], marker="v", color="gray", mec="black", mew=0.5, ls="none", ms=7)]
    labels += ["band: range over seeds (min–max;\nsingle seeds end below the floor,\nan expectation)",
               "mean iteration to converge"]
    longest = max((int(np.max(r.n_iterations)) for r in runs), default=1)
    if longest > 30:  # linear up to 1, logarithmic beyond: LM's 5 steps and GA's 600 both show
        ax.set_xscale("symlog", linthresh=1)
        from matplotlib.ticker import FuncFormatter

        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.set_yscale("log")
    _plain_ticks(ax.yaxis)
    ax.set_xlim(left=0)
    ax.set_xlabel("iteration")
    ax.set_ylabel("training RMSE / mm")
    ax.grid(alpha=0.3, which="both")
    ax.legend(handles, labels, fontsize=7)
    names = ", ".join(_tick(r).replace("\n", " ") for r in runs)
    ax.set_title(f"({letter}) training curves: {names}", fontsize=9)


def fig3_training(result: SweepResult, path=None, *, methods: Sequence[str] | None = None):
    """Fig. 3: (a, b) training RMSE vs iteration (mean over seeds, with the min–max range over
    seeds shaded; ▼ marks the mean iteration to converge; both in the legend; the final mean in
    each label; a dotted vertical line in the run's colour marks the mean iteration where a staged
    method such as ``"ga>lm"`` switches stage), x axis linear up to 1 then logarithmic; (c) time
    per trial (s, log scale)."""
    runs = _runs(result, methods)
    fig = _figure((max(14.0, 10.0 + 0.75 * len(runs)), 4.4))
    axes = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1.15, 1.15, max(1.0, 0.17 * len(runs))]})
    a, b = _split_halves(runs)
    floor = result.floor.train if result.floor is not None else None
    _curve_panel(axes[0], a, floor, "a")
    _curve_panel(axes[1], b, floor, "b")
    ymin = min(ax.get_ylim()[0] for ax in axes[:2])
    ymax = max(ax.get_ylim()[1] for ax in axes[:2])
    for ax in axes[:2]:
        ax.set_ylim(ymin, ymax)
    ax = axes[2]
    x = np.arange(len(runs))
    t = np.array([np.mean(r.time_per_trial_s) for r in runs])
    tc = np.array([np.mean(r.time_to_converge_s) for r in runs])
    colors = [method_color(r.method, i) for i, r in enumerate(runs)]
    ax.bar(x - 0.2, t, width=0.4, color=colors, edgecolor="black", linewidth=0.5, label="whole run", zorder=2)
    ax.bar(x + 0.2, np.maximum(tc, 1e-6), width=0.4, color=colors, edgecolor="black", linewidth=0.5, hatch="///",
           alpha=0.6, label="to converge (RMSE)", zorder=2)
    ax.set_yscale("log")
    _plain_ticks(ax.yaxis)
    ax.set_xticks(x, [_tick(r) for r in runs], fontsize=8)
    ax.set_ylabel("time per trial / s")
    ax.grid(axis="y", alpha=0.3, which="both", zorder=0)
    ax.legend(fontsize=7)
    dev = result.settings.get("n_devices", 1)
    how = "one trial after another" if batching_label(result) == "lax.map" else "trials batched"
    ax.set_title(f"(c) time per trial ({how}, {dev} {'device' if dev == 1 else 'devices'})", fontsize=10)
    fig.suptitle(f"Training curves and time, {result.n_seeds} seed(s)", fontsize=11)
    _save(fig, path)
    return fig


def fig4_positioning(result: SweepResult, path=None, *, methods: Sequence[str] | None = None, n_points: int = 30,
                     trial: int = 0, seed: int = 0):
    """Fig. 4: absolute error (mm) at ``n_points`` random test points of ``trial``, per method,
    with dashed lines at each method's mean over those points; (a) before calibration vs the
    best method, (b, c) the methods in two groups."""
    runs = [r for r in _runs(result, methods) if r.test_errors.shape[-1] > 0]
    if not runs or result.before_errors.shape[-1] == 0:
        raise ValueError("the sweep kept no per-sample test errors (run it with keep_errors=True)")
    n_test = result.before_errors.shape[-1]
    idx = np.sort(np.random.default_rng(seed).choice(n_test, size=min(n_points, n_test), replace=False))
    pts = np.arange(1, idx.size + 1)
    bc = np.abs(result.before_errors[trial, idx])
    fig = _figure((14, 4.4))
    axes = fig.subplots(1, 3)
    best = min(runs, key=lambda r: float(np.mean(np.abs(r.test_errors[trial, idx]))))
    show = next((r for r in runs if r.method == "adamodw"), best)

    def draw(ax, entries, letter, title):
        if not entries:
            ax.set_axis_off()
            return
        for lab, e, c, mk in entries:
            ax.plot(pts, e, marker=mk, ms=4, lw=0.8, color=c, label=f"{lab} (mean {e.mean():.3f})")
            ax.axhline(e.mean(), color=c, ls="--", lw=1)
        ax.set_xlabel("test point")
        ax.set_ylabel("|error| / mm")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=1 if len(entries) < 5 else 2)
        ax.set_title(f"({letter}) {title}", fontsize=10)

    draw(axes[0], [("before calibration", bc, "black", "s"),
                   (_tick(show).replace("\n", " "), np.abs(show.test_errors[trial, idx]), method_color(show.method), "o")],
         "a", "before vs after calibration")
    g1, g2 = _split_halves(runs)
    markers = "o^sDvP<>*"
    for ax, group, letter in ((axes[1], g1, "b"), (axes[2], g2, "c")):
        entries = [(_tick(r).replace("\n", " "), np.abs(r.test_errors[trial, idx]), method_color(r.method, i),
                    markers[i % len(markers)]) for i, r in enumerate(group)]
        draw(ax, entries, letter, "after calibration")
    top = max(float(np.max(np.abs(r.test_errors[trial, idx]))) for r in runs)
    for ax in axes[1:]:
        ax.set_ylim(0, top * 1.45)  # headroom for the legend
    axes[0].set_ylim(0, max(float(bc.max()), top) * 1.3)
    fig.suptitle(f"Errors at {idx.size} random test points (trial {trial}); dashed: means", fontsize=11)
    _save(fig, path)
    return fig


def grid_figure(result: SweepResult, method: str | None = None, path=None, *, metric: str = "rmse"):
    """Mean test ``metric`` over a hyperparameter grid: a heat map for two axes, a line for one."""
    runs = [r for r in result if r.grid_point is not None and (method is None or r.method == method)]
    if not runs:
        raise ValueError("the sweep has no grid runs")
    keys = list(runs[0].grid_point)
    fig = _figure((6.4, 4.8))
    ax = fig.subplots()
    vals = {r.label: float(np.mean(getattr(r.test, metric))) for r in runs}
    if len(keys) == 1:
        k = keys[0]
        xs = [r.grid_point[k] for r in runs]
        ys = [vals[r.label] for r in runs]
        ax.plot(xs, ys, marker="o")
        ax.set_xscale("log" if all(isinstance(v, (int, float)) and v > 0 for v in xs) else "linear")
        ax.set_xlabel(k)
        ax.set_ylabel(f"test {metric.upper()} / mm")
    else:
        kx, ky = keys[:2]
        xs = sorted({r.grid_point[kx] for r in runs})
        ys = sorted({r.grid_point[ky] for r in runs})
        Z = np.full((len(ys), len(xs)), np.nan)
        for r in runs:
            Z[ys.index(r.grid_point[ky]), xs.index(r.grid_point[kx])] = vals[r.label]
        im = ax.imshow(Z, origin="lower", cmap="viridis", aspect="auto")
        for i in range(len(ys)):
            for j in range(len(xs)):
                if np.isfinite(Z[i, j]):
                    ax.text(j, i, f"{Z[i, j]:.4f}", ha="center", va="center", fontsize=8,
                            color="white" if Z[i, j] < np.nanmean(Z) else "black")
        ax.set_xticks(range(len(xs)), [f"{v:g}" for v in xs])
        ax.set_yticks(range(len(ys)), [f"{v:g}" for v in ys])
        ax.set_xlabel(kx)
        ax.set_ylabel(ky)
        fig.colorbar(im, ax=ax, label=f"mean test {metric.upper()} / mm")
        if len(keys) > 2:
            ax.set_title("(first two grid axes; other axes overlaid)", fontsize=8)
    name = runs[0].method
    fig.suptitle(f"{name}: test {metric.upper()} over the grid, {result.n_seeds} seed(s)", fontsize=11)
    _save(fig, path)
    return fig


def save_figures(result: SweepResult, out_dir, *, formats: Sequence[str] = ("png", "pdf")) -> dict[str, pathlib.Path]:
    """Write Figs. 2–4 (and the grid figure if there are grid runs) into ``out_dir`` in each format.

    Returns ``{file name: path}``.
    """
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    plain = [r.label for r in result if r.grid_point is None]
    makers = [("fig2_accuracy", lambda: fig2_accuracy(result, methods=plain or None)),
              ("fig3_training", lambda: fig3_training(result, methods=plain or None))]
    if result.before_errors.shape[-1] > 0 and plain:
        makers.append(("fig4_positioning", lambda: fig4_positioning(result, methods=plain)))
    if any(r.grid_point is not None for r in result):
        makers.append(("grid", lambda: grid_figure(result)))
    files = {}
    for name, make in makers:
        fig = make()
        for ext in formats:
            p = out / f"{name}.{ext}"
            fig.savefig(p, dpi=150)
            files[p.name] = p
    return files


# -- one calibration (the HTML report of ``jaxcal report RESULT.json --html``) ------------------------
#: colours of the data parts of one calibration (train, test, new data)
PART_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd")


def residual_histogram(parts: dict, path=None):
    """Histogram of per-row error sizes (mm, ≥ 0): for each data part ``{label: (before [n], after [n])}`` the
    calibrated robot's errors (filled) and the nominal robot's (outline, extras from the data)."""
    fig = _figure((7.0, 3.6))
    ax = fig.subplots()
    allv = np.concatenate([np.concatenate([np.asarray(b), np.asarray(a)]) for b, a in parts.values()])
    allv = allv[np.isfinite(allv)]
    hi = float(np.quantile(allv, 0.99)) if allv.size else 1.0
    bins = np.linspace(0.0, max(hi, 1e-9) * 1.05, 40)
    for i, (label, (b, a)) in enumerate(parts.items()):
        c = PART_COLORS[i % len(PART_COLORS)]
        ax.hist(np.clip(a, 0, bins[-1]), bins=bins, color=c, alpha=0.45, label=f"{label}, after")
        ax.hist(np.clip(b, 0, bins[-1]), bins=bins, color=c, histtype="step", ls="--", lw=1.2,
                label=f"{label}, before")
    ax.set_xlabel("per-row error size / mm (values beyond the 99th percentile in the last bin)")
    ax.set_ylabel("rows")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax.set_title("Residuals before (nominal robot, extras from the data) and after calibration", fontsize=10)
    _save(fig, path)
    return fig


def residuals_vs_joints(parts: dict, path=None, *, joint_names: Sequence[str] | None = None):
    """Per-row error after calibration (mm; signed for a draw-wire) against each joint reading (°),
    one panel per joint;
    ``parts``: ``{label: (q_deg [n, dof], after [n])}``. Trends show unmodelled errors."""
    dof = next(iter(parts.values()))[0].shape[1]
    ncols = 3 if dof > 4 else 2
    nrows = math.ceil(dof / ncols)
    fig = _figure((9.0, 2.3 * nrows + 0.4))
    axes = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
    # a robust vertical range, so gross rows do not flatten the rest; they are drawn at its edge (▲/▼)
    allv = np.concatenate([np.asarray(e, np.float64) for _, e in parts.values()])
    allv = allv[np.isfinite(allv)]
    lo, hi = (np.quantile(allv, [0.005, 0.995]) if allv.size else (-1.0, 1.0))
    pad = 0.15 * max(hi - lo, 1e-9)
    lo, hi = lo - pad, hi + pad
    clipped = 0
    for j in range(dof):
        ax = axes[j]
        for i, (label, (q, e)) in enumerate(parts.items()):
            qj, e = np.asarray(q)[:, j], np.asarray(e, np.float64)
            inside = (e >= lo) & (e <= hi)
            ax.scatter(qj[inside], e[inside], s=6, alpha=0.6, color=PART_COLORS[i % len(PART_COLORS)], label=label)
            for sel, y, mk in ((e > hi, hi, "^"), (e < lo, lo, "v")):
                if sel.any():
                    ax.scatter(qj[sel], np.full(sel.sum(), y), s=30, marker=mk, color="black", zorder=3)
            clipped += int((~inside).sum()) if j == 0 else 0
        ax.set_ylim(lo, hi)
        ax.set_xlabel(f"q{j + 1}" + (f" {joint_names[j]}" if joint_names else "") + " / °", fontsize=8)
        ax.set_ylabel("error / mm", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    for ax in axes[dof:]:
        ax.set_visible(False)
    axes[0].legend(fontsize=7)
    fig.suptitle("Error after calibration against each joint"
                 + (f" ({clipped} row(s) beyond the range drawn at its edge: ▲ ▼)" if clipped else ""), fontsize=10)
    _save(fig, path)
    return fig


#: The quantile of the errors at which :func:`workspace_errors` clips its colour scale (one far
#: outlier would otherwise paint every other point the bottom colour).
WORKSPACE_COLOUR_QUANTILE = 0.98


def workspace_colour_max(errors) -> float:
    """The top of :func:`workspace_errors`' colour scale (mm): the ``WORKSPACE_COLOUR_QUANTILE``
    quantile of the ``[n]`` ``errors`` (1 for none)."""
    e = np.asarray(errors, np.float64)
    return max(float(np.quantile(e, WORKSPACE_COLOUR_QUANTILE)), 1e-9) if e.size else 1.0


def workspace_errors(points, errors, path=None, *, label: str = "tool point of the nominal robot"):
    """Error after calibration (mm, colour) over the workspace: the ``points`` ``[n, 3]`` (mm, base
    frame) seen from above (x–y) and from the side (x–z). The colour scale runs from 0 to
    :func:`workspace_colour_max` (clipped at that quantile; the colour bar says so)."""
    p = np.asarray(points, np.float64)
    e = np.asarray(errors, np.float64)
    fig = _figure((9.0, 3.8))
    axes = fig.subplots(1, 2)
    vmax = workspace_colour_max(e)
    for ax, (a, b) in zip(axes, ((0, 1), (0, 2))):
        sc = ax.scatter(p[:, a], p[:, b], c=e, s=10, cmap="viridis", vmin=0.0, vmax=vmax)
        ax.set_xlabel(f"{'xyz'[a]} / mm")
        ax.set_ylabel(f"{'xyz'[b]} / mm")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        ax.set_title(("from above" if b == 1 else "from the side") + f" ({'xyz'[a]}–{'xyz'[b]})", fontsize=9)
    fig.colorbar(sc, ax=axes, extend="max", shrink=0.9, label="error after calibration / mm")
    fig.suptitle(f"Error over the workspace ({label}; colour clipped at the "
                 f"{100 * WORKSPACE_COLOUR_QUANTILE:g}th percentile)", fontsize=10)
    _save(fig, path)
    return fig


def correlation_heatmap(covariance, names: Sequence[str], path=None):
    """Posterior correlation of the free parameters (from their covariance), −1 … 1."""
    c = np.asarray(covariance, np.float64)
    s = np.sqrt(np.clip(np.diag(c), 1e-300, None))
    r = np.clip(c / np.outer(s, s), -1.0, 1.0)
    n = len(names)
    size = min(9.0, max(4.5, 0.22 * n + 2.5))
    fig = _figure((size, size * 0.85))
    ax = fig.subplots()
    im = ax.imshow(r, cmap="RdBu_r", vmin=-1, vmax=1)
    fs = 7 if n <= 30 else 5
    ax.set_xticks(np.arange(n), names, rotation=90, fontsize=fs)
    ax.set_yticks(np.arange(n), names, fontsize=fs)
    fig.colorbar(im, ax=ax, shrink=0.8, label="correlation")
    ax.set_title("Posterior correlation of the calibrated parameters", fontsize=10)
    _save(fig, path)
    return fig
