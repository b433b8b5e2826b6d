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
