"""The face is the contract: the in-repo plugins and the example plugin import the framework only
through ``splat_framework.plugin`` (their tests also through ``splat_framework.testing``), read
with ``ast``: every import statement (top-level, in a function, under ``if TYPE_CHECKING:``) and
every ``importlib.import_module("...")`` / ``__import__("...")`` of a constant name."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PLUGINS = {
    "scg_plugin": REPO / "src" / "scg_plugin",
    "anchor_gs": REPO / "src" / "anchor_gs",
    "splat-example-plugin": REPO / "examples" / "splat-example-plugin",
}
FACE = "splat_framework.plugin"
TESTING = "splat_framework.testing"


def imported_modules(source: str) -> list[tuple[int, str]]:
    """(line, module) of every module ``source`` imports, a name taken from a package counted as its
    submodule (``from splat_framework import config`` imports ``splat_framework.config``)."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            if node.module == "splat_framework":
                out += [(node.lineno, f"splat_framework.{a.name}") for a in node.names]
            else:
                out.append((node.lineno, node.module))
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
            if called in ("import_module", "__import__") and isinstance(node.args[0].value, str):
                out.append((node.lineno, node.args[0].value))
    return sorted(out)


def outside_the_face(source: str, tests: bool) -> list[tuple[int, str]]:
    """(line, module) of the framework modules ``source`` imports other than the face (and, in a
    plugin's tests, :mod:`splat_framework.testing`)."""
    allowed = (FACE, TESTING) if tests else (FACE,)
    framework = [(n, m) for n, m in imported_modules(source) if m == "splat_framework" or m.startswith("splat_framework.")]
    return [(n, m) for n, m in framework if m not in allowed and not m.startswith(tuple(a + "." for a in allowed))]


def _files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*.py") if "build" not in p.relative_to(root).parts)


@pytest.mark.parametrize("plugin", sorted(PLUGINS))
def test_a_plugin_imports_the_framework_only_through_the_face(plugin):
    root = PLUGINS[plugin]
    files = _files(root)
    assert files, f"no Python files under {root}"
    found, through_face = [], 0
    for path in files:
        source = path.read_text()
        is_test = "tests" in path.relative_to(root).parts
        found += [f"{path.relative_to(REPO)}:{n}: {m}" for n, m in outside_the_face(source, is_test)]
        through_face += sum(m == FACE for _, m in imported_modules(source))
    assert found == [], "import these from splat_framework.plugin (add what is missing to its face):\n" + "\n".join(found)
    assert through_face > 0  # the plugin is read: it takes the framework from the face


def test_every_kind_of_import_is_seen():
    source = '''
import splat_framework
import splat_framework.model.init as init
from splat_framework import config, plugin
from splat_framework.plugin import GaussianModel
from typing import TYPE_CHECKING
if TYPE_CHECKING:
    from splat_framework.cameras import Camera
def f():
    from splat_framework.losses import photometric_loss
    import importlib
    return importlib.import_module("splat_framework.engine.trainer"), __import__("splat_framework.render")
from splat_framework.testing import run_cli
'''
    assert [m for _, m in outside_the_face(source, tests=False)] == [
        "splat_framework", "splat_framework.model.init", "splat_framework.config", "splat_framework.cameras",
        "splat_framework.losses", "splat_framework.engine.trainer", "splat_framework.render", "splat_framework.testing",
    ]
    assert "splat_framework.testing" not in [m for _, m in outside_the_face(source, tests=True)]
