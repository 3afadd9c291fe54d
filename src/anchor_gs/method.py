"""Method specs of the anchor plugin, registered through the ``splat_framework.methods`` entry point.

Kept torch-free: the CLI reads it to build ``--help``.
"""

from splat_framework.registry import MethodSpec

from .config import ScaffoldModelConfig, ScaffoldTrainConfig


def config_scaffold_gs() -> ScaffoldTrainConfig:
    """Scaffold-GS from random points placed as 3dgs's (see ``anchor_gs.config`` for the schedule rule)."""
    return ScaffoldTrainConfig(method="scaffold-gs", default_steps=1000, schedule_views=4)


def config_scaffold_gs_triang() -> ScaffoldTrainConfig:
    """Scaffold-GS from the matching prior triangulated with the known poses (the paper's Tab. comp_tria row)."""
    return ScaffoldTrainConfig(method="scaffold-gs-triang", default_steps=1000, schedule_views=4,
                               model=ScaffoldModelConfig(start_from="triangulated"))


spec_scaffold_gs = MethodSpec(
    name="scaffold-gs",
    description="Scaffold-GS: anchors decoded per view into neural Gaussians by MLPs (CVPR 2024), random init",
    config_factory=config_scaffold_gs,
    model="anchor_gs.model:ScaffoldModel",
)

spec_scaffold_gs_triang = MethodSpec(
    name="scaffold-gs-triang",
    description="Scaffold-GS whose anchors start from the matches triangulated with the known poses",
    config_factory=config_scaffold_gs_triang,
    model="anchor_gs.model:ScaffoldModel",
)
