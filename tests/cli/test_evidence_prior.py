"""``jaxcal calibrate --prior evidence`` on a DH-table file and a URDF robot: the prior's scale
chosen by the data is printed, written to the result file (and restored from it), shown by the
HTML report, and the posterior and verdicts are those under the chosen prior (a posterior σ is
never wider than its prior σ, so under the default 0.5° / 2 mm the parameters the data do not see
would show σ near 0.5° / 2 mm instead)."""

import math
import pathlib

import numpy as np
import pytest

import jaxcal
from jaxcal import robots
from jaxcal._calibration._io import load_result_dict, save_robot_csv
from jaxcal.cli import main

URDF = pathlib.Path(__file__).parents[1] / "data" / "urdf" / "ur10e.urdf"
NOISE = 0.5  # mm, `jaxcal simulate`'s default


@pytest.fixture(scope="module", params=["dh_file", "urdf"])
def robot_args(request, tmp_path_factory):
    if request.param == "dh_file":
        d = tmp_path_factory.mktemp("dh")
        save_robot_csv(robots.hsr_jr680(), d / "jr680.csv")
        return ["--robot", str(d / "jr680.csv")]
    return ["--robot", str(URDF), "--base", "base_link", "--tip", "tool0"]


def test_prior_evidence_through_the_cli(robot_args, tmp_path, capsys):
    data, out, page = tmp_path / "pos.csv", tmp_path / "res.json", tmp_path / "res.html"
    assert main(["simulate", *robot_args, "--measurement", "position", "--samples", "200", "--seed", "1",
                 "--out", str(data)]) == 0
    capsys.readouterr()
    code = main(["calibrate", str(data), *robot_args, "--measurement", "position", "--prior", "evidence",
                 "--out", str(out)])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "Traceback" not in printed.err
    d = load_result_dict(out)
    ev = d["prior_evidence"]
    assert ev["families"] == ["angles", "lengths"] and ev["rounds"] >= 2
    chosen = {"rad": math.radians(ev["angle_deg"]), "mm": ev["length_mm"]}
    assert 0 < ev["angle_deg"] < 0.5 and 0 < ev["length_mm"] < 2.0  # `jaxcal simulate`: 0.2°, 0.6 mm drawn
    assert all(s is not None and 0 < s < 1 for s in ev["log_std"])  # the data constrain both scales
    line = next(ln for ln in printed.out.splitlines() if ln.startswith("prior scale chosen by the evidence"))
    assert f"angles σ = {ev['angle_deg']:.3g}°" in line and f"lengths σ = {ev['length_mm']:.3g} mm" in line
    assert d["prior_spec"]["scale_by"] == "evidence" and d["prior_spec"]["angle_deg"] == pytest.approx(ev["angle_deg"])
    # posterior σ under the chosen prior: never wider than it, and as wide where the data see nothing
    unc = d["uncertainty"]
    verdicts = d["diagnostics"]["verdicts"]["verdict"]
    held = [n for n, v in verdicts.items() if v == "prior"]
    assert held
    for unit in ("rad", "mm"):
        sd = np.asarray([unc["std"][n] for n in unc["std"] if unc["units"][n] == unit])
        assert sd.max() <= chosen[unit] * (1 + 1e-6), (unit, sd.max(), chosen[unit])
    assert max(unc["std"][n] / chosen[unc["units"][n]] for n in held) > 0.9
    # the fit at the floor of fresh poses (a tracker's 3-D distance: σ√3), and the result restored
    assert d["metrics_mm"]["test, after"]["rmse"] < 1.3 * NOISE * math.sqrt(3), d["metrics_mm"]
    res = jaxcal.load_result(out)
    assert res.prior.evidence.factors == pytest.approx(tuple(ev["factors"]))
    assert main(["report", str(out), "--html", str(page)]) == 0
    assert "prior scale chosen by the evidence" in page.read_text(encoding="utf-8")
