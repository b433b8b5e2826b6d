"""Messages a command-line user reads name what to do in the user's terms: no Python keyword
hints (``pass tip=``, ``choose base=``, ``consider loss='huber'``) in jaxcal's messages; a message
that a Python user also meets names both (``--tip LINK on the command line, load_urdf's tip
argument in Python``)."""

import ast
import pathlib
import re

PKG = pathlib.Path(__file__).resolve().parents[2] / "jaxcal"
#: an instruction followed by a Python keyword argument ("pass tip=", "choose base=", "use loss=..."), not
#: the command line's own "--set NAME=VALUE"
HINT = re.compile(r"(?<![-\w])(pass|choose|consider|use|give|set)\s+[a-z][a-z_0-9]*=")


def _messages():
    for path in sorted(PKG.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                yield path, node.lineno, node.value


def test_no_python_keyword_hints_in_messages():
    found = [f"{p.relative_to(PKG.parent)}:{line}: {m.group(0)!r}" for p, line, text in _messages()
             for m in HINT.finditer(text)]
    assert not found, "messages with a Python keyword hint (name the flag and the argument in words):\n" + \
        "\n".join(found)


def test_the_scan_sees_such_a_hint():
    """The pattern finds the wordings it is there to keep out."""
    assert HINT.search("the tree branches; choose tip= among its leaf links")
    assert HINT.search("no floor (pass noise_std=)")
    assert not HINT.search("name the chain's tip link (--tip LINK on the command line, load_urdf's tip argument)")
    assert not HINT.search("method hyperparameter, e.g. --set steps=1000")
