"""Initial points from the matching prior triangulated with the known poses, for any method."""

from __future__ import annotations

import warnings

import torch
from torch import Tensor

from .gaussians import FALLBACK_POINTS, GaussianModel, random_init

MIN_TRIANGULATED = 50
"""Fewer triangulated points than this: the run warns and starts from random points instead."""


def triangulated_init(cfg, datamanager, generator: torch.Generator) -> tuple[Tensor, Tensor, dict]:
    """(points [N, 3], colours [N, 3], timing) to start a model from: the training views' matches
    triangulated with their poses (``cfg.matching``, ``cfg.max_reprojection_px``: a
    :class:`~splat_framework.methods.triangulated.TriangInitConfig`), or, with fewer than
    ``MIN_TRIANGULATED`` of them (texture-less views), ``max(cfg.init_num_points,
    FALLBACK_POINTS)`` random points placed by ``cfg.init`` (one warning)."""
    from ..matching.prior import triangulated_points

    points, colors, timing = triangulated_points(cfg.matching, cfg.max_reprojection_px, datamanager)
    if points.shape[0] < MIN_TRIANGULATED:
        warnings.warn("too few triangulated matches: falling back to random initialisation", stacklevel=2)
        views = datamanager.train_views()
        cameras, images = [c for c, _ in views], [b["image"] for _, b in views]
        n_rand = max(cfg.init_num_points, FALLBACK_POINTS)
        points, colors = random_init(cfg.init, datamanager.scene, cameras, images, n_rand, generator)
    return points, colors, timing


class TriangulatedGaussianModel(GaussianModel):
    """3DGS initialised from matches triangulated with the known poses (the paper's 3DGS-triang baseline)."""

    @classmethod
    def from_data(cls, config, datamanager, generator):
        points, colors, timing = triangulated_init(config.model, datamanager, generator)
        model = cls(config, datamanager.scene.scene_radius, points, colors)
        model.init_timing = timing
        model.init_stats = {"num_points": int(points.shape[0])}
        return model
