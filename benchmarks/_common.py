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


def append_section(path, title: str, how: str, table: str, load: tuple[float, float]) -> None:
    """Append a dated results section to ``path``: ``## title (date)``, the machine and the load
    average at the start and end (``load``), ``how`` the numbers were taken, then ``table``."""
    import pathlib

    text = (f"\n## {title} ({time.strftime('%Y-%m-%d')})\n\n"
            f"Machine: {machine()}; load average {load[0]:.2f} at the start, {load[1]:.2f} at the end. "
            f"{how}\n\n{table}\n")
    with pathlib.Path(path).open("a", encoding="utf-8") as f:
        f.write(text)


def write_results(path, lines) -> None:
    """Write the Markdown ``lines`` to the results file ``path``, print them and where they went."""
    import pathlib

    text = "\n".join(lines)
    pathlib.Path(path).write_text(text + "\n", encoding="utf-8")
    print(text)
    print(f"wrote {path}")
