"""jaxcal's persistent compilation cache (jaxcal._core._cache) and its programs kept as
``jax.export`` serialisations (jaxcal._core._exported): where they live, how they are turned off,
that a second process loads what a first one compiled and traced, with the same result, and that a
corrupt entry is ignored and written again."""

import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from jaxcal._core import _cache, _exported

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
events["x"] = [float(v) for v in res.x]
from jaxcal._core import _exported
events["exported"] = _exported.STATS
events["dir"] = jax.config.jax_compilation_cache_dir
import sys
events["optimistix"] = "optimistix" in sys.modules  # needed to trace LM's solve, not to load it
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


def test_programs_are_reused_across_processes_checked_and_rebuilt(tmp_path):
    """A library user (no CLI) gets the persistent cache: the second process loads what the first
    compiled. The solve and the identifiability program are also kept as ``jax.export``
    serialisations: the second process loads them (no tracing, and without importing optimistix)
    and gets the first's parameters bit for bit; a corrupt entry is rejected and written again; ``JAXCAL_EXPORT=off`` gives the same
    numbers without them."""
    path = tmp_path / "cache"
    first = _run({"JAXCAL_CACHE_DIR": str(path)})
    assert first["dir"] == str(path) and any(path.iterdir())
    assert first["exported"]["stored"] >= 2 and first["exported"]["loaded"] == 0, first["exported"]
    stored = sorted((path / "exported").glob("*.jaxexport"))
    assert len(stored) == first["exported"]["stored"]
    second = _run({"JAXCAL_CACHE_DIR": str(path)})
    # the simulation, the identifiability program and the solve (without tracing, no small eager
    # programs are left to load)
    assert second["hits"] >= 3, second
    assert second["exported"] == {"stored": 0, "loaded": len(stored), "rejected": 0}
    assert second["x"] == first["x"]
    assert first["optimistix"] and not second["optimistix"]
    blob = stored[0].read_bytes()
    stored[0].write_bytes(blob[: len(blob) // 2] + bytes(len(blob) - len(blob) // 2))  # corrupt, same size
    third = _run({"JAXCAL_CACHE_DIR": str(path)})
    assert third["exported"] == {"stored": 1, "loaded": len(stored) - 1, "rejected": 1}
    assert stored[0].read_bytes() == blob and third["x"] == first["x"]
    off = _run({"JAXCAL_CACHE_DIR": str(path), "JAXCAL_EXPORT": "off"})
    assert off["exported"] == {"stored": 0, "loaded": 0, "rejected": 0}
    np.testing.assert_allclose(off["x"], first["x"], rtol=0, atol=1e-12)


def test_plain_description_is_complete_or_none():
    """Only plain data describe a program: a callable in the configuration is never a key, and a
    dataclass is described by all its fields, also those its repr leaves out."""
    import dataclasses

    @dataclasses.dataclass(frozen=True)
    class Setting:
        name: str
        hidden: tuple = dataclasses.field(default=(), repr=False)

    assert repr(Setting("a", (1,))) == repr(Setting("a", (2,)))  # the repr leaves a field out ...
    assert _exported.plain_description(Setting("a", (1,))) != _exported.plain_description(Setting("a", (2,)))
    assert _exported.plain_description({"f": lambda x: x}) is None
    assert _exported.plain_description((1, "a", None, 2.5)) is not None
    assert _exported.describe(np.arange(3)) != _exported.describe(np.arange(3.0))
    assert _exported.describe(object()) is None


def test_program_keys_name_the_device_the_program_runs_on():
    """A program built inside ``jax.default_device(cpu)`` (what ``sweep`` does on a GPU machine to
    choose the free set on the host) is keyed and exported for the CPU, not for JAX's default
    backend; jax.export's platform names (``cuda``) are used for exporting."""
    import jax

    from jaxcal._core import _xla

    cpu = jax.devices("cpu")[0]
    with jax.default_device(cpu):
        assert _xla.target_device() == cpu
        assert _xla.target_platform() == "cpu" and _xla.export_platform() == "cpu"
    with jax.default_device("cpu"):
        assert _xla.target_platform() == "cpu"
    assert _xla.target_device() == jax.devices()[0]
    assert _xla.export_platform() in {"cpu", "cuda", "rocm", "tpu"}


def test_compile_options_per_platform_overridable_and_accepted_everywhere(monkeypatch):
    """jaxcal's compile options: XLA:CPU's classic emitters on the CPU, no autotuning on a GPU;
    ``$JAXCAL_XLA_OPTIONS`` replaces them, an option named in ``$XLA_FLAGS`` is left to it, and a
    jitted function carrying both platforms' options compiles and computes what ``jax.jit`` does."""
    import jax
    import jax.numpy as jnp

    from jaxcal._core import _xla

    monkeypatch.delenv(_xla.ENV_VAR, raising=False)
    monkeypatch.setenv("XLA_FLAGS", "")
    assert _xla.compiler_options("cpu") == {"xla_cpu_use_fusion_emitters": False}
    assert _xla.compiler_options("cuda") == _xla.compiler_options("gpu") == {"xla_gpu_autotune_level": 0}
    assert _xla.compiler_options("tpu") is None
    assert _xla.jit_options() == {"xla_cpu_use_fusion_emitters": False, "xla_gpu_autotune_level": 0}
    f = lambda x: jnp.sin(x) * jnp.exp(-x)  # noqa: E731
    x = jnp.linspace(0.0, 3.0, 17)
    for jitted in (_xla.jit(f), _xla.jit()(f), _xla.filter_jit(f)):
        np.testing.assert_array_equal(np.asarray(jitted(x)), np.asarray(jax.jit(f)(x)))
        # JAX takes compile options on the outermost jit only: inside a user's jit, vmap, grad or
        # jax.export the plain function runs
        np.testing.assert_array_equal(np.asarray(jax.jit(lambda v, g=jitted: g(v) + 1.0)(x)),
                                      np.asarray(jax.jit(lambda v: f(v) + 1.0)(x)))
        np.testing.assert_array_equal(np.asarray(jax.vmap(jitted)(x[:, None])), np.asarray(jax.vmap(f)(x[:, None])))
        np.testing.assert_allclose(np.asarray(jax.grad(lambda v, g=jitted: g(v).sum())(x)),
                                   np.asarray(jax.grad(lambda v: f(v).sum())(x)), rtol=1e-14)
        jax.export.export(jax.jit(lambda v, g=jitted: g(v)), platforms=["cpu"])(x)
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true")
    assert _xla.compiler_options("cpu") is None  # the user's own flag wins
    monkeypatch.setenv(_xla.ENV_VAR, "xla_gpu_autotune_level=4, xla_cpu_use_fusion_emitters=false")
    assert _xla.compiler_options("cuda") == {"xla_gpu_autotune_level": 4}
    monkeypatch.setenv(_xla.ENV_VAR, "none")
    assert _xla.compiler_options("cpu") is None and _xla.compiler_options("cuda") is None
    monkeypatch.setenv(_xla.ENV_VAR, "bogus")
    with pytest.raises(ValueError, match="name=value"):
        _xla.compiler_options("cpu")
