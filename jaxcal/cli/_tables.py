"""What ``jaxcal calibrate`` prints of a result: accuracy, parameters and extras ± σ, outliers, warnings.
"""

from __future__ import annotations

import math
import sys


def _metrics_rows(pairs):
    return [[name, m.rmse, m.mean, m.max] for name, m in pairs]


def _accuracy_table(pairs, unit: str, title: str) -> str:
    """The before/after table: ``pairs`` ``[(name, Metrics)]`` in ``unit`` (mm, px)."""
    from .._core._metrics import format_table

    return format_table(_metrics_rows(pairs), ["data", f"RMSE/{unit}", f"MEAN/{unit}", f"MAX/{unit}"], title=title)


def _fixed(v: float, sign: str = "") -> str:
    """``v`` at the tables' precision (4 decimals), a value that rounds to zero as ``0.0000``,
    never ``-0.0000`` (a deviation the prior holds at nominal comes out at round-off size)."""
    return f"{round(float(v), 4) + 0.0:{sign}.4f}"


def _fmt_value(v: float, sd: float | None, unit: str) -> str:
    if sd is None:
        return _fixed(v, "+")
    return f"{_fixed(v, '+')} ± {sd:.2g}" if sd < float("inf") else f"{_fixed(v, '+')} ± ∞"


def _print_dh_table(robot, res, sd) -> None:
    from .._core._metrics import format_table
    from .._core._trig import wrap_angle_deg
    from .._fit._verdicts import MARKS_LEGEND

    nominal = robot.dh_table_deg()
    cal = res.dh_table()
    mark = _marks(res)
    trows = []
    for j in range(robot.dof):
        cells = [str(j + 1)]
        for g, col in (("alpha", 0), ("a", 1), ("d", 2), ("theta", 3)):
            name = f"{g}_{j + 1}"
            delta = cal[j, col] - nominal[j, col]
            if col in (0, 3):
                delta = float(wrap_angle_deg(delta))
            if name in sd:
                cells.append(f"{_fixed(cal[j, col])}{mark(name)} ({_fmt_value(delta, sd[name][0], sd[name][1])})")
            else:
                cells.append(f"{_fixed(cal[j, col])}* ({_fixed(delta, '+')})")
        trows.append(cells)
    print()
    print(format_table(trows, ["joint", "α/° (Δ ± σ)", "a/mm (Δ ± σ)", "d/mm (Δ ± σ)", "θ/° (Δ ± σ)"],
                       title="Calibrated DH table (Δ = calibrated − nominal, ± one posterior standard deviation; "
                             + MARKS_LEGEND + ")"))


def _marks(res):
    """``name → "†" | ""`` of the free parameters: † where the result's verdict
    (:class:`~jaxcal._fit._verdicts.Verdicts`) is "held by the prior"."""
    from .._fit._verdicts import PRIOR

    verdicts = None if res.diagnostics is None else res.diagnostics.verdicts
    return lambda name: "†" if verdicts is not None and verdicts.verdict.get(name) == PRIOR else ""


def _print_robot_table(robot, res, sd) -> None:
    """The calibrated robot: its DH table, or a generic chain's or a tree's per-joint corrections."""
    if robot.dh_rows_deg() is not None:
        _print_dh_table(robot, res, sd)
    else:
        _print_chain_table(robot, res, sd)


def _print_chain_table(robot, res, sd) -> None:
    """Per-joint corrections of a generic chain: offset (°, or mm at prismatic joints), dx, dy, dz
    (mm), drx, dry, drz (°), and a last row with the tip transform's tip_dx … tip_drz; ± one
    posterior σ; * = not calibrated (not identifiable or fixed). A kinematic tree labels each
    joint with its branch (:meth:`~jaxcal.KinematicTree.entry_labels`) and has a row per tip."""

    from .._core._metrics import format_table
    from .._fit._verdicts import MARKS_LEGEND
    from .._models._chain import GEOMETRIC_GROUPS, TIP_GROUPS, correction_entries

    free = set(res.space.free_names)
    value = {n: v for n, v, _ in correction_entries(robot, res.deviations)}
    labels = robot.entry_labels()  # a tree: "branch / joint name", "tip <tip>"; a chain: none
    tips: dict[str, list[str]] = {}  # a tree's tip rows: label → its entries (tip_dx@<tip> …), layout order
    for n, lab in labels.items():
        if lab.startswith("tip "):
            tips.setdefault(lab[4:], []).append(n)
    units = dict(zip(res.space.layout.names, res.space.layout.units))
    dev = res.deviations.named()
    for n in (n for names in tips.values() for n in names):
        value[n] = math.degrees(float(dev[n])) if units[n] == "rad" else float(dev[n])
    mark = _marks(res)

    def cell(name):
        if name not in value:  # drz at a revolute joint: the joint offset
            return ""
        if name not in free:
            return f"{_fixed(value[name], '+')}*"
        return _fmt_value(value[name], sd.get(name, (None,))[0], "") + mark(name)

    rows = [[f"{j + 1} {labels.get(f'offset_{j + 1}', robot.joint_names[j])}"]
            + [cell(f"{g}_{j + 1}") for g, _ in GEOMETRIC_GROUPS] for j in range(robot.dof)]
    if tips:
        rows += [[f"tip → {t}", ""] + [cell(n) for n in names] for t, names in tips.items()]
    else:
        rows.append([f"tip → {robot.tip}", ""] + [cell(n) for _, names, _ in TIP_GROUPS for n in names])
    ends = ", ".join(tips) or robot.tip
    print()
    print(format_table(rows, ["joint" + (" (branch / name)" if labels else ""), "offset/° (mm)", "dx/mm", "dy/mm",
                              "dz/mm", "drx/°", "dry/°", "drz/°"],
                       title=f"Calibrated joint corrections of {robot.name} ({robot.base} → {ends}; ± one "
                             f"posterior standard deviation; {MARKS_LEGEND}; `jaxcal export` writes the corrected URDF)"))


def _extras_line(res, sd: dict, extras) -> str | None:
    """``"(deviation from the nominal/guessed value, ± one posterior σ): anchor_x +1.2 ± 0.3 mm, …"``:
    the estimated extras of ``res`` (and those ``extras`` asked for but held, marked *), or ``None``
    where there are none; ``sd``: :meth:`Uncertainty.std_display`."""
    import numpy as np

    from .._calibration._selection import SELECT_GROUPS
    from .._core._params import group_kind, group_of

    # every estimated sensor/set-up unknown: anchor, tool, cable offset, sensor frame, marker positions
    extra_names = [n for n in res.space.free_names if group_kind(n) == "extra"]
    # asked for but held (no prior, and the data cannot tell them from another extra): at their start
    asked = {g for e in extras for g in SELECT_GROUPS.get(e, ())}
    frozen = [n for n in res.space.names if group_kind(n) == "extra" and group_of(n) in asked
              and n not in res.space.free_names]
    if not (extra_names or frozen):
        return None
    dev = {**res.deviations.named(), **dict(zip(res.space.free_names, np.asarray(res.x)))}
    units = dict(zip(res.space.names, res.space.units))
    mark = _marks(res)  # † where the prior, not the data, holds it (the DH table's mark)
    held = any(mark(n) for n in extra_names)
    # an extra the prior holds, most often through the robot parameters it trades with (a plane's
    # offset and d_1, a tool point and a tip frame): its σ relative to the calibrated robot as well
    rel = {}
    if held and res.uncertainty is not None:
        unc = res.uncertainty
        robot = [n for n in unc.names if group_kind(n) != "extra"]
        rel = dict(zip(unc.names, unc.given_std(robot)))
    parts = []
    for n in extra_names + frozen:
        u = "°" if units[n] == "rad" else units[n]
        v = math.degrees(dev[n]) if units[n] == "rad" else dev[n]
        s_ = sd.get(n, (None,))[0]
        r = rel.get(n) if mark(n) else None
        r = "" if r is None else f" (robot-relative ± {math.degrees(r) if units[n] == 'rad' else r:.2g})"
        parts.append(f"{n}{mark(n)} {_fmt_value(v, s_, u)}{'*' if n in frozen else ''} {u}{r}")
    return ("(deviation from the nominal/guessed value, ± one posterior σ"
            + ("; † held by the prior, directly or through robot parameters it trades with, whose prior σ its ± "
               "carries (the default prior has no term on extras); robot-relative: its σ with the robot's "
               "parameters known, what the data determine" if held else "")
            + ("; * held at its start value: without a prior the data cannot tell it from another extra"
               if frozen else "")
            + "): " + ", ".join(parts))


def _print_nongeometric(res, sd: dict) -> None:
    """The robot's estimated non-geometric errors (harmonics in °, compliance in µrad/(N·m)) ± one
    posterior σ, if any."""
    import numpy as np

    from .._core._params import group_kind

    ng_names = [n for n in res.space.free_names if group_kind(n) == "nongeometric"]
    if ng_names:
        dev = dict(zip(res.space.free_names, np.asarray(res.x)))
        units = dict(zip(res.space.names, res.space.units))
        parts = []
        for n in ng_names:
            s_ = sd.get(n, (None,))[0]
            if units[n] == "rad":
                parts.append(f"{n} {_fmt_value(math.degrees(dev[n]), s_, '°')}°")
            else:  # compliance: µrad/(N·m)
                parts.append(f"{n} {_fmt_value(dev[n] * 1e6, None if s_ is None else s_ * 1e6, '')} µrad/(N·m)")
        print("non-geometric errors (± one posterior σ): " + ", ".join(parts))


def _print_estimates(res, sd: dict, extras, unit: str) -> None:
    """The estimated extras (and those asked for but held), the non-geometric errors, σ̂ and the
    condition number, each ± one posterior σ (``sd``: :meth:`Uncertainty.std_display`); ``unit``:
    the readings' unit (mm, px)."""
    extras_line = _extras_line(res, sd, extras)
    if extras_line is not None:
        print("estimated extras " + extras_line)
    _print_nongeometric(res, sd)
    if res.uncertainty is not None:
        if res.uncertainty.component_std:  # a pose: a σ̂ per component, the orientation weighed by their ratio
            w = float(res.measurement.orientation_scale)
            how = "given" if res.measurement.orientation_scale_given else "estimated: σ̂ position / σ̂ orientation"
            print(f"residual σ̂ per component: {res.uncertainty.component_lines()}; orientation weight "
                  f"{w:.4g} mm/rad ({how})")
        print(f"residual σ̂ {res.uncertainty.noise_std:.4f} {unit}, effective parameters "
              f"{res.uncertainty.effective_parameters:.1f}; condition number {res.diagnostics.condition_number:.3g}"
              + (" (data and prior together)" if res.prior is not None else ""))


def _print_outliers_and_warnings(res, args, file_row, where: str, rate: float, n_file: int) -> None:
    """The training rows' outliers (:func:`_outlier_line`, named as 1-based data rows by ``file_row``)
    and the result's other warnings."""
    from .._calibration._calibrate import outlier_warnings

    for sc in res.diagnostics.outlier_scans:
        if sc.rows:
            rows = [file_row(i) for i in sc.rows]
            print(f"jaxcal: warning: {_outlier_line(sc, where, rows, rate, n_file, args, train=True)}", file=sys.stderr)
    flagged = set(outlier_warnings(res))
    for w in res.warnings:
        if w not in flagged:
            print(f"jaxcal: warning: {w}", file=sys.stderr)


def _outlier_line(scan, where: str, rows, rate: float, n_file: int, args, train: bool) -> str:
    """One file's outlier rows in the words every command uses (:meth:`OutlierScan.message`): the
    file, its 1-based data ``rows``, σ̂ and the threshold, the false-alarm ``rate`` over the file's
    ``n_file`` rows (its training and test rows were scanned at the same per-row rate), what to do."""
    import dataclasses

    listed = ",".join(map(str, rows)) if len(rows) <= 12 else "ROWS"
    if train:
        guard = ("they are down-weighted by the robust loss; " if args.loss != "linear" else
                 "--loss huber guards against them; ")
        todo = guard + ("" if args.exclude_outliers else "--exclude-outliers refits without them, ") + \
            f"--exclude-rows {listed} leaves them out"
    else:
        todo = f"held out, not fitted: they raise the test RMSE/MAX above; --exclude-rows {listed} leaves them out"
    if scan.rate is not None:  # the per-row tail is that of the file's rate over all its rows
        scan = dataclasses.replace(scan, rate=rate, n_file=n_file)
    return scan.message(f"{where}, {'training' if train else 'test'} rows", rows, todo)
