"""SCGaussian configuration (torch-free: read when building ``--help``)."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from splat_framework.plugin import (
    MAX_GAUSSIANS,
    MAX_MATCHES,
    AutoMatchConfig,
    DensifyConfig,
    FrustumInitConfig,
    GaussianModelConfig,
    Kind,
    LearningRate,
    MatchKinds,
    NonNegative,
    Period,
    PlyInitConfig,
    Positive,
    RandomInitConfig,
    Steps,
    TrainConfig,
    init_field,
    strategy_field,
)


class OrdinaryRandomInit(RandomInitConfig):
    """Random init of the ordinary Gaussians (the 3DGS reference's): uniform in the scene box, grey."""

    num_points: int = Field(10_000, ge=0, le=MAX_GAUSSIANS)
    """Random ordinary Gaussians beside the ray-based ones (0 = none)."""


class OrdinaryFrustumInit(FrustumInitConfig):
    """Frustum init of the ordinary Gaussians: random points inside the training frusta, coloured by their pixels."""

    num_points: int = Field(10_000, ge=0, le=MAX_GAUSSIANS)
    """Random ordinary Gaussians beside the ray-based ones (0 = none)."""


OrdinaryKinds = init_field(OrdinaryRandomInit, OrdinaryFrustumInit, PlyInitConfig)
"""SCGaussian's inits for its ordinary Gaussians: the random kinds, which may be empty, or a PLY's
points (every method starts from a PLY: its Gaussians' centres become the ordinary Gaussians)."""


class SCGModelConfig(GaussianModelConfig):
    """SCGaussian: hybrid ray-based + ordinary Gaussians with matching-prior losses."""

    init: OrdinaryKinds = Field(default_factory=OrdinaryRandomInit)
    """The ordinary Gaussians' init (the ray-based ones are initialised on the matches)."""
    matching: MatchKinds = Field(default_factory=AutoMatchConfig)
    """Matching prior (--model.matching.kind K picks the matcher)."""
    ray_binding: bool = True
    """Keep ray-based Gaussians on their rays (False: free after the warm-up)."""
    schedule: Literal["two-stage", "single-stage"] = "two-stage"
    """two-stage: z warm-up, then training (public code); single-stage: paper."""
    warmup_steps: Steps = 2000
    """Iterations of the z warm-up (two-stage schedule; 0 = no warm-up)."""
    warmup_lr: LearningRate = 0.03
    """Warm-up step of z (Adam lr) in warmup_lr_unit, halved every warmup_lr_halve_every."""
    warmup_lr_unit: Literal["depth-range", "scene"] = "depth-range"
    """Unit of warmup_lr: a fraction of the matched rays' depth range, or scene units (the official code's)."""
    warmup_lr_halve_every: Period = 500
    """Halve the warm-up learning rate every this many warm-up iterations."""
    lambda_gp: NonNegative = 0.0
    """beta: weight of the Gaussian-position loss during main training."""
    lambda_rg: NonNegative = 0.3
    """delta: weight of the rendering-geometry loss."""
    rg_start: Steps = 0
    """Main-training iteration from which the rendering-geometry loss is on."""
    cache_filter: bool = True
    """Keep each match's best z; drop matches whose error stays above eta."""
    cache_until: Steps = 0
    """Single-stage: cache during iterations [0, cache_until), then apply."""
    filter_eta_px: Positive = 2.0
    """eta: drop matches whose best reprojection error exceeds this (px)."""
    z_lr: LearningRate = 1.6e-4
    """Learning rate of ray depths, times the scene scale."""
    z_lr_final: LearningRate | None = None
    """Final rate of ray depths, reached at the end of the run (None: z follows the position
    rate's decay, to z_lr x means_lr_final / means_lr)."""
    min_matches: int = Field(50, ge=0, le=MAX_MATCHES)
    """Fewer verified matches than this: no prior, ordinary Gaussians only."""
    sparse_matches: int = Field(1000, ge=0, le=MAX_MATCHES)
    """Fewer matches than this: add at least 10,000 random Gaussians (0 = never)."""
    thin_prior_baseline: bool = True
    """With a missing or sparse prior, train on the 3dgs baseline's schedule."""


class RayStrategyConfig(DensifyConfig):
    """3DGS adaptive density control for the hybrid model: the Gaussians of matches are never
    pruned, and clones / split children are ordinary Gaussians (``scg_plugin.strategy``)."""

    kind: Kind[Literal["ray-gaussian"]] = "ray-gaussian"
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
