"""Shared test configuration: float64 and strict dtype promotion, robot presets as a fixture."""

import os
import tempfile

# The test run's own programs (finite differences, eager operations) compile with the XLA:CPU
# option jaxcal passes for its programs (jaxcal._core._xla.CPU_DEFAULTS; they compile ~1.5x
# faster with it): set before JAX creates its CPU backend, inherited by xdist workers and the
# subprocesses tests start. A run that names the option in XLA_FLAGS keeps its own choice.
if "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_use_fusion_emitters=false").strip()

# One BLAS thread per test worker (two workers on two cores), as the command line runs
# (jaxcal.cli.console_main): OpenBLAS's worker threads busy-wait between calls and took the cores
# from XLA's thread pool. NumPy is loaded already in this process (a plugin imports it), but the
# xdist workers and the subprocesses tests start inherit the variables and read them at load.
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
# The CLI, called in-process by tests, turns on JAX's persistent compilation cache for the rest
# of the process. Give the test run its own cache directory, shared by its xdist workers (the
# controller loads this file first and the workers inherit the variable): tests should not read
# or write the user's ~/.cache/jaxcal, and a CI run that shared it with other busy processes once
# crashed with a segmentation fault inside jax's cache read (most likely an entry read while
# another process wrote it). Sharing within the run keeps the workers' compilations reusable.
os.environ.setdefault("JAXCAL_TEST_CACHE_DIR", tempfile.mkdtemp(prefix="jaxcal-test-cache-"))
os.environ["JAXCAL_CACHE_DIR"] = os.environ["JAXCAL_TEST_CACHE_DIR"]
if os.environ.get("JAXCAL_TEST_EAGER_CACHE", "1") == "1":
    # on from the start (not only after the first in-process CLI test): a program that another test
    # or the other xdist worker compiled already (the same HLO from a new closure, e.g. a fresh
    # Calibrator for the same problem shape) is loaded instead of compiled again
    jax.config.update("jax_compilation_cache_dir", os.environ["JAXCAL_TEST_CACHE_DIR"])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)

from jaxcal import robots  # noqa: E402

ROBOT_NAMES = sorted(robots.DH_PRESETS)  # the serial presets; trees: tests/models/test_tree_presets.py


def central_differences(f, x0, h):
    """Central finite differences of ``f`` at ``x0``: column ``k`` is
    ``(f(x0 + h_k e_k) − f(x0 − h_k e_k)) / (2 h_k)``, ``f``'s output flattened; shape
    ``(f's output size, x0.size)``. ``h``: a scalar or one step per column.

    An independent check of JAX's derivatives (evaluations only, no autodiff). The ``2 x0.size``
    evaluations run as one compiled, vmapped program: evaluated op by op, each of ``f``'s
    operations is a small program of its own, and a chain's ~50 columns took minutes."""
    import jax.numpy as jnp

    x0 = jnp.asarray(x0)
    steps = np.broadcast_to(np.asarray(h, np.float64), x0.shape)
    shift = jnp.asarray(np.diag(steps), x0.dtype)
    out = np.asarray(jax.jit(jax.vmap(f))(jnp.concatenate([x0 + shift, x0 - shift]))).reshape(2, x0.size, -1)
    return ((out[0] - out[1]) / (2.0 * steps[:, None])).T


# Modules whose tests share nothing in-process (each starts its own Python processes): spread over
# the workers test by test instead of kept together.
_SPREAD_MODULES = {"test_notebooks.py", "test_multiprocess.py"}


def pytest_xdist_make_scheduler(config, log):
    """``--dist loadscope`` (the README's command) keeps each test module's tests on one xdist
    worker, as xdist's own ``loadscope`` does, except the modules in ``_SPREAD_MODULES``, whose
    tests are spread one by one. A module's tests share module-scoped fixtures (simulated data
    sets, fits) and compiled programs of the same shapes, which under ``--dist load`` both workers
    built, each for its share of the module. Scopes go out largest first (xdist's
    ``--loadscope-reorder``), so the spread tests fill the end of the run. Other ``--dist`` modes
    are xdist's own."""
    if config.getvalue("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class _ModuleScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return nodeid if module.rsplit("/", 1)[-1] in _SPREAD_MODULES else module

    return _ModuleScheduling(config, log)


@pytest.fixture(autouse=True, scope="module")
def _free_compiled_programs():
    """After a test module, when the worker's resident memory is above
    ``$JAXCAL_TEST_RSS_LIMIT_MB`` (default 3 000), free every compiled program it holds
    (:func:`jaxcal.clear_compiled`): a worker runs ~50 modules and kept every program (~3–16 MB
    resident each on XLA:CPU) until the run ended (5.6 GB peak per worker). Programs a later
    module needs again are then traced again and loaded from the run's persistent compilation
    cache, which costs time; hence a threshold, not a clear after every module. ``0`` clears after
    every module, ``JAXCAL_TEST_KEEP_COMPILED=1`` never."""
    yield
    if os.environ.get("JAXCAL_TEST_KEEP_COMPILED", "0") == "1":
        return
    from jaxcal._core._buckets import resident_mb

    rss = resident_mb()  # None where /proc is missing (not Linux): never clear
    if rss is not None and rss > float(os.environ.get("JAXCAL_TEST_RSS_LIMIT_MB", "3000")):
        import jaxcal

        jaxcal.clear_compiled()


@pytest.fixture(scope="module")
def experiment():
    """The paper's experiment as :func:`jaxcal.simulate_experiment` makes it by default (key 0), one
    per test module."""
    from jaxcal import simulate_experiment

    return simulate_experiment(jax.random.PRNGKey(0))


@pytest.fixture(params=ROBOT_NAMES)
def robot(request):
    """Every robot preset."""
    return robots.get_robot(request.param)


@pytest.fixture(scope="session")
def paper_robot():
    """The paper's robot, the ``hsr_jr680`` preset: one per test run (a robot is immutable), for
    the modules that test one robot, not every preset (:func:`robot`)."""
    return robots.hsr_jr680()


def np_rz(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def np_rx(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def np_ry(t):
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])


def np_tr(x, y, z):
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def numpy_dh_frames(alpha, a, d, theta, beta, qi, convention="standard", beta_joints=()):
    """Independent reference: the ``[dof+1]`` 4×4 frames (base, after A_1, ..., after A_dof) of
    one sample ``qi`` ``[dof]``, a plain NumPy product of 4×4 matrices."""
    T = np.eye(4)
    out = [T]
    for j in range(len(alpha)):
        B = np_ry(beta[j]) if (j + 1) in beta_joints else np.eye(4)
        if convention == "standard":
            A = np_rz(theta[j] + qi[j]) @ np_tr(0, 0, d[j]) @ np_tr(a[j], 0, 0) @ np_rx(alpha[j]) @ B
        else:
            A = np_rx(alpha[j]) @ B @ np_tr(a[j], 0, 0) @ np_rz(theta[j] + qi[j]) @ np_tr(0, 0, d[j])
        T = T @ A
        out.append(T)
    return out


def numpy_dh_fk(alpha, a, d, theta, beta, q, convention="standard", beta_joints=(), tool=None):
    """Independent reference FK: a plain NumPy product of 4×4 matrices, one sample at a time."""
    out = []
    for qi in np.atleast_2d(q):
        T = numpy_dh_frames(alpha, a, d, theta, beta, qi, convention, beta_joints)[-1]
        out.append(T if tool is None else T @ np_tr(*tool))
    return np.array(out)


@pytest.fixture(scope="session")
def figaroh_bench():
    """``benchmarks/bench_figaroh.py`` as a module: its loaders of the FIGAROH TIAGo fixtures
    (tests/data/figaroh_tiago*, Apache-2.0) and of the TIAGo URDF."""
    import importlib.util
    import pathlib
    import sys

    path = pathlib.Path(__file__).parents[1] / "benchmarks" / "bench_figaroh.py"
    spec = importlib.util.spec_from_file_location("bench_figaroh", path)
    mod = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(path.parent))
    try:
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(path.parent))
    return mod
