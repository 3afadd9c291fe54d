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
    """Weight of the rendered alpha over an unlit backdrop (DTU's); 0 = off."""
    depth_smoothness: NonNegative = 0.0
    """Weight of the edge-aware smoothness of the rendered depth; 0 = off."""
    depth_smoothness_gamma: NonNegative = 10.0
    """Edge sensitivity of depth_smoothness: weights exp(-gamma * colour step)."""
    stereo_weight: NonNegative = 0.0
    """Weight of the binocular consistency (Binocular3DGS); 0 = off."""
    stereo_disparity: Positive = 0.05
    """Largest disparity of the stereo partner, as a fraction of the width."""
    stereo_start: Fraction = 2 / 3
    """Fraction of the run after which the binocular consistency applies."""
    multiview_weight: NonNegative = 0.0
    """Weight of the multi-view photometric consistency of the rendered depth; 0 = off."""
    multiview_partners: int = Field(2, ge=1, le=64)
    """How many training views (nearest camera centres) multiview_weight compares each view with."""
    multiview_downsample: int = Field(1, ge=1, le=64)
    """multiview_weight compares the views at 1/this of the render's size (area-averaged)."""
    multiview_until: Fraction = 1.0
    """Fraction of the run until which the multi-view consistency applies (1: all of it)."""
    multiview_edge_ratio: NonNegative = 0.0
    """multiview_weight skips pixels whose depth spans more than this ratio over their 3x3 neighbours (occluding edges); 0 = keeps all."""
    multiview_max_angle: float = Field(180.0, gt=0, le=180)
    """multiview_weight compares a view only with partners whose viewing direction is within this many degrees of its own (180 = any)."""
    multiview_compare: Literal["colour", "ncc"] = "colour"
    """How multiview_weight compares a pixel with a partner: its colour, or its 3x3 patch's normalised cross-correlation (textured pixels only)."""
    multiview_min_texture: NonNegative = 1e-4
    """With multiview_compare ncc: pixels whose 3x3 patch has at most this grey variance are left out."""
    pseudo_view_weight: NonNegative = 0.0
    """Weight of the consistency of a render between a training view and its nearest: lifted to its depth, it must find its colours in both photos; 0 = off."""
    pseudo_view_until: Fraction = 1.0
    """Fraction of the run until which pseudo_view_weight applies (1: all of it)."""
    pseudo_view_downsample: int = Field(2, ge=1, le=64)
    """pseudo_view_weight renders its view at 1/this of the training photos' size."""
    anisotropy_weight: NonNegative = 0.0
    """Weight of the anisotropy regulariser (PhysGaussian); 0 = off."""
    max_anisotropy: Annotated[float, Field(ge=1, allow_inf_nan=False)] = 10.0
    """The scale ratio above which anisotropy_weight penalises a Gaussian."""
    drop_rate: Annotated[float, Field(ge=0, lt=1, allow_inf_nan=False)] = 0.0
    """DropGaussian: drop each Gaussian with this probability, ramped; 0 = off."""
    opacity_noise: NonNegative = 0.0
    """Opacity noise (Co-Adaptation): its standard deviation; 0 = off."""


class ModelConfig(SplatConfig):
    """What every model reads: its init, its photometric loss, its depth, the opt-in regularisers."""

    init: InitKinds = Field(default_factory=RandomInitConfig)
    """Where the initial points come from (--model.init.kind K)."""
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
    """Multiplier of the initial scale (distance to the 3 nearest neighbours)."""
    sh_degree: int = Field(3, ge=0, le=3)
    """Highest spherical-harmonics degree."""
    sh_degree_interval: RampPeriod = 500
    """Raise the active SH degree every this many iterations."""


class OptimConfig(SplatConfig):
    """Learning rates of the Gaussian parameters (Adam, one optimizer per group)."""

    means_lr: LearningRate = 1.6e-4
    """Initial position learning rate, multiplied by the scene scale."""
    means_lr_final: LearningRate = 1.6e-6
    """Final position learning rate (exponential decay), times the scene scale."""
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
