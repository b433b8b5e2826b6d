"""What a new user meets (issue 15): tabular DH tables, an honest status for fixed budgets,
CLI help and messages, pose data, the ignore file."""

import pathlib
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
