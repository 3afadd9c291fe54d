"""Scaffold-GS and Octree-GS configuration (torch-free: read when building ``--help``).

Defaults are the public code's (city-super/Scaffold-GS and city-super/Octree-GS,
``arguments/__init__.py``; Octree-GS's level options as its ``single_train.sh``),
their 30,000- and 40,000-iteration schedules compressed to this project's budget by
one rule: 1000 iterations for up to 4 training views, growing in proportion beyond
(``schedule_views = 4``; why not 3: docs/decisions.md), and every iteration count of the
schedule (statistics start, anchor-growing window, progressive levels, learning-rate
decays over the whole run) scaled by the same factor 1000 / 30000 (Scaffold-GS) or
1000 / 40000 (Octree-GS), except the growing interval (100, like 3DGS's
refine_every), whose length the success criteria count visits in.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from splat_framework.plugin import (
    Fraction,
    Interval,
    Kind,
    LearningRate,
    ModelConfig,
    NonNegative,
    Positive,
    SplatConfig,
    Steps,
    StrategyConfig,
    TrainConfig,
    strategy_field,
)

MAX_OFFSETS = 256
"""Most neural Gaussians per anchor (n_offsets)."""
MAX_FEAT_DIM = 1024
"""Largest anchor feature size (feat_dim): anchors x feat_dim floats, and MLPs feat_dim wide."""
MAX_LEVELS = 32
"""Most levels of detail or growing levels (a voxel size divided by fork^levels)."""


class ScaffoldModelConfig(ModelConfig):
    """Anchors (voxelised initial points) decoded per view into neural Gaussians."""

    voxel_size: NonNegative = 0.0
    """Anchor grid size in world units (0 = the points' median 3-NN distance)."""
    n_offsets: int = Field(10, ge=1, le=MAX_OFFSETS)
    """k: neural Gaussians per anchor (at most 256)."""
    feat_dim: int = Field(32, ge=1, le=MAX_FEAT_DIM)
    """Anchor feature size, the MLPs' width (at most 1024)."""
    lambda_scaling: NonNegative = 0.01
    """Weight of the volume regulariser (the neural Gaussians' scales)."""

    def memory_per_point(self, bytes_per_gaussian: int) -> int:
        """An anchor: its n_offsets neural Gaussians, and its feature, offsets and scaling with their
        gradients and two Adam moments (4 copies of float32)."""
        return self.n_offsets * bytes_per_gaussian + 16 * (self.feat_dim + 3 * self.n_offsets + 6)


class ScaffoldOptimConfig(SplatConfig):
    """Learning rates of Scaffold-GS's and Octree-GS's anchors and MLPs (Adam, one optimizer per group)."""

    offset_lr: LearningRate = 0.01
    """Offset learning rate, times the scene scale (decays to offset_lr_final)."""
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


class AnchorUpdateConfig(StrategyConfig):
    """What Scaffold-GS's and Octree-GS's anchor updates share: statistics, schedule, pruning."""

    start_stat: Steps = 17
    """Accumulate the neural Gaussians' statistics from this iteration."""
    update_from: Steps = 50
    """First iteration at which anchors grow and are pruned."""
    update_until: Steps = 500
    """Last iteration of the anchor updates (public code: 15,000 of 30,000)."""
    update_interval: Interval = 100
    """Iterations between anchor updates (not rescaled by --steps)."""
    grad_threshold: NonNegative = 0.0002
    """Grow where the mean screen-space gradient exceeds this (per level)."""
    success_threshold: Fraction = 0.8
    """Fraction of an interval an anchor must be seen in before it is pruned."""
    min_opacity: NonNegative = 0.005
    """Prune anchors whose mean summed neural opacity falls below this."""


class AnchorStrategyConfig(AnchorUpdateConfig):
    """Scaffold-GS anchor growing and pruning (``anchor_gs.strategy.AnchorStrategy``)."""

    kind: Kind[Literal["anchor"]] = "anchor"
    """The strategy's tag."""
    update_depth: int = Field(3, ge=1, le=MAX_LEVELS)
    """Growing levels (voxels init_factor / hierarchy_factor^i of the base)."""
    init_factor: int = Field(16, ge=1, le=2**16)
    """Coarsest growing level's voxel size in base voxels."""
    hierarchy_factor: int = Field(4, ge=2, le=64)
    """Voxel size ratio between growing levels."""
    strategy_class: ClassVar[str] = "anchor_gs.strategy:AnchorStrategy"


class ScaffoldTrainConfig(TrainConfig):
    """Training options of Scaffold-GS."""

    model: ScaffoldModelConfig = Field(default_factory=ScaffoldModelConfig)
    """Model options."""
    strategy: strategy_field(AnchorStrategyConfig) = Field(default_factory=AnchorStrategyConfig)
    """Anchor growing and pruning."""
    optim: ScaffoldOptimConfig = Field(default_factory=ScaffoldOptimConfig)
    """Learning rates."""


class OctreeModelConfig(ScaffoldModelConfig):
    """Scaffold-GS anchors on the levels of an octree, drawn per view by camera distance."""

    voxel_size: NonNegative = 0.0
    """Anchor grid size at init_level, world units (0 = median 3-NN distance)."""
    fork: int = Field(2, ge=2, le=64)
    """Voxel size ratio between consecutive levels."""
    levels: int = Field(0, ge=0, le=MAX_LEVELS)
    """Levels of detail (0 = from the cameras' distances to the points)."""
    init_level: int = Field(-1, ge=-1, le=MAX_LEVELS)
    """Level at which progressive training starts; -1 = levels // 2."""
    dist_ratio: Fraction = 0.999
    """Quantile of the camera-point distances taken as d_max (and 1 - it as d_min)."""
    visible_threshold: Fraction = 0.0
    """Drop anchors seen by no more than this fraction of the training views."""
    progressive: bool = True
    """Train coarse to fine: finer levels open over the first coarse_iter."""
    coarse_iter: Steps = 250
    """Iterations of progressive training (public code: 10,000 of 40,000)."""
    coarse_factor: Positive = 1.5
    """Each level opens this much sooner than the previous one."""


class OctreeStrategyConfig(AnchorUpdateConfig):
    """Octree-GS anchor growing (per level, and one level finer for strong gradients) and pruning
    (``anchor_gs.strategy.OctreeStrategy``). Schedule: the public code's 40,000 iterations x 1000 / 40,000."""

    kind: Kind[Literal["octree"]] = "octree"
    """The strategy's tag."""
    start_stat: Steps = 12
    """Accumulate the neural Gaussians' statistics from this iteration."""
    update_from: Steps = 38
    """First iteration at which anchors grow and are pruned."""
    update_until: Steps = 625
    """Last iteration of the anchor updates (public code: 25,000 of 40,000)."""
    update_ratio: NonNegative = 0.2
    """Exponent u of the per-level growth thresholds t fork^(u l)."""
    extra_ratio: NonNegative = 0.25
    """An anchor whose mean gradient exceeds the level's threshold x this is drawn at a finer level from then on ..."""
    extra_up: NonNegative = 0.01
    """... by this much per level per update (its extra_level)."""
    strategy_class: ClassVar[str] = "anchor_gs.strategy:OctreeStrategy"


class OctreeTrainConfig(TrainConfig):
    """Training options of Octree-GS."""

    model: OctreeModelConfig = Field(default_factory=OctreeModelConfig)
    """Model options."""
    strategy: strategy_field(OctreeStrategyConfig) = Field(default_factory=OctreeStrategyConfig)
    """Octree anchor growing and pruning."""
    optim: ScaffoldOptimConfig = Field(default_factory=ScaffoldOptimConfig)
    """Learning rates."""
