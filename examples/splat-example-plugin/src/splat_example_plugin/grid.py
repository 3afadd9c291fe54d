"""An init kind from outside the framework: points on a regular lattice filling the scene's box,
grey (``splat-train 3dgs --model.init.kind grid --model.init.per-axis 20``)."""

import torch

from splat_framework.plugin import StartPoints, scene_box


def grid_points(init, datamanager, generator: torch.Generator) -> StartPoints:
    """``init.per_axis`` ** 3 points on the lattice of the scene's box, grey (on the CPU: the framework
    moves a start to the training images' device); the generator is not needed (the start is the
    same for every seed)."""
    lo, hi = scene_box(datamanager)
    axes = [torch.linspace(float(lo[i]), float(hi[i]), init.per_axis) for i in range(3)]
    points = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
    return StartPoints(points, torch.full_like(points, 0.5))
