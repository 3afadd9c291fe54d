"""Built-in baseline: 3DGS initialised from the matching prior triangulated with the known poses
(the paper's "Triang. init + 3DGS").

The initialiser (:func:`splat_framework.model.triangulated.triangulated_init`) is the
framework's, so that any plugin's method can start from the same points (a ``-triang``
variant of an anchor-based method, say). This module must not import torch (it is read
to build ``--help``).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from ..config import GaussianModelConfig, SplatConfig, TrainConfig
from ..matching import MatchConfig
from ..registry import MethodSpec


class TriangInitConfig(SplatConfig):
    """Where a method's initial points come from: the matching prior's matches triangulated with
    the known poses. Mixed into a model config (its fields sit beside the model's own)."""

    matching: MatchConfig = Field(default_factory=MatchConfig)
    """Matching prior used for triangulation."""
    max_reprojection_px: float = Field(2.0, gt=0)
    """Drop triangulated points whose reprojection error exceeds this (pixels)."""


class TriangModelConfig(GaussianModelConfig, TriangInitConfig):
    """3DGS initialised from matches triangulated with the known poses."""

    init: Literal["random", "frustum"] = "random"
    """Placement of the random Gaussians used only when too few matches triangulate (normally the model starts from the triangulated points)."""


class TriangTrainConfig(TrainConfig):
    """Training options of the triangulation-initialised 3DGS baseline."""

    model: TriangModelConfig = Field(default_factory=TriangModelConfig)
    """Model options."""


def config_3dgs_triang() -> TriangTrainConfig:
    """3DGS initialised from the matching prior triangulated with the known poses."""
    return TriangTrainConfig(method="3dgs-triang")


spec_3dgs_triang = MethodSpec(
    name="3dgs-triang",
    description="3DGS initialised from matches triangulated with the known poses",
    config_factory=config_3dgs_triang,
    model="splat_framework.model.triangulated:TriangulatedGaussianModel",
)
