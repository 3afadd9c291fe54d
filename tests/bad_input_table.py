"""The bad-input table of docs/reliability.md, generated from the tests that prove each row.

A test that proves what the tools do with a bad input carries the marker

    @pytest.mark.bad_input("`splat-export --out` naming a FIFO or a device", "exit 2, one line; nothing opened")

and this module collects the markers (by reading the test files, without importing
them) into the table between ``<!-- bad-input-table -->`` and ``<!-- /bad-input-table -->``
in docs/reliability.md. Tests marked with the same input text share a row. So the docs cannot
promise a behaviour that no test checks: ``test_readme_bad_input_table`` fails when the
page differs from what the markers say.

    python tests/bad_input_table.py            # print the table
    python tests/bad_input_table.py --write    # rewrite it in docs/reliability.md
"""

from __future__ import annotations

import ast
import sys
from dataclasses import dataclass, field
from pathlib import Path

TESTS = Path(__file__).resolve().parent
PAGE = TESTS.parent / "docs" / "reliability.md"
"""The page holding the table."""
BEGIN = "<!-- bad-input-table: generated from the tests' bad_input markers by `python tests/bad_input_table.py --write` -->"
END = "<!-- /bad-input-table -->"


@dataclass
class Row:
    """One row: the input, what happens, and the tests (``path::name``) that prove it."""

    input: str
    behaviour: str
    tests: list[str] = field(default_factory=list)


def _marker_args(decorator: ast.expr) -> tuple[str, str] | None:
    """("input", "behaviour") of ``@pytest.mark.bad_input("...", "...")``, else None."""
    if not (isinstance(decorator, ast.Call) and isinstance(decorator.func, ast.Attribute)):
        return None
    if decorator.func.attr != "bad_input" or ast.unparse(decorator.func.value) != "pytest.mark":
        return None
    args = decorator.args
    if len(args) != 2 or not all(isinstance(a, ast.Constant) and isinstance(a.value, str) for a in args):
        raise ValueError(f"bad_input takes two string literals: {ast.unparse(decorator)}")
    return args[0].value, args[1].value


def collect(root: Path = TESTS) -> list[Row]:
    """Rows of every ``bad_input`` marker under ``root``, in file then line order."""
    rows: dict[str, Row] = {}
    for path in sorted(root.rglob("test_*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for dec in node.decorator_list:
                found = _marker_args(dec)
                if found is None:
                    continue
                if not node.name.startswith("test"):
                    raise ValueError(f"{path}:{node.lineno}: bad_input marks {node.name}, which pytest does not collect")
                text, behaviour = found
                row = rows.setdefault(text, Row(text, behaviour))
                if row.behaviour != behaviour:
                    raise ValueError(f"{path}:{node.lineno}: {text!r} is marked with two behaviours")
                row.tests.append(f"`{path.relative_to(root.parent).as_posix()}::{node.name}`")
    return list(rows.values())


def render(rows: list[Row]) -> str:
    """The markdown table."""
    lines = ["| input | what happens | test |", "|---|---|---|"]
    lines += [f"| {r.input} | {r.behaviour} | {', '.join(r.tests)} |" for r in rows]
    return "\n".join(lines)


def readme_section(text: str) -> str:
    """What the page holds between the markers (raises ValueError when they are missing)."""
    start, end = text.find(BEGIN), text.find(END)
    if start < 0 or end < start:
        raise ValueError(f"{PAGE}: the bad-input table markers are missing")
    return text[start + len(BEGIN):end].strip("\n")


def write(readme: Path = PAGE) -> None:
    text = readme.read_text(encoding="utf-8")
    readme_section(text)
    start, end = text.find(BEGIN) + len(BEGIN), text.find(END)
    readme.write_text(text[:start] + "\n" + render(collect()) + "\n" + text[end:], encoding="utf-8")


if __name__ == "__main__":
    if "--write" in sys.argv[1:]:
        write()
    else:
        print(render(collect()))
