"""Method specs of the anchor plugin, registered through the ``splat_framework.methods`` entry point.

Kept torch-free: the CLI reads it to build ``--help``.
"""

from splat_framework.plugin import MethodSpec

from .config import OctreeTrainConfig, ScaffoldTrainConfig


def config_scaffold_gs() -> ScaffoldTrainConfig:
    """Scaffold-GS from random points placed as 3dgs's (see ``anchor_gs.config`` for the schedule rule)."""
    return ScaffoldTrainConfig(method="scaffold-gs", default_steps=1000, schedule_views=4)


def config_octree_gs() -> OctreeTrainConfig:
    """Octree-GS from random points placed as 3dgs's (see ``anchor_gs.config`` for the schedule rule)."""
    return OctreeTrainConfig(method="octree-gs", default_steps=1000, schedule_views=4)


spec_scaffold_gs = MethodSpec(
    name="scaffold-gs",
    description="Scaffold-GS: anchors decoded per view into neural Gaussians by MLPs (CVPR 2024), random init",
    config_factory=config_scaffold_gs,
    model="anchor_gs.model:ScaffoldModel",
)

spec_octree_gs = MethodSpec(
    name="octree-gs",
    description="Octree-GS: Scaffold-GS anchors on octree levels of detail chosen per view by distance, trained coarse to fine, random init",
    config_factory=config_octree_gs,
    model="anchor_gs.octree:OctreeModel",
)
