"""Multi-process sweeps: two local processes joined by ``jax.distributed.initialize`` on CPU.

The README says a sweep runs on several hosts after ``jax.distributed.initialize()``; this test
runs that path on one machine: two processes (one CPU device each, coordinator on localhost,
gloo collectives) sweep over the global device list. The result must equal a single-process
run, and only process 0 writes the output directory.
"""

import json
import os
import pathlib
import socket
import subprocess
import sys
import textwrap

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]

WORKER = textwrap.dedent("""
    import json, pathlib, sys
    import numpy as np
    import jax
    addr, pid, n_proc, out_dir, result = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4], sys.argv[5]
    if n_proc > 1:
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
        jax.distributed.initialize(coordinator_address=addr, num_processes=n_proc, process_id=pid,
                                   initialization_timeout=60)
    import jaxcal
    jaxcal.enable_x64()
    assert jax.process_count() == n_proc and len(jax.devices()) == 2, (jax.process_count(), jax.devices())
    res = jaxcal.sweep(["lm"], 4, n_samples=120, chunk_size=2, out_dir=out_dir or None, progress=False,
                       keep_errors=False, keep_history=False)
    run = res.runs["lm"]
    out = {"x": np.asarray(run.x).tolist(), "rmse": np.asarray(run.test.rmse).tolist(),
           "its": np.asarray(run.n_iterations).tolist(), "status": np.asarray(run.status).tolist(),
           "process": jax.process_index()}
    pathlib.Path(result).write_text(json.dumps(out))
""")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env(**extra):
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAX_PLATFORMS")}
    env |= {"JAX_PLATFORMS": "cpu", "PYTHONPATH": str(ROOT) + os.pathsep + env.get("PYTHONPATH", ""),
            "JAXCAL_COMPILE_THREADS": "1"} | extra
    return env


def test_two_processes_sweep_equals_one(tmp_path):
    script = tmp_path / "worker.py"
    script.write_text(WORKER)
    # reference: one process with two forced CPU devices (the same global device count), run at the
    # same time as the two processes (they wait on each other's collectives; the reference fills
    # the gaps)
    ref = tmp_path / "ref.json"
    reference = subprocess.Popen([sys.executable, str(script), "", "0", "1", "", str(ref)],
                                 env=_env(XLA_FLAGS="--xla_force_host_platform_device_count=2"),
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    addr = f"127.0.0.1:{_free_port()}"
    out_dir = tmp_path / "sweep"
    procs = [subprocess.Popen([sys.executable, str(script), addr, str(i), "2", str(out_dir), str(tmp_path / f"p{i}.json")],
                              env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for i in range(2)]
    logs = []
    try:
        for p in procs:
            logs.append(p.communicate(timeout=600)[0])
        ref_log = reference.communicate(timeout=600)[0]
    finally:
        for p in (*procs, reference):
            if p.poll() is None:
                p.kill()
    assert reference.returncode == 0, ref_log[-3000:]
    for p, log in zip(procs, logs):
        if p.returncode != 0 and ("gloo" in log.lower() or "collectives" in log.lower()) and "not" in log.lower():
            pytest.skip(f"this jaxlib has no CPU collectives for multi-process runs: {log.strip().splitlines()[-1]}")
        assert p.returncode == 0, log[-3000:]
    a = json.loads(ref.read_text())
    for i in range(2):
        b = json.loads((tmp_path / f"p{i}.json").read_text())
        assert b["process"] == i
        np.testing.assert_allclose(b["x"], a["x"], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(b["rmse"], a["rmse"], rtol=1e-12)
        assert b["its"] == a["its"] and b["status"] == a["status"]
    # only process 0 wrote: one settings file, one file per chunk, no leftovers of a second writer
    files = sorted(str(p.relative_to(out_dir)) for p in out_dir.rglob("*") if p.is_file())
    assert "sweep.json" in files
    chunks = [f for f in files if f.endswith(".npz")]
    assert len(chunks) == 2 and not any(".tmp" in f for f in files), files
