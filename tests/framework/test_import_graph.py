"""The import graph of src/: module -> module, read with ``ast`` (top-level, function-level and
``if TYPE_CHECKING:`` imports: a loop for the type checker is a loop of the design too), with the
package ``__init__``s an import runs on the way (``import a.b.c`` runs ``a/b/__init__.py`` first):
no circle, drawn or hidden behind a package, no module taking another module's private names, and
every module placed in a layer by its folder."""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[2] / "src"


def _module_files(src: Path = SRC) -> dict[str, Path]:
    """Dotted module name -> file, for every package under ``src``."""
    out = {}
    for path in src.rglob("*.py"):
        rel = path.relative_to(src).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
        if parts and all(p.isidentifier() for p in parts):
            out[".".join(parts)] = path
    return out


def _imports(name: str, path: Path, modules: dict[str, Path]) -> list[tuple[str, str | None]]:
    """(imported module, imported name or None) of every import ``name`` runs, with module names
    resolved (relative imports, ``from package import submodule``); modules outside src/ dropped."""
    tree = ast.parse(path.read_text(), str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, None) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module != "__future__":
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            for a in node.names:
                sub = f"{target}.{a.name}"
                out.append((sub, None) if sub in modules else (target, a.name))
    return [(m, n) for m, n in out if m in modules]


def _packages_run(importer: str, target: str, modules: dict[str, Path]) -> list[str]:
    """The packages whose ``__init__`` importing ``target`` runs first: its parent packages, except
    those holding ``importer`` (already being imported when ``importer`` runs)."""
    parts = target.split(".")
    parents = (".".join(parts[:i]) for i in range(1, len(parts)))
    return [p for p in parents if p in modules and not (importer == p or importer.startswith(p + "."))]


def import_graph(src: Path = SRC) -> tuple[dict[str, set[str]], list[str]]:
    """The module graph of ``src`` (an edge to every package ``__init__`` an import runs) and the
    private-name imports found (``importer: target.name``)."""
    modules = _module_files(src)
    graph, private = {}, []
    for name, path in modules.items():
        graph[name] = set()
        for target, item in _imports(name, path, modules):
            graph[name] |= {target, *_packages_run(name, target, modules)} - {name}
            own_package = name == target.rpartition(".")[0] or name.rpartition(".")[0] == target.rpartition(".")[0]
            hidden_module = target.rpartition(".")[2].startswith("_") and not target.endswith("__")
            if (item is not None and item.startswith("_") and not item.startswith("__")) or (
                hidden_module and not own_package
            ):
                private.append(f"{name}: {target}" + (f".{item}" if item else ""))
    return graph, private


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_graph_is_read():
    graph, _ = import_graph()
    assert "splat_framework.render.sh" in graph["splat_framework.render"]  # from .sh import ...
    assert "splat_framework.config.matcher_names" in graph["splat_framework.config.matching"]
    assert graph["splat_framework.config.matcher_names"] == set()  # a matcher name validates with nothing else
    # ``from ..model.init import ...`` runs model/__init__.py first
    assert {"splat_framework.model", "splat_framework.model.init"} <= graph["splat_framework.matching.prior"]
    assert len(graph) > 100


def test_a_circle_behind_a_package_init_is_found(tmp_path):
    """Today's main had this one: ``c.i`` imports ``m.cfg`` (running ``m/__init__``, which imports the
    package ``c``, whose ``__init__`` imports ``c.i``); no edge of it names a package's own module."""
    files = {"p/__init__.py": "", "p/c/__init__.py": "from .i import X\n", "p/c/base.py": "B = 1\n",
             "p/c/i.py": "from ..m.cfg import M\nX = M\n", "p/m/__init__.py": "from .. import c\nfrom .cfg import M\n",
             "p/m/cfg.py": "from ..c.base import B\nM = B\n"}
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    graph, _ = import_graph(tmp_path)
    assert graph["p.c.i"] == {"p.m", "p.m.cfg"} and graph["p.m.cfg"] == {"p.c", "p.c.base"}
    assert cycles(graph) == [["p.c", "p.c.i", "p.m", "p.m.cfg"]]


def test_cycles_are_found():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_in_src():
    graph, _ = import_graph()
    assert cycles(graph) == []


def test_no_module_imports_another_modules_private_names():
    assert import_graph()[1] == []


def test_the_config_package_reaches_no_torch_module():
    """``--help`` is built from the configs: nothing ``splat_framework.config`` imports, at any depth,
    is a module of the model, the renderer or the engine (they import torch)."""
    graph, _ = import_graph()
    reached, todo = set(), ["splat_framework.config"]
    while todo:
        for target in graph[todo.pop()] - reached:
            reached.add(target)
            todo.append(target)
    heavy = [m for m in reached if m.startswith(("splat_framework.model", "splat_framework.render", "splat_framework.engine"))]
    assert "splat_framework.config.persist" in reached and heavy == []


LAYERS: list[tuple[str, ...]] = [
    # what every layer uses
    ("__init__", "errors", "entry_points", "environment", "console", "runtime", "cameras"),
    # configs and what they name (torch-free; read for --help)
    ("config", "registry", "methods", "devices"),
    # where commands may write
    ("files",),
    # data: datasets, and the file formats a start is read from or a run is exported to
    ("data", "export"),
    ("render", "losses"),
    # the model imports nothing of matching or sfm: their init kinds register as entry points
    ("model",),
    # poses from one's own photos, and the SfM init
    ("sfm",),
    # the matching prior, and the triangulated init
    ("matching",),
    ("evaluation",),
    # the data and the model of a run: one step's batch and loss, the evaluation
    ("pipeline",),
    ("plugin", "scg_plugin", "anchor_gs"),
    ("engine",),
    ("viewer", "sweep"),
    # the commands, and what tests (a plugin's too) run them with
    ("cli", "testing"),
]
"""The layers of src/, lowest first: a module imports modules of its own layer or lower ones only.
Entries are folders (packages) and top-level modules of ``splat_framework``, or a plugin package: a
module's folder gives its layer, never its own name (``matching.config`` is in the matching layer)."""


def layer_of(module: str) -> int:
    """The layer of ``module``: that of its folder under ``splat_framework`` (or its plugin package)."""
    name = module.removeprefix("splat_framework.") if module != "splat_framework" else "__init__"
    folder = name.partition(".")[0]
    found = [i for i, entries in enumerate(LAYERS) if folder in entries]
    if not found:
        raise AssertionError(f"{module} is in no layer: add {folder!r} to LAYERS")
    return found[0]


def test_no_import_runs_back_up_a_layer():
    graph, _ = import_graph()
    upward = sorted(f"{a} -> {b}" for a, targets in graph.items() for b in targets if layer_of(b) > layer_of(a))
    assert upward == []


def test_layers_name_folders_once():
    entries = [e for layer in LAYERS for e in layer]
    assert len(entries) == len(set(entries)) and not [e for e in entries if "." in e]


def test_the_layer_rule_sees_an_upward_import():
    assert layer_of("splat_framework.config.train") < layer_of("splat_framework.viewer.serving")
    assert layer_of("splat_framework.matching.config") == layer_of("splat_framework.matching.pipeline")
    assert layer_of("splat_framework.config") < layer_of("splat_framework.data.photos") < layer_of("splat_framework.sfm.photos")
    assert layer_of("splat_framework.export.ply") < layer_of("splat_framework.model.init")
    assert layer_of("splat_framework.model.gaussians") < layer_of("splat_framework.sfm.points") < layer_of("splat_framework.matching.prior")


def test_the_model_imports_nothing_of_matching_or_sfm():
    """The model layer sits below matching and sfm: their init kinds (triangulated, sfm) register
    through the ``splat_framework.inits`` entry points, so no module of ``model/`` imports theirs."""
    graph, _ = import_graph()
    found = sorted(f"{a} -> {b}" for a, targets in graph.items() if a.startswith("splat_framework.model")
                   for b in targets if b.startswith(("splat_framework.matching", "splat_framework.sfm")))
    assert found == []


def test_every_module_imports_first_in_a_fresh_process():
    """Importing a module first runs its parent packages' ``__init__`` too, an edge the graph above
    does not draw: ``import splat_framework.matching`` as a process's first import once failed on a
    half-built ``MatchConfig`` (matching -> config package -> config.init -> matching.config). Each
    module is imported first in a child forked from a process that holds only third-party modules."""
    import os
    import subprocess
    import sys

    import pytest

    if not hasattr(os, "fork"):
        pytest.skip("needs os.fork")
    names = sorted(n for n in _module_files()  # a __main__ module runs its command when imported
                   if n.split(".")[0] in ("splat_framework", "scg_plugin", "anchor_gs") and not n.endswith("__main__"))
    code = r'''
import importlib, os, sys
import cv2, kornia, numpy, pydantic, rich, torch, tyro  # noqa: F401  shared by the forks, imported once
for name in sys.argv[1:]:
    pid = os.fork()
    if pid == 0:
        try:
            importlib.import_module(name)
        except BaseException as e:
            print(f"{name}: {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}", flush=True)
            os._exit(1)
        os._exit(0)
    os.waitpid(pid, 0)
'''
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", code, *names], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "", out.stdout


def test_the_trainer_imports_at_most_15_framework_modules():
    """The trainer drives the loop; the pipeline builds the data and the model, so the trainer's
    imports stay few (it imported 28 when it built everything itself)."""
    modules = _module_files()
    name = "splat_framework.engine.trainer"
    imported = {target for target, _ in _imports(name, modules[name], modules)}
    assert len(imported) <= 15, sorted(imported)
    assert not {m for m in imported if m.startswith(("splat_framework.data", "splat_framework.model"))}
