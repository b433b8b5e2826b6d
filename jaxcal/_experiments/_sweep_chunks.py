"""How a sweep's chunks of trials run (:mod:`jaxcal._experiments._sweep`).

A chunk is one compiled function over a batch of trials (``jax.vmap``, or ``jax.lax.map`` on a
single CPU device: :func:`_batched`, :func:`_run_chunk`), sharded over a one-axis device mesh when
there are several devices. :func:`_chunking` sizes the chunks, :class:`_Runner` lowers, compiles
(cached in :data:`_COMPILED_CHUNKS`) and runs one unit's chunks, :func:`_compile_units` compiles
the units in parallel threads, :class:`_Store` keeps finished chunks in ``out_dir`` (resume), and
:class:`_Execution` ties them together: every chunk of a unit, computed or loaded.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import pathlib
import sys
import time
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from .._core._buckets import BoundedCache, cache_size, release_memory, signature
from .._core._precision import cast_floating, dtype_scope
from .._core._xla import compile_lowered, jit

__all__ = ["DEFAULT_CHUNK_PER_DEVICE", "DEFAULT_CHUNK_PER_ACCELERATOR"]


#: Default maximum number of trials per device in one vmapped chunk (bounds memory: the RBF
#: network and the population methods hold a few MB per trial at 2 000 samples).
DEFAULT_CHUNK_PER_DEVICE = 16


#: The same on a GPU or TPU (one vmapped chunk of up to 1 024 trials per device). An accelerator
#: runs a vmapped chunk of 16 LM trials about as fast as one of 1 000 (launch-bound: 19 ms for
#: 1 000 trials × 2 000 samples on an H100), so with the CPU's 16 a 1 000-trial sweep cost 63
#: chunks (3.6–4.2 s) instead of one.
DEFAULT_CHUNK_PER_ACCELERATOR = 1024


def _progress(enabled: bool, msg: str) -> None:
    if enabled:
        print(f"[jaxcal.sweep] {msg}", file=sys.stderr, flush=True)


def _resolve_devices(devices) -> list:
    if devices is None:
        devs = jax.devices()
    elif isinstance(devices, int):
        devs = jax.devices()[:devices]
        if len(devs) < devices:
            raise ValueError(f"asked for {devices} devices, only {len(jax.devices())} present")
    else:
        devs = list(devices)
    if not devs:
        raise ValueError("no devices")
    return devs


def _chunking(n: int, chunk_size: int | None, n_dev: int, platform: str = "cpu") -> tuple[int, int]:
    """``(per_device, per_chunk)``: trials per device in one vmapped call, and per chunk.

    The per-device batch is balanced (``n`` trials with a cap of 16 run as 2 × 10, not 16 + 4).
    With an explicit ``chunk_size`` it does not depend on the device count, so trial ``i`` is
    computed in the same batch of trials on any number of devices (bitwise-equal results); by
    default the cap is ``min(16, ceil(n / n_dev))`` (1 024 instead of 16 on a GPU or TPU) so that
    every device gets work.
    """
    if chunk_size is None:
        default = DEFAULT_CHUNK_PER_DEVICE if platform == "cpu" else DEFAULT_CHUNK_PER_ACCELERATOR
        cap = min(default, math.ceil(n / n_dev))
    else:
        cap = int(chunk_size)
        if cap < 1:
            raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
    per_device = math.ceil(n / math.ceil(n / cap))
    return per_device, per_device * n_dev


def _batched(static, dyn, inputs, hyper, sequential: bool = False):
    """The trial over a chunk: ``inputs`` is a tuple of trial-batched pytrees; with a grid, the
    hyperparameter points form an outer axis. ``jax.vmap`` (all trials at once), or with
    ``sequential`` ``jax.lax.map`` (one trial after the other inside the compiled function)."""
    trial = eqx.combine(dyn, static)
    batch = (lambda f, xs: jax.lax.map(lambda a: f(*a), xs)) if sequential else (lambda f, xs: jax.vmap(f)(*xs))  # noqa: E731
    over_trials = lambda h: batch(lambda *a: trial(*a, h), inputs)  # noqa: E731
    return over_trials(None) if hyper is None else batch(over_trials, (hyper,))


@functools.partial(jit, static_argnums=(0, 1, 2, 3))
def _run_chunk(static, mesh, grid: bool, sequential: bool, dyn, inputs, hyper):
    """One chunk of trials, jitted (module level so compilations are cached by the static part).

    With a ``mesh`` the trial axis of ``inputs`` arrives sharded over the devices and everything
    else replicated; the vmapped trial is partitioned along that axis by XLA (GSPMD), and the
    outputs are constrained to the same sharding.
    """
    out = _batched(static, dyn, inputs, hyper, sequential)
    if mesh is not None:
        spec = P(None, "trials") if grid else P("trials")
        out = jax.lax.with_sharding_constraint(out, NamedSharding(mesh, spec))
    return out


class _Store:
    """Chunk files of a sweep in ``out_dir`` (written as each chunk finishes; read to resume)."""

    def __init__(self, out_dir):
        self.root = None if out_dir is None else pathlib.Path(out_dir)
        if self.root is not None:
            self.root.mkdir(parents=True, exist_ok=True)

    def path(self, unit: str, start: int, stop: int) -> pathlib.Path | None:
        if self.root is None:
            return None
        safe = "".join(c if c.isalnum() or c in "-_.=," else "_" for c in unit)
        return self.root / "chunks" / safe / f"trials_{start:06d}-{stop:06d}.npz"

    def exists(self, unit, start, stop) -> bool:
        p = self.path(unit, start, stop)
        return p is not None and p.exists()

    def load(self, unit, start, stop, fingerprint):
        p = self.path(unit, start, stop)
        if p is None or not p.exists():
            return None
        with np.load(p, allow_pickle=False) as f:
            meta = json.loads(str(f["__meta__"]))
            if meta.get("fingerprint") != fingerprint:
                raise ValueError(
                    f"{p} was written by a sweep with other settings (fingerprint {meta.get('fingerprint')} "
                    f"!= {fingerprint}); use another out_dir or delete it"
                )
            arrays = {k: np.array(f[k]) for k in f.files if k != "__meta__"}
        return arrays, meta

    def save(self, unit, start, stop, fingerprint, arrays: dict, meta: dict) -> None:
        p = self.path(unit, start, stop)
        if p is None or jax.process_index() != 0:
            return
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_name(p.stem + ".tmp.npz")
        np.savez(tmp, __meta__=np.asarray(json.dumps(meta | {"fingerprint": fingerprint})), **arrays)
        os.replace(tmp, p)  # atomic: an interrupted write never leaves a half file


def _flatten(tree) -> dict[str, np.ndarray]:
    leaves, _ = jax.tree_util.tree_flatten_with_path(tree)
    return {jax.tree_util.keystr(path): np.asarray(leaf) for path, leaf in leaves}


def _unflatten(like, arrays: dict[str, np.ndarray]):
    leaves, treedef = jax.tree_util.tree_flatten_with_path(like)
    return jax.tree_util.tree_unflatten(treedef, [arrays[jax.tree_util.keystr(p)] for p, _ in leaves])


def _to_host(tree):
    def get(a):
        if isinstance(a, jax.Array) and not a.is_fully_addressable:
            from jax.experimental import multihost_utils

            return np.asarray(multihost_utils.process_allgather(a, tiled=True))
        return np.asarray(a)

    return jax.tree.map(get, tree)


def _put_global(tree, sharding):
    """``jax.device_put(tree, sharding)``, also when the sharding spans devices of other processes
    (multi-process runs after ``jax.distributed.initialize()``, where ``device_put`` refuses a
    non-addressable sharding): every process holds the same host values, and each puts the shards
    of its own devices (``jax.make_array_from_callback``)."""
    if sharding.is_fully_addressable:
        return jax.device_put(tree, sharding)

    def one(x):
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            return x  # already a global array
        if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jax.dtypes.prng_key):
            return jax.random.wrap_key_data(one(jax.random.key_data(x)), impl=jax.random.key_impl(x))
        x = np.asarray(x)
        return jax.make_array_from_callback(x.shape, sharding, lambda idx: x[idx])

    return jax.tree.map(one, tree)


def _one_trial_like(runner, eval_shape, dtype):
    """Shapes of one trial's output: from the unit's compiled chunk (``[chunk, ...]`` outputs), or,
    when every chunk was loaded from disk (nothing compiled), by tracing the trial."""
    if runner.compiled is not None:
        return jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape[1:], a.dtype), runner.compiled.out_info)
    with dtype_scope(dtype):
        return eval_shape()


class _Runner:
    """Compiles and runs the chunks of one unit (data pass, method, or grid group)."""

    def __init__(self, trial: eqx.Module, mesh: Mesh | None, dtype, grid: bool, sequential: bool, device=None):
        self.dyn, self.static = eqx.partition(trial, eqx.is_array)
        self.dyn = cast_floating(self.dyn, dtype)
        if mesh is not None:  # the trial's own arrays are replicated on every device
            self.dyn = _put_global(self.dyn, NamedSharding(mesh, P()))
        elif device is not None:  # one given device (e.g. the CPU of a GPU machine): run there
            self.dyn = jax.device_put(self.dyn, device)
        self.mesh, self.dtype, self.grid, self.sequential = mesh, dtype, grid, sequential
        self.device = device
        if mesh is not None:
            self.platform = mesh.devices.flat[0].platform
        else:
            self.platform = jax.default_backend() if device is None else device.platform
        self.compiled = None
        self._lowered = None
        self._key = None
        self.compile_time_s = 0.0
        self.reused = False

    def _cache_key(self, inputs, hyper):
        """The key of this unit's compiled chunk function in :data:`_COMPILED_CHUNKS`: the static
        part of the trial (a padded simulation's static part is its bucket, not its sample count),
        the mesh or device and the shapes/dtypes of every argument; ``None`` if unhashable."""
        try:
            key = (self.static, self.mesh, None if self.device is None else self.device.id, self.platform,
                   self.grid, self.sequential, str(jnp.dtype(self.dtype)), jax.config.jax_enable_x64,
                   signature(self.dyn), signature(inputs), signature(hyper))
            hash(key)
        except TypeError:
            return None
        return key

    def _place(self, inputs, hyper):
        if self.mesh is None:
            if self.device is not None:
                if any(isinstance(a, jax.ShapeDtypeStruct) for a in jax.tree.leaves(inputs)):  # lowering only
                    return inputs, jax.device_put(hyper, self.device)
                return jax.device_put((inputs, hyper), self.device)
            return inputs, hyper
        rep = NamedSharding(self.mesh, P())
        inputs = _put_global(inputs, NamedSharding(self.mesh, P("trials")))
        return inputs, _put_global(hyper, rep)

    def lower(self, inputs, hyper):
        """Trace and lower the chunk function for ``inputs`` (Python-bound: the main thread), or
        take the compiled function from :data:`_COMPILED_CHUNKS` (an earlier sweep of the same
        unit and shapes in this process: nothing to trace or compile)."""
        t0 = time.perf_counter()
        with dtype_scope(self.dtype):
            inputs, hyper = self._place(inputs, hyper)
            self._key = self._cache_key(inputs, hyper)
            hit = None if self._key is None else _COMPILED_CHUNKS.get(self._key)
            if hit is not None:
                self.compiled, self.reused, self.compile_time_s = hit, True, 0.0
                return
            self._lowered = _run_chunk.lower(self.static, self.mesh, self.grid, self.sequential, self.dyn, inputs, hyper)
        self.compile_time_s = time.perf_counter() - t0

    def compile(self):
        """XLA-compile what :meth:`lower` traced (releases the GIL: units compile in parallel threads)."""
        if self.compiled is not None:  # reused from _COMPILED_CHUNKS
            return
        t0 = time.perf_counter()
        self.compiled = compile_lowered(self._lowered, self.platform)
        self._lowered = None
        self.compile_time_s += time.perf_counter() - t0
        if self._key is not None:
            _COMPILED_CHUNKS.put(self._key, self.compiled)

    def __call__(self, inputs, hyper):
        if self.compiled is None:
            self.lower(inputs, hyper)
            self.compile()
            _forget_traces()
        with dtype_scope(self.dtype):
            inputs, hyper = self._place(inputs, hyper)
            t0 = time.perf_counter()
            out = jax.block_until_ready(self.compiled(self.dyn, inputs, hyper))
            wall = time.perf_counter() - t0
        return _to_host(out), wall


#: compiled chunk functions of this process, least recently used dropped first
#: (``$JAXCAL_SWEEP_CACHE`` entries, default 32: the data unit and a method of 16 shape buckets;
#: each holds an executable, ~14 MB resident on the 2-core CPU for the paper experiment's LM): a
#: second sweep of the same units and shapes — a learning curve over sample counts of one shape
#: bucket, a notebook re-running a cell — compiles nothing.
_COMPILED_CHUNKS = BoundedCache(cache_size("sweep", 32))


def _forget_traces() -> None:
    """Drop ``_run_chunk``'s own trace and lowering caches (tens of MB per unit, never freed by
    JAX; the compiled functions live in :data:`_COMPILED_CHUNKS`) and give freed heap pages back."""
    _run_chunk.clear_cache()
    release_memory()


@dataclasses.dataclass(frozen=True)
class _Execution:
    """How a sweep's trials run: chunks of ``csize`` trials (``per_device`` on each of ``devs``,
    sharded over ``mesh`` when there are several), ``lax.map`` or ``vmap`` inside a chunk
    (``sequential``), and the chunk store of ``out_dir``."""

    n_seeds: int
    per_device: int
    csize: int
    devs: list
    mesh: Mesh | None
    sequential: bool
    dtype: Any
    store: _Store
    progress: bool
    #: real test rows of a padded simulation (per-sample error arrays are cut to them), or None
    n_test: int | None = None

    @classmethod
    def build(cls, n_seeds, chunk_size, devices, batching, dtype, out_dir, progress, n_test=None) -> _Execution:
        devs = _resolve_devices(devices)
        mesh = Mesh(np.asarray(devs), ("trials",)) if len(devs) > 1 else None
        if batching not in ("auto", "vmap", "map"):
            raise ValueError(f"batching must be 'auto', 'vmap' or 'map', got {batching!r}")
        if batching == "map" and mesh is not None:
            raise ValueError("batching='map' runs on one device; use 'vmap' (or 'auto') with several devices")
        sequential = batching == "map" or (batching == "auto" and mesh is None and devs[0].platform == "cpu")
        per_device, csize = _chunking(n_seeds, chunk_size, len(devs), devs[0].platform)
        return cls(n_seeds, per_device, csize, devs, mesh, sequential, dtype, _Store(out_dir), progress, n_test)

    @property
    def n_chunks(self) -> int:
        return math.ceil(self.n_seeds / self.csize)

    def bounds(self, c: int) -> tuple[int, int]:
        """Trials ``a … b−1`` of chunk ``c``."""
        return c * self.csize, min((c + 1) * self.csize, self.n_seeds)

    def pending(self, unit: str) -> bool:
        """Whether some chunk of ``unit`` is not in the store yet (it has to be computed)."""
        return any(not self.store.exists(unit, *self.bounds(c)) for c in range(self.n_chunks))

    def new_runner(self, trial, hyper) -> _Runner:
        return _Runner(trial, self.mesh, self.dtype, hyper is not None, self.sequential,
                       None if self.mesh is not None else self.devs[0])

    def run_unit(self, unit: str, trial, hyper, fp: str, n_points: int | None, inputs_of, runner=None):
        """Run (or load) every chunk of one compiled unit; returns the merged arrays, the time
        per trial ``[n]``, the compile time, the per-chunk arrays and the runner."""
        runner = self.new_runner(trial, hyper) if runner is None else runner
        chunks, walls = [], []
        for c in range(self.n_chunks):
            arrays, per = self._load_chunk(unit, c, fp, runner)
            if arrays is None:
                arrays, per = self._compute_chunk(unit, c, fp, runner, hyper, n_points, inputs_of)
            chunks.append(arrays)
            walls.append(per)
        axis = 1 if hyper is not None else 0
        merged = {k: np.concatenate([ch[k] for ch in chunks], axis=axis) for k in chunks[0]}
        times = np.concatenate([np.full(b - a, w) for (a, b), w in zip(map(self.bounds, range(self.n_chunks)), walls)])
        return merged, times, runner.compile_time_s, chunks, runner

    def _load_chunk(self, unit: str, c: int, fp: str, runner):
        """``(arrays, time per trial)`` of chunk ``c`` from the store, or ``(None, None)``."""
        a, b = self.bounds(c)
        loaded = self.store.load(unit, a, b, fp)
        if loaded is None:
            return None, None
        arrays, meta = loaded
        if c == 0:
            runner.compile_time_s = meta.get("compile_time_s", 0.0)
        _progress(self.progress, f"{_shown(unit)}: chunk {c + 1}/{self.n_chunks} (trials {a}–{b - 1}) loaded from "
                  f"{self.store.root}")
        return arrays, meta["time_per_trial_s"]

    def _compute_chunk(self, unit: str, c: int, fp: str, runner, hyper, n_points, inputs_of):
        """Compute chunk ``c`` (compiling the unit on first use) and save it to the store."""
        a, b = self.bounds(c)
        fresh = runner.compiled is None
        out, wall = runner(inputs_of(c, a, b), hyper)
        arrays = {k: (v[:, : b - a] if hyper is not None else v[: b - a]) for k, v in _flatten(out).items()}
        if self.n_test is not None:  # padded simulation: per-sample errors of the real test rows only
            arrays = {k: v[..., : self.n_test] if k.endswith(("test_errors", "before_errors")) else v
                      for k, v in arrays.items()}
        per = wall / (self.csize * (n_points or 1))
        self.store.save(unit, a, b, fp, arrays, {"time_per_trial_s": per, "compile_time_s": runner.compile_time_s})
        comp = "" if not fresh else (", compiled program reused" if runner.reused else
                                     f", compiled in {runner.compile_time_s:.1f} s")
        _progress(self.progress, f"{_shown(unit)}: chunk {c + 1}/{self.n_chunks} (trials {a}–{b - 1}) {wall:.2f} s "
                  f"({per * 1e3:.1f} ms/trial){comp}")
        return arrays, per


def _shown(unit: str) -> str:
    return "data" if unit == "_data" else unit


def _compile_units(units, new_runner, inputs_of, needed, progress: bool) -> dict:
    """``{unit name: compiled _Runner}`` for the units ``needed(unit)`` says will run a chunk
    (``inputs_of(unit)``: its first chunk's inputs, or their shapes):
    lowered in this thread, then compiled by a thread pool (one thread per unit, at most the
    number of CPU cores; ``JAXCAL_COMPILE_THREADS`` overrides, 1 = one after the other)."""
    todo = [u for u in units if needed(u)]
    if not todo:
        return {}
    runners = {}
    for u in todo:
        r = new_runner(u.trial, u.hyper)
        r.lower(inputs_of(u), u.hyper)
        runners[u.name] = r
    workers = int(os.environ.get("JAXCAL_COMPILE_THREADS") or min(len(todo), os.cpu_count() or 1))
    t0 = time.perf_counter()
    if workers <= 1 or len(todo) == 1:
        for r in runners.values():
            r.compile()
    else:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(lambda r: r.compile(), runners.values()))
    _forget_traces()
    reused = sum(r.reused for r in runners.values())
    if len(todo) > 1:
        _progress(progress, f"{len(todo)} units compiled in {time.perf_counter() - t0:.1f} s ({workers} thread(s))"
                  + (f"; {reused} reused from earlier sweeps" if reused else ""))
    return runners
