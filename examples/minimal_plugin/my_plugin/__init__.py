"""A minimal plugin: 3DGS with one extra loss term, and a strategy that prunes (torch-free: read for --help)."""

from typing import ClassVar, Literal

from splat_framework.plugin import Kind, MethodSpec, StrategyConfig, TrainConfig

ENTRY_POINTS = {
    "splat_framework.methods": {"my-method": "my_plugin:spec"},
    "splat_framework.strategies": {"my-prune": "my_plugin:MyPruneConfig"},
}


class MyPruneConfig(StrategyConfig):
    """Remove the Gaussians whose opacity is below ``min_opacity``, at every step."""

    kind: Kind[Literal["my-prune"]] = "my-prune"
    """The strategy's tag."""
    min_opacity: float = 0.005
    """Remove the Gaussians whose opacity is below this."""
    strategy_class: ClassVar[str] = "my_plugin.model:MyPruneStrategy"


def config() -> TrainConfig:
    return TrainConfig(method="my-method", strategy=MyPruneConfig())


spec = MethodSpec(name="my-method", description="3DGS with an isotropy loss, pruned at every step",
                  config_factory=config, model="my_plugin.model:MyModel")
