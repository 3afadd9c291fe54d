"""The public API is the contract: the in-repo plugins and the example plugins import the framework only
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
    "minimal_plugin": REPO / "examples" / "minimal_plugin",
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
    """(line, module) of the framework modules ``source`` imports other than the public API (and, in a
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
    assert found == [], "import these from splat_framework.plugin (add what is missing to its public API):\n" + "\n".join(found)
    assert through_face > 0  # the plugin is read: it takes the framework from the public API


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


PLUGIN_PACKAGES = ("scg_plugin", "anchor_gs", "splat_example_plugin", "my_plugin")
"""The top-level packages of the plugins above: the framework must not import them."""
OBJECT_PATH = r"^[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*:[A-Za-z_]\w*$"


def object_paths(source: str) -> list[tuple[int, str]]:
    """(line, text) of every string constant of ``source`` shaped as a ``"module:Name"`` path (what
    ``strategy_class``, ``points_fn``, ``MethodSpec.model`` and entry-point tables hold)."""
    import re

    return sorted((n.lineno, n.value) for n in ast.walk(ast.parse(source))
                  if isinstance(n, ast.Constant) and isinstance(n.value, str) and re.match(OBJECT_PATH, n.value))


def internal_object_paths(source: str) -> list[tuple[int, str]]:
    """The ``"module:Name"`` strings of a plugin's ``source`` naming a framework module other than the public API."""
    return [(n, p) for n, p in object_paths(source)
            if p.partition(":")[0].split(".")[0] == "splat_framework" and p.partition(":")[0] != FACE]


def plugin_references(source: str) -> list[tuple[int, str]]:
    """(line, module or path) of every import of a plugin package in framework ``source``, and every
    ``"module:Name"`` string naming one."""
    imports = [(n, m) for n, m in imported_modules(source) if m.split(".")[0] in PLUGIN_PACKAGES]
    paths = [(n, p) for n, p in object_paths(source) if p.split(":")[0].split(".")[0] in PLUGIN_PACKAGES]
    return sorted(imports + paths)


def test_the_framework_never_imports_a_plugin():
    root = REPO / "src" / "splat_framework"
    found = [f"{p.relative_to(REPO)}:{n}: {m}" for p in _files(root) for n, m in plugin_references(p.read_text())]
    assert found == [], "the framework must not import or name a plugin (the plugin registers itself):\n" + "\n".join(found)


@pytest.mark.parametrize("plugin", sorted(PLUGINS))
def test_a_plugins_object_paths_name_only_the_face_or_its_own_modules(plugin, monkeypatch):
    """Every ``"module:Name"`` string a plugin holds names the public API or the plugin's own modules, and
    names an object that is there (tools and readers follow it)."""
    from splat_framework.entry_points import load_object

    found, paths = [], []
    for path in _files(PLUGINS[plugin]):
        source = path.read_text()
        found += [f"{path.relative_to(REPO)}:{n}: {p}" for n, p in internal_object_paths(source)]
        paths += [p for _, p in object_paths(source) if p.split(":")[0].split(".")[0] in (*PLUGIN_PACKAGES, "splat_framework")]
    assert found == [], "name the object through splat_framework.plugin:\n" + "\n".join(found)
    if plugin == "splat-example-plugin":  # read from its source folder, not installed
        monkeypatch.syspath_prepend(str(PLUGINS[plugin] / "src"))
    if plugin == "minimal_plugin":  # a module on the path, never installed
        monkeypatch.syspath_prepend(str(PLUGINS[plugin]))
    assert paths and all(load_object(p) is not None for p in paths)


def test_the_checks_fail_on_planted_violations():
    """Planted: the framework importing SCGaussian's model (three ways) and naming it by path, and a
    plugin naming a framework internal by ``"module:Class"``: each is found; the public API is not."""
    framework = '''
import scg_plugin.model
from anchor_gs import method
def build():
    import importlib
    return importlib.import_module("splat_example_plugin.mcmc"), "scg_plugin.model:SCGaussianModel"
'''
    assert sorted(m for _, m in plugin_references(framework)) == sorted([
        "scg_plugin.model", "anchor_gs", "splat_example_plugin.mcmc", "scg_plugin.model:SCGaussianModel"])
    plugin = '''
strategy_class = "splat_framework.model.strategy:DefaultStrategy"
model = "splat_framework.plugin:GaussianModel"
own = "my_plugin.model:Model"
'''
    assert [p for _, p in internal_object_paths(plugin)] == ["splat_framework.model.strategy:DefaultStrategy"]


def test_each_in_repo_plugin_declares_its_parts_in_one_table():
    """scg_plugin and anchor_gs list their parts in ``ENTRY_POINTS`` (as the example plugin does);
    the project's pyproject.toml declares exactly those entry points for their modules."""
    import tomllib

    declared = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["entry-points"]
    for package in ("scg_plugin", "anchor_gs"):
        tree = ast.parse((PLUGINS[package] / "__init__.py").read_text())  # read, not imported: tests/anchor_gs shadows the name
        table = next(ast.literal_eval(n.value) for n in tree.body
                     if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", None) == "ENTRY_POINTS")
        in_pyproject = {group: {k: v for k, v in entries.items() if v.split(".")[0].split(":")[0] == package}
                        for group, entries in declared.items()}
        assert table == {g: e for g, e in in_pyproject.items() if e}, package


PLUGIN_TESTS = {"scg_plugin": REPO / "tests" / "scgaussian", "anchor_gs": REPO / "tests" / "anchor_gs"}
"""The in-repo plugins' tests, held to what an outside plugin's tests may import."""


@pytest.mark.parametrize("plugin", sorted(PLUGIN_TESTS))
def test_an_in_repo_plugins_tests_import_only_the_face_and_testing(plugin):
    """tests/scgaussian and tests/anchor_gs take the framework from ``splat_framework.plugin`` and
    ``splat_framework.testing`` alone, and so do the suite's helper modules they import
    (``cli_harness``, ``support``)."""
    files = _files(PLUGIN_TESTS[plugin])
    helpers = {p.stem: p for p in (REPO / "tests").glob("*.py")}
    used = {m for f in files for _, m in imported_modules(f.read_text()) if m in helpers}
    found = [f"{p.relative_to(REPO)}:{n}: {m}" for p in [*files, *(helpers[h] for h in sorted(used))]
             for n, m in outside_the_face(p.read_text(), tests=True)]
    assert files and found == [], "take these from splat_framework.plugin or splat_framework.testing:\n" + "\n".join(found)
