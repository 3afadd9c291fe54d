"""Typed run configuration shared by every method (torch-free: the CLIs build their ``--help``
from these classes; every field carries a docstring right below it, which tyro shows as the
flag's help). Every name is importable from here; the modules say what each is:

- :mod:`.base`: the machinery under every config (:class:`SplatConfig`, markers such as
  :data:`Steps` and :data:`RUN_OPTION`, bounded field types, :func:`cli_parsing`),
- :mod:`.init`: the initialisation kinds of ``model.init``,
- :mod:`.matching`: the matching prior's configs, one per matcher (:class:`MatchConfig`, :data:`MatchKinds`; and :mod:`.matcher_names`, the matchers it may choose),
- :mod:`.strategy`: the densification strategies' configs,
- :mod:`.model`: what every model reads (:class:`ModelConfig`), the opt-in regularisers
  (``model.reg``), the 3DGS model and its learning rates,
- :mod:`.run_facts`: :class:`RunFacts`, what a model reads of its run besides ``config.model``,
- :mod:`.train`: :class:`TrainConfig`, the command-line contract, and the experiment's fields,
- :mod:`.schedule`: ``--steps`` rescaling the schedule (:data:`Steps` and :data:`StepFactor` fields),
- :mod:`.merge`: overrides of variants and sweeps (:func:`apply_overrides`),
- :mod:`.persist`: ``config.json`` (save, read),
- :mod:`.versions`: its schema versions and the ordered steps upgrading each to the next.

A method's config is a subclass of :class:`TrainConfig` whose ``model`` field holds the
method-specific part. Variants (paper ablation rows) are a base config plus a few overrides.
"""

from __future__ import annotations

from .base import (
    DEVICE_MARKER,
    FOLDED,
    MAX_GAUSSIANS,
    MAX_MATCHES,
    MAX_SCHEDULE,
    MAX_STEPS,
    MAX_VIEWS,
    PER_STEP_MARKER,
    RUN_OPTION,
    SHORTEN_ONLY,
    STEPS_MARKER,
    Device,
    Finite,
    Fraction,
    Interval,
    InvalidArguments,
    Kind,
    KindConfig,
    LearningRate,
    Marker,
    NonNegative,
    OptionalPeriod,
    Period,
    Positive,
    RampPeriod,
    SplatConfig,
    StartSteps,
    StepFactor,
    Steps,
    cli_parsing,
    flag_name,
)
from .init import InitConfig, InitKinds, RandomInitConfig, init_field, init_kinds
from .matching import (
    AlikedLightGlueMatchConfig,
    AutoMatchConfig,
    DenseMatchConfig,
    DiskLightGlueMatchConfig,
    LoFTRMatchConfig,
    MatchConfig,
    MatchKinds,
    SiftMatchConfig,
    match_config,
    match_kinds,
)
from .merge import apply_overrides, deep_merge
from .model import GaussianModelConfig, ModelConfig, OptimConfig, RegularisersConfig
from .persist import SavedConfig, config_payload, read_config_json, save_config
from .run_facts import RunFacts
from .schedule import follows_schedule, resolve_steps, scale_schedule
from .strategy import DensifyConfig, RegisteredStrategies, StrategyConfig, strategy_field, strategy_kinds
from .train import TrainConfig, experiment_fields, run_options
from .versions import SCHEMA_VERSION, UPGRADES, upgrade_saved_config

__all__ = [
    "DEVICE_MARKER", "FOLDED", "MAX_GAUSSIANS", "MAX_MATCHES", "MAX_SCHEDULE", "MAX_STEPS", "MAX_VIEWS",
    "PER_STEP_MARKER", "RUN_OPTION", "SCHEMA_VERSION", "SHORTEN_ONLY", "STEPS_MARKER",
    "DensifyConfig", "Device", "Finite", "Fraction", "GaussianModelConfig", "InitConfig", "InitKinds", "Interval",
    "InvalidArguments", "Kind", "KindConfig", "LearningRate", "Marker", "MatchConfig", "ModelConfig", "NonNegative", "OptimConfig", "OptionalPeriod",
    "Period", "Positive", "RampPeriod", "RandomInitConfig", "RegisteredStrategies", "RegularisersConfig", "RunFacts",
    "SavedConfig", "SplatConfig", "StartSteps", "StepFactor", "Steps", "StrategyConfig", "TrainConfig", "UPGRADES",
    "apply_overrides", "cli_parsing", "config_payload", "deep_merge", "experiment_fields", "init_field", "init_kinds", "read_config_json",
    "run_options", "flag_name", "follows_schedule", "resolve_steps", "save_config", "scale_schedule", "strategy_field", "strategy_kinds",
    "upgrade_saved_config",
    "AlikedLightGlueMatchConfig", "AutoMatchConfig", "DenseMatchConfig", "DiskLightGlueMatchConfig", "LoFTRMatchConfig",
    "MatchKinds", "SiftMatchConfig", "match_config", "match_kinds",
]
