"""One verdict per parameter everywhere (issue 53): the identifiability lines, the DH table's marks,
the block report, the warnings and the result file of `jaxcal calibrate` name each parameter
determined by the data, held by the prior or not calibrated alike.

Checked against something independent: calibrated again under a prior twice as wide, a parameter
the prior holds has a posterior σ that grows with it (more than 1.5×), one the data determine does
not (a linear-Gaussian posterior: σ² = the data's part + the prior's part, the latter ×4)."""

import contextlib
import io
import json
import pathlib
import re

import pytest

from jaxcal import robots
from jaxcal._calibration._io import save_robot_csv
from jaxcal.cli import main

URDF = pathlib.Path(__file__).parents[1] / "data" / "urdf" / "ur10e.urdf"
WIDE = "angle_deg=1,length_mm=4"  # the default prior (0.5°, 2 mm) twice as wide


def _robot_args(kind, d) -> list[str]:
    if kind == "preset":
        return ["--robot", "hsr_jr680"]
    if kind == "dh_file":
        save_robot_csv(robots.hsr_jr680(), d / "jr680.csv")
        return ["--robot", str(d / "jr680.csv")]
    return ["--robot", str(URDF), "--base", "base_link", "--tip", "tool0"]


def _run(argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    assert "Traceback" not in err.getvalue(), err.getvalue()
    return code, out.getvalue(), err.getvalue()


def _names(text: str) -> list[str]:
    return [n.strip() for n in text.split(",") if n.strip()]


def _verdict_lines(out: str) -> dict[str, str]:
    """``{name: "data" | "prior" | "held"}`` from the printed lines (identifiability or block report)."""
    seen = {}
    for line in (ln.strip() for ln in out.splitlines()):
        for head, verdict in (("determined by the data: ", "data"), ("held by the prior (†): ", "prior"),
                              ("held by the prior (†) although the data see them, weakly (see the warning): ", "prior"),
                              ("not calibrated (*), held at their start value: ", "held")):
            if line.startswith(head):
                for n in _names(line[len(head):].split(" — ")[0].rstrip(":")):
                    assert seen.setdefault(n, verdict) == verdict, f"{n}: two verdicts"
    return seen


def _dh_marks(out: str) -> dict[str, str]:
    """``{name: "" | "†" | "*"}`` of the printed DH table's cells."""
    lines = out[out.index("Calibrated DH table"):].splitlines()[3:]
    marks = {}
    for line in lines:
        if not re.match(r"\s+\d+\s", line):
            break
        j = int(line.split()[0])
        cells = re.findall(r"-?\d+\.\d{4}([†*]?) \(", line)
        assert len(cells) == 4, line
        marks |= {f"{g}_{j}": m for g, m in zip(("alpha", "a", "d", "theta"), cells)}
    return marks


def _warned(err: str) -> list[str]:
    """The parameters a warning says the poses determine less than the prior does."""
    return [n for m in re.findall(r"these poses determine (.*?) less than the prior", err) for n in _names(m)]


@pytest.fixture(scope="module", params=["preset", "dh_file"])
def draw_wire(request, tmp_path_factory):
    """The getting-started draw-wire file (300 rows, unknown anchor) calibrated under the default
    prior and under one twice as wide."""
    d = tmp_path_factory.mktemp(request.param)
    robot = _robot_args(request.param, d)
    assert _run(["simulate", *robot, "--out", str(d / "data.csv"), "--samples", "300", "--unknown-anchor"])[0] == 0
    runs = {}
    for name, extra in (("default", []), ("wide", ["--prior", WIDE])):
        code, out, err = _run(["calibrate", str(d / "data.csv"), *robot, "--out", str(d / f"{name}.json"), *extra])
        assert code == 0, err
        runs[name] = (out, err, json.loads((d / f"{name}.json").read_text()))
    return runs


def test_draw_wire_one_verdict_everywhere(draw_wire):
    out, err, saved = draw_wire["default"]
    printed = _verdict_lines(out)
    assert {"data", "prior"} <= set(printed.values())
    verdicts = saved["diagnostics"]["verdicts"]["verdict"]
    assert {n: verdicts[n] for n in printed} == printed  # the result file says what was printed
    marks = _dh_marks(out)
    for n, m in marks.items():  # the table's marks are the verdicts
        assert m == {"data": "", "prior": "†", "held": "*"}[verdicts[n]], (n, m, verdicts[n])
    # the cases: d_5 and θ_5 were "identifiable from the data" and marked † at once
    assert verdicts["d_5"] == verdicts["theta_5"] == "prior" and marks["d_5"] == marks["theta_5"] == "†"
    # what a draw wire cannot see is said once, in the normal output; this file warns about nothing
    assert "nothing to do" in out and "jaxcal: warning" not in err and _warned(err) == []
    assert "-7.435e-09" not in out and "-0.0000" not in out  # values zero to rounding print as 0


def test_draw_wire_verdict_follows_the_prior(draw_wire):
    """Independent of the verdict's formula: a parameter the prior holds has a σ that doubles with
    the prior's; one the data determine keeps its σ."""
    std = {k: run[2]["uncertainty"]["std"] for k, run in draw_wire.items()}
    verdicts = draw_wire["default"][2]["diagnostics"]["verdicts"]["verdict"]
    for n, s in std["default"].items():
        grows = std["wide"][n] / s > 1.5
        assert grows == (verdicts[n] == "prior"), (n, std["wide"][n] / s, verdicts[n])


@pytest.mark.parametrize("kind", ["preset", "urdf"])
def test_combined_plane_and_bar_one_verdict_everywhere(kind, tmp_path):
    """The block report names as determined by a block only what the data determine (plane data
    see d_1 and θ_1 only together with the planes, which the prior then holds), names what the
    prior holds in the verdicts' words, and the warnings of the final fit come once."""
    robot = _robot_args(kind, tmp_path)
    for m, n in (("plane", "200"), ("distance", "150")):
        assert _run(["simulate", *robot, "--seed", "1", "--measurement", m, "--samples", n,
                     "--out", str(tmp_path / f"{m}.csv")])[0] == 0
    code, out, err = _run(["calibrate", str(tmp_path / "plane.csv"), str(tmp_path / "distance.csv"), "--combine",
                           *robot, "--out-dir", str(tmp_path / "fit")])
    assert code == 0, err
    printed = _verdict_lines(out)
    block = json.loads((tmp_path / "fit" / "plane.json").read_text())["diagnostics"]["verdicts"]["verdict"]
    assert "prior" in printed.values() and all(block[n] == v for n, v in printed.items() if n in block)
    if kind == "preset":  # the combined output's DH table marks each parameter by its verdict, as one file's does
        marks = _dh_marks(out)
        assert len(marks) == 24 and "†" in marks.values()
        for n, m in marks.items():
            assert m == {"data": "", "prior": "†", "held": "*"}[block[n]], (n, m, block[n])
    report = [ln.strip() for ln in out.splitlines()]
    determined = [n for ln in report if " alone determines: " in ln for n in _names(ln.split(": ", 1)[1])]
    shared = [re.sub(r" \(.*", "", t) for ln in report if ln.startswith("shared by several blocks: ")
              for t in re.split(r", (?=[a-z_]+[\w@]* \()", ln.split(": ", 1)[1])]
    assert determined + shared and all(block.get(n, "data") == "data" for n in determined + shared), (
        [n for n in determined + shared if block.get(n) != "data"])
    assert set(_warned(err)) <= {n for n, v in printed.items() if v == "prior"}
    warnings = [ln for ln in err.splitlines() if ln.startswith("jaxcal: warning")]
    assert len(warnings) == len(set(warnings))  # the final fit's warnings, once
