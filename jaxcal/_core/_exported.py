"""Programs kept on disk as serialised StableHLO (``jax.export``): a fresh process skips tracing.

JAX's persistent compilation cache (:mod:`jaxcal._core._cache`) spares a new process the XLA
compilation of a program it compiled before, but not the tracing and lowering that come first:
for a warm ``jaxcal calibrate`` on a 2-core CPU these took about as long as everything else the
command does (the solve's program alone ~2 s). This module keeps the *lowered* program too, as a
``jax.export`` serialisation (never a pickle), so that the next process deserialises it, wraps it
in a small ``jit`` (lowered in milliseconds) and finds the compiled executable in the persistent
cache.

An entry is used only when everything that decides the program is equal: its key is a SHA-256
of the program's name, a hash of jaxcal's own source files, the JAX and jaxlib versions, the
backend and its device kind, the float64 setting, the structure and static configuration of the
arguments written out as plain data (:func:`plain_description`; a configuration holding a
callable, e.g. a custom optax chain or a user-defined model, has no plain description and is
simply not stored), and the shapes and dtypes of the array arguments. The entry's own file
records the SHA-256 of the serialisation and the output structure; a corrupt, truncated or stale
entry (or one whose shapes do not match) is ignored and written again, never trusted.

Where: the folder ``exported/`` inside jaxcal's cache directory
(:func:`~jaxcal._core._cache.cache_dir`; ``JAXCAL_CACHE_DIR=off`` and ``jaxcal --no-cache`` turn
this off with the compilation cache). ``JAXCAL_EXPORT=off`` turns off only this layer.
Serialisation needs the ``flatbuffers`` package (a dependency of jaxcal; the layer is off where it
is missing).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import pathlib

__all__ = ["ENV_VAR", "enabled", "plain_description", "describe", "source_hash", "compile_stored", "StoredProgram"]

#: environment variable: ``off`` (``0``, ``false``, ``no``, ``none``) turns the layer off.
ENV_VAR = "JAXCAL_EXPORT"

_PLAIN = (bool, int, float, str, type(None))

#: ``{"stored": n, "loaded": n, "rejected": n}`` of this process (tests and benchmarks read it).
STATS = {"stored": 0, "loaded": 0, "rejected": 0}


def _directory() -> pathlib.Path | None:
    from ._cache import _STATE, cache_dir

    base = None if _STATE.get("disabled") else cache_dir()
    return None if base is None else base / "exported"


def enabled() -> bool:
    """Whether programs are kept and looked up on disk in this process."""
    from ._cache import switched_off

    if switched_off(ENV_VAR) or _directory() is None:
        return False
    try:
        import flatbuffers  # noqa: F401  (jax.export's serialisation needs it)
    except ImportError:
        return False
    return True


@functools.lru_cache(maxsize=1)
def source_hash() -> str:
    """SHA-256 of every ``.py`` file of the installed jaxcal package (path and bytes): an entry
    written by other jaxcal code never matches."""
    root = pathlib.Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for p in sorted(root.rglob("*.py")):
        h.update(str(p.relative_to(root)).encode())
        h.update(b"\0")
        h.update(p.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def plain_description(tree) -> str | None:
    """The structure and non-array leaves of a pytree (e.g. the static part of an
    ``equinox.partition``, or a function's static arguments) as text, or ``None`` when it has no
    faithful plain description: a leaf that is not plain data (:func:`describe`), or a node whose
    static data print as an object address (a function, a user's callable)."""
    import jax

    leaves, treedef = jax.tree_util.tree_flatten(tree)
    text = str(treedef)
    if " at 0x" in text or "<lambda>" in text or "<function" in text:
        return None
    parts = [describe(leaf) for leaf in leaves]
    return None if any(p is None for p in parts) else text + "|" + "|".join(parts)


def describe(obj) -> str | None:
    """A complete description of plain data as text: bool/int/float/str/None, tuples and lists
    of them, NumPy arrays (dtype, shape, values) and dataclasses of such fields (e.g. a
    :class:`~jaxcal.ParameterSpace` with its layout); ``None`` for anything else."""
    import dataclasses

    import numpy as np

    if type(obj) in _PLAIN:
        return repr(obj)
    if isinstance(obj, (tuple, list)):
        parts = [describe(v) for v in obj]
        return None if any(p is None for p in parts) else f"{type(obj).__name__}({','.join(parts)})"
    if isinstance(obj, np.ndarray):
        return f"ndarray({obj.dtype},{obj.shape},{obj.tolist()!r})"
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        parts = [(f.name, describe(getattr(obj, f.name))) for f in dataclasses.fields(obj)]
        if any(p is None for _, p in parts):
            return None
        return f"{type(obj).__module__}.{type(obj).__qualname__}(" + ",".join(f"{k}={v}" for k, v in parts) + ")"
    return None


def _avals(leaves) -> list[str]:
    import jax

    return [str(jax.typeof(x)) for x in leaves]


def _key(name: str, description: str, leaves) -> str:
    import jax
    import jaxlib

    from ._xla import export_platform, target_device

    dev = target_device()
    parts = ["jaxcal-exported/1", name, source_hash(), jax.__version__, jaxlib.__version__, export_platform(),
             getattr(dev, "device_kind", ""), str(jax.config.jax_enable_x64), description, *_avals(leaves)]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


class StoredProgram:
    """A compiled program over the flat leaves of its arguments, called with the arguments as
    pytrees: ``program(*args)`` flattens them, runs the executable and rebuilds the output (from
    ``out_tree``, or as the program returns it when ``None``)."""

    def __init__(self, compiled, out_tree=None):
        self.compiled, self.out_tree = compiled, out_tree

    def __call__(self, *args):
        import jax

        out = self.compiled(*jax.tree_util.tree_leaves(args))
        return out if self.out_tree is None else jax.tree_util.tree_unflatten(self.out_tree, out)


def _read(path: pathlib.Path, out_tree, leaves):
    """The deserialised :class:`jax.export.Exported` at ``path``, or ``None`` (absent, corrupt,
    another output structure, other shapes)."""
    from jax import export

    meta_path = path.with_suffix(".json")
    if not meta_path.is_file():
        return None
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
        blob = path.read_bytes()
        if hashlib.sha256(blob).hexdigest() != meta["sha256"] or meta["out_tree"] != str(out_tree):
            raise ValueError("checksum or output structure")
        exp = export.deserialize(bytearray(blob))
        n_out = exp.out_tree.num_leaves if out_tree is None else out_tree.num_leaves
        if [str(a) for a in exp.in_avals] != _avals(leaves) or len(exp.out_avals) != n_out:
            raise ValueError("shapes")
    except Exception:  # noqa: BLE001 — whatever is wrong with it, it is not used
        STATS["rejected"] += 1
        return None
    STATS["loaded"] += 1
    return exp


def _write(path: pathlib.Path, blob: bytes, out_tree) -> None:
    meta = {"sha256": hashlib.sha256(blob).hexdigest(), "out_tree": str(out_tree)}
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        for target, data in ((path, blob), (path.with_suffix(".json"), json.dumps(meta).encode())):
            tmp = target.with_name(f"{target.name}.{os.getpid()}.tmp")
            tmp.write_bytes(data)
            os.replace(tmp, target)  # atomic: a reader sees the old entry or the new one
    except OSError:
        return
    STATS["stored"] += 1


#: programs of this process that cannot be kept (an output node jax.export cannot serialise):
#: not exported again
_UNSTORABLE: set = set()


def compile_stored(name: str, fn, args: tuple, description: str, compile_lowered, out_tree=None):
    """A :class:`StoredProgram` of ``fn(*args)`` (``args`` pytrees of arrays), from the disk entry
    when one matches, else exported (traced and lowered once), written to disk and compiled.

    ``description``: the plain description of everything static that decides the program
    (:func:`plain_description`). ``out_tree``: the output's pytree structure when the caller knows
    it without tracing (the program then returns the flat leaves, and an entry recorded with
    another structure is not used, nor is a traced output of another structure stored); ``None``:
    the output is built of containers ``jax.export`` serialises (tuples, lists, dicts, ``None``),
    recorded in the entry. ``compile_lowered``: compiles a ``jax.stages.Lowered`` (with jaxcal's
    options and persistent cache). Returns ``None`` when the program cannot be kept (the caller
    compiles it the usual way)."""
    import jax
    from jax import export

    from ._xla import export_platform

    leaves, in_tree = jax.tree_util.tree_flatten(args)
    key = _key(name, description + "|" + str(in_tree), leaves)
    if key in _UNSTORABLE:
        return None
    path = _directory() / f"{key}.jaxexport"
    exp = _read(path, out_tree, leaves)
    if exp is None:
        traced = {}

        def flat(*xs):
            out = fn(*jax.tree_util.tree_unflatten(in_tree, xs))
            if out_tree is None:
                return out
            out_leaves, traced["tree"] = jax.tree_util.tree_flatten(out)
            return tuple(out_leaves)

        try:
            exp = export.export(jax.jit(flat), platforms=[export_platform()])(*leaves)
            if out_tree is not None and traced["tree"] != out_tree:
                raise ValueError("output structure")
            blob = bytes(exp.serialize())
        except Exception:  # noqa: BLE001 — not exportable (a LAPACK call without jax.export's
            # compatibility guarantee, e.g. LM's QR solver) or an output it cannot serialise:
            # compiled the usual way
            _UNSTORABLE.add(key)
            return None
        _write(path, blob, out_tree)
    compiled = compile_lowered(jax.jit(exp.call).lower(*leaves))
    return StoredProgram(compiled, out_tree)
