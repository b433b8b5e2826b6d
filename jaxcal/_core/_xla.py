"""XLA compiler options for jaxcal's own compilations.

**CPU.** XLA:CPU's newer MLIR fusion emitters compile jaxcal's programs markedly slower than its
classic emitters, for the same run speed: the simulation program of the paper's experiment
compiled in 11.2 s with the defaults and in 8.9 s with ``xla_cpu_use_fusion_emitters=false``
(bit-identical data), and three of the test suite's modules ran in 348 s instead of 550 s
(2-core CPU, JAX 0.10.2; ``benchmarks/results/compile_cpu.md``). So jaxcal compiles its own
programs on the CPU with that option.

**GPU.** XLA autotunes the kernels of every fusion it compiles. For jaxcal's programs (long
``while_loop``/``scan`` bodies of small reductions over the samples) that step dominates: on an
H100 (JAX 0.11.2) the vmapped chunk of 1 000 LM trials compiled in more than 2 minutes with the
default flags, almost all of it autotuning reduction fusions ("Compiling module
input_reduce_fusion… very slow compile"), and in 4.3 s with ``--xla_gpu_autotune_level=0``.
So jaxcal compiles its own programs on GPUs with ``xla_gpu_autotune_level=0``.

The options are passed per compilation (``jax.stages.Lowered.compile(compiler_options)`` for the
programs jaxcal compiles itself, ``jax.jit(..., compiler_options=...)`` for its jitted functions,
:func:`jit` and :func:`filter_jit`), not through the process-wide ``XLA_FLAGS``, so the user's
other JAX programs are untouched. A jitted function gets the options of every platform (each
platform ignores the other's), decided when jaxcal's module is imported, and only when it is
called at the top level: inside a user's ``jit`` (or ``vmap``, ``grad``) the outermost program's
options apply, as JAX requires.

Overriding: set ``JAXCAL_XLA_OPTIONS`` to a comma-separated list of ``name=value`` XLA debug
options (e.g. ``JAXCAL_XLA_OPTIONS=xla_gpu_autotune_level=4``) to replace the defaults on every
platform, or to ``none`` (or an empty string) for XLA's defaults. An option the user already sets
in ``XLA_FLAGS`` is never overridden.
"""

from __future__ import annotations

import os

__all__ = ["ENV_VAR", "CPU_DEFAULTS", "GPU_DEFAULTS", "compiler_options", "compile_lowered", "jit", "filter_jit",
           "TopLevelOptions", "computed_once"]

#: environment variable that replaces :data:`GPU_DEFAULTS` (``name=value,...`` or ``none``).
ENV_VAR = "JAXCAL_XLA_OPTIONS"

#: options jaxcal passes when it compiles for the CPU.
CPU_DEFAULTS: dict[str, object] = {"xla_cpu_use_fusion_emitters": False}

#: options jaxcal passes when it compiles for a GPU.
GPU_DEFAULTS: dict[str, object] = {"xla_gpu_autotune_level": 0}


def computed_once(tree, token):
    """``tree`` (arrays) as buffers that their consumers read, not computations each consumer repeats.

    XLA fuses a producer made of cheap elementwise operations into every consumer, however large
    the producer: the forward-mode kinematic Jacobian of the paper's robot (~600 operations per
    entry, ``[N, p]``) with three consumers in the identifiability program (column norms, the
    scaled copy, the output) was computed three times (its optimised HLO 3 806 → 2 615 lines
    with this), and twice per step in LM's loop (XLA:CPU, JAX 0.10.2).
    ``jax.lax.optimization_barrier`` does not stop it on XLA:CPU; the operand of a conditional is
    a buffer, so ``tree`` passes through one.
    ``token``: a run-time scalar the predicate reads (XLA removes a conditional with a constant
    predicate or with identical branches: the branch taken where ``token`` is NaN adds ``0.0``,
    which leaves every value but −0.0 as it is). Under ``jax.vmap`` with a batched ``token`` the
    conditional becomes a select of both branches, which no longer keeps the producer apart."""
    import jax
    import jax.numpy as jnp

    return jax.lax.cond(jnp.isnan(token), lambda t: jax.tree.map(lambda a: a + 0, t), lambda t: t, tree)


def _parse_value(text: str):
    t = text.strip()
    if t.lower() in ("true", "false"):
        return t.lower() == "true"
    try:
        return int(t)
    except ValueError:
        pass
    try:
        return float(t)
    except ValueError:
        return t


def _parse(text: str) -> dict[str, object]:
    text = text.strip()
    if text.lower() in ("", "none", "default", "defaults"):
        return {}
    out = {}
    for item in text.split(","):
        if not item.strip():
            continue
        if "=" not in item:
            raise ValueError(f"{ENV_VAR} expects name=value[,name=value...] or 'none', got {item.strip()!r}")
        k, v = item.split("=", 1)
        out[k.strip().lstrip("-")] = _parse_value(v)
    return out


def compiler_options(platform: str) -> dict[str, object] | None:
    """XLA options for a jaxcal compilation on ``platform`` (``"cpu"``, ``"gpu"``/``"cuda"``/``"rocm"``,
    ...), or ``None`` for XLA's defaults. ``$JAXCAL_XLA_OPTIONS`` replaces the defaults; options
    named in ``$XLA_FLAGS`` are left to it."""
    env = os.environ.get(ENV_VAR)
    if env is not None:
        opts = _parse(env)
    elif platform.lower() in ("gpu", "cuda", "rocm"):
        opts = dict(GPU_DEFAULTS)
    elif platform.lower() == "cpu":
        opts = dict(CPU_DEFAULTS)
    else:
        opts = {}
    flags = os.environ.get("XLA_FLAGS", "")
    opts = {k: v for k, v in opts.items() if f"--{k}" not in flags}
    return opts or None


def target_device():
    """The device a program jitted now over uncommitted arguments runs on: the one set by
    ``jax.default_device`` (a context or ``jax.config``) when set, else JAX's first device. Keys of
    compiled programs name its platform, not :func:`jax.default_backend`, so that a program built
    for the host CPU inside ``jax.default_device(cpu)`` on a GPU machine is kept apart from the
    GPU's."""
    import jax

    dev = jax.config.jax_default_device
    if dev is None:
        return jax.devices()[0]
    return jax.devices(dev)[0] if isinstance(dev, str) else dev


def target_platform() -> str:
    """The platform (``"cpu"``, ``"gpu"``, ``"tpu"``) of :func:`target_device`."""
    return target_device().platform


def export_platform() -> str:
    """:func:`target_platform` as :mod:`jax.export` names it (``"cuda"``/``"rocm"`` for ``"gpu"``)."""
    from jax import export

    platform = target_platform()
    return export.default_export_platform() if platform == "gpu" else platform


def compile_lowered(lowered, platform: str | None = None):
    """``lowered.compile(...)`` with :func:`compiler_options` for ``platform`` (default:
    :func:`target_platform`), with jaxcal's persistent compilation cache on
    (:func:`~jaxcal._core._cache.ensure_compilation_cache`)."""
    from ._cache import ensure_compilation_cache

    ensure_compilation_cache()
    if platform is None:
        platform = target_platform()
    opts = compiler_options(platform)
    return lowered.compile() if opts is None else lowered.compile(opts)


def jit_options() -> dict[str, object] | None:
    """The compiler options of jaxcal's jitted functions (:func:`jit`, :func:`filter_jit`): those
    of the CPU and of a GPU together (each platform ignores the other's); ``None`` for XLA's
    defaults."""
    opts = {**(compiler_options("cpu") or {}), **(compiler_options("gpu") or {})}
    return opts or None


def _top_level() -> bool:
    """Whether JAX is not tracing or transforming anything now (a call here runs eagerly);
    ``False`` when it cannot tell (then no options are passed). Called on every call of a jitted
    function: JAX's check is looked up once."""
    check = _STATE.get("check")
    if check is None:
        try:
            from jax._src import core

            check = getattr(core, "trace_state_clean", None)
        except ImportError:  # pragma: no cover - JAX moved its internals
            check = None
        check = _STATE["check"] = check or (lambda: False)
    return bool(check())


#: ``{"check": JAX's top-level test}`` once :func:`_top_level` has looked it up.
_STATE: dict = {}


class TopLevelOptions:
    """A jitted function that passes :func:`jit_options` when called at the top level and runs the
    plain jitted function inside a transformation (another ``jit``, ``vmap``, ``grad``,
    ``jax.export``): JAX accepts ``compiler_options`` on the outermost ``jit`` only, and the
    outermost program's own options apply to everything inside it. Attributes (``lower``,
    ``trace``, ``clear_cache``, ...) are the plain function's; :func:`compile_lowered` adds the
    options to a lowering."""

    def __init__(self, plain, optioned):
        import functools

        self._plain, self._optioned = plain, optioned
        functools.update_wrapper(self, plain)

    def __call__(self, *args, **kwargs):
        return (self._optioned if _top_level() else self._plain)(*args, **kwargs)

    def __getattr__(self, name):
        return getattr(self._plain, name)


def _with_options(make, fun, kwargs):
    opts = jit_options()
    plain = make(fun, **kwargs)
    if opts is None or "compiler_options" in kwargs:
        return plain
    return TopLevelOptions(plain, make(fun, compiler_options=opts, **kwargs))


def jit(fun=None, **kwargs):
    """``jax.jit(fun, **kwargs)`` with :func:`jit_options` at the top level
    (:class:`TopLevelOptions`; a decorator, bare or with arguments)."""
    import functools

    import jax

    if fun is None:
        return functools.partial(jit, **kwargs)
    return _with_options(jax.jit, fun, kwargs)


def filter_jit(fun=None, **kwargs):
    """``equinox.filter_jit(fun, **kwargs)`` with :func:`jit_options` at the top level
    (:class:`TopLevelOptions`; a decorator, bare or with arguments)."""
    import functools

    import equinox as eqx

    if fun is None:
        return functools.partial(filter_jit, **kwargs)
    return _with_options(eqx.filter_jit, fun, kwargs)


# -- compiling ahead on a background thread --------------------------------------------------------
def ahead_enabled() -> bool:
    """Whether programs may compile ahead on a background thread (:func:`compile_ahead`): a second
    core, and ``JAXCAL_COMPILE_AHEAD`` not ``off``. XLA compiles without holding Python's lock, so
    a program compiles there while the calling thread runs others."""
    from ._cache import switched_off

    return (os.cpu_count() or 1) >= 2 and not switched_off("JAXCAL_COMPILE_AHEAD")


def compile_ahead(pending: dict, key, build) -> None:
    """Start ``build()`` (a program's compilation, or a first call of it) on the background compile
    thread under ``key`` of ``pending``, unless one is pending already; :func:`take_ahead` gives
    its result."""
    if key not in pending:
        pending[key] = _ahead_pool().submit(build)


def take_ahead(pending: dict, key):
    """The result of the :func:`compile_ahead` ``pending`` holds for ``key`` (waited for, and
    removed), or ``None``: none started, or it failed (the caller builds again in its own thread,
    where the error is raised)."""
    future = pending.pop(key, None)
    if future is None:
        return None
    try:
        return future.result()
    except Exception:  # noqa: BLE001 - built again by the caller, which then raises it
        return None


_POOL: list = []


def _ahead_pool():
    if not _POOL:
        from concurrent.futures import ThreadPoolExecutor

        _POOL.append(ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxcal-compile"))
    return _POOL[0]
