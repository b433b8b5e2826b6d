"""The ``jaxcal`` command line: help, simulate → calibrate → JSON round trip, reproduce, bad input."""

import json

import numpy as np
import pytest

from jaxcal import load_csv, robots
from jaxcal._calibration._io import load_result, load_result_dict, load_robot_csv, save_robot_csv
from jaxcal.cli import main

N = 120


@pytest.fixture(scope="module")
def data_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "data.csv"
    assert main(["simulate", "--out", str(path), "--samples", str(N), "--seed", "3"]) == 0
    return path


def _one_error_line(capsys, code, argv, match):
    assert main(argv) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("jaxcal: error:") and match in err[0], err[0]
    assert "Traceback" not in err[0]


@pytest.mark.parametrize("sub", [[], ["reproduce"], ["calibrate"], ["simulate"], ["report"], ["evaluate"]])
def test_help(sub, capsys):
    assert main([*sub, "--help"]) == 0
    out = capsys.readouterr().out
    assert "usage: jaxcal" in out
    if sub in (["calibrate"], ["simulate"]):
        assert "q1_deg" in out and "length_mm" in out and "alpha_deg,a_mm,d_mm,theta_deg" in out
    if sub == ["reproduce"]:
        assert "--quick" in out and "ga ekf bso lm iwoa rbfnn adam adamodw" in out


def test_no_command_prints_help(capsys):
    assert main([]) == 2
    assert "COMMAND" in capsys.readouterr().out


def test_simulate_writes_a_loadable_csv(data_csv):
    text = data_csv.read_text()
    assert "# anchor_mm:" in text and "q1_deg" in text
    ds = load_csv(data_csv)
    assert ds.n == N and ds.kind == "cable" and ds.dof == 6


def test_calibrate_prints_tables_and_round_trips(data_csv, tmp_path, capsys):
    out = tmp_path / "result.json"
    assert main(["calibrate", str(data_csv), "--robot", "hsr_jr680", "--method", "lm", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "test, after" in text and "Calibrated DH table" in text and "rank 19" in text
    d = load_result_dict(out)
    assert d["status"] == "converged" and d["settings"]["n_test"] == 24
    assert d["settings"]["outlier_rows_test"] == [] and "outliers in the test rows" not in text
    before, after = d["metrics_mm"]["test, before"], d["metrics_mm"]["test, after"]
    assert after["rmse"] < before["rmse"] / 3
    # the saved result predicts like the original: same held-out metrics, same DH table
    res = load_result(out)
    import jax

    k_split, _ = jax.random.split(jax.random.key(0))
    _, test = load_csv(data_csv).split(k_split, 0.2)
    assert res.evaluate(test).rmse == pytest.approx(after["rmse"], rel=1e-10)
    np.testing.assert_allclose(res.dh_table(), np.asarray(d["calibrated_dh_table"]["rows"]), rtol=1e-12)
    # the default prior: MAP over all 24 DH deviations, of which the data identify 19; nothing held
    assert res.space.n_free == 24 and res.identifiability["rank"] == 19 and res.identifiability["held"] == []
    assert f"{res.dh_table()[0, 1]:.4f}" in text  # a1 as printed


def test_a_gross_test_row_is_named(data_csv, tmp_path, capsys):
    """A gross error in a held-out row (not fitted) is named by its data row, as the training rows'
    outliers are, and kept in the result file."""
    import csv

    from jaxcal._datasets._split import seed_split

    rows = list(csv.reader(data_csv.open()))
    head = next(i for i, r in enumerate(rows) if r and r[0].startswith("q1"))
    col = rows[head].index("length_mm")
    _, _, test_idx = seed_split(0, N, 0.2)
    bad = int(test_idx[3])
    rows[head + 1 + bad][col] = str(float(rows[head + 1 + bad][col]) + 40.0)
    path, out = tmp_path / "bad.csv", tmp_path / "bad.json"
    with path.open("w", newline="") as f:
        csv.writer(f).writerows(rows)
    assert main(["calibrate", str(path), "--robot", "hsr_jr680", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    line = next(ln for ln in err.splitlines() if "test rows: 1 outlier row" in ln)
    # the file and its 1-based data row, σ̂ with its unit, the threshold in σ̂, the file's false-alarm rate
    assert line.startswith(f"jaxcal: warning: {path}, test rows: 1 outlier row at data row {bad + 1}: residual ")
    assert " mm, above the threshold " in line and " σ̂ (σ̂ = " in line
    assert "what a file of 120 clean rows crosses with a 1 % chance" in line
    assert "0-based" not in err and "nothing was dropped" in line and f"--exclude-rows {bad + 1}" in line
    assert load_result_dict(out)["settings"]["outlier_rows_test"] == [bad + 1]


def test_robot_file_round_trip(tmp_path):
    p = tmp_path / "robot.csv"
    r = robots.hsr_jr680()
    save_robot_csv(r, p)
    back = load_robot_csv(p)
    np.testing.assert_allclose(back.dh_table_deg(), r.dh_table_deg(), atol=1e-12)
    np.testing.assert_allclose(np.asarray(back.q_max), np.asarray(r.q_max), rtol=1e-14)
    assert back.name == "hsr_jr680"


def test_bad_input_is_one_line(data_csv, tmp_path, capsys):
    d = str(data_csv)
    _one_error_line(capsys, 2, ["calibrate", d, "--robot", "r2d2"], "unknown robot 'r2d2'")
    _one_error_line(capsys, 2, ["calibrate", d, "--robot", "hsr_jr680", "--method", "magic"], "unknown method")
    _one_error_line(capsys, 2, ["calibrate", str(tmp_path / "none.csv"), "--robot", "hsr_jr680"], "not found")
    _one_error_line(capsys, 2, ["calibrate", d, "--robot", "hsr_jr680", "--anchor", "1,2"], "--anchor")
    _one_error_line(capsys, 2, ["calibrate", d, "--robot", "hsr_jr680", "--estimate", "wings"], "--estimate")
    _one_error_line(capsys, 2, ["calibrate", d, "--robot", "puma560x"], "unknown robot")
    lines = data_csv.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    # a missing column
    bad = tmp_path / "nocol.csv"
    bad.write_text("\n".join([lines[header].replace(",length_mm", "")]
                             + [",".join(x.split(",")[:-1]) for x in lines[header + 1:]]) + "\n")
    _one_error_line(capsys, 2, ["calibrate", str(bad), "--robot", "hsr_jr680"], "length_mm")
    # a NaN row
    nan = tmp_path / "nan.csv"
    rows = lines[: header + 1] + [lines[header + 1].rsplit(",", 1)[0] + ",nan"] + lines[header + 2:]
    nan.write_text("\n".join(rows) + "\n")
    _one_error_line(capsys, 2, ["calibrate", str(nan), "--robot", "hsr_jr680"], "NaN")
    # too few samples for the free parameters
    few = tmp_path / "few.csv"
    few.write_text("\n".join(lines[: header + 1 + 12]) + "\n")
    _one_error_line(capsys, 2, ["calibrate", str(few), "--robot", "hsr_jr680"], "too few samples")
    # a DH table file without the required columns
    rob = tmp_path / "robot.csv"
    rob.write_text("alpha_deg,a_mm,d_mm\n0,1,2\n")
    _one_error_line(capsys, 2, ["calibrate", d, "--robot", str(rob)], "theta_deg")
    # wrong number of joints
    rob.write_text("alpha_deg,a_mm,d_mm,theta_deg\n0,100,0,0\n0,100,0,0\n")
    _one_error_line(capsys, 2, ["calibrate", d, "--robot", str(rob)], "joint")
    _one_error_line(capsys, 2, ["reproduce", "--methods", "nope", "--out", str(tmp_path)], "unknown method")
    _one_error_line(capsys, 2, ["report", str(tmp_path)], "no sweep")
    # argparse errors: usage + one error line, status 2
    assert main(["calibrate", d]) == 2
    assert "--robot" in capsys.readouterr().err


def test_reproduce_small_then_report(tmp_path, capsys):
    out = tmp_path / "rep"
    argv = ["reproduce", "--methods", "lm", "--seeds", "2", "--samples", str(N), "--out", str(out), "--quiet"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "Table III" in text and "Table IV" in text and "Table V" in text and "M4" in text
    for name in ("table3_accuracy.md", "table3_accuracy.csv", "table4_convergence.txt", "table5_dh.md",
                 "summary.json", "report.md", "fig2_accuracy.png", "fig3_training.pdf", "fig4_positioning.png"):
        assert (out / name).stat().st_size > 100, name
    s = json.loads((out / "summary.json").read_text())
    assert s["summary"]["n_seeds"] == 2 and s["summary"]["runs"]["lm"]["status"] == {"converged": 2}
    # report regenerates the same tables from the sweep's chunks without computing
    (out / "table3_accuracy.txt").unlink()
    assert main(["report", str(out), "--no-figures"]) == 0
    again = capsys.readouterr().out
    assert (out / "table3_accuracy.txt").exists()
    assert again.split("Table IV")[0].strip() == text.split("Table IV")[0].strip()


def test_choosing_parameters_and_settings(data_csv, capsys):
    d = str(data_csv)
    assert main(["calibrate", d, "--robot", "hsr_jr680", "--free", "anchor,offset", "--test-fraction", "0"]) == 0
    out = capsys.readouterr().out
    assert "determined by the data: anchor_x, anchor_y, anchor_z, cable_offset" in out
    assert main(["calibrate", d, "--robot", "hsr_jr680", "--fix", "d_6,theta", "--test-fraction", "0"]) == 0
    out = capsys.readouterr().out
    ident = next(line for line in out.splitlines() if line.startswith("determined by the data:"))
    assert "d_6" not in ident and "theta" not in ident and "a_2" in ident
    _one_error_line(capsys, 2, ["calibrate", d, "--robot", "hsr_jr680", "--set", "foo=1"],
                    "unknown setting(s) ['foo'] for method lm; its settings: atol, linear_solver, max_steps, rtol")
    _one_error_line(capsys, 2, ["calibrate", d, "--robot", "hsr_jr680", "--method", "ga", "--set", "steps=3"],
                    "generations")
    _one_error_line(capsys, 2, ["calibrate", d, "--robot", "hsr_jr680", "--fix", "wings"], "unknown parameter or group")


def test_simulate_help_describes_what_it_writes(capsys):
    """``jaxcal simulate --help`` lists the formats it writes, not marker data it cannot make."""
    assert main(["simulate", "--help"]) == 0
    out = capsys.readouterr().out
    assert "what it writes" in out and "u_1_px" in out and "distance_mm" in out
    assert "marker_1_x_mm" not in out and "makes no marker" in out


def test_garbage_collector_after_the_command(monkeypatch):
    """``main`` (called inside a longer-lived process) leaves the collector as it found it and
    freezes nothing; the program's entry point (``console_main``: the console script and
    ``python -m jaxcal.cli``) freezes the command's objects before switching it on again, so that
    neither a collection after the command nor the one at exit traverses them."""
    import gc
    import pathlib

    import tomllib

    root = pathlib.Path(__file__).resolve().parents[2]
    scripts = tomllib.loads((root / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["jaxcal"] == "jaxcal.cli:console_main"
    assert "console_main()" in (root / "jaxcal" / "cli" / "__main__.py").read_text()
    from jaxcal.cli import console_main

    frozen = gc.get_freeze_count()
    assert gc.isenabled()
    assert main(["simulate", "--help"]) == 0
    assert gc.isenabled() and gc.get_freeze_count() == frozen
    monkeypatch.setattr("sys.argv", ["jaxcal", "simulate", "--help"])
    try:
        assert console_main() == 0
        assert gc.isenabled() and gc.get_freeze_count() > frozen
    finally:
        gc.unfreeze()


def test_import_and_help_do_not_import_jax():
    """``import jaxcal`` and ``jaxcal --help`` import neither JAX nor a jaxcal module beyond the
    package and the command line (start-up: 0.05 s of CPU instead of 1.3 s); every public name
    still resolves (imported on first use)."""
    import os
    import pathlib
    import subprocess
    import sys

    root = pathlib.Path(__file__).resolve().parents[2]
    code = ("import sys, jaxcal, jaxcal.cli\n"
            "assert jaxcal.cli.main(['--help']) == 0\n"
            "heavy = sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'jaxlib', 'equinox', 'optax', "
            "'optimistix', 'numpy', 'matplotlib') or (m.startswith('jaxcal.') and m.split('.')[:2] != ['jaxcal', 'cli']"
            # the sensor kinds' names (--measurement's choices): the registry, plain Python
            " and m not in ('jaxcal._sensors', 'jaxcal._sensors._kind')))\n"
            "assert not heavy, heavy\n"
            "import jaxcal.methods as M\n"
            "assert 'optax' not in sys.modules and 'jaxcal.methods._ga' not in sys.modules\n"
            "missing = [n for n in jaxcal.__all__ if getattr(jaxcal, n, None) is None]\n"
            "assert not missing, missing\n"
            "assert sorted(M.METHODS) == sorted(['adam', 'adamod', 'adamodw', 'adamw', 'bso', 'ekf', 'ga', 'gn', "
            "'iwoa', 'lm', 'rbfnn'])\n")
    env = os.environ | {"PYTHONPATH": str(root) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]


def test_seed_split_on_the_host_is_jax_bit_for_bit():
    """The command line's train/test permutation and method key, drawn in NumPy at start-up (no
    compiled program to load), are those of ``jax.random.split`` and ``jax.random.permutation``
    (one and two shuffle rounds, 64-bit seeds); fails if JAX changes its PRNG."""
    import jax

    from jaxcal._datasets._split import key_numpy, seed_split_numpy, seed_split_program

    for seed in (0, 3, 2**32 + 5, 2**63 - 1):
        key, key_ref = key_numpy(seed), jax.random.key(seed)  # calibrate's default key is key_numpy(0)
        np.testing.assert_array_equal(jax.random.key_data(key), jax.random.key_data(key_ref))
        assert key.dtype == key_ref.dtype
        for n in (1, 400, 1625, 2000):
            key, perm = seed_split_numpy(seed, n)
            key_ref, perm_ref = seed_split_program()(seed, n)
            np.testing.assert_array_equal(perm, np.asarray(perm_ref))
            np.testing.assert_array_equal(jax.random.key_data(key), jax.random.key_data(key_ref))
            assert key.dtype == key_ref.dtype
