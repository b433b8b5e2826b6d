"""What a new user meets (issue 15): tabular DH tables, an honest status for fixed budgets,
CLI help and messages, pose data, the ignore file."""

import pathlib
import re
import shlex
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import jaxcal
from jaxcal import Status
from jaxcal._fit._result import DHTable, still_improving
from jaxcal.cli import main

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def small():
    return jaxcal.simulate_experiment(jax.random.PRNGKey(3), n_samples=200)


def test_dh_table_is_tabular_and_indexes_like_the_array(small):
    ex = small
    res = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm")
    tab = res.dh_table()
    assert isinstance(tab, DHTable) and tab.shape == (6, 4) and tab.columns == ("alpha_deg", "a_mm", "d_mm", "theta_deg")
    assert tab.rows == (1, 2, 3, 4, 5, 6)
    arr = np.asarray(tab)
    assert arr.shape == (6, 4) and tab[0, 1] == arr[0, 1] and np.all(np.abs(arr[:, [0, 3]]) <= 180)
    np.testing.assert_allclose(tab - ex.robot.dh_table_deg(), arr - ex.robot.dh_table_deg())
    text = str(tab)
    assert "Joint i" in text and "θ_i/°" in text and f"{arr[0, 1]:.4f}" in text
    # the not-identifiable entries (α5, a5, d3, α6, θ6) are marked
    assert text.count("*") == 1 + 5 and "not calibrated" in text
    md = tab.to_markdown()
    assert md.count("\n| ") == 7 and "\\*" in md


def test_still_improving_helper():
    n = 100
    falling = jnp.linspace(2.0, 1.0, n + 1)
    flat = jnp.concatenate([jnp.linspace(2.0, 1.0, 51), jnp.full(50, 1.0)])
    wiggle = flat * (1 + 0.005 * jnp.sin(jnp.arange(n + 1.0)))
    assert bool(still_improving(falling, n)) and not bool(still_improving(flat, n))
    assert not bool(still_improving(wiggle, n))
    assert not bool(still_improving(falling, 5))  # too short to judge
    batched = jax.vmap(still_improving)(jnp.stack([falling, flat]), jnp.asarray([n, n]))
    assert batched.tolist() == [True, False]


def test_budget_exhausted_while_improving_is_not_converged(small):
    ex = small
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        chain = optax.chain(optax.clip_by_global_norm(1.0), jaxcal.optim.adamodw(1e-2))  # the chain
        res = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, chain, steps=100)
    assert res.status == Status.STILL_IMPROVING and not res.ok
    assert "still improving" in res.message and any("still improving" in str(w.message) for w in caught)
    assert res.to_dict()["status"] == "still_improving"
    # existing codes unchanged
    assert [int(s) for s in Status] == [0, 1, 2, 3, 4, 5]


def test_pose_identifiability_sees_orientation():
    ex = jaxcal.simulate_experiment(jax.random.PRNGKey(0), n_samples=200, measurement=jaxcal.Pose())
    rep = jaxcal.identifiability(ex.robot, ex.measurement, ex.train.q)
    assert rep.rank == 23 and rep.unidentifiable == ("d_3",)


def test_cli_help_and_messages(capsys, monkeypatch, tmp_path):
    assert main(["reproduce", "--help"]) == 0
    out = capsys.readouterr().out
    assert "%%" not in out and "80 %" in out
    assert main(["simulate", "--out", str(tmp_path / "p.csv"), "--measurement", "pose", "--samples", "20"]) == 0
    assert "pose samples" in capsys.readouterr().out
    import jaxcal._experiments._sweep

    def other_settings(*a, **k):
        raise ValueError("x.npz was written by a sweep with other settings (fingerprint a != b); use another out_dir")

    monkeypatch.setattr(jaxcal._experiments._sweep, "sweep", other_settings)
    assert main(["--no-cache", "reproduce", "--quick", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "out_dir" not in err


def test_default_output_folder_is_ignored():
    assert "jaxcal-reproduce/" in (ROOT / ".gitignore").read_text().split()


def test_adamodw_defaults_story_is_told_in_both_places():
    """The optimizer keeps the paper's b3; the registry's tuned values are named in its docstring."""
    import inspect

    from jaxcal.methods import GRADIENT_DEFAULTS as DEFAULTS

    sig = inspect.signature(jaxcal.optim.adamodw)
    assert sig.parameters["b3"].default == 0.999
    tuned = DEFAULTS["adamodw"]
    doc = jaxcal.optim.adamodw.__doc__
    assert f"learning_rate={tuned['learning_rate']:g}" in doc and f"b3={tuned['b3']:g}" in doc
    guide = (ROOT / "docs" / "guides" / "methods.md").read_text()  # the story moved out of the README
    assert f"jaxcal.optim.adamodw({tuned['learning_rate']:g}, b3={tuned['b3']:g})" in guide


# ---------------------------------------------------------------------------------------------
# the getting-started page's five-minute tutorial, run as written (issue 35)

TUTORIAL = "## Calibrate your robot from a CSV in five minutes"


def _tutorial_section() -> str:
    page = (ROOT / "docs" / "getting-started.md").read_text(encoding="utf-8")
    start = page.index(TUTORIAL)
    return page[start:page.index("\n## ", start + len(TUTORIAL))]


def _blocks(section: str, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", section, flags=re.S)


def test_the_tutorial_runs_as_written_and_prints_its_numbers(tmp_path, monkeypatch, capsys):
    """Every command of the page's bash blocks (comments stripped) exits 0 in a fresh folder, every
    line of its text blocks is a line the commands printed, and every warning they printed is on the
    page (issue 53: a warning the page did not show ended every run): the page cannot drift from the
    program."""
    pytest.importorskip("matplotlib")  # jaxcal report --html
    section = _tutorial_section()
    commands = [shlex.split(line, comments=True) for block in _blocks(section, "bash")
                for line in block.splitlines() if line.strip()]
    assert [c[:2] for c in commands] == [["jaxcal", "simulate"], ["jaxcal", "calibrate"], ["jaxcal", "simulate"],
                                         ["jaxcal", "evaluate"], ["jaxcal", "report"], ["jaxcal", "export"]]
    monkeypatch.chdir(tmp_path)
    printed, warned = set(), []
    for argv in commands:
        assert main(argv[1:]) == 0, argv
        out = capsys.readouterr()
        printed |= {line.rstrip() for line in out.out.splitlines()}
        warned += [line.rstrip() for line in out.err.splitlines() if line.startswith("jaxcal: warning")]
    shown = [line.rstrip() for block in _blocks(section, "text") for line in block.splitlines() if line.strip()]
    assert len(shown) > 10 and [line for line in shown if line not in printed | set(warned)] == []
    assert [w for w in warned if w not in shown] == []
    # one verdict per parameter: the identifiability lines and the DH table's † say the same
    assert "determined by the data: alpha_1" in section and "0.5758† (+0.5758 ± 1.3)" in section

    # the simulated set-up is unknown to calibrate: no anchor line, its truth quoted on the page
    meta = jaxcal.load_csv(tmp_path / "data.csv").meta
    assert "anchor_mm" not in meta and "extras from the data: anchor" in "\n".join(printed)
    ax, ay, az = (float(v) for v in meta["true_anchor_mm"].split(","))
    truth = f"anchor {ax:.2f}, {ay:.2f}, {az:.2f} mm, offset {float(meta['true_cable_offset_mm']):.2f} mm"
    assert truth.replace("-", "−") in " ".join(section.split())
    # tomorrow.csv is the same robot and set-up; with data.csv's seed and size it is data.csv's rows
    new = jaxcal.load_csv(tmp_path / "tomorrow.csv").meta
    assert (new["true_anchor_mm"], new["true_cable_offset_mm"], new["true_robot_seed"]) == (
        meta["true_anchor_mm"], meta["true_cable_offset_mm"], meta["seed"])
    assert main(["simulate", "--like", "result.json", "--out", "again.csv", "--samples", "300", "--seed", "0"]) == 0
    rows = lambda name: [ln for ln in (tmp_path / name).read_text().splitlines() if not ln.startswith("#")]  # noqa: E731
    assert rows("again.csv") == rows("data.csv")

    # the report: † marks, the colour clip, version/date/input identity, no empty header row, angles wrapped
    page = (tmp_path / "result.html").read_text(encoding="utf-8")
    assert "theta_1†" in page and "held by the prior: the prior, not the data" in page
    assert "clipped at the 98th percentile" in page
    assert f"jaxcal {jaxcal.__version__} report, made 20" in page and "result.json (sha256 " in page
    assert "data data.csv (sha256 " in page and "<th></th>" not in page and 'class="l"></th>' not in page
    assert "-179.7557" in page and "180.24" not in page
    urdf = (tmp_path / "calibrated.urdf").read_text(encoding="utf-8")
    assert "theta=-179.75" in urdf and "theta=180.24" not in urdf


def test_simulate_like_refuses_what_it_cannot_repeat(tmp_path, capsys):
    """--like needs a result whose data file `jaxcal simulate` wrote; the set-up comes from it alone."""
    assert main(["simulate", "--like", str(tmp_path / "none.json"), "--out", str(tmp_path / "x.csv")]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["simulate", "--like", "r.json", "--robot", "ur5", "--out", str(tmp_path / "x.csv")]) == 2
    assert "drop --robot" in capsys.readouterr().err
    assert main(["simulate", "--unknown-anchor", "--measurement", "position", "--out", str(tmp_path / "x.csv")]) == 2
    assert "--unknown-anchor applies to --measurement cable" in capsys.readouterr().err


def test_closed_form_start_says_what_it_left_out():
    """On clean data the rows a closed-form start leaves out are the nominal robot's largest errors:
    the message says they are left out of the start only and kept by the calibration (issue 35)."""
    from jaxcal._sensors._contact import length_reference_note
    from jaxcal._sensors._initialise import trimmed_note

    assert trimmed_note(0) == ""
    note = trimmed_note(3)
    assert note.startswith(", 3 row(s) beyond 5 robust σ left out of this start only")
    assert "the calibration keeps them" in note and "gross outliers" in note  # the either/or, not a verdict
    assert "no length reference" in length_reference_note("plane")
    assert "no length reference" in length_reference_note("point")  # pivot points, or an unknown radius
    sphere = length_reference_note("point", known_radius=True)
    assert "no length reference" not in sphere and "weak" in sphere
