"""Outlier alarms of a combined fit through the command line (issue 53): each file's rows in their
own robust σ̂, a warning only for a row that is one, naming the file and its 1-based data row
(the 20-seed sweep over every sensor kind: ``benchmarks/bench_outlier_alarms.py``)."""

import re

from jaxcal.cli import main


def _run(argv, capsys):
    code = main(argv)
    return code, capsys.readouterr()


def test_combined_fit_names_a_planted_row_by_file_and_row(tmp_path, capsys):
    """Plane + distance-bar files of one simulated set-up: clean, no outlier warning (the pooled
    whitened scan of before named 3.1–3.4 σ̂ plane rows of a clean 800-row file); one bar row with
    a 10σ error (5 mm on its 0.5 mm noise): one warning naming bar.csv and that data row, in the
    bar's own σ̂ and unit, and nothing about the plane file."""
    sim = ["simulate", "--robot", "hsr_jr680", "--seed", "2"]
    plane, bar = tmp_path / "plane.csv", tmp_path / "bar.csv"
    assert _run([*sim, "--measurement", "plane", "--samples", "150", "--out", str(plane)], capsys)[0] == 0
    assert _run([*sim, "--measurement", "distance", "--samples", "100", "--out", str(bar)], capsys)[0] == 0
    fit = ["calibrate", str(plane), str(bar), "--robot", "hsr_jr680", "--combine", "--out-dir", str(tmp_path / "fit")]
    code, out = _run(fit, capsys)
    assert code == 0, out.err
    assert "outlier" not in out.err
    lines = bar.read_text().splitlines()
    head = next(i for i, ln in enumerate(lines) if ln.startswith("q1"))
    col = lines[head].split(",").index("distance_mm")
    row = 37  # 1-based data row
    cells = lines[head + row].split(",")
    cells[col] = repr(float(cells[col]) + 5.0)
    lines[head + row] = ",".join(cells)
    bar.write_text("\n".join(lines) + "\n")
    code, out = _run(fit, capsys)
    assert code == 0, out.err
    warned = [ln for ln in out.err.splitlines() if "outlier" in ln]
    assert len(warned) == 1, out.err
    line = warned[0]
    assert line.startswith(f"jaxcal: warning: {bar}: 1 outlier row at data row {row}: residual 5"), line
    m = re.search(r"above the threshold ([0-9.]+) mm = ([0-9.]+) σ̂ \(σ̂ = ([0-9.]+) mm, these rows' robust σ; what a "
                  r"file of 100 clean rows crosses with a 1 % chance\); nothing was dropped — ", line)
    assert m is not None, line
    thr, k, s = map(float, m.groups())
    assert 0.35 < s < 0.7 and 3.5 < k < 6 and thr < 5.0  # the bar's own σ̂ (0.5 mm simulated), in mm
    assert "0-based" not in out.err and "--combine" not in line
