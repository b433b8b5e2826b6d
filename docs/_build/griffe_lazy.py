"""Griffe extension: make jaxcal's lazily imported public names visible to mkdocstrings.

``jaxcal/__init__.py`` (and ``jaxcal/methods/__init__.py``) import their public names on first
use through a module-level ``_LAZY = {name: (module, attribute or None)}`` table and PEP 562's
``__getattr__``, so static analysis sees no ``from ._x import f`` lines. This extension reads
every ``_LAZY`` table (statically, nothing is imported) and adds the aliases ``jaxcal.name ->
jaxcal.<module>.<attribute>``, so the API pages can say ``::: jaxcal.calibrate`` and keep
working when the modules move (only the ``_LAZY`` table changes then).

It also shows the docstrings' Sphinx roles (``:class:`~jaxcal.Prior```, ``:func:`calibrate```)
as code (``Prior``, ``calibrate``) instead of the raw role text, a private target
(``:func:`jaxcal._x._y.f```) by its last name only, and splits an argument line that documents
several arguments at once (``a, b: ...`` in an ``Args:`` section) into one entry per argument, so
each shows its own type and default from the signature (griffe cannot match ``a, b`` to the
signature and would print "required"). The source is left as it is.
"""

from __future__ import annotations

import ast
import re

import griffe

_ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|obj|exc|const):`(~?)([^`]+)`")


def _role_as_code(m: re.Match) -> str:
    target = m.group(2)
    short = m.group(1) or re.search(r"(^|\.)_[A-Za-z]", target.rsplit(".", 1)[0])
    return f"`{target.rsplit('.', 1)[-1] if short else target}`"


_SECTION = re.compile(r"^(\s*)(Args|Arguments|Parameters|Keyword Args|Keyword Arguments|Other Parameters):\s*$")
_GROUPED = re.compile(r"^(\s+)([A-Za-z_]\w*(?:,\s*[A-Za-z_]\w*)+):(\s.*|)$")


def _split_grouped_args(text: str) -> str:
    """``    a, b: text`` in an arguments section -> ``    a: text`` and ``    b: as for ``a``.``"""
    out, section_indent, item_indent = [], None, None
    for line in text.splitlines():
        m = _SECTION.match(line)
        if m:
            section_indent, item_indent = len(m.group(1)), None
            out.append(line)
            continue
        if section_indent is not None and line.strip():
            indent = len(line) - len(line.lstrip())
            if indent <= section_indent:
                section_indent = None
            elif item_indent is None:
                item_indent = indent
        g = _GROUPED.match(line) if section_indent is not None else None
        if g and len(g.group(1)) == item_indent:
            names = [n.strip() for n in g.group(2).split(",")]
            out.append(f"{g.group(1)}{names[0]}:{g.group(3)}")
            follow = [f"{g.group(1)}{n}: as for ``{names[0]}``." for n in names[1:]]
            out.append("\x00" + "\n".join(follow))  # placed after the first entry's continuation lines
            continue
        out.append(line)
    # move each placeholder past the continuation lines (indented deeper) of the entry above it
    done: list[str] = []
    pending: list[str] = []
    for line in out:
        if line.startswith("\x00"):
            pending.append(line[1:])
            continue
        if pending and line.strip() and (len(line) - len(line.lstrip())) <= _indent_of(pending[-1]):
            done.extend(pending)
            pending = []
        done.append(line)
    done.extend(pending)
    return "\n".join(done)


def _indent_of(block: str) -> int:
    first = block.splitlines()[0]
    return len(first) - len(first.lstrip())


def _walk(module: griffe.Module):
    yield module
    for member in module.modules.values():
        if not member.is_alias:
            yield from _walk(member)


def _objects(obj):
    yield obj
    for member in obj.members.values():
        if not member.is_alias:
            yield from _objects(member)


class LazyExports(griffe.Extension):
    def on_package(self, *, pkg: griffe.Module, **kwargs) -> None:
        for obj in _objects(pkg):
            if obj.docstring is not None:
                obj.docstring.value = _split_grouped_args(_ROLE.sub(_role_as_code, obj.docstring.value))
        for module in list(_walk(pkg)):
            table = module.members.get("_LAZY")
            if table is None or table.is_alias or getattr(table, "value", None) is None:
                continue
            for name, (where, attr) in ast.literal_eval(str(table.value)).items():
                if name in module.members:
                    continue
                target = f"{module.path}.{where}" + ("" if attr is None else f".{attr}")
                module.set_member(name, griffe.Alias(name, target, parent=module))
