"""SCGaussian configuration (torch-free: read when building ``--help``)."""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

from pydantic import Field

import tyro

from splat_framework.plugin import (
    DensifyConfig,
    GaussianModelConfig,
    MAX_GAUSSIANS,
    MAX_MATCHES,
    LearningRate,
    NonNegative,
    Positive,
    Period,
    Steps,
    TrainConfig,
    strategy_field,
)

from splat_framework.config.init import KIND, FrustumInitConfig, RandomInitConfig, init_field
from splat_framework.matching import MatchConfig


class OrdinaryRandomInit(RandomInitConfig):
    """Random start of the ordinary Gaussians (the 3DGS reference's): uniform in the scene box, grey."""

    kind: Annotated[Literal["random"], KIND] = "random"
    """The start's kind."""
    num_points: int = Field(10_000, ge=0, le=MAX_GAUSSIANS)
    """Random ordinary Gaussians at start beside the ray-based ones (0 = ordinary ones come only from densification): matched rays cover only textured surfaces."""


class OrdinaryFrustumInit(FrustumInitConfig):
    """Frustum start of the ordinary Gaussians: random points inside the training frusta, coloured by their pixels."""

    kind: Annotated[Literal["frustum"], KIND] = "frustum"
    """The start's kind."""
    num_points: int = Field(10_000, ge=0, le=MAX_GAUSSIANS)
    """Random ordinary Gaussians at start beside the ray-based ones (0 = ordinary ones come only from densification)."""


OrdinaryKinds = init_field(OrdinaryRandomInit, OrdinaryFrustumInit)
"""SCGaussian's starts for its ordinary Gaussians: the random kinds, which may be empty."""


class SCGModelConfig(GaussianModelConfig):
    """SCGaussian: hybrid ray-based + ordinary Gaussians with matching-prior losses."""

    init: OrdinaryKinds = Field(default_factory=OrdinaryRandomInit)
    """Random ordinary Gaussians at start beside the ray-based ones (the sparse-prior fill and the no-prior fallback are placed by the same kind); ray-based Gaussians always start on the matched rays."""
    matching: MatchConfig = Field(default_factory=MatchConfig)
    """Matching prior."""
    ray_binding: bool = True
    """Keep ray-based Gaussians bound to their rays during training (False = they become ordinary Gaussians after the warm-up: the 'only non-structure' ablation)."""
    schedule: Literal["two-stage", "single-stage"] = "two-stage"
    """two-stage: z warm-up with L_gp, then L_photo + delta*L_rg (public code); single-stage: L_photo + beta*L_gp + delta*L_rg from the start (paper text)."""
    warmup_steps: Steps = 2000
    """Iterations of the z warm-up (two-stage schedule; 0 = no warm-up)."""
    warmup_lr: LearningRate = 0.03
    """Warm-up step size of z (Adam lr) in warmup_lr_unit, halved every warmup_lr_halve_every."""
    warmup_lr_unit: Literal["depth-range", "scene"] = "depth-range"
    """Unit of warmup_lr: depth-range, a fraction of the median depth range (far - near) of the matched rays, the same at any scene scale; scene, the scene's own length unit, as the official code's 0.5 (LLFF and Blender are stored in the official code's units; its DTU is a COLMAP model of its own, not the dataset's cameras)."""
    warmup_lr_halve_every: Period = 500
    """Halve the warm-up learning rate every this many warm-up iterations."""
    lambda_gp: NonNegative = 0.0
    """beta: weight of the Gaussian-position loss during main training."""
    lambda_rg: NonNegative = 0.3
    """delta: weight of the rendering-geometry loss."""
    rg_start: Steps = 0
    """Main-training iteration from which the rendering-geometry loss is on."""
    cache_filter: bool = True
    """Cache per match the z with the lowest position error and drop matches whose best error stays above filter_eta_px."""
    cache_until: Steps = 0
    """Single-stage: cache during main iterations [0, cache_until), then apply (two-stage caches during the warm-up)."""
    filter_eta_px: Positive = 2.0
    """eta: drop matches whose best reprojection error (pixels, worse of both directions) exceeds this."""
    z_lr: LearningRate = 1.6e-4
    """Learning rate of ray depths during main training, times the scene scale (decays like the position lr)."""
    min_matches: int = Field(50, ge=0, le=MAX_MATCHES)
    """Below this many verified matches the run warns and falls back to random ordinary Gaussians."""
    sparse_matches: int = Field(1000, ge=0, le=MAX_MATCHES)
    """Below this many verified matches the prior is too sparse to grow a model from: the run warns and adds max(init.num_points, 10000) random ordinary Gaussians alongside the ray-based ones (0 = never)."""
    thin_prior_baseline: bool = True
    """When the prior is missing or sparse (fewer than sparse_matches matches), also train as the 3dgs baseline does at the same budget: its densification schedule and SH schedule, the ray-based Gaussians still kept (scg_plugin.startup.baseline_schedule). A model made mostly of random Gaussians then grows like one, so a thin prior does not leave SCGaussian below its baseline."""


class RayStrategyConfig(DensifyConfig):
    """3DGS adaptive density control for the hybrid model: the Gaussians of matches are never
    pruned, and clones / split children are ordinary Gaussians (``scg_plugin.strategy``)."""

    kind: tyro.conf.Suppress[Literal["ray-gaussian"]] = "ray-gaussian"
    """The strategy's tag."""
    strategy_class: ClassVar[str] = "scg_plugin.strategy:RayGaussianStrategy"


RayStrategies = strategy_field(RayStrategyConfig)
"""SCGaussian's strategy kinds: only those that keep the Gaussians of matches and their flags (no registered
kind, e.g. an MCMC relocation, which would move or prune them)."""


class SCGTrainConfig(TrainConfig):
    """Training options of SCGaussian."""

    model: SCGModelConfig = Field(default_factory=SCGModelConfig)
    """Model options."""
    strategy: RayStrategies = Field(default_factory=RayStrategyConfig)
    """Densification options."""
