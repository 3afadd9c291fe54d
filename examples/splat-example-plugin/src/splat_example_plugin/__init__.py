"""A minimal splat plugin: 3DGS with view-independent (SH degree 0) colour and a prune-only densification strategy.

A plugin is a package that names a ``MethodSpec`` in the entry-point group
``splat_framework.methods``. Its config factory must stay torch-free (it is read
to build ``splat-train --help``); the model is imported only when training starts.
"""

from splat_framework.config import GaussianModelConfig, TrainConfig
from splat_framework.registry import MethodSpec


def config() -> TrainConfig:
    return TrainConfig(method="flat-3dgs", model=GaussianModelConfig(sh_degree=0))


spec = MethodSpec(
    name="flat-3dgs",
    description="Example plugin: 3DGS with view-independent colour (SH degree 0)",
    config_factory=config,
    model="splat_example_plugin.model:FlatGaussianModel",
)
