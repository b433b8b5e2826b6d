"""Shared helpers for the benchmark scripts: machine description and robust timing."""

from __future__ import annotations

import os
import platform
import time

import jax
import numpy as np


def machine() -> str:
    """One line naming the machine the numbers come from."""
    dev = jax.devices()[0]
    cpu = platform.processor() or platform.machine()
    try:  # the model name: machines of one kind differ (the same code ran 5 vs 10 ms on two of them)
        with open("/proc/cpuinfo") as f:
            model = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), "")
        cpu = f"{cpu}, {model}" if model else cpu
    except OSError:
        pass
    return (f"{dev.platform.upper()} ({dev.device_kind}), {os.cpu_count()} CPU cores ({cpu}), "
            f"JAX {jax.__version__}, Python {platform.python_version()}")


def median_time(fn, *args, repeats: int = 20, warmup: int = 1) -> float:
    """Median wall time (s) of ``fn(*args)`` with results blocked on, after ``warmup`` calls."""
    for _ in range(warmup):
        jax.block_until_ready(fn(*args))
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))
