"""The command line with every robot type: a preset, a DH table file, a modified-DH (Craig) table
file, a URDF chain and a kinematic tree, each through the features that read the robot's own
parameters (the combined fit's length scale, a previous result or a fleet prior as ``--prior``,
`drift`, the non-geometric errors).

Each feature ends with exit 0 and numbers near the simulated noise, or a one-line refusal; never
a traceback (``jaxcal calibrate --combine`` with a URDF robot ended in ``'SerialChain' object has
no attribute 'a'``, ``--prior previous.json`` of a URDF result in ``unknown parameter name
'offset_1'``, and a ``# convention: modified`` line was ignored)."""

import csv
import json
import pathlib
import re
import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from jaxcal import robots
from jaxcal._calibration._io import load_result_dict, save_robot_csv
from jaxcal.cli import main

URDF = pathlib.Path(__file__).parents[1] / "data" / "urdf" / "ur10e.urdf"
NOISE = 0.5  # mm, `jaxcal simulate`'s default
NOISE_PX = 0.3  # px, the camera files' noise here

# Franka Emika Panda as published in Craig's (modified DH) convention: alpha_{i-1} (deg), a_{i-1}
# (mm), d_i (mm), theta_i (deg); joint limits (deg); the flange 107 mm along the last z
PANDA_CRAIG = np.array([
    [0.0, 0.0, 333.0, 0.0, -166, 166],
    [-90.0, 0.0, 0.0, 0.0, -101, 101],
    [90.0, 0.0, 316.0, 0.0, -166, 166],
    [90.0, 82.5, 0.0, 0.0, -176, -4],
    [-90.0, -82.5, 384.0, 0.0, -166, 166],
    [90.0, 0.0, 0.0, 0.0, -1, 215],
    [90.0, 88.0, 0.0, 0.0, -166, 166],
])
PANDA_TOOL = (0.0, 0.0, 207.0)


def write_panda_craig(path) -> pathlib.Path:
    """The Panda's Craig table as a DH table file with its ``# convention: modified`` line."""
    lines = ["# name: panda_craig", "# convention: modified", "# tool_mm: " + ",".join(map(str, PANDA_TOOL)),
             "alpha_deg,a_mm,d_mm,theta_deg,q_min_deg,q_max_deg"]
    lines += [",".join(repr(float(v)) for v in row) for row in PANDA_CRAIG]
    path = pathlib.Path(path)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def robot_type_args(kind: str, d: pathlib.Path) -> list[str]:
    """``--robot ...`` arguments of a robot type (``"preset"``, ``"dh_file"``, ``"modified_dh_file"``,
    ``"urdf"``, ``"tree"``: the dual-arm preset with both tool tips), its files written into ``d``."""
    if kind == "preset":
        return ["--robot", "hsr_jr680"]
    if kind == "dh_file":
        save_robot_csv(robots.hsr_jr680(), d / "jr680.csv")
        return ["--robot", str(d / "jr680.csv")]
    if kind == "modified_dh_file":
        return ["--robot", str(write_panda_craig(d / "panda.csv"))]
    if kind == "tree":
        return ["--robot", "dual_arm_ma1400", "--tip", "left_tool,right_tool"]
    return ["--robot", str(URDF), "--base", "base_link", "--tip", "tool0"]


@pytest.fixture(scope="module", params=["preset", "dh_file", "modified_dh_file", "urdf"])
def robot_args(request, tmp_path_factory):
    """``--robot ...`` arguments of each robot type."""
    return robot_type_args(request.param, tmp_path_factory.mktemp(request.param))


def _run(argv, capsys):
    code = main(argv)
    out = capsys.readouterr()
    assert "Traceback" not in out.err, out.err
    return code, out


def test_previous_result_as_prior(robot_args, tmp_path, capsys):
    """The drift workflow's prior: a position file calibrated under the previous result of the same
    unit (the parameter names of its robot type), on a new day of the same set-up."""
    sim = ["simulate", *robot_args, "--seed", "1"]
    assert _run([*sim, "--measurement", "position", "--samples", "200", "--out", str(tmp_path / "a.csv")],
                capsys)[0] == 0
    assert _run(["calibrate", str(tmp_path / "a.csv"), *robot_args, "--measurement", "position",
                 "--out", str(tmp_path / "a.json")], capsys)[0] == 0
    assert _run(["simulate", "--like", str(tmp_path / "a.json"), "--seed", "2", "--out", str(tmp_path / "b.csv")],
                capsys)[0] == 0
    code, out = _run(["calibrate", str(tmp_path / "b.csv"), *robot_args, "--measurement", "position",
                      "--prior", str(tmp_path / "a.json"), "--out", str(tmp_path / "b.json")], capsys)
    assert code == 0, out.err
    assert "previous calibration" in out.out
    d = load_result_dict(tmp_path / "b.json")
    assert d["metrics_mm"]["test, after"]["rmse"] < 1.3 * NOISE * np.sqrt(3), d["metrics_mm"]  # a tracker's 3-D distance


@pytest.mark.parametrize("robot_args", ["dh_file", "urdf"], indirect=True)
def test_combined_fit_with_relations(robot_args, seed_files, tmp_path, capsys):
    """Plane + distance-bar files of one simulated set-up in one fit with a (loose) known relation
    between two planes: each block's σ near the simulated noise, the bar setting the length scale.
    The robot enters the combined fit through its length entries (``nominal_lengths``), which a DH
    table gives alike in both conventions and a chain gives as its joint-origin translations: a
    DH table file (the preset's programs) and a URDF chain cover both. The files are the module's
    seed files (`jaxcal simulate`, seed 1: 300 plane rows, 200 bar rows), whose simulations and
    row counts the other combined fits of this module share."""
    rel = tmp_path / "rel.txt"
    rel.write_text("plane_angle table wall_a 90 45  # loose: a relation the fit barely leans on\n")
    code, out = _run(["calibrate", str(seed_files["plane"]), str(seed_files["bar"]), "--combine",
                      "--relations", str(rel), *robot_args, "--out-dir", str(tmp_path / "fit")], capsys)
    assert code == 0, out.err
    combined = json.loads((tmp_path / "fit" / "combined.json").read_text())
    assert combined["status"] == "converged"
    for name in ("plane", "bar"):  # each block's σ estimated near the simulated noise
        assert 0.6 * NOISE < combined["sigma"][name] < 1.5 * NOISE, combined["sigma"]
    assert "length scale: set by bar" in out.out
    _check_block_tables(out.out, combined, tmp_path / "fit", chain=robot_args[1].endswith(".urdf"))
    # the combined result's report page: every block's section, the robot table, the relation
    pytest.importorskip("matplotlib")
    code, _ = _run(["report", str(tmp_path / "fit" / "combined.json"), "--html", str(tmp_path / "r.html")], capsys)
    assert code == 0
    page = (tmp_path / "r.html").read_text(encoding="utf-8")
    ET.fromstring(page.split("\n", 1)[1])  # well-formed (after the doctype line)
    for section in ("Blocks", "Warnings", "Calibrated robot", "Which block sees what", "Relations",
                    "Block plane: plane data", "Block bar: distance data"):
        assert f"<h2>{section}" in page, section
    assert "no held-out data" in page and "plane_angle" in page
    for b in combined["blocks"][:2]:  # each block's σ̂ and its file's stated noise, as the JSON has them
        assert f"<td>{b['sigma_hat']:.4f}</td>" in page and f"<td>{b['sigma_stated']:.4f}</td>" in page
    assert page.count("data:image/png;base64,") >= 6  # per block: histogram, joints, workspace


def _check_block_tables(out: str, combined: dict, fit: pathlib.Path, chain: bool) -> None:
    """`calibrate --combine` prints, per block, the before/after table of its rows in its unit
    (the after row = the block's statistics in combined.json, the same rows in its result file),
    the robot's table (DH or per-joint corrections) and each block's extras."""
    lines = out.splitlines()
    assert any(ln.startswith("Accuracy before/after calibration, per block") for ln in lines)
    assert "these are training numbers: nothing was held out" in out
    for b in (b for b in combined["blocks"] if "result" in b):
        head = next(i for i, ln in enumerate(lines) if ln.startswith(f"{b['name']} ({b['name']}.csv: "))
        rows = {}
        for ln in lines[head + 3:]:
            m = re.fullmatch(r"\s*(train, [a-z ]+?)\s+(\S+)\s+(\S+)\s+(\S+)", ln)
            if m is None:
                break
            rows[m[1]] = [float(v) for v in m.groups()[1:]]
        assert rows["train, after"] == pytest.approx([b["rmse"], b["mean"], b["max"]], abs=6e-5), (b["name"], rows)
        assert rows["train, before"][0] > 2 * rows["train, after"][0]
        saved = json.loads((fit / f"{b['name']}.json").read_text())
        assert saved["metrics_mm"]["train, after"]["rmse"] == pytest.approx(b["rmse"], rel=1e-6)
        assert len(saved["rows"]["train"]["after_mm"]) == b["n_samples"] == saved["settings"]["n_samples"]
        assert b["result"]["metrics_mm"] == saved["metrics_mm"]  # combined.json holds the same tables
    assert ("Calibrated joint corrections of" if chain else "Calibrated DH table") in out
    assert out.count("estimated extras (") == 1 and "plane_d@table" in out  # the shared tool once
    _check_extras_sigma(out, combined)


def _check_extras_sigma(out: str, combined: dict) -> None:
    """The default prior has no term on an extra: an extra is † only through the robot parameters
    it trades with (a plane's offset and the robot's base height), its ± their prior σ, so each †
    extra also shows its σ relative to the calibrated robot, smaller than its ±; the table plane's
    offset relative to the robot is about the mean of its rows' noise, σ̂/√n (all planes share the
    tool point, so up to 2×)."""
    line = next(ln for ln in out.splitlines() if ln.startswith("estimated extras ("))
    entries = re.findall(r"(\S+?)(†?) [+-][\d.]+ ± (\S+) \S+(?: \(robot-relative ± (\S+)\))?", line)
    assert entries and all(name.startswith(("tool_", "plane_")) for name, *_ in entries), line
    for name, held, sd, rel in entries:
        assert bool(held) == bool(rel), (name, line)  # every † extra, and only those, robot-relative
        assert not rel or float(rel) < float(sd), (name, line)
    rel = {name: float(r) for name, _, _, r in entries if r}
    assert "plane_d@table" in rel, line  # at the base height's prior σ (d_1 / the first joint's dz)
    plane = next(b for b in combined["blocks"] if b["name"] == "plane")
    n_table = 100  # of the 300 rows of `jaxcal simulate --measurement plane` (table, wall_a, wall_b)
    assert 0.8 < rel["plane_d@table"] / (plane["sigma_hat"] / np.sqrt(n_table)) < 2.0, (rel, plane["sigma_hat"])


def test_modified_dh_file_at_the_floor_on_independent_data(tmp_path, capsys):
    """Tool positions made in plain NumPy from the Panda's Craig table with small errors (0.3 mm,
    0.03°) and 0.05 mm noise: `calibrate --robot panda.csv` with the file's `# convention: modified`
    reaches the floor of a 3-D distance (σ√3 on fresh poses, within 15 %), and the result says
    "modified"."""
    from conftest import np_rx, np_rz

    robot_file = write_panda_craig(tmp_path / "panda.csv")
    rng = np.random.default_rng(7)
    alpha, a, d, theta = (np.deg2rad(PANDA_CRAIG[:, 0]), PANDA_CRAIG[:, 1], PANDA_CRAIG[:, 2],
                          np.deg2rad(PANDA_CRAIG[:, 3]))
    da, dd = rng.normal(0, 0.3, 7), rng.normal(0, 0.3, 7)
    dal, dth = np.deg2rad(rng.normal(0, 0.03, 7)), np.deg2rad(rng.normal(0, 0.03, 7))
    n, sigma = 400, 0.05
    q = np.deg2rad(rng.uniform(PANDA_CRAIG[:, 4], PANDA_CRAIG[:, 5], size=(n, 7)))

    def tr(x, z):
        T = np.eye(4)
        T[0, 3], T[2, 3] = x, z
        return T

    rows = []
    for k in range(n):
        T = np.eye(4)
        for i in range(7):  # Craig: Rx(α_{i-1}) · Tx(a_{i-1}) · Rz(θ_i + q_i) · Tz(d_i)
            T = T @ np_rx(alpha[i] + dal[i]) @ tr(a[i] + da[i], 0.0) @ np_rz(theta[i] + dth[i] + q[k, i]) @ \
                tr(0.0, d[i] + dd[i])
        p = (T @ np.append(PANDA_TOOL, 1.0))[:3] + rng.normal(0, sigma, 3)
        rows.append(",".join(repr(float(v)) for v in np.concatenate([np.rad2deg(q[k]), p])))
    data = tmp_path / "track.csv"
    data.write_text("# kind: position\n" + ",".join(f"q{i + 1}_deg" for i in range(7)) + ",x_mm,y_mm,z_mm\n"
                    + "\n".join(rows) + "\n")
    code, out = _run(["calibrate", str(data), "--robot", str(robot_file), "--measurement", "position",
                      "--out", str(tmp_path / "res.json")], capsys)
    assert code == 0, out.err
    d = load_result_dict(tmp_path / "res.json")
    assert d["robot"]["convention"] == "modified"
    assert d["metrics_mm"]["test, after"]["rmse"] < 1.15 * sigma * np.sqrt(3), d["metrics_mm"]


def test_urdf_fleet_prior_used_by_a_new_unit(tmp_path, capsys):
    """Three simulated units of the URDF robot → `jaxcal fleet-prior` → `--prior FILE` for a fourth
    (the chain's parameter names, ``offset_1`` ..., in the prior file)."""
    urdf = ["--robot", str(URDF), "--base", "base_link", "--tip", "tool0"]
    results = []
    for unit in range(4):
        csv = tmp_path / f"u{unit}.csv"
        assert _run(["simulate", *urdf, "--measurement", "position", "--samples", "150", "--seed", str(10 + unit),
                     "--out", str(csv)], capsys)[0] == 0
        if unit < 3:
            results.append(tmp_path / f"u{unit}.json")
            assert _run(["calibrate", str(csv), *urdf, "--measurement", "position", "--out", str(results[-1])],
                        capsys)[0] == 0
    code, out = _run(["fleet-prior", *map(str, results), "--out", str(tmp_path / "fleet.prior.json")], capsys)
    assert code == 0, out.err
    code, out = _run(["calibrate", str(tmp_path / "u3.csv"), *urdf, "--measurement", "position",
                      "--prior", str(tmp_path / "fleet.prior.json"), "--out", str(tmp_path / "u3.json")], capsys)
    assert code == 0, out.err
    assert "offset_1" in (tmp_path / "fleet.prior.json").read_text()


@pytest.mark.parametrize("robot_args", ["tree"], indirect=True)
def test_tree_fleet_prior_drift_and_nongeometric_errors(robot_args, tmp_path, capsys):
    """A kinematic tree (two arms on a torso; the position files measure the first tip) through the
    features that read its own parameter names: three units as a fleet (`calibrate` of three files,
    `--out-dir`) with harmonic errors at joints 2 and 3, each unit's σ̂ the simulated noise (within
    25 %); `fleet-prior` of them and `--prior FILE` for a fourth unit, at the floor on its held-out
    rows (σ√3, within 30 %); `drift` from one unit to another (another true robot: parameters
    moved, exit 1); `--compliance` refused in one line (not modelled on a tree: a shared joint's
    gravity torque sums its branches). Two compiled fits (the fleet's, the prior's) on 100-row files."""
    fit = ["--measurement", "position", "--harmonics", "2,3:1"]
    files = [tmp_path / f"u{unit}.csv" for unit in range(4)]
    for unit, path in enumerate(files):
        assert _run(["simulate", *robot_args, "--measurement", "position", "--samples", "100", "--seed",
                     str(10 + unit), "--out", str(path)], capsys)[0] == 0
    fleet = tmp_path / "fleet"
    code, out = _run(["calibrate", *map(str, files[:3]), *robot_args, *fit, "--out-dir", str(fleet)], capsys)
    assert code == 0, out.err
    with open(fleet / "summary.csv", newline="") as f:
        units = list(csv.DictReader(f))
    assert [u["status"] for u in units] == ["converged"] * 3, units
    assert all(abs(float(u["noise_std_mm"]) / NOISE - 1) < 0.25 for u in units), units
    # the floor from the σ the files state (their '# noise_std_mm:' line), no --noise-std needed
    assert f"floor for sensor σ {NOISE:g} mm" in out.out and all(0.8 < float(u["floor_ratio"]) < 1.2 for u in units)
    prior = tmp_path / "tree.prior.json"
    code, out = _run(["fleet-prior", *(str(fleet / f"u{unit}.json") for unit in range(3)), "--out", str(prior)], capsys)
    assert code == 0, out.err
    assert all(name in prior.read_text() for name in ("offset_8", "tip_dx@left_tool", "h1s_2")), "the tree's names"
    code, out = _run(["calibrate", str(files[3]), *robot_args, *fit, "--prior", str(prior),
                      "--out", str(tmp_path / "u3.json")], capsys)
    assert code == 0, out.err
    assert "fleet of 3 units of dual_arm_ma1400" in out.out
    rmse = load_result_dict(tmp_path / "u3.json")["metrics_mm"]["test, after"]["rmse"]
    assert rmse < 1.3 * NOISE * np.sqrt(3), rmse
    code, out = _run(["drift", str(fleet / "u0.json"), str(fleet / "u1.json")], capsys)
    assert code == 1 and " moved " in out.out.splitlines()[0], out.out
    code, out = _run(["calibrate", str(files[0]), *robot_args, "--measurement", "position", "--compliance", "default"],
                     capsys)
    assert code == 2 and out.err.count("\n") == 1, out.err
    assert "--compliance" in out.err and "kinematic tree" in out.err and "--harmonics" in out.err, out.err


def test_chain_parameter_names_known_before_any_chain_is_made():
    """A prior naming a chain's parameters parses in a fresh process that has made no chain yet
    (the group names are registered with the chain model, not by its first layout)."""
    code = ("from jaxcal._fit._objective import Prior; "
            "p = Prior.parse('offset_1=0.01,dx_2=0.5,tip_dx=1,tip_drz=0.001'); print(len(p.overrides))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "4"


@pytest.fixture(scope="module")
def seed_files(robot_args, tmp_path_factory):
    """`jaxcal simulate` files of one seed (position, point contact, plane contact, distance bar),
    and a point-contact file of another seed (another true robot): ``{name: path}``."""
    d = tmp_path_factory.mktemp("seed_files")
    files = {}
    for name, kind, seed, n in (("pos", "position", 1, 300), ("point", "point", 1, 300), ("plane", "plane", 1, 300),
                                ("bar", "distance", 1, 200), ("point_seed2", "point", 2, 300)):
        files[name] = d / f"{name}.csv"
        assert main(["simulate", *robot_args, "--measurement", kind, "--seed", str(seed), "--samples", str(n),
                     "--out", str(files[name])]) == 0
    return files


def _combined_sigma(robot_args, files, names, out_dir, capsys):
    """`jaxcal calibrate FILES --combine`: ``({block: σ̂}, stderr)``."""
    code, out = _run(["calibrate", *(str(files[n]) for n in names), "--combine", *robot_args,
                      "--out-dir", str(out_dir)], capsys)
    assert code == 0, out.err
    blocks = json.loads((out_dir / "combined.json").read_text())["blocks"]
    return {b["name"]: b["sigma_hat"] for b in blocks}, out.err


NOISE_LINE = "noise its file states"  # the words of the warning about a block's σ̂ (stated_noise_warning)


@pytest.mark.parametrize("robot_args", ["preset", "dh_file", "urdf"], indirect=True)
@pytest.mark.parametrize("names", [("pos", "point"), ("plane", "bar")])
def test_files_of_one_seed_combine_at_their_noise(robot_args, seed_files, names, tmp_path, capsys):
    """Files of every kind that `jaxcal simulate` writes with one seed share one true set-up (the
    robot, the tool, the sensor frame): combined, each block's σ̂ is the simulated noise (within
    20 %; the contact files once had a tool 2.3 mm off that the position file lacked: σ̂ 0.95 mm on
    both blocks for 0.5 mm noise), and no block is warned about."""
    sigma, err = _combined_sigma(robot_args, seed_files, names, tmp_path / "fit", capsys)
    for name in names:
        assert abs(sigma[name] / NOISE - 1) < 0.2, sigma
    assert NOISE_LINE not in err, err
    assert "outlier" not in err, err  # clean data: no alarm (the pooled scan once named 3.1–3.4 σ̂ plane rows)


@pytest.mark.parametrize("robot_args", ["preset", "dh_file", "urdf"], indirect=True)
def test_combined_fit_names_a_planted_row_by_file_and_row(robot_args, seed_files, tmp_path, capsys):
    """The plane + bar files of the seed with one bar row 10σ off (5 mm on its 0.5 mm noise): one
    outlier warning, naming bar.csv and that 1-based data row, in the bar's own σ̂ and unit at the
    stated false-alarm rate, and nothing about the plane file (clean: no warning, above). The
    files' shapes are the clean test's, so the fit reuses its compiled programs."""
    bar = tmp_path / "bar.csv"
    lines = seed_files["bar"].read_text().splitlines()
    head = next(i for i, ln in enumerate(lines) if ln.startswith("q1"))
    col = lines[head].split(",").index("distance_mm")
    row = 37  # 1-based data row
    cells = lines[head + row].split(",")
    cells[col] = repr(float(cells[col]) + 5.0)
    lines[head + row] = ",".join(cells)
    bar.write_text("\n".join(lines) + "\n")
    _, err = _combined_sigma(robot_args, {**seed_files, "bar": bar}, ("plane", "bar"), tmp_path / "fit", capsys)
    warned = [ln for ln in err.splitlines() if "outlier" in ln]
    assert len(warned) == 1, err
    line = warned[0]
    assert line.startswith(f"jaxcal: warning: {bar}: 1 outlier row at data row {row}: residual "), line
    assert 3.5 < float(line.split(": residual ")[1].split()[0]) < 6.5, line  # the planted 5 mm and the row's noise
    m = re.search(r"above the threshold ([0-9.]+) mm = ([0-9.]+) σ̂ \(σ̂ = ([0-9.]+) mm, these rows' robust σ; what a "
                  r"file of 200 clean rows crosses with a 1 % chance\); nothing was dropped — ", line)
    assert m is not None, line
    thr, k, s = map(float, m.groups())
    assert 0.35 < s < 0.7 and 3.5 < k < 6 and thr < 5.0  # the bar's own σ̂ (0.5 mm simulated), in mm
    assert "0-based" not in err and "--combine" not in line


@pytest.mark.parametrize("robot_args", ["preset", "dh_file"], indirect=True)
def test_camera_file_of_the_seed_combines_at_its_noise(robot_args, seed_files, tmp_path, capsys):
    """A camera file of the seed (10 images, 0.3 px) with its position file: each block's σ̂ at its
    noise within 20 % (the camera was once simulated on another robot than the other kinds of its
    seed: σ̂ 1.57 px for 0.3 px). Not the URDF chain: its camera program alone compiles for ~17 s
    on a busy 2-core host; the chain's set-up is the position file's (`test_files_of_one_seed…`)."""
    cam = tmp_path / "cam.csv"
    assert main(["simulate", *robot_args, "--measurement", "camera", "--seed", "1", "--samples", "10",
                 "--noise-std", str(NOISE_PX), "--out", str(cam)]) == 0
    sigma, err = _combined_sigma(robot_args, {**seed_files, "cam": cam}, ("pos", "cam"), tmp_path / "fit", capsys)
    assert abs(sigma["pos"] / NOISE - 1) < 0.2 and abs(sigma["cam"] / NOISE_PX - 1) < 0.2, sigma
    assert NOISE_LINE not in err, err


@pytest.mark.parametrize("robot_args", ["preset", "dh_file", "urdf"], indirect=True)
def test_block_of_another_set_up_is_named(robot_args, seed_files, tmp_path, capsys):
    """A point-contact file of another seed (another true robot) combined with a position file:
    one warning, naming that file with its σ̂ and stated noise; the position file is not named."""
    sigma, err = _combined_sigma(robot_args, seed_files, ("pos", "point_seed2"), tmp_path / "fit", capsys)
    assert sigma["point_seed2"] >= 2 * NOISE, sigma  # the misfit the warning is about
    warned = [line for line in err.splitlines() if NOISE_LINE in line]
    assert len(warned) == 1 and str(seed_files["point_seed2"]) in warned[0], err
    assert f"{sigma['point_seed2']:.3g} mm" in warned[0] and "noise_std_mm: 0.5" in warned[0], warned


@pytest.mark.parametrize("robot_args", ["preset", "dh_file", "urdf"], indirect=True)
def test_noise_line_that_understates_is_named(robot_args, seed_files, tmp_path, capsys):
    """A file whose '# noise_std_mm:' line says 0.15 mm for 0.5 mm noise: `jaxcal calibrate` of it
    alone, and of it combined with a file of its seed, warns naming it; its stated σ is quoted."""
    low = tmp_path / "point_low.csv"
    low.write_text(seed_files["point"].read_text().replace("# noise_std_mm: 0.5\n", "# noise_std_mm: 0.15\n"))
    assert "noise_std_mm: 0.15" in low.read_text()
    code, out = _run(["calibrate", str(low), *robot_args], capsys)
    assert code == 0, out.err
    warned = [line for line in out.err.splitlines() if NOISE_LINE in line]
    assert len(warned) == 1 and str(low) in warned[0] and "noise_std_mm: 0.15" in warned[0], out.err
    files = {**seed_files, "point_low": low}
    sigma, err = _combined_sigma(robot_args, files, ("pos", "point_low"), tmp_path / "fit", capsys)
    assert abs(sigma["point_low"] / NOISE - 1) < 0.2, sigma  # the data are fine: only the line is wrong
    warned = [line for line in err.splitlines() if NOISE_LINE in line]
    assert len(warned) == 1 and str(low) in warned[0], err
