"""Write the generated parts of the documentation, so that they cannot drift from the code.

    python docs/generate.py           # rewrite the blocks in docs/*.md
    python docs/generate.py --check   # exit 1 naming the pages that are out of date

Each block sits between ``<!-- generated:NAME -->`` and ``<!-- /generated:NAME -->`` markers in a
page; everything else in the page is written by hand. The blocks:

- ``cli-help``: every ``splat-*`` command's ``--help``, captured in-process from the command
  itself (tyro builds it from the configs' field docstrings);
- ``environment``: every ``SPLAT_*`` variable (:mod:`splat_framework.environment`);
- ``exit-codes``: :data:`splat_framework.cli.common.EXIT_CODES`;
- ``methods``: every registered method and config variant, with its description and base.

The README and the pages also quote measured figures inline, between ``<!-- figure:NAME -->`` and
``<!-- /figure:NAME -->``: each figure's text is written once, in ``docs/figures.toml``, with how it
was measured, and copied into every page that quotes it.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import re
import sys
import tomllib
from importlib.metadata import entry_points
from pathlib import Path
from unittest import mock

DOCS = Path(__file__).resolve().parent
FIGURES = DOCS / "figures.toml"
FIGURE = re.compile(r"<!-- figure:([a-z0-9-]+) -->(.*?)<!-- /figure:([a-z0-9-]+) -->", re.S)
HELP_COLUMNS = "100"
ONLY_SHIPPED = {"SPLAT_CONFIG_PATH": "", "SPLAT_PLUGINS": "", "SPLAT_INSTALLED_PLUGINS": "off"}
"""The parts of this repository only: no user variants, no plugin installed beside the project or named in SPLAT_PLUGINS."""
ENV = {"COLUMNS": HELP_COLUMNS, "NO_COLOR": "1", "TERM": "dumb", **ONLY_SHIPPED}
"""The environment the help is captured in: a fixed width, no colour, this repository's parts only."""


def command_help(argv: list[str]) -> str:
    """What ``argv --help`` prints (``argv[0]`` a console script; ``argv`` may hold its ``--help`` already,
    with a group after it), at a fixed width, trailing spaces cut."""
    (ep,) = [e for e in entry_points(group="console_scripts") if e.name == argv[0]]
    out = io.StringIO()
    with mock.patch.dict(os.environ, ENV), \
            mock.patch.object(sys, "argv", argv if "--help" in argv else [*argv, "--help"]), \
            contextlib.redirect_stdout(out), \
            contextlib.redirect_stderr(io.StringIO()):
        try:
            ep.load()()
        except SystemExit as e:
            if e.code not in (0, None):
                raise RuntimeError(f"{' '.join(argv)} --help exited {e.code}") from None
    return "\n".join(line.rstrip() for line in out.getvalue().strip("\n").splitlines())


def commands() -> list[str]:
    return sorted(e.name for e in entry_points(group="console_scripts") if e.name.startswith("splat-"))


def cli_help_block() -> str:
    parts = []
    for name in commands():
        parts += [f"### `{name}`", "", "```text", command_help([name]), "```", ""]
    parts += ["### `splat-train 3dgs` (the flags of one method)", "",
              "Every method has the run options above plus its own model, strategy and optimiser flags; "
              "`splat-train METHOD --help` shows the main ones and names the groups it leaves off. For `3dgs`:", "",
              "```text", command_help(["splat-train", "3dgs"]), "```", "",
              "### `splat-train 3dgs --help all` (every flag of one method)", "",
              "`--help GROUP` shows one of those groups; `--help all` every flag:", "",
              "```text", command_help(["splat-train", "3dgs", "--help", "all"]), "```"]
    return "\n".join(parts)


def environment_block() -> str:
    from splat_framework.environment import VARIABLES

    rows = ["| variable | what it does |", "|---|---|"]
    rows += [f"| `{name}` | {text} |" for name, text in VARIABLES.items()]
    return "\n".join(rows)


def exit_codes_block() -> str:
    from splat_framework.cli.common import EXIT_CODES

    rows = ["| code | meaning |", "|---|---|"]
    rows += [f"| {code} | {text} |" for code, text in EXIT_CODES.items()]
    return "\n".join(rows)


def methods_block() -> str:
    from splat_framework.registry import discover_methods

    rows = ["| name | what it is |", "|---|---|"]
    with mock.patch.dict(os.environ, ONLY_SHIPPED):
        methods = discover_methods()
    for name, spec in sorted(methods.items()):
        rows.append(f"| `{name}` | {spec.description.strip().splitlines()[0]} |")
    return "\n".join(rows)


BLOCKS = {"cli-help": cli_help_block, "environment": environment_block, "exit-codes": exit_codes_block,
          "methods": methods_block}


def splice(text: str, name: str, block: str, page: str) -> str:
    start, end = f"<!-- generated:{name} -->", f"<!-- /generated:{name} -->"
    i, j = text.find(start), text.find(end)
    if i < 0 or j < i:
        raise SystemExit(f"{page}: no '{start}' ... '{end}' markers")
    return text[: i + len(start)] + "\n" + block.strip("\n") + "\n" + text[j:]


def figures() -> dict[str, str]:
    """Each figure's name -> the text the pages quote (``docs/figures.toml``)."""
    table = tomllib.loads(FIGURES.read_text())
    for name, entry in table.items():
        if not isinstance(entry, dict) or not isinstance(entry.get("text"), str) or not entry.get("measured"):
            raise SystemExit(f"{FIGURES.name}: [{name}] needs a text and how it was measured")
    return {name: entry["text"] for name, entry in table.items()}


def fill_figures(text: str, known: dict[str, str], page: str) -> str:
    """``text`` with every quoted figure's text as ``known`` has it; an unknown figure, or markers
    that do not pair, stop with a line naming the page."""
    def fill(m: re.Match) -> str:
        name, end = m.group(1), m.group(3)
        if end != name:
            raise SystemExit(f"{page}: figure '{name}' is closed by '/figure:{end}'")
        if name not in known:
            raise SystemExit(f"{page}: figure '{name}' is not in {FIGURES.name}")
        return f"<!-- figure:{name} -->{known[name]}<!-- /figure:{name} -->"

    return FIGURE.sub(fill, text)


def generated_pages() -> dict[Path, str]:
    """Every page holding a generated block or a quoted figure -> its text with every one up to date."""
    out = {}
    built: dict[str, str] = {}
    known = figures()
    for page in [DOCS.parent / "README.md", *sorted(DOCS.glob("*.md"))]:
        text = new = page.read_text()
        for name, make in BLOCKS.items():
            if f"<!-- generated:{name} -->" in new:
                built.setdefault(name, make())
                new = splice(new, name, built[name], page.name)
        new = fill_figures(new, known, page.name)
        if new != text:
            out[page] = new
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only report pages that are out of date (exit 1)")
    args = parser.parse_args(argv)
    stale = generated_pages()
    if args.check:
        for page in stale:
            print(f"{page.relative_to(DOCS.parent)} is out of date: run python docs/generate.py")
        return 1 if stale else 0
    for page, text in stale.items():
        page.write_text(text)
        print(f"wrote {page.relative_to(DOCS.parent)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
