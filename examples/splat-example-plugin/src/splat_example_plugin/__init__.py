"""A minimal splat plugin: 3DGS with view-independent (SH degree 0) colour and a prune-only densification
strategy, plus an MCMC-style strategy that every method accepting registered strategies can train with,
and a lattice init that every model accepting registered init kinds can be initialised from.

A plugin declares its parts in one table, :data:`ENTRY_POINTS`: a ``MethodSpec`` in the group
``splat_framework.methods``, a strategy config in ``splat_framework.strategies``
(``splat-train 3dgs --strategy.kind mcmc``), an init config in ``splat_framework.inits``
(``splat-train 3dgs --model.init.kind grid``) and a dataset format in ``splat_framework.dataparsers``
(``splat-train 3dgs --data FOLDER``, a folder holding ``scene.json``). Installed, pyproject.toml's
entry points hold the same table; not installed, ``SPLAT_PLUGINS=splat_example_plugin`` (with ``src/`` on
``PYTHONPATH``) reads it from here. Configs must stay torch-free (they are
read to build ``splat-train --help``); the model and the strategies are imported
only when training starts (a strategy config names its class as ``module:Class``).
"""

from typing import ClassVar, Literal

from pydantic import Field

from splat_framework.plugin import (
    MAX_GAUSSIANS,
    DensifyConfig,
    GaussianModelConfig,
    InitConfig,
    Interval,
    Kind,
    MethodSpec,
    NonNegative,
    StartSteps,
    Steps,
    StrategyConfig,
    TrainConfig,
    strategy_field,
)

ENTRY_POINTS = {
    "splat_framework.methods": {"flat-3dgs": "splat_example_plugin:spec",
                                "two-view-3dgs": "splat_example_plugin:spec_two_view"},
    "splat_framework.strategies": {"mcmc": "splat_example_plugin:MCMCConfig"},
    "splat_framework.inits": {"grid": "splat_example_plugin:GridInitConfig"},
    "splat_framework.photo_matchers": {"orb": "splat_example_plugin.matching:match_photos"},
    "splat_framework.configs": {"splat_example_plugin": "splat_example_plugin.configs"},
    "splat_framework.dataparsers": {"scene-json": "splat_example_plugin.scene_json:dataparser"},
}
"""Every part of this plugin, by entry-point group (pyproject.toml's entry points say the same)."""


class GridInitConfig(InitConfig):
    """Lattice init: points on a regular grid filling the scene's box, grey."""

    kind: Kind[Literal["grid"]] = "grid"
    """The init's kind."""
    per_axis: int = Field(20, ge=2, le=200)
    """Points along each axis of the box (per_axis ** 3 in all)."""
    points_fn: ClassVar[str] = "splat_example_plugin.grid:grid_points"

    @property
    def planned_points(self) -> int:
        return self.per_axis**3


class PruneOnlyConfig(StrategyConfig):
    """Never grow the model; every ``every`` iterations remove the Gaussians whose opacity is below ``min_opacity``."""

    kind: Kind[Literal["prune-only"]] = "prune-only"
    """The strategy's tag."""
    min_opacity: float = Field(0.005, ge=0, lt=1)
    """Remove Gaussians whose opacity is below this."""
    every: int = Field(100, ge=1, le=10**9)
    """Prune every this many iterations."""
    strategy_class: ClassVar[str] = "splat_example_plugin.model:PruneOnlyStrategy"


class MCMCConfig(StrategyConfig):
    """3DGS as Markov chain Monte Carlo (Kheradmand et al. 2024): dead Gaussians are relocated onto live
    ones drawn by opacity, the model grows by drawing more, and opacity and scale are regularised."""

    kind: Kind[Literal["mcmc"]] = "mcmc"
    """The strategy's tag."""
    cap_max: int = Field(1_000_000, ge=1, le=MAX_GAUSSIANS)
    """Most Gaussians the model grows to."""
    growth_rate: NonNegative = 0.05
    """Each refinement adds this fraction of the Gaussians (until cap_max)."""
    min_opacity: float = Field(0.005, ge=0, lt=1)
    """A Gaussian whose opacity is at most this is dead and relocated."""
    refine_start_iter: StartSteps = 500
    """First iteration at which Gaussians are relocated and added."""
    refine_stop_iter: Steps = 2500
    """Last iteration at which Gaussians are relocated and added."""
    refine_every: Interval = 100
    """Relocate and add every this many iterations."""
    noise_lr: NonNegative = 5e5
    """Position noise of nearly transparent Gaussians, times the position learning rate (0 = none)."""
    opacity_reg: NonNegative = 0.01
    """Weight of the mean opacity in the loss."""
    scale_reg: NonNegative = 0.01
    """Weight of the mean scale in the loss."""
    strategy_class: ClassVar[str] = "splat_example_plugin.mcmc:MCMCStrategy"


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


class TwoViewModelConfig(GaussianModelConfig):
    """3DGS's model options, and the weight of the second view's loss."""

    two_view_weight: NonNegative = 0.5
    """Weight of the photometric loss of each step's second view (its neighbour in the training order)."""


class TwoViewTrainConfig(TrainConfig):
    """Training options of two-view-3dgs: the framework's, with the second view's weight."""

    model: TwoViewModelConfig = Field(default_factory=TwoViewModelConfig)
    """Model options (3DGS's, and the second view's weight)."""


def config_two_view() -> TwoViewTrainConfig:
    return TwoViewTrainConfig(method="two-view-3dgs")


spec_two_view = MethodSpec(
    name="two-view-3dgs",
    description="Example plugin: 3DGS fed two training views a step by its own pipeline",
    config_factory=config_two_view,
    model="splat_framework.plugin:GaussianModel",
    pipeline="splat_example_plugin.pipeline:TwoViewPipeline",
)
