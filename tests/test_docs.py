"""The documentation covers the public API and the README's links resolve.

No mkdocs needed: the API pages are read as text (``::: jaxcal.name`` is mkdocstrings' directive;
``mkdocs build --strict`` in ``.ci/run`` checks that each one renders).
"""

import re
from pathlib import Path

import jaxcal

ROOT = Path(__file__).resolve().parents[1]
API = ROOT / "docs" / "reference" / "api"


def _directives():
    """``[(page, 'jaxcal.name')]`` for every ``::: `` line of the API pages."""
    found = []
    for page in sorted(API.glob("*.md")):
        for line in page.read_text(encoding="utf-8").splitlines():
            m = re.match(r"^:::\s+(\S+)\s*$", line)
            if m:
                found.append((page.name, m.group(1)))
    return found


def test_every_public_name_has_one_reference_entry():
    documented = [target.removeprefix("jaxcal.") for _, target in _directives() if target.count(".") == 1]
    assert sorted(set(jaxcal.__all__) - set(documented)) == [], "public names without an API entry"
    assert sorted(set(documented) - set(jaxcal.__all__)) == [], "API entries for names not in jaxcal.__all__"
    repeated = sorted({n for n in documented if documented.count(n) > 1})
    assert repeated == [], f"documented more than once: {repeated}"


def test_reference_entries_name_public_objects_only():
    for page, target in _directives():
        parts = target.split(".")
        assert parts[0] == "jaxcal", (page, target)
        assert not any(p.startswith("_") for p in parts), f"{page}: {target} is private (it may move)"


def _relative_links(path: Path):
    text = path.read_text(encoding="utf-8")
    text = re.sub(r"```.*?```", "", text, flags=re.S)  # links in code blocks are not links
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if not re.match(r"^[a-z]+:|^#", target):
            yield target.split("#", 1)[0]


def test_readme_links_resolve():
    readme = ROOT / "README.md"
    missing = [t for t in _relative_links(readme) if not (ROOT / t).exists()]
    assert missing == [], f"README.md links to missing files: {missing}"


def test_docs_links_resolve_in_the_repository():
    """The pages read on GitHub too: every relative link names a file of the repository (the CLI
    reference is generated at build time; ``mkdocs build --strict`` checks the site's links)."""
    missing = []
    for page in sorted((ROOT / "docs").rglob("*.md")):
        for target in _relative_links(page):
            if target and not (page.parent / target).exists() and not target.endswith("reference/cli.md"):
                missing.append(f"{page.relative_to(ROOT)} -> {target}")
    assert missing == []


# --- user-facing pages read as a library's documentation -------------------------------------
# The pages a user reads (docs/**/*.md, README.md, the notebooks' markdown cells) cite nothing a
# user cannot open (files outside the repository, absolute paths of some machine), name no private
# module (``jaxcal._x`` moves without notice: the public name or words instead) and no issue
# numbers of this project (a page says what is true now, not when it changed). Raw benchmark
# results (benchmarks/results/) are records of a run and are not checked.

_OUTSIDE = re.compile(r"DESIGN\.md|design notes|\.\./shared\b|(?<![\w.:/~-])/(?:work|home|tmp|root|Users|mnt)/",
                      re.I)
_PRIVATE = re.compile(r"\bjaxcal[./]_[A-Za-z]")  # jaxcal._fit._problem or jaxcal/_fit/_problem.py
_ISSUE = re.compile(r"\bissues?\s+#?\d+", re.I)


def _user_pages():
    """``[(name, text)]``: every user-facing page; a notebook contributes its markdown cells."""
    import json

    pages = [p for p in sorted((ROOT / "docs").rglob("*.md")) if "_build" not in p.parts]
    found = [(p.relative_to(ROOT).as_posix(), p.read_text(encoding="utf-8")) for p in pages]
    found.append(("README.md", (ROOT / "README.md").read_text(encoding="utf-8")))
    for nb in sorted((ROOT / "notebooks").glob("*.ipynb")):
        cells = json.loads(nb.read_text(encoding="utf-8"))["cells"]
        for i, cell in enumerate(cells):
            if cell["cell_type"] == "markdown":
                found.append((f"{nb.relative_to(ROOT).as_posix()} cell {i}", "".join(cell["source"])))
    return found


def _offences(pattern: re.Pattern) -> list[str]:
    out = []
    for name, text in _user_pages():
        for n, line in enumerate(text.splitlines(), 1):
            for m in pattern.finditer(line):
                out.append(f"{name}:{n}: {line[max(0, m.start() - 30):m.end() + 30]!r}")
    return out


def test_pages_cite_no_file_outside_the_repository():
    assert _offences(_OUTSIDE) == [], "a user cannot open these (say what they hold instead)"


def test_pages_name_no_private_module():
    assert _offences(_PRIVATE) == [], "private paths move without notice: name the public API or say it in words"


def test_pages_cite_no_issue_numbers():
    assert _offences(_ISSUE) == [], "say what is true now; the history is in git"


# --- figures: committed SVGs drawn by docs/_build/figures.py ------------------------------------

FIGURES_DIR = ROOT / "docs" / "figures"
_IMAGE = re.compile(r"!\[[^\]]*\]\(([^)\s]+\.svg)\)")


def _script_figures() -> list[str]:
    """The names in ``FIGURES`` of ``docs/_build/figures.py``, read without importing matplotlib."""
    import ast

    tree = ast.parse((ROOT / "docs" / "_build" / "figures.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "FIGURES" for t in node.targets):
            return sorted(ast.literal_eval(node.value))
    raise AssertionError("docs/_build/figures.py defines no FIGURES")


def _figure_uses() -> dict[str, list[str]]:
    """``{figure file name: [pages that show it]}`` for every ``![alt](…/figures/x.svg)`` of the pages."""
    uses: dict[str, list[str]] = {}
    for page in sorted((ROOT / "docs").rglob("*.md")):
        for target in _IMAGE.findall(page.read_text(encoding="utf-8")):
            path = (page.parent / target).resolve()
            assert path.parent == FIGURES_DIR, f"{page.relative_to(ROOT)}: {target} is not in docs/figures"
            uses.setdefault(path.name, []).append(page.relative_to(ROOT).as_posix())
    return uses


def test_figures_are_the_scripts_and_every_one_is_shown():
    committed = sorted(p.name for p in FIGURES_DIR.glob("*.svg"))
    assert committed == _script_figures(), "docs/figures differs from FIGURES: run python docs/_build/figures.py"
    uses = _figure_uses()
    assert sorted(set(committed) - set(uses)) == [], "figures no page shows"
    assert sorted(set(uses) - set(committed)) == [], "pages show figures that are not committed"


def test_figures_have_alt_text_and_no_page_uses_mermaid():
    for page in sorted((ROOT / "docs").rglob("*.md")):
        text = page.read_text(encoding="utf-8")
        assert "```mermaid" not in text, f"{page.relative_to(ROOT)}: Mermaid needs a script from a CDN (draw an SVG)"
        for alt in re.findall(r"!\[([^\]]*)\]\([^)]*figures/", text):
            assert len(alt.split()) >= 5, f"{page.relative_to(ROOT)}: a figure without a describing alt text"


def test_figures_are_reproducible_svgs():
    """Small text SVGs with no date and a fixed id salt (so regenerating changes only what was redrawn)."""
    for svg in sorted(FIGURES_DIR.glob("*.svg")):
        text = svg.read_text(encoding="utf-8")
        assert len(text) < 60_000, f"{svg.name}: {len(text)} bytes (text as paths? svg.fonttype must be 'none')"
        assert "<dc:date>" not in text, f"{svg.name} carries a date"
