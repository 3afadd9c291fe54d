"""Memory plan of a training run: the decoded-image cache budget, and a check that the run fits before any decoding."""

from __future__ import annotations

import os

from ..config import TrainConfig
from ..console import say
from ..data import DataError
from ..data.datamanager import estimate_image_bytes
from ..environment import size_bytes
from ..runtime.resources import available_memory_bytes, physical_memory_bytes

MEMORY_ENV = "SPLAT_IMAGE_MEMORY_BUDGET"
"""Environment variable: cap on the decoded-image cache, in bytes ("512M", "2G", "1.5GiB" accepted)."""
BYTES_PER_GAUSSIAN = 2048
"""Rough memory of one Gaussian during training: 59 floats of parameters, their
gradients, two Adam moments, strategy statistics and projection intermediates."""
DENSIFY_GROWTH = 3
"""Assumed growth of the Gaussian count through densification (memory estimate only)."""


def parse_bytes(text: str | int) -> int:
    """``"123"``, ``"512K"``, ``"2G"``, ``"1.5GiB"``, ``"3GB"`` -> bytes (binary units)."""
    return text if isinstance(text, int) else size_bytes(MEMORY_ENV, str(text))


def image_memory_budget() -> int | None:
    """The decoded-image cache budget from ``$SPLAT_IMAGE_MEMORY_BUDGET`` (None = unlimited)."""
    text = os.environ.get(MEMORY_ENV, "").strip()
    return parse_bytes(text) if text else None


def _gb(n: float) -> str:
    return f"{n / 2**30:.2f} GiB" if n >= 2**28 else f"{n / 2**20:.0f} MiB"


def plan_memory(scene, config: TrainConfig, budget: int | None) -> int | None:
    """Check that a run fits in memory before any decoding; return the image-cache budget to use.

    Estimate: decoded images (those the budget lets us cache) + initial points
    (``config.model.memory_per_point``: ``BYTES_PER_GAUSSIAN`` for a Gaussian, more for an anchor
    with its neural Gaussians and feature), times ``DENSIFY_GROWTH`` when densifying. With the
    config's bounds (``config.MAX_GAUSSIANS`` points, anchor_gs's ``MAX_OFFSETS`` and
    ``MAX_FEAT_DIM``) every count reaches this check instead of an allocation.
    Raises DataError when that exceeds the machine's RAM; warns (one line)
    when it exceeds the currently free RAM. Without a budget, images that
    would take more than half the RAM are decoded on demand instead.
    """
    total = physical_memory_bytes()
    img = estimate_image_bytes(scene)
    if total is not None and budget is None and img > total // 2:
        budget = total // 4
        say(
            f"warning: decoded images need {_gb(img)} (more than half of the {_gb(total)} of RAM): "
            f"caching {_gb(budget)} and decoding the rest on demand (set {MEMORY_ENV} to choose)",
            "yellow",
        )
    cached = img if budget is None else min(img, budget)
    n = max(config.model.init.planned_points, 10_000)
    growth = DENSIFY_GROWTH if config.strategy.enabled else 1
    gauss = n * config.model.memory_per_point(BYTES_PER_GAUSSIAN) * growth
    need = cached + gauss
    if total is not None and need > total:
        raise DataError(
            f"{scene.root}: the run needs about {_gb(need)} of memory (images {_gb(cached)}, "
            f"Gaussians {_gb(gauss)}) but the machine has {_gb(total)}; lower {MEMORY_ENV}, "
            "--downscale or --model.init.num-points"
        )
    free = available_memory_bytes()
    if free is not None and need > free:
        say(
            f"warning: the run needs about {_gb(need)} of memory but only {_gb(free)} is free; it may swap or be killed",
            "yellow",
        )
    return budget
