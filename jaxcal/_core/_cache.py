"""jaxcal's persistent compilation cache: compiled programs kept on disk across processes.

Almost all the time a first calibration takes is XLA compiling jaxcal's programs (seconds on a
2-core CPU; the fit itself takes milliseconds). JAX can keep compiled programs on disk and load
them in a later process instead of compiling them again (its *persistent compilation cache*).
jaxcal turns it on the first time it compiles one of its programs — in the library as on the
command line — unless the user has configured JAX's cache already:

* directory: ``$JAXCAL_CACHE_DIR``, else ``$XDG_CACHE_HOME/jaxcal/jax``, else
  ``~/.cache/jaxcal/jax`` (:func:`cache_dir`);
* ``JAXCAL_CACHE_DIR=off`` (or ``none``, ``0``, ``false``; ``jaxcal --no-cache`` on the command
  line, :func:`disable_compilation_cache` in Python) turns it off;
* every compilation is kept, also the small ones (JAX's own default keeps only those over 1 s;
  jaxcal's identifiability and diagnostic programs take 0.1–0.5 s each);
* a user who set ``jax.config.update("jax_compilation_cache_dir", ...)`` keeps that setting:
  jaxcal changes nothing then.

JAX's cache is one setting of the process, so once jaxcal has turned it on, the user's other JAX
programs in that process are kept there too. The entries are keyed by JAX from the program, the
compile options, the JAX/jaxlib versions and the device, so a stale entry is never loaded; the
directory can be deleted at any time. If it cannot be created (read-only home), nothing is cached.
"""

from __future__ import annotations

import os
import pathlib

__all__ = ["ENV_VAR", "cache_dir", "ensure_compilation_cache", "disable_compilation_cache"]

#: environment variable: the cache directory, or ``off`` to turn the cache off.
ENV_VAR = "JAXCAL_CACHE_DIR"

#: the words that turn a jaxcal switch (an environment variable) off, in any case.
OFF_WORDS = ("off", "none", "0", "false", "no")


def switched_off(var: str) -> bool:
    """Whether the environment variable ``var`` says :data:`OFF_WORDS` (unset: not off)."""
    return os.environ.get(var, "").strip().lower() in OFF_WORDS

#: ``{"done": True}`` once :func:`ensure_compilation_cache` has decided for this process.
_STATE: dict = {}


def cache_dir() -> pathlib.Path | None:
    """The directory jaxcal keeps compiled programs in, or ``None`` when turned off."""
    env = os.environ.get(ENV_VAR, "").strip()
    if switched_off(ENV_VAR):
        return None
    if env:
        return pathlib.Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME", "").strip()
    return (pathlib.Path(base) if base else pathlib.Path.home() / ".cache") / "jaxcal" / "jax"


def disable_compilation_cache() -> None:
    """Do not turn JAX's persistent compilation cache on in this process (``jaxcal --no-cache``);
    a cache jaxcal already turned on stays on. Programs are then not kept as ``jax.export``
    serialisations either (:mod:`jaxcal._core._exported`)."""
    _STATE["done"] = _STATE["disabled"] = True


def ensure_compilation_cache() -> str | None:
    """Turn JAX's persistent compilation cache on in :func:`cache_dir` (once per process; cheap
    afterwards) unless it is off or the user configured JAX's cache. Returns the directory in use
    (the user's own included), or ``None``."""
    import jax

    if _STATE.get("done"):
        return jax.config.jax_compilation_cache_dir or None
    _STATE["done"] = True
    if jax.config.jax_compilation_cache_dir:  # the user's own setting wins
        return jax.config.jax_compilation_cache_dir
    path = cache_dir()
    if path is None:
        return None
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    # JAX decides once per process whether its cache is used, at the first compilation: a
    # program compiled before this call (a user's jnp operation) would have turned it off for good
    from jax.experimental.compilation_cache import compilation_cache

    compilation_cache.reset_cache()
    return str(path)
