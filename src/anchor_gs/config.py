"""Scaffold-GS configuration (torch-free: read when building ``--help``).

Defaults are the public code's (city-super/Scaffold-GS, ``arguments/__init__.py``),
its 30,000-iteration schedule compressed to this project's budget by one rule, the
rule ``scgaussian`` follows: 1000 iterations for up to 4 training views, growing in
proportion beyond (``schedule_views``), and every iteration count of the schedule
(statistics start, anchor-growing window, learning-rate decays over the whole run)
scaled by the same factor 1000 / 30000, except the growing interval (100, like
3DGS's refine_every), whose length the success criteria count visits in.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

import tyro

from splat_framework.config import (
    Fraction,
    GaussianModelConfig,
    LearningRate,
    NonNegative,
    Steps,
    StrategyConfig,
    TrainConfig,
    strategy_field,
)
from splat_framework.methods.triangulated import TriangInitConfig


class ScaffoldModelConfig(GaussianModelConfig, TriangInitConfig):
    """Anchors (voxelised initial points) decoded per view into neural Gaussians."""

    start_from: Literal["random", "triangulated"] = "random"
    """Initial points: random as 3dgs (init, init_num_points), or the matching prior triangulated with the known poses as 3dgs-triang (matching, max_reprojection_px)."""
    voxel_size: NonNegative = 0.0
    """Anchor grid size in world units; 0 = the median distance of the initial points to their 3 nearest neighbours."""
    n_offsets: int = Field(10, ge=1)
    """k: neural Gaussians per anchor."""
    feat_dim: int = Field(32, ge=1)
    """Anchor feature size (the MLPs' width)."""
    lambda_scaling: NonNegative = 0.01
    """Weight of the volume regulariser: mean product of the neural Gaussians' scales."""
    offset_lr: LearningRate = 0.01
    """Offset learning rate, times the scene scale (exponential decay to offset_lr_final over the run)."""
    offset_lr_final: LearningRate = 1e-4
    """Final offset learning rate, times the scene scale."""
    feature_lr: LearningRate = 0.0075
    """Anchor feature learning rate."""
    scaling_lr: LearningRate = 0.007
    """Anchor log-scaling learning rate."""
    mlp_opacity_lr: LearningRate = 0.002
    """Opacity MLP learning rate (decays to 1 % over the run)."""
    mlp_cov_lr: LearningRate = 0.004
    """Scale/rotation MLP learning rate (constant)."""
    mlp_color_lr: LearningRate = 0.008
    """Colour MLP learning rate (decays to 0.625 % over the run)."""


class AnchorStrategyConfig(StrategyConfig):
    """Scaffold-GS anchor growing and pruning (``anchor_gs.strategy.AnchorStrategy``)."""

    kind: tyro.conf.Suppress[Literal["anchor"]] = "anchor"
    """The strategy's tag."""
    start_stat: Steps = 17
    """Accumulate neural-Gaussian gradients and opacities from this iteration (public code: 500 of 30,000)."""
    update_from: Steps = 50
    """First iteration at which anchors grow and are pruned (public code: 1500 of 30,000)."""
    update_until: Steps = 500
    """Last iteration of the anchor updates (public code: 15,000 of 30,000)."""
    update_interval: int = Field(100, ge=1)
    """Iterations between anchor updates (not rescaled: the success criteria count visits within it)."""
    grad_threshold: NonNegative = 0.0002
    """Grow where a neural Gaussian's mean screen-space gradient (NDC units) exceeds this (x 2^i at level i)."""
    success_threshold: Fraction = 0.8
    """Fraction of an interval an anchor must have been seen in before it may be pruned (half of it for growing)."""
    min_opacity: NonNegative = 0.005
    """Prune anchors whose mean summed neural opacity falls below this."""
    update_depth: int = Field(3, ge=1)
    """Growing levels: voxel size init_factor / hierarchy_factor^i times the base size."""
    init_factor: int = Field(16, ge=1)
    """Coarsest growing level's voxel size in base voxels."""
    hierarchy_factor: int = Field(4, ge=2)
    """Voxel size ratio between growing levels."""

    def setup(self):
        from .strategy import AnchorStrategy

        return AnchorStrategy(self)


class ScaffoldTrainConfig(TrainConfig):
    """Training options of Scaffold-GS."""

    model: ScaffoldModelConfig = Field(default_factory=ScaffoldModelConfig)
    """Model options."""
    strategy: strategy_field(AnchorStrategyConfig) = Field(default_factory=AnchorStrategyConfig)
    """Anchor growing and pruning."""
