"""mkdocs hooks: pages built from the repository at build time, nothing copied or committed.

* ``notebooks/*.ipynb`` (executed and committed), ``benchmarks/results/*`` and ``PERF_NOTES.md`` are mounted into
  the site at the same paths (``notebooks/...``, ``benchmarks/results/...``): mkdocs-jupyter
  renders the notebooks without running them, the results files are rendered as they are.
  The results files and ``PERF_NOTES.md`` are not in the nav: ``benchmarks.md`` holds the
  headline tables, links each row's results file and ends with a generated list of them all.
* A page may link to a mounted file by its path in the repository (``../../notebooks/x.ipynb``
  from ``docs/howto/``), so the link also works on GitHub; the link is rewritten to the mounted
  copy's place in the site.
* ``reference/cli.md`` is generated from the command's argparse parsers (``jaxcal.cli.build_parser``):
  one section per sub-command with its options in a table, so the page cannot drift from them.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import posixpath
import re
import textwrap
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


def _prose(text: str) -> str:
    """Help text as Markdown prose: ``<`` and ``*`` are text, not HTML or emphasis."""
    return str(text).replace("<", "&lt;").replace("*", "\\*")


def _cell(text: str) -> str:
    """One Markdown table cell: no line breaks, no bare pipes."""
    return _prose(" ".join(str(text).split())).replace("|", "\\|")


def _usage(parser: argparse.ArgumentParser) -> str:
    lines = parser.format_usage().strip().removeprefix("usage: ").splitlines()
    indent = min((len(s) - len(s.lstrip()) for s in lines[1:]), default=0)
    return "\n".join([lines[0], *("    " + s[indent:] for s in lines[1:])])


def _epilog(text: str) -> str:
    """An epilog of one paragraph as prose; a laid-out one (lists, examples) as text, its long
    lines wrapped at 100 columns under their own indentation."""
    text = text.strip()
    if "\n" not in text:
        return _prose(text) + "\n"
    out = []
    for line in text.splitlines():
        lead = line[: len(line) - len(line.lstrip())]
        out += textwrap.wrap(line, 100, subsequent_indent=lead + "  ") or [""]
    return "```text\n" + "\n".join(out) + "\n```\n"


def _option_rows(parser: argparse.ArgumentParser) -> list[str]:
    """A table per argument group: the option, what it takes, its default, its help."""
    formatter = parser._get_formatter()
    out = []
    for group in parser._action_groups:
        actions = [a for a in group._group_actions
                   if a.help is not argparse.SUPPRESS and not isinstance(a, (argparse._HelpAction,
                                                                              argparse._SubParsersAction))]
        if not actions:
            continue
        title = {"positional arguments": "Arguments", "options": "Options",
                 "optional arguments": "Options"}.get(group.title, group.title[:1].upper() + group.title[1:])
        # the div (md_in_html) lets the stylesheet keep option names on one line: "--no-cache", not "--no-" / "cache"
        out += [f"**{_cell(title)}**\n", '<div class="cli-options" markdown>\n',
                "| option | value | default | description |", "|---|---|---|---|"]
        if group.description:
            out.insert(len(out) - 3, _cell(group.description) + "\n")
        for action in actions:
            names = ", ".join(f"`{s}`" for s in action.option_strings) or f"`{action.dest}`"
            if action.choices is not None and not isinstance(action.choices, dict):
                value = " \\| ".join(f"`{c}`" for c in action.choices)
            elif action.nargs == 0:
                value = ""
            else:
                value = f"`{formatter._format_args(action, action.metavar or action.dest.upper())}`" \
                    if action.option_strings else ""
            default = action.default
            shown = "" if (default is None or default is argparse.SUPPRESS or action.nargs == 0
                           or not action.option_strings) else f"`{default}`"
            help_text = formatter._expand_help(action) if action.help else ""
            out.append(f"| {names} | {value} | {_cell(shown)} | {_cell(help_text)} |")
        out += ["", "</div>\n"]
    return out


def cli_reference() -> str:
    """Markdown of the command line: per sub-command, its description and a table of its options,
    read from the argparse parsers (so the page cannot drift from them)."""
    from jaxcal.cli import build_parser

    with _columns(100):
        parser = build_parser()
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        helps = {c.dest: c.help for c in sub._choices_actions}
        parts = [
            "# Command-line reference\n",
            "Generated from the command's argument parsers when the site is built; "
            "`jaxcal COMMAND --help` prints the same. Worked examples: the "
            "[how-to guides](../howto/index.md).\n",
            "| command | what it does |", "|---|---|",
            *[f"| [`{n}`](#jaxcal-{n}) | {_cell(helps.get(n) or '')} |" for n in sub.choices],
            "",
            "## `jaxcal`\n",
            "```text\n" + _usage(parser) + "\n```\n",
            *_option_rows(parser),
        ]
        for name, command in sub.choices.items():
            parts += [f"## `jaxcal {name}` {{#jaxcal-{name}}}\n",
                      "```text\n" + _usage(command) + "\n```\n"]
            if command.description:
                parts.append(_prose(command.description.strip()) + "\n")
            parts += _option_rows(command)
            if command.epilog:
                parts.append(_epilog(command.epilog))
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
