"""Griffe extension: make jaxcal's lazily imported public names visible to mkdocstrings.

``jaxcal/__init__.py`` (and ``jaxcal/methods/__init__.py``) import their public names on first
use through a module-level ``_LAZY = {name: (module, attribute or None)}`` table and PEP 562's
``__getattr__``, so static analysis sees no ``from ._x import f`` lines. This extension reads
every ``_LAZY`` table (statically, nothing is imported) and adds the aliases ``jaxcal.name ->
jaxcal.<module>.<attribute>``, so the API pages can say ``::: jaxcal.calibrate`` and keep
working when the modules move (only the ``_LAZY`` table changes then).
"""

from __future__ import annotations

import ast

import griffe


def _walk(module: griffe.Module):
    yield module
    for member in module.modules.values():
        if not member.is_alias:
            yield from _walk(member)


class LazyExports(griffe.Extension):
    def on_package(self, *, pkg: griffe.Module, **kwargs) -> None:
        for module in list(_walk(pkg)):
            table = module.members.get("_LAZY")
            if table is None or table.is_alias or getattr(table, "value", None) is None:
                continue
            for name, (where, attr) in ast.literal_eval(str(table.value)).items():
                if name in module.members:
                    continue
                target = f"{module.path}.{where}" + ("" if attr is None else f".{attr}")
                module.set_member(name, griffe.Alias(name, target, parent=module))
