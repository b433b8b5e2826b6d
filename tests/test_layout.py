"""The package's import graph, read from the source with ``ast``: no import circles, and no floor
imports a higher floor.

Every import counts: module level and inside functions, relative and absolute, ``from . import x``
of a submodule, and the packages a submodule import runs (``import jaxcal.a.b`` runs
``jaxcal/a/__init__.py``). Imports under ``if TYPE_CHECKING:`` run only for type checkers and are
left out. The graph is built by walking ``jaxcal/`` on disk.
"""

from __future__ import annotations

import ast
import pathlib

PKG = pathlib.Path(__file__).resolve().parents[1] / "jaxcal"
while not (PKG / "__init__.py").exists():  # tests moved into a subfolder: look one level further up
    PKG = PKG.parents[1] / "jaxcal"

#: Floors of the layout, lowest first: a module may import its own floor and
#: the floors below, never a higher one. Keyed by the first name below ``jaxcal``: a private
#: subpackage (``_fit``) or a public module/package (``methods``, ``report``...).
FLOORS = {
    "_core": 0, "optim": 0,  # precision, parameter groups, metrics, xla, json, buckets, joint trigonometry
    "_models": 1, "robots": 1,  # DH robot, non-geometric errors, kinematics, chains, URDF
    "_sensors": 2,  # measurement models, each sensor kind's data-file form, the closed-form starts of their extras
    "_datasets": 3,  # Dataset and the CSV reader/writer, which loop over the sensor kinds
    "_simulation": 4,  # simulated experiments and sensor data
    "_fit": 5,  # objective, problem, identifiability, diagnostics, result
    "methods": 6,
    "_calibration": 7,  # calibrate, evaluate, result files
    "_experiments": 8, "report": 8, "plots": 8,  # sweeps, planning, validation, hold-outs, HTML
    "cli": 9,
}

#: Upward imports kept on purpose, by module name (importer, imported) and why. Each must exist
#: (the test fails on a stale entry). None is left, and no hook either: the sensor kinds sit below
#: the data sets that loop over them, and ``CalibrationResult.evaluate(data)`` (floor 5) reaches
#: nothing above it (the evaluation with the extras registered again is ``evaluate_result``, floor 7).
#: The one lazy import is the sensor-kind registry's (``jaxcal._sensors._kind._BUILTIN``), within its floor.
KEPT: dict[tuple[str, str], str] = {}


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING")


def modules(root: pathlib.Path = PKG) -> dict[str, pathlib.Path]:
    """``{dotted name: path}`` of every module and package under ``root``."""
    out = {}
    for p in sorted(root.rglob("*.py")):
        parts = list(p.relative_to(root.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = p
    return out


def _imported(name: str, tree: ast.AST, is_package: bool, known) -> dict[str, int]:
    """``{module: line}`` that module ``name`` imports (jaxcal modules only)."""
    package = name if is_package else name.rpartition(".")[0]
    found: dict[str, int] = {}

    def add(target: str, line: int) -> None:
        parts = target.split(".")
        for k in range(2, len(parts) + 1):  # the packages on the way run too
            prefix = ".".join(parts[:k])
            if prefix in known and not name.startswith(prefix + ".") and prefix != name:
                found.setdefault(prefix, line)

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for c in child.orelse:
                    visit_one(c)
                continue
            visit_one(child)

    def visit_one(node: ast.AST) -> None:
        if isinstance(node, ast.Import):
            for a in node.names:
                add(a.name, node.lineno)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            add(mod, node.lineno)
            for a in node.names:  # `from . import _simulate`: a submodule
                if f"{mod}.{a.name}" in known:
                    add(f"{mod}.{a.name}", node.lineno)
        visit(node)

    visit(tree)
    return found


def import_graph(root: pathlib.Path = PKG) -> dict[str, dict[str, int]]:
    """``{module: {imported module: line}}`` of the package at ``root``."""
    mods = modules(root)
    return {name: _imported(name, ast.parse(path.read_text()), path.name == "__init__.py", mods)
            for name, path in mods.items()}


def _short(module: str) -> str:
    return module.rpartition(".")[2]


def cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """One circle per strongly connected component with more than one module (Tarjan's
    algorithm, then a shortest circle through the component's first module by BFS); the
    component's other modules are on further circles, shown once the first is broken."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    comps: list[list[str]] = []

    def strong(v: str) -> None:  # recursion depth ≤ number of modules (~60)
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                comps.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    out = []
    for comp in comps:
        members, start = set(comp), comp[0]
        parent, queue = {start: None}, [start]
        while queue:
            v = queue.pop(0)
            nxt = [w for w in graph[v] if w in members]
            if start in nxt:
                path = [v]
                while parent[path[-1]] is not None:
                    path.append(parent[path[-1]])
                out.append([*reversed(path), start])
                break
            for w in nxt:
                if w not in parent:
                    parent[w] = v
                    queue.append(w)
    return out


def _is_allowed(m: str, t: str, imports, allowed) -> bool:
    """Whether the import ``m → t`` is a kept exception (or the package of one: importing
    ``jaxcal._calibration._evaluate`` also runs ``jaxcal._calibration``)."""
    if (_short(m), _short(t)) in allowed:
        return True
    return any(s.startswith(t + ".") and (_short(m), _short(s)) in allowed for s in imports)


def _without_allowed(graph):
    allowed = KEPT
    return {m: {t: line for t, line in ts.items() if not _is_allowed(m, t, ts, allowed)} for m, ts in graph.items()}


def _describe(circle, graph) -> str:
    return " -> ".join(f"{a} (line {graph[a][b]})" for a, b in zip(circle, circle[1:])) + f" -> {circle[-1]}"


def test_no_import_circles():
    graph = import_graph()
    found = cycles(_without_allowed(graph))
    assert not found, "import circles (one per tangle):\n" + "\n".join(_describe(c, graph) for c in found)


def test_kept_upward_imports_exist():
    """Every kept exception is still an import (a stale entry would let a new circle through)."""
    graph = import_graph()
    edges = {(_short(m), _short(t)) for m, ts in graph.items() for t in ts}
    stale = sorted(set(KEPT) - edges)
    assert not stale, f"entries of KEPT that are no longer imports (remove them): {stale}"


def test_floors():
    """A lower floor never imports a higher one."""
    graph = import_graph()
    room = lambda m: m.split(".")[1] if m.count(".") else None  # noqa: E731
    unknown = sorted({room(m) for m in graph if room(m) is not None and room(m) not in FLOORS})
    assert not unknown, f"modules outside the floor map (add them to FLOORS): {unknown}"
    up = [f"{m} (floor {FLOORS[room(m)]}) imports {t} (floor {FLOORS[room(t)]}) at line {line}"
          for m, ts in graph.items() if room(m) is not None for t, line in ts.items()
          if room(t) is not None and FLOORS[room(t)] > FLOORS[room(m)] and not _is_allowed(m, t, ts, KEPT)]
    assert not up, "imports from a higher floor:\n" + "\n".join(up)


def test_the_graph_sees_every_kind_of_import(tmp_path):
    """The reader finds relative, absolute, function-level and package imports, skips
    TYPE_CHECKING blocks, and reports a circle through a function-level import."""
    pkg = tmp_path / "jaxcal"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from . import _c\n")
    (pkg / "_a.py").write_text("from typing import TYPE_CHECKING\nfrom ._b import f\n"
                               "if TYPE_CHECKING:\n    from .sub import _c\n")
    (pkg / "_b.py").write_text("def f():\n    import jaxcal.sub._c\n")
    (pkg / "sub" / "_c.py").write_text("def g():\n    from .._a import x\n")
    g = import_graph(pkg)
    assert g["jaxcal._a"] == {"jaxcal._b": 2}
    assert set(g["jaxcal._b"]) == {"jaxcal.sub", "jaxcal.sub._c"}
    assert g["jaxcal.sub"] == {"jaxcal.sub._c": 1}
    assert g["jaxcal.sub._c"] == {"jaxcal._a": 2}
    (circle,) = cycles(g)
    assert circle[0] == circle[-1] and set(circle) >= {"jaxcal._a", "jaxcal._b", "jaxcal.sub._c"}


def test_result_evaluate_has_one_return_type_and_no_hook():
    """``CalibrationResult.evaluate(data)`` (floor 5) returns Metrics and reaches nothing above it;
    the evaluation on new data with the extras registered again is :func:`jaxcal.evaluate_result`
    (floor 7), and the old ``extras=`` keyword says so instead of calling upward."""
    import inspect

    import pytest

    from jaxcal._core._metrics import Metrics
    from jaxcal._fit import _result

    assert not hasattr(_result, "set_extras_evaluator") and not hasattr(_result, "_extras_evaluator")
    assert inspect.signature(_result.CalibrationResult.evaluate).return_annotation in (Metrics, "Metrics")
    with pytest.raises(TypeError, match="evaluate_result"):
        _result.CalibrationResult.evaluate(object(), None, extras="auto")
