"""pytest plugin: per test, the XLA compilations (count, seconds) by program name, from jax's
compile log (``jax_log_compiles``). Appends one block per test to ``$COMPILEPROF_OUT`` (default
``compileprof.txt``). It logs every compilation, so the run is slower with it.

Run: ``PYTHONPATH=benchmarks COMPILEPROF_OUT=/tmp/prof.txt python -m pytest -q -n 2 --dist loadscope -m "not slow" -p compileprof``.
Summary of the last full run: ``benchmarks/results/test_compile_profile_cpu.md``.
"""
import collections
import logging
import os
import re

import jax
import pytest

_REC = []
PAT = re.compile(r"Finished XLA compilation of (.+?) in ([0-9.e-]+) sec")
PAT2 = re.compile(r"Finished tracing (?:\+ transforming )?(.+?) for p?jit in ([0-9.e-]+) sec")
PAT3 = re.compile(r"Finished jaxpr to MLIR module conversion (.+?) in ([0-9.e-]+) sec")

class H(logging.Handler):
    def emit(self, record):
        msg = record.getMessage()
        m = PAT.search(msg)
        if m:
            _REC.append(("compile", m.group(1), float(m.group(2))))
        m = PAT2.search(msg)
        if m:
            _REC.append(("trace", m.group(1), float(m.group(2))))
        m = PAT3.search(msg)
        if m:
            _REC.append(("lower", m.group(1), float(m.group(2))))

def pytest_configure(config):
    jax.config.update("jax_log_compiles", True)
    h = H()
    h.setLevel(logging.DEBUG)
    for name in ("jax._src.dispatch", "jax._src.interpreters.pxla", "jax._src.pjit", "jax"):
        lg = logging.getLogger(name)
        lg.addHandler(h)
        lg.setLevel(logging.DEBUG)
        lg.propagate = False

@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
    start = len(_REC)
    yield
    recs = _REC[start:]
    comp = [r for r in recs if r[0] == "compile"]
    by, t = collections.Counter(), collections.Counter()
    for _, n, s in comp:
        by[n] += 1
        t[n] += s
    with open(os.environ.get("COMPILEPROF_OUT", "compileprof.txt"), "a") as f:
        f.write(f"== {item.nodeid}: {len(comp)} compiles, {sum(r[2] for r in comp):.1f} s compile; trace {sum(r[2] for r in recs if r[0]=='trace'):.1f} s; lower {sum(r[2] for r in recs if r[0]=='lower'):.1f} s\n")
        for n, c in sorted(t.items(), key=lambda kv: -kv[1])[:12]:
            f.write(f"   {c:7.2f} s  x{by[n]:<4d} {n}\n")
