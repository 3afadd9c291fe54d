"""docs/extending.md's code is the code that runs: every Python and TOML snippet is an excerpt of a
file it names (``<!-- from: PATH -->``), under examples/ or src/, whose plugin the suite trains
(tests/examples/test_plugin_example.py, tests/anchor_gs); its hook table is GaussianModel's; its
row operations are ``ops``' own signatures."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "extending.md"
BLOCK = re.compile(r"(?:<!-- (?P<marker>[^\n]*?) -->\n)?```(?P<lang>\w*)\n(?P<body>.*?)^```$", re.S | re.M)


def snippets(text: str) -> list[tuple[str | None, str, str, int]]:
    """(marker or None, language, body, line) of every fenced block of ``text``."""
    return [(m["marker"], m["lang"], m["body"], text[: m.start()].count("\n") + 1) for m in BLOCK.finditer(text)]


def _code_lines(text: str) -> list[str]:
    """The lines that carry code: trailing ``  # comments`` and whole-line comments dropped,
    indentation and blank lines ignored; ``...`` (an elision) dropped."""
    out = []
    for line in text.splitlines():
        line = re.sub(r"\s{2,}#\s.*$", "", line).strip()
        if line and not line.startswith("#") and line != "...":
            out.append(line)
    return out


def missing_from(snippet: str, source: str) -> list[str]:
    """The code lines of ``snippet`` that do not appear, in order, among ``source``'s lines."""
    lines, at, missing = _code_lines(source), 0, []
    for line in _code_lines(snippet):
        try:
            at = lines.index(line, at) + 1
        except ValueError:
            missing.append(line)
    return missing


def test_every_code_snippet_is_an_excerpt_of_a_file_the_suite_runs():
    found = []
    blocks = [b for b in snippets(GUIDE.read_text()) if b[1] in ("python", "toml")]
    assert len(blocks) >= 15
    for marker, lang, body, line in blocks:
        if not (marker or "").startswith("from: "):
            found.append(f"extending.md:{line}: a {lang} snippet without <!-- from: PATH -->")
            continue
        path = ROOT / marker.removeprefix("from: ")
        if not path.is_file() or path.relative_to(ROOT).parts[0] not in ("examples", "src"):
            found.append(f"extending.md:{line}: {marker}: no such file under examples/ or src/")
            continue
        found += [f"extending.md:{line}: not in {path.relative_to(ROOT)}: {m}" for m in missing_from(body, path.read_text())]
    assert found == [], "\n".join(found)


def test_the_excerpt_check_fails_on_a_changed_line():
    source = "class A(Base):\n    kind = 'a'  # tag\n    x: int = 1\n\n    def f(self):\n        return 2\n"
    assert missing_from("class A(Base):\n...\n    def f(self):  # the hook\n        return 2\n", source) == []
    assert missing_from("class A(Base):\n    def f(self, y):\n", source) == ["def f(self, y):"]
    assert missing_from("return 2\nclass A(Base):\n", source) == ["class A(Base):"]  # out of order


def test_the_hook_table_is_gaussian_models():
    from splat_framework.model.gaussians import GaussianModel

    doc = inspect.getdoc(GaussianModel).splitlines()
    rules = [i for i, line in enumerate(doc) if line.startswith("=====")]
    table = "\n".join(doc[rules[0]: rules[-1] + 1])
    guide = next(body for marker, _, body, _ in snippets(GUIDE.read_text()) if (marker or "").startswith("hooks:"))
    assert guide.rstrip("\n") == table


def test_the_row_operations_are_ops_own_signatures():
    from splat_framework.plugin import ops

    text = GUIDE.read_text()
    table = text[text.index("<!-- ops-signatures -->"): text.index("<!-- /ops-signatures -->")]
    listed = re.findall(r"^\| `(\w+)\((.*?)\)` \|", table, re.M)
    assert len(listed) >= 5
    for name, args in listed:
        params = inspect.signature(getattr(ops, name)).parameters.values()
        real = ", ".join(p.name if p.default is inspect.Parameter.empty else f"{p.name}={p.default!r}" for p in params)
        assert args == real, name


@pytest.mark.parametrize("name", ["duplicate", "split", "append", "rewrite", "remove"])
def test_every_row_operation_is_in_the_guide(name):
    assert f"| `{name}(" in GUIDE.read_text()


def test_the_guide_is_short_and_opens_with_the_whole_minimal_plugin():
    """Issue 105: at most 350 lines, opening with examples/minimal_plugin: every file of it, shown
    whole (nothing elided), in at most 40 lines of code."""
    text = GUIDE.read_text()
    assert len(text.splitlines()) <= 350
    plugin = sorted((ROOT / "examples" / "minimal_plugin" / "my_plugin").glob("*.py"))
    opening = snippets(text)[: len(plugin)]
    assert [m.removeprefix("from: ") for m, *_ in opening] == [str(p.relative_to(ROOT)) for p in plugin]
    for (_, _, body, _), path in zip(opening, plugin):
        assert "..." not in _code_lines(body)
        assert _code_lines(body) == [ln for ln in _code_lines(path.read_text()) if not ln.startswith('"""')]
    assert sum(len([ln for ln in body.splitlines() if ln.strip()]) for _, _, body, _ in opening) <= 40
