"""The public API for plugin authors: every framework name a method plugin needs, from one module.

    from splat_framework.plugin import GaussianModel, MethodSpec, TrainConfig, rasterize

Names resolve lazily (module ``__getattr__``): importing this module, or a method's
``config.py`` that takes its config classes from here, imports no torch, so ``--help``
stays fast; the model side (``GaussianModel``, ``Strategy``, ``ops``, ``rasterize``,
``Camera``) is imported on first use. Names not listed here are internal and may move:
the in-repo plugins (``scg_plugin``, ``anchor_gs``) and ``examples/`` import the framework
only from here (``tests/framework/test_plugin_imports.py``), and their tests also from
:mod:`splat_framework.testing`.

**The contract** (:data:`CONTRACT`): registration and configs (``MethodSpec``, ``TrainConfig`` and
the model, strategy, init and optimiser configs with their field markers; ``RunFacts``, what a model
reads of its run), the model (``GaussianModel``, ``ops``, ``adam``, ``knn_scale``, the inits it
builds from: ``initial_points``, ``StartPoints``, ``scene_box``), strategies (``Strategy``,
``DefaultStrategy``, ``check_rows``), losses (``photometric_loss``, ``regulariser_terms``),
schedules (``run_fraction``, ``log_lerp``; ``baseline_schedule``, the 3dgs baseline's schedules
for a run), the renderer (``rasterize``, ``RenderOutput``, ``rgb_to_sh``, ``quat_to_rotmat``),
the camera (``Camera``), the pipeline (``Pipeline``), dataset formats (``DataparserSpec``: how a
dataparser recognises a folder and its loader; for the loader ``SceneData``, ``build_scene``,
``read_image_size``, ``DataError``), the terminal and the profile (``phase``, ``section``).

**Optional services** (:data:`SERVICES`), for a method that builds on them: the matching prior:
its configs (``MatchKinds``: a config's ``matching`` field, any matcher by its ``kind``;
``AutoMatchConfig`` the default, ``MatchConfig`` their base), ``compute_match_set`` (the verified
matches of the training views, cached), ``match_pairs`` (them, pair by pair) and
``FALLBACK_POINTS`` (the random points a missing or sparse prior is filled with).
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

CONTRACT: dict[str, str] = {
    # method registration and configs (torch-free)
    "MethodSpec": "splat_framework.registry",
    "SplatConfig": "splat_framework.config",
    "TrainConfig": "splat_framework.config",
    "RunFacts": "splat_framework.config",
    "ModelConfig": "splat_framework.config",
    "RegularisersConfig": "splat_framework.config",
    "GaussianModelConfig": "splat_framework.config",
    "OptimConfig": "splat_framework.config",
    "StrategyConfig": "splat_framework.config",
    "DensifyConfig": "splat_framework.config",
    "strategy_field": "splat_framework.config",
    "InitConfig": "splat_framework.config",
    "init_field": "splat_framework.config",
    "RandomInitConfig": "splat_framework.config",
    "FrustumInitConfig": "splat_framework.config.init",
    "PlyInitConfig": "splat_framework.config.init",
    "Kind": "splat_framework.config",
    "BaselineSchedule": "splat_framework.methods.baseline",
    "baseline_schedule": "splat_framework.methods.baseline",
    # dataset formats: a dataparser's spec (torch-free) and what its loader builds the scene with
    "DataparserSpec": "splat_framework.data.dataparsers",
    "DataError": "splat_framework.errors",
    "SceneData": "splat_framework.data.scene",
    "build_scene": "splat_framework.data.parsers.common",
    "read_image_size": "splat_framework.data.images",
    # field markers of configs
    "Steps": "splat_framework.config",
    "StartSteps": "splat_framework.config",
    "Period": "splat_framework.config",
    "OptionalPeriod": "splat_framework.config",
    "RampPeriod": "splat_framework.config",
    "StepFactor": "splat_framework.config",
    "Interval": "splat_framework.config",
    "Fraction": "splat_framework.config",
    "LearningRate": "splat_framework.config",
    "NonNegative": "splat_framework.config",
    "Positive": "splat_framework.config",
    "MAX_GAUSSIANS": "splat_framework.config",
    "MAX_MATCHES": "splat_framework.config",
    "RUN_OPTION": "splat_framework.config",
    # the terminal and the profile
    "phase": "splat_framework.console",
    "section": "splat_framework.runtime.profiling",
    # the model side (imports torch on first use)
    "GaussianModel": "splat_framework.model.gaussians",
    "Pipeline": "splat_framework.pipeline",
    "Strategy": "splat_framework.model.strategy",
    "DefaultStrategy": "splat_framework.model.strategy",
    "check_rows": "splat_framework.model.strategy",
    "adam": "splat_framework.model.optim",
    "StartPoints": "splat_framework.model.init",
    "scene_box": "splat_framework.model.init",
    "initial_points": "splat_framework.model.init",
    "knn_scale": "splat_framework.model.gaussians",
    "run_fraction": "splat_framework.model.gaussians",
    "log_lerp": "splat_framework.model.gaussians",
    "regulariser_terms": "splat_framework.model.regularisers",
    "photometric_loss": "splat_framework.losses",
    "Camera": "splat_framework.cameras",
    "RenderOutput": "splat_framework.render",
    "RenderSettings": "splat_framework.render",
    "rasterize": "splat_framework.render",
    "rgb_to_sh": "splat_framework.render",
    "quat_to_rotmat": "splat_framework.render",
}
"""The contract: name -> the module it lives in."""
SERVICES: dict[str, str] = {
    # the matching prior
    "MatchConfig": "splat_framework.config",
    "MatchKinds": "splat_framework.config",
    "AutoMatchConfig": "splat_framework.config",
    "compute_match_set": "splat_framework.matching.prior",
    "match_pairs": "splat_framework.matching.prior",
    "FALLBACK_POINTS": "splat_framework.config.init",
}
"""The optional services: name -> the module it lives in."""
_EXPORTS: dict[str, str] = CONTRACT | SERVICES
_MODULES: dict[str, str] = {"ops": "splat_framework.model.ops"}
"""Whole modules re-exported (``plugin.ops.remove``: the row-editing ops of strategies and hooks)."""

__all__ = sorted([*_EXPORTS, *_MODULES])

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs only
    from .cameras import Camera
    from .config import (
        MAX_GAUSSIANS,
        MAX_MATCHES,
        RUN_OPTION,
        AutoMatchConfig,
        DensifyConfig,
        Fraction,
        GaussianModelConfig,
        InitConfig,
        Interval,
        Kind,
        LearningRate,
        MatchConfig,
        MatchKinds,
        ModelConfig,
        NonNegative,
        OptimConfig,
        OptionalPeriod,
        Period,
        Positive,
        RampPeriod,
        RandomInitConfig,
        RegularisersConfig,
        RunFacts,
        SplatConfig,
        StartSteps,
        StepFactor,
        Steps,
        StrategyConfig,
        TrainConfig,
        init_field,
        strategy_field,
    )
    from .config.init import FALLBACK_POINTS, FrustumInitConfig, PlyInitConfig
    from .console import phase
    from .data.dataparsers import DataparserSpec
    from .data.images import read_image_size
    from .data.parsers.common import build_scene
    from .data.scene import SceneData
    from .errors import DataError
    from .losses import photometric_loss
    from .matching.prior import compute_match_set, match_pairs
    from .methods.baseline import BaselineSchedule, baseline_schedule
    from .model import ops
    from .model.gaussians import GaussianModel, knn_scale, log_lerp, run_fraction
    from .model.init import StartPoints, initial_points, scene_box
    from .model.optim import adam
    from .model.regularisers import regulariser_terms
    from .model.strategy import DefaultStrategy, Strategy, check_rows
    from .pipeline import Pipeline
    from .registry import MethodSpec
    from .render import RenderOutput, RenderSettings, quat_to_rotmat, rasterize, rgb_to_sh
    from .runtime.profiling import section


def __getattr__(name: str) -> Any:
    if name in _MODULES:
        value = import_module(_MODULES[name])
    elif name in _EXPORTS:
        value = getattr(import_module(_EXPORTS[name]), name)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value  # resolved once
    return value


def __dir__() -> list[str]:
    return __all__
