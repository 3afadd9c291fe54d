"""Datasets: parsers, few-shot splits, image decoding and the data manager.

Names resolve lazily (module ``__getattr__``), so that importing a light submodule
(``data.resolve``, ``data.splits``) loads no PyTorch: ``splat-train`` finds a mistyped ``--data``
before it loads PyTorch, in a fraction of a second instead of after 3-6 s."""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

_EXPORTS: dict[str, str] = {
    "DataManager": "datamanager",
    "load_alpha": "images",
    "load_image": "images",
    "read_image_size": "images",
    "detect_format": "parsers",
    "load_scene": "parsers",
    "apply_pose_file": "pose_file",
    "describe_split": "run_data",
    "record_data": "run_data",
    "resolve_views": "run_data",
    "DataError": "scene",
    "SceneData": "scene",
    "blender_split": "splits",
    "dtu_split": "splits",
    "llff_split": "splits",
}
"""Each public name -> the submodule that holds it."""

__all__ = sorted(_EXPORTS)

if TYPE_CHECKING:  # pragma: no cover - for type checkers, IDEs and the import-graph test
    from .datamanager import DataManager
    from .images import load_alpha, load_image, read_image_size
    from .parsers import detect_format, load_scene
    from .pose_file import apply_pose_file
    from .run_data import describe_split, record_data, resolve_views
    from .scene import DataError, SceneData
    from .splits import blender_split, dtu_split, llff_split


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f".{_EXPORTS[name]}", __name__), name)
    globals()[name] = value  # resolved once
    return value


def __dir__() -> list[str]:
    return __all__
