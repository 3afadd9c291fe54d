"""The model configs: :class:`ModelConfig` (what every model reads), the opt-in regularisers any
model can switch on (:class:`RegularisersConfig`, ``model.reg``), the 3DGS Gaussian model's
config (:class:`GaussianModelConfig`) and its learning rates (:class:`OptimConfig`). Torch-free."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from .base import Fraction, LearningRate, NonNegative, Positive, RampPeriod, SplatConfig
from .init import InitKinds, RandomInitConfig


class RegularisersConfig(SplatConfig):
    """Opt-in regularisers any model can switch on (``model.reg``; each is off at 0); the model adds
    their terms with one call (``splat_framework.model.regularisers.regulariser_terms``)."""

    backdrop_weight: NonNegative = 0.0
    """On scenes with an unlit backdrop (DTU's black studio background; see data.images.dark_backdrop_mask): weight of the mean rendered alpha over the backdrop, whose target colour is also set to black, so that it stays empty space (the public SCGaussian and DNGaussian code use 1 on DTU); 0 = off."""
    depth_smoothness: NonNegative = 0.0
    """Weight of the edge-aware smoothness of each training view's rendered depth (losses.depth_smoothness: |depth difference| of neighbouring covered pixels, relative to the mean depth, weighted by exp(-gamma * colour difference)); 0 = off."""
    depth_smoothness_gamma: NonNegative = 10.0
    """Edge sensitivity of depth_smoothness: a neighbour pair's weight is exp(-gamma * mean |colour difference|), colours in [0, 1]."""
    stereo_weight: NonNegative = 0.0
    """Weight of the binocular consistency (Binocular3DGS, Han et al. NeurIPS 2024; losses.stereo_consistency): the training view is rendered again from a camera shifted sideways, and that render, warped back with the disparity of the view's rendered depth, must match the photo (L1 over covered pixels); one more render per step while it is on; 0 = off."""
    stereo_disparity: Positive = 0.05
    """Largest disparity of the stereo partner at the view's mean rendered depth, as a fraction of the image width (the shift is drawn uniformly up to it, either side), a rule in pixels so that it holds at any scene scale."""
    stereo_start: Fraction = 2 / 3
    """Fraction of the run after which the binocular consistency applies (Binocular3DGS: 20000 of 30000 iterations), once the depth is worth warping with."""
    anisotropy_weight: NonNegative = 0.0
    """Weight of the anisotropy regulariser (PhysGaussian; losses.scale_anisotropy: the mean excess of each rendered Gaussian's largest-to-smallest scale ratio over max_anisotropy); 0 = off."""
    max_anisotropy: Annotated[float, Field(ge=1, allow_inf_nan=False)] = 10.0
    """The scale ratio above which anisotropy_weight penalises a Gaussian."""
    drop_rate: Annotated[float, Field(ge=0, lt=1, allow_inf_nan=False)] = 0.0
    """DropGaussian (Park et al., CVPR 2025): each training step renders with every Gaussian dropped with this probability times the fraction of the run done (a ramp from 0), the kept ones' opacity divided by (1 - probability); evaluation renders all Gaussians; 0 = off."""
    opacity_noise: NonNegative = 0.0
    """Opacity noise (Co-Adaptation, Chen et al., NeurIPS 2025): each training step renders with every Gaussian's opacity multiplied by (1 + this x a standard normal draw), floored at 0, after DropGaussian's draw; evaluation renders the opacities as they are; 0 = off."""


class ModelConfig(SplatConfig):
    """What every model reads: its start, its photometric loss, its depth, the opt-in regularisers."""

    init: InitKinds = Field(default_factory=RandomInitConfig)
    """Where the initial points come from (--model.init.kind: random, frustum, triangulated, sfm, ply)."""
    lambda_dssim: Fraction = 0.2
    """Weight of the D-SSIM term in the photometric loss."""
    depth_mode: Literal["accumulated", "expected"] = "expected"
    """Depth reported in outputs and renders."""
    reg: RegularisersConfig = Field(default_factory=RegularisersConfig)
    """Opt-in regularisers (all off by default)."""

    def memory_per_point(self, bytes_per_gaussian: int) -> int:
        """Training memory of one initial point, in bytes (the memory plan's estimate, see
        ``memory_plan.plan_memory``): one Gaussian here; a model that decodes several Gaussians per
        point (anchors) says so."""
        return bytes_per_gaussian


class GaussianModelConfig(ModelConfig):
    """The 3DGS Gaussian model."""

    init_opacity: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] = 0.1
    """Initial opacity of every Gaussian."""
    init_scale: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] = 1.0
    """Multiplier of the initial scale (mean distance to the 3 nearest neighbours), at most 1000."""
    sh_degree: int = Field(3, ge=0, le=3)
    """Highest spherical-harmonics degree."""
    sh_degree_interval: RampPeriod = 500
    """Raise the active SH degree by one every this many iterations (a longer run keeps the interval, as the 3DGS reference raises it every 1000 iterations whatever the length; a shorter one compresses it)."""


class OptimConfig(SplatConfig):
    """Learning rates of the Gaussian parameters (Adam, one optimizer per group)."""

    means_lr: LearningRate = 1.6e-4
    """Initial position learning rate, multiplied by the scene scale."""
    means_lr_final: LearningRate = 1.6e-6
    """Final position learning rate (exponential decay over the run), times the scene scale."""
    scales_lr: LearningRate = 5e-3
    """Log-scale learning rate."""
    quats_lr: LearningRate = 1e-3
    """Rotation learning rate."""
    opacities_lr: LearningRate = 5e-2
    """Opacity-logit learning rate."""
    sh0_lr: LearningRate = 2.5e-3
    """Base colour (SH degree 0) learning rate."""
    shN_lr: LearningRate = 2.5e-3 / 20
    """Higher SH coefficients learning rate."""
