"""Griffe extension: make jaxcal's lazily imported public names visible to mkdocstrings.

``jaxcal/__init__.py`` (and ``jaxcal/methods/__init__.py``) import their public names on first
use through a module-level ``_LAZY = {name: (module, attribute or None)}`` table and PEP 562's
``__getattr__``, so static analysis sees no ``from ._x import f`` lines. This extension reads
every ``_LAZY`` table (statically, nothing is imported) and adds the aliases ``jaxcal.name ->
jaxcal.<module>.<attribute>``, so the API pages can say ``::: jaxcal.calibrate`` and keep
working when the modules move (only the ``_LAZY`` table changes then).

It also shows the docstrings' Sphinx roles (``:class:`~jaxcal.Prior```, ``:func:`calibrate```)
as code (``Prior``, ``calibrate``) instead of the raw role text; the source is left as it is.
"""

from __future__ import annotations

import ast
import re

import griffe

_ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|obj|exc|const):`(~?)([^`]+)`")


def _role_as_code(m: re.Match) -> str:
    target = m.group(2)
    return f"`{target.rsplit('.', 1)[-1] if m.group(1) else target}`"


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
                obj.docstring.value = _ROLE.sub(_role_as_code, obj.docstring.value)
        for module in list(_walk(pkg)):
            table = module.members.get("_LAZY")
            if table is None or table.is_alias or getattr(table, "value", None) is None:
                continue
            for name, (where, attr) in ast.literal_eval(str(table.value)).items():
                if name in module.members:
                    continue
                target = f"{module.path}.{where}" + ("" if attr is None else f".{attr}")
                module.set_member(name, griffe.Alias(name, target, parent=module))
