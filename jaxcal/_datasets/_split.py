"""The train/test split of ``jaxcal calibrate`` from a seed, drawn on the host.

:func:`seed_split` gives the method key and the rows of :meth:`jaxcal.Dataset.split` for
``k_split, k_method = jax.random.split(jax.random.key(seed))``: in NumPy, JAX's threefry bits and
sort-based shuffle bit for bit (no compiled program to load at start-up), or by one compiled
program where JAX's PRNG settings differ. A script that wants the command line's split of a file
calls it with the same seed and test fraction.
"""

from __future__ import annotations

import functools

import jax
import numpy as np

from .._core._xla import jit

__all__ = ["seed_split", "permutation_rounds"]


def permutation_rounds(n: int) -> int:
    """How many sort rounds ``jax.random.permutation`` makes for ``n`` elements (its heuristic:
    ``ceil(3·ln n / ln(2³²−1))``; 1 up to 1 625 elements, 2 up to ~2.6 million)."""
    return int(np.ceil(3 * np.log(max(1, int(n))) / np.log(np.iinfo(np.uint32).max)))


def seed_split(seed: int, n: int, test_fraction: float):
    """``(k_method, train_idx, test_idx)``: ``k_split, k_method = jax.random.split(jax.random.key(seed))``
    and the row indices (0-based, into the file's data rows) of :meth:`Dataset.split`'s train/test
    parts drawn with ``k_split``. Computed on the host by :func:`seed_split_numpy` (JAX's
    threefry bits and sort-based shuffle, bit for bit) under JAX's default PRNG settings, else by
    one compiled program (which a start loads from the compilation cache: ~0.1 s on 2 cores)."""
    host = seed_split_numpy(seed, n)
    if host is not None:
        k_method, perm = host
    else:
        k_method, perm = seed_split_program()(seed, n)
        perm = np.asarray(perm)
    n_test = int(round(n * test_fraction))
    return k_method, perm[n_test:], perm[:n_test]


def _threefry2x32_numpy(k1, k2, x1, x2):
    """JAX's Threefry-2x32 hash (``jax._src.random.threefry2x32``) of uint32 arrays, in NumPy."""
    rotations = ((13, 15, 26, 6), (17, 29, 16, 24))
    ks = (k1, k2, k1 ^ k2 ^ np.uint32(0x1BD11BDA))
    a, b = x1 + ks[0], x2 + ks[1]
    for i in range(5):
        for r in rotations[i % 2]:
            a = a + b
            b = (b << np.uint32(r)) | (b >> np.uint32(32 - r))
            b = a ^ b
        a, b = a + ks[(i + 1) % 3], b + ks[(i + 2) % 3] + np.uint32(i + 1)
    return a, b


def key_numpy(seed: int):
    """``jax.random.key(seed)`` made on the host: the typed key wrapping ``[seed >> 32, seed &
    0xFFFFFFFF]`` (what the threefry seeding program computes), without running that program
    (``jax.random.key`` compiles and dispatches two small programs per process, ~30–60 ms of a
    command); ``jax.random.key(seed)`` itself where JAX's settings differ (another PRNG, no x64)
    or the seed is outside ``[0, 2**63)``."""
    cfg = jax.config
    seed = int(seed)
    if not (cfg.jax_default_prng_impl == "threefry2x32" and cfg.jax_enable_x64 and 0 <= seed < 2 ** 63):
        return jax.random.key(seed)
    return jax.random.wrap_key_data(np.asarray([seed >> 32, seed & 0xFFFFFFFF], np.uint32))


def seed_split_numpy(seed: int, n: int):
    """``(k_method, permutation of range(n))`` of :func:`seed_split` in NumPy: the same bits as
    ``jax.random.key``/``split`` (partitionable threefry) and ``jax.random.permutation`` (rounds of
    stable sorts by 32 random bits), checked against JAX in ``tests/cli``; ``None`` where JAX's
    settings differ from those (another PRNG, ``jax_threefry_partitionable`` off, no x64) or the
    seed is outside ``[0, 2**63)``."""
    cfg = jax.config
    if not (cfg.jax_default_prng_impl == "threefry2x32" and cfg.jax_threefry_partitionable
            and cfg.jax_enable_x64 and 0 <= int(seed) < 2 ** 63 and n >= 1):
        return None
    seed = int(seed)
    key = np.asarray([seed >> 32, seed & 0xFFFFFFFF], np.uint32)  # jax.random.key(seed)

    def split(key):  # jax.random.split(key): counts (0, 0), (0, 1)
        b1, b2 = _threefry2x32_numpy(key[0], key[1], np.zeros(2, np.uint32), np.arange(2, dtype=np.uint32))
        return np.stack([b1, b2], axis=1)

    k_split, k_method = split(key)
    x = np.arange(n)
    for _ in range(permutation_rounds(n)):  # as jax.random.permutation
        k_split, sub = split(k_split)
        b1, b2 = _threefry2x32_numpy(sub[0], sub[1], np.zeros(n, np.uint32), np.arange(n, dtype=np.uint32))
        x = x[np.argsort(b1 ^ b2, kind="stable")]  # lax.sort_key_val: a stable sort
    return jax.random.wrap_key_data(k_method), x


@functools.cache
def seed_split_program():
    """The split as one compiled JAX program ``(seed, n) -> (k_method, permutation)`` (built on first use)."""

    @functools.partial(jit, static_argnums=1)
    def program(seed, n):
        k_split, k_method = jax.random.split(jax.random.key(seed))
        return k_method, jax.random.permutation(k_split, n)

    return program
