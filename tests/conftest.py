"""Shared test fixtures, and the test tiers (:mod:`tiers`: which tests are slow, the fast tier's limit)."""

import os
import shutil
import time
import warnings
from pathlib import Path

import pytest

pytest_plugins = ["tiers"]


def pytest_configure(config):
    """Every test sees the framework's own registered parts and those it sets up itself (a fake entry
    point, a module in SPLAT_PLUGINS, a variant folder), never a plugin installed beside the project
    nor the developer's SPLAT_PLUGINS or SPLAT_CONFIG_PATH: the suite passes with the example plugin
    installed (CI installs it). Set before collection: test modules list the methods as they load."""
    os.environ["SPLAT_INSTALLED_PLUGINS"] = "off"
    for name in ("SPLAT_PLUGINS", "SPLAT_CONFIG_PATH"):
        os.environ.pop(name, None)


@pytest.fixture(autouse=True, scope="session")
def _tiny_scenes(tmp_path_factory):
    """The tiny built-in scenes in this session's cache before any test (a command's first use would
    print its "generating the built-in scene" phase line before the one-line error a test expects):
    generated once per machine into :func:`tiers.machine_cache`, keyed by the generator's sources,
    and copied from there (a test may change its copy; the machine's stays as generated)."""
    from splat_framework.data.synthetic import ensure_scene
    from splat_framework.runtime.trusted import private_folder
    from splat_framework.testing import TINY_SCENES
    from tiers import SRC, machine_cache, sources_digest

    kept = machine_cache() / f"scenes-{sources_digest(SRC / 'splat_framework' / 'data' / 'synthetic')}"
    private_folder(kept)
    session = tmp_path_factory.getbasetemp() / "splatcache" / "synthetic"
    for name in TINY_SCENES:
        folder = ensure_scene(name, kept)
        if not (session / folder.name).exists():
            shutil.copytree(folder, session / folder.name)


HAVE_TOOLCHAIN = bool((shutil.which("c++") or shutil.which("g++")) and shutil.which("ninja"))


@pytest.fixture(scope="session")
def native_module():
    """The loaded extension (render/native/*.cpp), from this machine's test cache: built there when
    its sources, flags, torch or compiler changed (about 25 s on 2 idle cores: docs/figures.toml),
    else loaded (the product's cache rules), by every later session and worker."""
    from splat_framework.render import _native
    from tiers import machine_cache, note

    if not HAVE_TOOLCHAIN:
        pytest.skip("no C++ compiler or ninja on this machine: the native kernels cannot be built here")
    t0 = time.time()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = _native.native_kernels(machine_cache())
    assert module is not None, [str(w.message) for w in caught]  # with a toolchain the build must work
    library = Path(module.__file__)
    built = library.stat().st_mtime >= t0
    note(f"native kernels: {'built' if built else 'loaded'} ({time.time() - t0:.1f} s), {library.parent}")
    return module


@pytest.fixture(autouse=True, scope="session")
def _native_kernels_loaded(request, tmp_path_factory) -> bool:
    """Whether the machine's native kernels are loaded in this worker, before any test: a run in
    the test's process renders with them as a user's run on a CPU does, and the session's cache
    holds a copy, so a command the tests start loads them too (never builds them: 45 s). Where they
    cannot be built, False: the tests that need them (``native_module``) skip or fail saying why."""
    from tiers import KERNELS, seed_kernels

    if not HAVE_TOOLCHAIN:
        return False
    try:
        module = request.getfixturevalue("native_module")
    except AssertionError:  # a failed build fails the tests that need the kernels, not all
        return False
    KERNELS["folder"] = Path(module.__file__).parent
    seed_kernels(tmp_path_factory.getbasetemp() / "splatcache")
    return True


def compile_env(native_loaded: bool) -> str:
    """The tests' SPLAT_COMPILE: "1" (the native kernels, a CPU run's default: training tests took
    2-6x as long on the eager torch kernels) where they are loaded; else "0", the eager kernels,
    never torch.compile's minutes (the tests that compile ask for it)."""
    return "1" if native_loaded else "0"


@pytest.fixture(autouse=True)
def _private_cache(tmp_path_factory, monkeypatch, _native_kernels_loaded):
    """Generated scenes and match caches go to this session's temp folder, never ~/.cache."""
    monkeypatch.setenv("SPLAT_CACHE", str(tmp_path_factory.getbasetemp() / "splatcache"))
    monkeypatch.setenv("SPLAT_COMPILE", compile_env(_native_kernels_loaded))


def _tiny_run(tmp_path_factory) -> Path:
    """A 30-step 3dgs run on forward-tiny, trained once per pytest session."""
    from splat_framework.engine.trainer import train
    from splat_framework.registry import get_method

    run = tmp_path_factory.getbasetemp() / "tiny-3dgs-run"
    if not (run / "metrics.json").is_file():
        cfg = get_method("3dgs").default_config()
        cfg = cfg.model_copy(
            update=dict(
                data="synthetic/forward-tiny", steps=30, output=run, progress=False, overwrite=True,
                model=cfg.model.model_copy(update=dict(init=cfg.model.init.model_copy(update=dict(num_points=2000)))),
            )
        )
        train(cfg)
    return run


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory, _native_kernels_loaded):
    """Folder of a finished tiny 3dgs run (shared by the export, evaluation and render tests)."""
    with pytest.MonkeyPatch.context() as mp:  # module fixtures run before the autouse one above
        mp.setenv("SPLAT_CACHE", str(tmp_path_factory.getbasetemp() / "splatcache"))
        mp.setenv("SPLAT_COMPILE", compile_env(_native_kernels_loaded))
        yield _tiny_run(tmp_path_factory)
