"""A minimal splat plugin: 3DGS with view-independent (SH degree 0) colour and a prune-only densification strategy.

A plugin is a package that names a ``MethodSpec`` in the entry-point group
``splat_framework.methods``. Its config factory must stay torch-free (it is read
to build ``splat-train --help``); the model and the strategy are imported only
when training starts.
"""

from typing import Literal

import tyro
from pydantic import Field

from splat_framework.plugin import (
    DensifyConfig, GaussianModelConfig, MethodSpec, StrategyConfig, TrainConfig, strategy_field,
)


class PruneOnlyConfig(StrategyConfig):
    """Never grow the model; every ``every`` iterations remove the Gaussians whose opacity is below ``min_opacity``."""

    kind: tyro.conf.Suppress[Literal["prune-only"]] = "prune-only"
    """The strategy's tag."""
    min_opacity: float = Field(0.005, ge=0, lt=1)
    """Remove Gaussians whose opacity is below this."""
    every: int = Field(100, ge=1, le=10**9)
    """Prune every this many iterations."""

    def setup(self):
        from .model import PruneOnlyStrategy

        return PruneOnlyStrategy(self.min_opacity, self.every)


class FlatTrainConfig(TrainConfig):
    """Training options of flat-3dgs: the framework's, with one more strategy kind."""

    strategy: strategy_field(PruneOnlyConfig, DensifyConfig) = Field(default_factory=PruneOnlyConfig)
    """Densification options (prune-only by default; kind "default" is 3DGS's)."""


def config() -> FlatTrainConfig:
    return FlatTrainConfig(method="flat-3dgs", model=GaussianModelConfig(sh_degree=0))


spec = MethodSpec(
    name="flat-3dgs",
    description="Example plugin: 3DGS with view-independent colour (SH degree 0), pruned but never grown",
    config_factory=config,
    model="splat_example_plugin.model:FlatGaussianModel",
)
