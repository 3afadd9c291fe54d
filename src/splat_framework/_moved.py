"""Old import paths of modules that moved into a wing, kept working for one release.

``import splat_framework.trainer`` (or ``from splat_framework import trainer``) still
works: a finder on ``sys.meta_path`` answers the old name with the moved module itself (the
same object, so monkeypatching either name patches both) and warns once with a
``DeprecationWarning`` naming the new path. The wings whose package took a moved module's old
name (``evaluation``, ``export``, ``viewer``) forward its names from their ``__init__``
through :func:`forwarding`. Standard library only: imported by ``splat_framework/__init__``.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings
from types import ModuleType

PACKAGE = "splat_framework"

#: old module (under splat_framework) -> where it lives now
MOVED: dict[str, str] = {
    "trainer": "engine.trainer", "checkpoint": "engine.checkpoint", "run": "engine.run",
    "run_folder": "engine.run_folder", "run_lock": "files.run_lock",
    "memory_plan": "engine.memory_plan", "rng": "runtime.rng", "profiling": "runtime.profiling",
    "resources": "runtime.resources",
    "metrics": "evaluation.metrics", "st_lpips": "evaluation.st_lpips",
    "pose_refine": "evaluation.pose_refine", "figures": "evaluation.figures",
    "video": "export.video", "camera_paths": "export.camera_paths",
    "serving": "viewer.serving", "viser_clients": "viewer.viser_clients",
    "io": "runtime.io", "output_paths": "files.output_paths", "work_folder": "files.work_folder",
    "config_base": "config.base", "init_config": "config.init", "render.threads": "runtime.threads",
}


def _warn(old: str, new: str) -> None:
    warnings.warn(f"{old} moved to {new}; the old path goes away in the next release",
                  DeprecationWarning, stacklevel=3)


class _Alias(importlib.abc.Loader):
    def __init__(self, new: str):
        self.new = new

    def create_module(self, spec) -> ModuleType:
        module = importlib.import_module(self.new)
        self.spec = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        module.__spec__ = self.spec  # already executed; keep its own spec, not the old name's


class _MovedFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname: str, path=None, target=None):
        package, _, name = fullname.partition(".")
        if package != PACKAGE or name not in MOVED:
            return None
        new = f"{PACKAGE}.{MOVED[name]}"
        _warn(fullname, new)
        return importlib.util.spec_from_loader(fullname, _Alias(new))


def install() -> None:
    """Put the old-path finder on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        sys.meta_path.append(_MovedFinder())


def forwarding(package: str, homes: dict[str, str]):
    """The module ``__getattr__`` of a wing whose package took a moved module's old name: a name
    of the old module ``package`` resolves to the module ``homes[name]`` (relative to ``package``)
    holding it now, with a DeprecationWarning; any other name is an AttributeError."""

    def __getattr__(name: str):
        if name not in homes:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module = f"{package}.{homes[name]}"
        _warn(f"{package}.{name}", f"{module}.{name}")
        return getattr(importlib.import_module(module), name)

    return __getattr__
