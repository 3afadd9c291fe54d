"""The test tiers: a test is ``slow`` by what it uses, and the fast tier is held to its time limit.

A pytest plugin (``tests/conftest.py`` loads it). At collection, every test whose function, a
fixture it requests, or a helper it calls uses one of :data:`SLOW_USES` (or that reads the real
scenes: ``integration``) is marked ``slow``, with the reason recorded, before ``-m "not slow"``
deselects anything. Helpers are followed through the functions of ``tests/`` (a test module's own
helpers, ``support.py``, fixtures), not into the framework. So a new test gets its tier from what it
does, never from a hand-written mark (a hand-written ``slow`` mark still counts).

- ``python -m pytest -m "not slow" -n 2``: the fast tier, run before every commit. A test in it whose
  call takes longer than :data:`FAST_LIMIT_S` fails there, naming the limit and this module: it uses
  something slow that :data:`SLOW_USES` does not list yet (list it), or it should be made faster.
- Every run ends with a line for each unmarked test above the limit (the whole suite too, where
  nothing fails for it), and ``--why-slow`` lists every slow test with the reason it is slow.
- Work done once per machine: the native kernels (``native_module``) and the tiny built-in scenes
  (``_tiny_scenes``) are kept in :func:`machine_cache` between sessions, so their set-up is not
  counted against a test's call.
"""

from __future__ import annotations

import hashlib
import importlib
import os
import shutil
import sys
import time
import types
from pathlib import Path
from typing import Any, Iterator

import pytest

TESTS = Path(__file__).resolve().parent
SRC = TESTS.parent / "src"

FAST_LIMIT_S = float(os.environ.get("SPLAT_FAST_LIMIT_S", "5"))
"""Seconds a fast-tier test's call may take (set up and tear down not counted: a session's fixtures
are built once and the per-machine ones once per machine)."""

SLOW_USES: dict[str, str] = {
    "splat_framework.testing.cli:run_cli": "runs a splat-* command in a new Python process",
    "splat_framework.testing.cli:stop_training": "trains through the CLI until a checkpoint",
    "splat_framework.engine.trainer:Trainer": "trains a run",
    "splat_framework.engine.trainer:train": "trains a run",
    "splat_framework.render._native:native_kernels": "builds the native kernels",
    "splat_framework.sweep:run_sweep": "runs a sweep of training runs",
    "splat_framework.cli.sweep:main": "runs a sweep of training runs",
    "splat_framework.sfm.reconstruct:estimate_scene": "poses photos",
    "splat_framework.sfm.training_poses:estimate_training_poses": "poses photos",
    "splat_framework.sfm.own_photos:own_photos_scene": "poses photos",
    "splat_framework.sfm.reconstruct:reconstruct": "poses photos (COLMAP's mapper)",
    "support:DATA": "reads the real scenes",
    "support:HeadlessPage": "drives a headless browser",
    "subprocess:run": "starts a process",
    "subprocess:Popen": "starts a process",
    "subprocess:check_output": "starts a process",
}
"""``"module:name"`` of what makes a test slow -> why. A test using it (directly, through a fixture, or
through a helper function of ``tests/``) is marked ``slow``."""

ONCE_PER_MACHINE = frozenset({"native_module", "_native_kernels_loaded", "_tiny_scenes"})
"""Fixtures whose work is kept between sessions (:func:`machine_cache`): not followed for slow uses."""

_WHY = pytest.StashKey[dict]()
_PACKAGES = pytest.StashKey[dict]()


def machine_cache() -> Path:
    """This machine's cache of test work done once (the native kernels, the tiny scenes):
    ``$SPLAT_TEST_CACHE``, else ``~/.cache/splat-tests``. The kernels there are loaded only under the
    product's rules (a private folder, a signed manifest: :mod:`splat_framework.runtime.trusted`)."""
    env = os.environ.get("SPLAT_TEST_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "splat-tests"


KERNELS: dict[str, Path] = {}
"""``"folder"``: this machine's built native kernels once ``native_module`` loaded them."""


def seed_kernels(cache: Path) -> Path:
    """``cache`` (a ``SPLAT_CACHE`` folder, made if missing) holding a copy of this machine's built
    native kernels (the library and its signed manifest), as a user's second run finds them: a
    process on that cache loads them instead of building them (45 s on 2 idle cores). Nothing is
    copied where the kernels were not loaded (no toolchain: the runs take the torch kernels)."""
    from splat_framework.runtime.trusted import MANIFEST, private_folder

    cache = Path(cache)
    private_folder(cache)
    built = KERNELS.get("folder")
    if built is not None:
        target = cache / "native" / built.name
        private_folder(cache / "native")
        private_folder(target)
        for f in [*built.glob("*.so"), built / MANIFEST]:
            if not (target / f.name).exists():
                shutil.copy2(f, target / f.name)
    return cache


def kernels_built_under(folder: Path, since: float) -> list[Path]:
    """The native kernel builds (a ``build.ninja``) under ``folder`` started after ``since``."""
    return sorted(p.parent for p in Path(folder).glob("**/native/kernels-*/build.ninja") if p.stat().st_mtime >= since)


def sources_digest(folder: Path, pattern: str = "*.py") -> str:
    """16 hex digits over the files of ``folder`` matching ``pattern`` (names and bytes): what a
    cached product of them is keyed by."""
    h = hashlib.sha256()
    for f in sorted(folder.rglob(pattern)):
        h.update(f.relative_to(folder).as_posix().encode() + b"\0" + f.read_bytes())
    return h.hexdigest()[:16]


# ----------------------------------------------------------------- what a test uses
def _resolve(path: str) -> Any:
    module, _, name = path.partition(":")
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError):  # an optional part that is not installed: nothing uses it
        return None


def _code_objects(code: types.CodeType) -> Iterator[types.CodeType]:
    yield code
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            yield from _code_objects(const)


def _in_tests(obj: Any) -> bool:
    code = getattr(obj, "__code__", None)
    return code is not None and Path(code.co_filename).resolve().is_relative_to(TESTS)


_PROJECT_PACKAGES = frozenset({"splat_framework", "scg_plugin", "anchor_gs"})


def _imported_here(name: str) -> types.ModuleType | None:
    """The module a function's own ``import a.b`` / ``from a.b import c`` names (its code lists the
    dotted name): one already imported, or one of the project's or of ``tests/``; None otherwise."""
    if name in sys.modules:
        return sys.modules[name]
    top = name.partition(".")[0]
    if top not in _PROJECT_PACKAGES and not (TESTS / f"{top}.py").is_file():
        return None
    try:
        return importlib.import_module(name)
    except Exception:  # not a module (an attribute named like one), or an optional part not installed
        return None



def _referenced(fn: Any, seen: set[int]) -> Iterator[Any]:
    """Every global object ``fn``'s code names (``module.attr`` too), and those of the ``tests/``
    functions and classes it names, recursively."""
    fn = getattr(fn, "__func__", fn)
    fn = getattr(fn, "__wrapped__", fn)
    if id(fn) in seen or not hasattr(fn, "__code__"):
        return
    seen.add(id(fn))
    scope = fn.__globals__
    for code in _code_objects(fn.__code__):
        names = set(code.co_names)
        for name in names:
            obj = scope.get(name)
            if obj is None:
                obj = _imported_here(name)
            if obj is None:
                continue
            yield obj
            if isinstance(obj, types.ModuleType):  # module.attr: the attribute, when the module holds it
                for attr in names:
                    value = vars(obj).get(attr)
                    if value is not None:
                        yield value
                    if isinstance(value, types.ModuleType):  # from package import module; module.attr
                        yield from (vars(value)[a] for a in names if a in vars(value))
            elif isinstance(obj, types.FunctionType) and _in_tests(obj):
                yield from _referenced(obj, seen)
            elif isinstance(obj, type) and obj.__module__ in scope.get("__name__", ""):
                for member in vars(obj).values():
                    if _in_tests(getattr(member, "__func__", member)):
                        yield from _referenced(member, seen)


def _uses(item: pytest.Item) -> list[Any]:
    """The objects a test item uses: through its function and the fixtures it requests."""
    seen: set[int] = set()
    found = list(_referenced(item.function, seen)) if hasattr(item, "function") else []
    info = getattr(item, "_fixtureinfo", None)
    for name in getattr(item, "fixturenames", ()):
        if name in ONCE_PER_MACHINE or info is None:
            continue
        for fixturedef in info.name2fixturedefs.get(name, ()):
            if _in_tests(fixturedef.func):
                found += _referenced(fixturedef.func, seen)
    return found


def _packages(objects: list[Any], packages: set[str]) -> set[str]:
    """The ``src/`` packages that define any of ``objects`` (a package counts for its parents too)."""
    hit = set()
    for obj in objects:
        module = obj.__name__ if isinstance(obj, types.ModuleType) else getattr(obj, "__module__", None)
        while isinstance(module, str) and module:
            if module in packages:
                hit.add(module)
            module = module.rpartition(".")[0]
    return hit


def src_packages() -> set[str]:
    """Every package under ``src/`` (a folder with an ``__init__.py``), dotted."""
    return {".".join(p.parent.relative_to(SRC).parts) for p in SRC.rglob("__init__.py")}


# ----------------------------------------------------------------- the plugin's hooks
def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--why-slow", action="store_true", help="list every slow test with what makes it slow")


@pytest.hookimpl(tryfirst=True)  # before -m deselects: the marks added here count
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    slow = {id(obj): why for path, why in SLOW_USES.items() if (obj := _resolve(path)) is not None}
    packages = src_packages()
    why: dict[str, str] = {}
    covered: dict[str, set[str]] = {p: set() for p in packages}
    for item in items:
        uses = _uses(item)
        reason = next((slow[id(o)] for o in uses if id(o) in slow), None)
        if reason is None and item.get_closest_marker("integration"):
            reason = "reads the real scenes"
        if reason is None and item.get_closest_marker("slow"):
            reason = "marked slow by hand"
        if reason is not None:
            why[item.nodeid] = reason
            if not item.get_closest_marker("slow"):
                item.add_marker(pytest.mark.slow)
            continue
        module = getattr(item, "module", None)
        module_uses = list(vars(module).values()) if module is not None else []
        for package in _packages(uses + module_uses, packages):
            covered[package].add(item.nodeid)
    config.stash[_WHY] = why
    config.stash[_PACKAGES] = {"covered": covered, "files": {str(item.path) for item in items}}


def fast_tier(config: pytest.Config) -> bool:
    """Whether this run deselects the slow tests (``-m "not slow"``)."""
    return "not slow" in (config.getoption("markexpr", "") or "")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo):
    outcome = yield
    report = outcome.get_result()
    if (report.when == "call" and report.passed and call.duration > FAST_LIMIT_S
            and fast_tier(item.config) and not item.get_closest_marker("slow")):
        report.outcome = "failed"
        report.longrepr = (
            f"{item.nodeid} took {call.duration:.1f} s, over the fast tier's {FAST_LIMIT_S:g} s "
            "(tests/tiers.py): list what makes it slow in SLOW_USES, or make it faster")


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if report.when == "call" and report.duration > FAST_LIMIT_S and "slow" not in report.keywords:
        _over.append((report.nodeid, report.duration))


_over: list[tuple[str, float]] = []
_notes: list[str] = []


def note(line: str) -> None:
    """A line for the run's summary (e.g. whether the native kernels were built or loaded); from an
    xdist worker it reaches the controller's summary."""
    if line not in _notes:
        _notes.append(line)


_STARTED = time.time()


def pytest_sessionfinish(session: pytest.Session) -> None:
    factory = getattr(session.config, "_tmp_path_factory", None)
    worker = hasattr(session.config, "workeroutput")  # the controller looks under every worker's folder
    if not worker and factory is not None and getattr(factory, "_basetemp", None) is not None:
        base = factory.getbasetemp()
        for build in kernels_built_under(base, _STARTED):
            note(f"native kernels built during the session (45 s each): {build.relative_to(base)}: "
                 "a test's own SPLAT_CACHE gets the machine's with tiers.seed_kernels")
    if worker:  # hand the notes to the controller
        session.config.workeroutput["tier_notes"] = list(_notes)


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error) -> None:
    for line in getattr(node, "workeroutput", {}).get("tier_notes", ()):
        note(line)


def pytest_terminal_summary(terminalreporter, exitstatus: int, config: pytest.Config) -> None:
    if _notes:
        terminalreporter.section("work kept between sessions")
        for line in _notes:
            terminalreporter.write_line(line)
    if _over:
        terminalreporter.section("unmarked tests over the fast tier's limit")
        for nodeid, seconds in sorted(_over, key=lambda x: -x[1]):
            terminalreporter.write_line(f"{seconds:6.1f} s  {nodeid}  (over {FAST_LIMIT_S:g} s; see tests/tiers.py)")
    if config.getoption("why_slow") and _WHY in config.stash:
        terminalreporter.section("slow tests and why")
        for nodeid, reason in sorted(config.stash[_WHY].items()):
            terminalreporter.write_line(f"{nodeid}: {reason}")


def package_coverage(config: pytest.Config) -> tuple[dict[str, set[str]], set[str]]:
    """(package -> the fast tests that use it, the test files this session collected)."""
    stash = config.stash[_PACKAGES]
    return stash["covered"], stash["files"]
