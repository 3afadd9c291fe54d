"""Built-in baseline: vanilla 3DGS with random initialisation (the few-shot baseline of the paper).

Registered through the ``splat_framework.methods`` entry point like any plugin.
This module must not import torch (it is read to build ``--help``).
"""

from ..config import TrainConfig
from ..registry import MethodSpec


def config_3dgs() -> TrainConfig:
    """3DGS with the reference defaults, its schedule compressed to 3000 iterations for few-shot training."""
    return TrainConfig(method="3dgs")


spec_3dgs = MethodSpec(
    name="3dgs",
    description="3D Gaussian Splatting, the reference random initialisation (uniform in the scene box, grey)",
    config_factory=config_3dgs,
    model="splat_framework.model.gaussians:GaussianModel",
)
