"""The public face for plugin authors: every framework name a method plugin needs, from one module.

    from splat_framework.plugin import GaussianModel, MethodSpec, TrainConfig, rasterize

Names resolve lazily (module ``__getattr__``): importing this module, or a method's
``config.py`` that takes its config classes from here, imports no torch, so ``--help``
stays fast; the model side (``GaussianModel``, ``Strategy``, ``ops``, ``rasterize``,
``Camera``) is imported on first use. Names not listed here are internal and may move.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

_EXPORTS: dict[str, str] = {
    # method registration and configs (torch-free)
    "MethodSpec": "splat_framework.registry",
    "SplatConfig": "splat_framework.config",
    "TrainConfig": "splat_framework.config",
    "ModelConfig": "splat_framework.config",
    "RegularisersConfig": "splat_framework.config",
    "GaussianModelConfig": "splat_framework.config",
    "OptimConfig": "splat_framework.config",
    "StrategyConfig": "splat_framework.config",
    "DensifyConfig": "splat_framework.config",
    "strategy_field": "splat_framework.config",
    "InitConfig": "splat_framework.config",
    "init_field": "splat_framework.config",
    "Kind": "splat_framework.config",
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
    # the model side (imports torch on first use)
    "GaussianModel": "splat_framework.model.gaussians",
    "Strategy": "splat_framework.model.strategy",
    "DefaultStrategy": "splat_framework.model.strategy",
    "check_rows": "splat_framework.model.strategy",
    "adam": "splat_framework.model.optim",
    "StartPoints": "splat_framework.model.init",
    "scene_box": "splat_framework.model.init",
    "Camera": "splat_framework.cameras",
    "RenderOutput": "splat_framework.render",
    "rasterize": "splat_framework.render",
    "rgb_to_sh": "splat_framework.render",
    "quat_to_rotmat": "splat_framework.render",
}
_MODULES: dict[str, str] = {"ops": "splat_framework.model.ops"}
"""Whole modules re-exported (``plugin.ops.remove``: the row-editing ops of strategies and hooks)."""

__all__ = sorted([*_EXPORTS, *_MODULES])

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs only
    from .cameras import Camera
    from .config import (
        MAX_GAUSSIANS, MAX_MATCHES, RUN_OPTION, DensifyConfig, Fraction, GaussianModelConfig, Interval, LearningRate,
        ModelConfig, NonNegative, OptimConfig, OptionalPeriod, Period, Positive, RampPeriod, RegularisersConfig,
        Kind, SplatConfig, StartSteps, StepFactor, Steps,
        StrategyConfig, TrainConfig, strategy_field, InitConfig, init_field,
    )
    from .model.init import StartPoints, scene_box
    from .model import ops
    from .model.gaussians import GaussianModel
    from .model.optim import adam
    from .model.strategy import DefaultStrategy, Strategy, check_rows
    from .registry import MethodSpec
    from .render import RenderOutput, quat_to_rotmat, rasterize, rgb_to_sh


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
