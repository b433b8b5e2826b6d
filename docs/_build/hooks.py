"""mkdocs hooks: pages built from the repository at build time, nothing copied or committed.

* ``notebooks/*.ipynb`` (executed and committed), ``benchmarks/results/*`` and ``PERF_NOTES.md`` are mounted into
  the site at the same paths (``notebooks/...``, ``benchmarks/results/...``): mkdocs-jupyter
  renders the notebooks without running them, the results files are rendered as they are.
* A page may link to a mounted file by its path in the repository (``../../notebooks/x.ipynb``
  from ``docs/howto/``), so the link also works on GitHub; the link is rewritten to the mounted
  copy's place in the site.
* ``reference/cli.md`` is generated from :func:`jaxcal.cli._parser.build_parser`: the ``--help`` of the
  command and of every sub-command, so the page cannot drift from the parser.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import posixpath
import re
from pathlib import Path

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File, Files, InclusionLevel

ROOT = Path(__file__).resolve().parents[2]
MOUNTED = ("PERF_NOTES.md", "notebooks/*.ipynb", "benchmarks/results/*.md", "benchmarks/results/*.png",
           "benchmarks/results/*.html")


@contextlib.contextmanager
def _columns(n: int):
    """argparse wraps help text to $COLUMNS: fix it so the page does not depend on the terminal."""
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(n)
    try:
        yield
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old


def cli_reference() -> str:
    """Markdown of every sub-command's ``--help``, in the parser's order."""
    from jaxcal.cli import build_parser

    with _columns(100):
        parser = build_parser()
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parts = [
            "# Command-line reference\n",
            "Generated at build time from `jaxcal.cli._parser.build_parser()` (the text of `--help`); "
            "see the [how-to guides](../howto/index.md) for worked examples.\n",
            "## `jaxcal`\n",
            "```text\n" + parser.format_help().rstrip() + "\n```\n",
        ]
        for name, command in sub.choices.items():
            parts += [f"## `jaxcal {name}`\n", "```text\n" + command.format_help().rstrip() + "\n```\n"]
    return "\n".join(parts)


def on_config(config):
    """A notebook missing from the nav's ``Notebooks`` section is appended to it, so a new notebook
    appears without editing mkdocs.yml (and does not fail ``--strict`` as a page left out of the
    nav). The results files are not in the nav: ``benchmarks.md`` links the headline ones and lists
    every one."""
    notebooks = [p.relative_to(ROOT).as_posix() for p in sorted(ROOT.glob("notebooks/*.ipynb"))]
    for item in config["nav"] or []:
        if isinstance(item, dict) and isinstance(item.get("Notebooks"), list):
            listed = {v for entry in item["Notebooks"] for v in (entry.values() if isinstance(entry, dict) else [entry])}
            item["Notebooks"] += [nb for nb in notebooks if nb not in listed]
    return config


@event_priority(100)  # before mkdocs-jupyter's on_files, which turns the notebooks into pages
def on_files(files: Files, config) -> Files:
    for pattern in MOUNTED:
        for path in sorted(ROOT.glob(pattern)):
            rel = path.relative_to(ROOT).as_posix()
            if files.get_file_from_path(rel) is None:
                # results files and the performance log are reached through benchmarks.md's
                # links, not the nav (NOT_IN_NAV: no "omitted from the nav" warning)
                inclusion = InclusionLevel.UNDEFINED if rel.startswith("notebooks/") else InclusionLevel.NOT_IN_NAV
                files.append(File(rel, src_dir=str(ROOT), dest_dir=config["site_dir"],
                                  use_directory_urls=config["use_directory_urls"], inclusion=inclusion))
    files.append(File.generated(config, "reference/cli.md", content=cli_reference()))
    return files


_LINK = re.compile(r"\]\(([^)\s#]+)(#[^)\s]*)?\)")


def _repository_links(markdown: str, src_uri: str, files: Files) -> str:
    """``](../../notebooks/x.ipynb)`` in ``docs/howto/p.md`` → ``](../notebooks/x.ipynb)``."""
    docs = Path(src_uri).parent.as_posix()

    def fix(m: re.Match) -> str:
        target = m.group(1)
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("/"):
            return m.group(0)
        in_repo = posixpath.normpath(posixpath.join("docs", docs, target))
        if in_repo.startswith("docs/") or files.get_file_from_path(in_repo) is None:
            return m.group(0)
        return f"]({posixpath.relpath(in_repo, docs or '.')}{m.group(2) or ''})"

    return _LINK.sub(fix, markdown)


def on_page_markdown(markdown: str, page, config, files: Files) -> str:
    """Links to mounted repository files are rewritten (see above); benchmarks.md ends with a
    list of every results file, so a new one is never missing."""
    markdown = _repository_links(markdown, page.file.src_uri, files)
    if page.file.src_uri != "benchmarks.md":
        return markdown
    rows = [f"- [`{f.src_uri.rsplit('/', 1)[-1]}`]({f.src_uri})" for f in sorted(files, key=lambda f: f.src_uri)
            if f.src_uri.startswith("benchmarks/results/") and f.src_uri.endswith(".md")]
    return markdown.rstrip() + "\n\n## Every results file\n\n" + "\n".join(rows) + "\n"
