"""Anchor-based Gaussians as a plugin: Scaffold-GS (Lu et al., CVPR 2024) and Octree-GS
(Ren et al., TPAMI 2025) built on its decoder.

Registered through ``splat_framework.methods`` entry points exactly as a third-party
package would be, importing only ``splat_framework``'s public API: anchors with a
feature, a scaling and k learnable offsets, decoded per view into neural Gaussians by
small MLPs (``networks``), grown on a voxel grid and pruned by an anchor strategy.
"""

ENTRY_POINTS = {
    "splat_framework.methods": {
        "scaffold-gs": "anchor_gs.method:spec_scaffold_gs",
        "octree-gs": "anchor_gs.method:spec_octree_gs",
    },
}
"""Every part of this plugin, by entry-point group (the project's pyproject.toml declares the same
entry points; a test checks they agree)."""
