"""Issue 105: the field's words in what a user reads. The docs (docs/*.md, README.md), the CLI's help
text (the docstrings of the config modules, the framework's and the plugins') and the messages the
code raises, warns or says call initialisation "init" (not "start kind"), the plugin module "the
public API" (not "the face") and Gaussians "Gaussians" (not "rows"; a paper's or a table's rows stay
rows, and code in backticks keeps its names: ``rows_changed``, ``RowChange``)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EVERYWHERE = {r"\bstart[- ]kinds?\b": "init kind", r"\bthe face\b": "the public API"}
"""Words refused in every text a user reads -> the words to use."""
ROWS = re.compile(r"\brows?\b", re.I)
TABLE_ROWS = re.compile(r"paper|ablation|table|literature|pixel|rotation|matrix|progress|live row|poses_bounds", re.I)
"""A line naming rows of these is about a table's or a matrix's rows, not Gaussians."""
GAUSSIAN_ROWS = re.compile(r"\bper-row\b|\brow operations?\b|\bthe rows\b|\brows (?:were|changed)\b|\bchanged the rows\b", re.I)
"""How "rows" was said of Gaussians, refused in every text outside a table's context (any "rows" is
refused in the pages and help that speak of the model: :data:`MODEL_PAGES` and :data:`HELP`)."""
MODEL_PAGES = ("extending.md", "architecture.md")
MAY_REFUSE = re.compile("|".join([*EVERYWHERE, GAUSSIAN_ROWS.pattern]), re.I)
"""Any refused word outside the pages and help: a module without one has no message to read."""
HELP = [ROOT / "src" / "splat_framework" / "config", ROOT / "src" / "scg_plugin" / "config.py",
        ROOT / "src" / "anchor_gs" / "config.py", ROOT / "examples" / "splat-example-plugin" / "src" / "splat_example_plugin" / "__init__.py",
        ROOT / "examples" / "minimal_plugin" / "my_plugin" / "__init__.py"]
"""The modules whose docstrings are the CLI's help text."""
TELLING = {"say", "warn", "fail", "exit", "error", "note"}
"""Functions whose string arguments a user reads (besides every ``raise``)."""


def prose(markdown: str) -> list[tuple[int, str]]:
    """(line number, text) of a page's prose: fenced blocks and ``code`` spans left out."""
    out, fence = [], False
    for i, line in enumerate(markdown.splitlines(), 1):
        if line.lstrip().startswith("```"):
            fence = not fence
        elif not fence:
            out.append((i, re.sub(r"`[^`]*`", "``", line)))
    return out


def help_texts(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every docstring of a module: its, its classes' and functions', its fields'."""
    return [(n.lineno, n.value.value) for n in ast.walk(ast.parse(path.read_text()))
            if isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant) and isinstance(n.value.value, str)]


def messages(path: Path) -> list[tuple[int, str]]:
    """(line, text) of the strings a module raises, warns or says (f-strings' literal parts joined)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Raise) and node.exc is not None:
            parts = [node.exc]
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None)) in TELLING:
            parts = node.args
        else:
            continue
        for part in parts:
            text = "".join(c.value for n in ast.walk(part) for c in [n]
                           if isinstance(c, ast.Constant) and isinstance(c.value, str))
            if text:
                found.append((node.lineno, text))
    return sorted(found)


def refused(text: str, rows: bool) -> list[str]:
    """The refused words in ``text``, each with the word to use."""
    out = [f"{m.group(0)!r} (say {use})" for pattern, use in EVERYWHERE.items() for m in re.finditer(pattern, text, re.I)]
    if (GAUSSIAN_ROWS.search(text) or rows and ROWS.search(text)) and not TABLE_ROWS.search(text):
        out.append("'rows' (say Gaussians)")
    return out


def _sources():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    docs = [(p, i, t, p.name in MODEL_PAGES) for p in pages for i, t in prose(p.read_text())]
    helps = [(p, i, t, True) for base in HELP for p in ([base] if base.is_file() else sorted(base.rglob("*.py")))
             for i, t in help_texts(p)]
    said = [(p, i, t, False) for base in ("src", "examples") for p in sorted((ROOT / base).rglob("*.py"))
            if MAY_REFUSE.search(p.read_text()) for i, t in messages(p)]  # parsed only where a word may be
    return docs + helps + said


def test_docs_help_and_messages_use_the_fields_words():
    found = [f"{p.relative_to(ROOT)}:{i}: {w}" for p, i, text, rows in _sources()
             for line in text.splitlines() for w in refused(re.sub(r"`[^`]*`", "``", line), rows)]
    assert found == [], "\n".join(found)


@pytest.mark.parametrize("text, rows, words", [
    ("Choose a start kind with --model.init.kind.", True, ["'start kind' (say init kind)"]),
    ("Import from the face, not the internals.", True, ["'the face' (say the public API)"]),
    ("The strategy resizes the rows it keeps.", True, ["'rows' (say Gaussians)"]),
    ("The strategy resizes the rows it keeps.", False, ["'rows' (say Gaussians)"]),
    ("Keep per-row tensors aligned.", False, ["'rows' (say Gaussians)"]),
    ("values[k] has 3 rows for 4 indices", False, []),
    ("values[k] has 3 rows for 4 indices", True, ["'rows' (say Gaussians)"]),
    ("One variant per row of the paper's ablation table.", True, []),
    ("The init kind decides where the Gaussians are.", True, []),
])
def test_the_check_finds_each_refused_word(text, rows, words):
    assert refused(text, rows) == words


def test_the_check_reads_prose_docstrings_and_messages(tmp_path):
    page = "Say `rows_changed` here.\n```python\nrows = 1\n```\nthe rows\n"
    assert prose(page) == [(1, "Say `` here."), (5, "the rows")]
    module = tmp_path / "m.py"
    module.write_text('"""Module."""\nclass A:\n    x: int = 1\n    """Field help."""\n'
                      'def f(n):\n    say(f"a start kind of {n}")\n    raise ValueError("bad " + "face")\n')
    assert [t for _, t in help_texts(module)] == ["Module.", "Field help."]
    assert messages(module) == [(6, "a start kind of "), (7, "bad face")]
