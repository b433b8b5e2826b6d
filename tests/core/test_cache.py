"""jaxcal's persistent compilation cache (jaxcal._core._cache): where it lives, how it is turned
off, and that a second process loads the programs a first one compiled."""

import json
import os
import pathlib
import subprocess
import sys

from jaxcal._core import _cache

# a fresh process: a small calibration through the library API (no CLI), counting the programs it
# compiled and those it loaded from the persistent cache
_SNIPPET = r"""
import json, jax
events = {"compiled": 0, "hits": 0}
def on_event(name, **kw):
    if name == "/jax/compilation_cache/cache_hits":
        events["hits"] += 1
def on_duration(name, duration, **kw):
    if name == "/jax/core/compile/backend_compile_duration":
        events["compiled"] += 1
jax.monitoring.register_event_listener(on_event)
jax.monitoring.register_event_duration_secs_listener(on_duration)
import jaxcal
jaxcal.enable_x64()
jnp_first = jax.numpy.arange(3.0) * 2  # a user's program before jaxcal's: the cache must still turn on
ex = jaxcal.simulate_experiment(jax.random.key(0), n_samples=60)
res = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm")
events["rmse"] = res.train_metrics.rmse
events["dir"] = jax.config.jax_compilation_cache_dir
print(json.dumps(events))
"""


def _run(env_extra):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAXCAL_", "JAX_", "XLA_"))}
    env.update(JAX_PLATFORMS="cpu", **env_extra)
    out = subprocess.run([sys.executable, "-c", _SNIPPET], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_cache_dir_setting(monkeypatch, tmp_path):
    monkeypatch.setenv("JAXCAL_CACHE_DIR", str(tmp_path / "c"))
    assert _cache.cache_dir() == tmp_path / "c"
    for off in ("off", "none", "0", "false"):
        monkeypatch.setenv("JAXCAL_CACHE_DIR", off)
        assert _cache.cache_dir() is None
    monkeypatch.delenv("JAXCAL_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert _cache.cache_dir() == tmp_path / "jaxcal" / "jax"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert _cache.cache_dir() == pathlib.Path.home() / ".cache" / "jaxcal" / "jax"


def test_library_calibrate_reuses_programs_across_processes(tmp_path):
    """A library user (no CLI) gets the persistent cache: the second process loads what the
    first compiled, with the same result."""
    path = tmp_path / "cache"
    first = _run({"JAXCAL_CACHE_DIR": str(path)})
    assert first["dir"] == str(path) and any(path.iterdir())
    second = _run({"JAXCAL_CACHE_DIR": str(path)})
    assert second["hits"] >= 3, second  # the identifiability program and the solve among them
    assert second["rmse"] == first["rmse"]
