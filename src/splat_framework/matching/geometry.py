"""Two-view geometry of the matching prior: fundamental matrices, epipolar distances, MAGSAC, pair verification."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from .base import Pts, no_matches

if TYPE_CHECKING:  # pragma: no cover
    from splat_framework.cameras import Camera

    from ..config.matching import MatchConfig

MIN_PAIR_MATCHES = 8
"""A pair keeps its verified matches only when at least this many remain (else it is left empty)."""


def as_numpy(x: Any) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def _skew(t: np.ndarray) -> np.ndarray:
    return np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]], dtype=np.float64)


def fundamental_from_cameras(cam_a: "Camera", cam_b: "Camera") -> np.ndarray:
    """[3, 3] F with ``x_b^T F x_a = 0`` for continuous (+0.5) pixel coordinates."""
    Ka, Kb = as_numpy(cam_a.K), as_numpy(cam_b.K)
    T_ab = as_numpy(cam_b.world_to_cam) @ np.linalg.inv(as_numpy(cam_a.world_to_cam))
    R, t = T_ab[:3, :3], T_ab[:3, 3]
    F = np.linalg.inv(Kb).T @ _skew(t) @ R @ np.linalg.inv(Ka)
    n = np.linalg.norm(F)
    return F / n if n > 0 else F


def epipolar_distance(pts_a: np.ndarray, pts_b: np.ndarray, F: np.ndarray) -> np.ndarray:
    """[M] symmetric epipolar distance in pixels: max of d(x_b, F x_a) and d(x_a, F^T x_b)."""
    pa = np.asarray(pts_a, np.float64).reshape(-1, 2)
    pb = np.asarray(pts_b, np.float64).reshape(-1, 2)
    xa = np.c_[pa, np.ones(len(pa))]
    xb = np.c_[pb, np.ones(len(pb))]
    lb = xa @ F.T  # epipolar lines in B
    la = xb @ F  # epipolar lines in A
    num = np.abs(np.sum(xb * lb, axis=1))
    db = num / np.maximum(np.hypot(lb[:, 0], lb[:, 1]), 1e-12)
    da = num / np.maximum(np.hypot(la[:, 0], la[:, 1]), 1e-12)
    return np.maximum(da, db)


def magsac_inliers(
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    threshold: float = 1.0,
    confidence: float = 0.999,
    max_iters: int = 10000,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Fundamental matrix with MAGSAC (cv2.USAC_MAGSAC); returns (inlier mask [M] bool, F or None).

    Fewer than 8 matches (or no model found) gives an all-False mask and None.
    """
    import cv2

    m = len(pts_a)
    if m < 8:
        return np.zeros(m, bool), None
    try:
        F, mask = cv2.findFundamentalMat(
            np.asarray(pts_a, np.float64).reshape(-1, 2),
            np.asarray(pts_b, np.float64).reshape(-1, 2),
            cv2.USAC_MAGSAC,
            float(threshold),
            float(confidence),
            int(max_iters),
        )
    except cv2.error:
        return np.zeros(m, bool), None
    if F is None or mask is None or F.shape[0] < 3:
        return np.zeros(m, bool), None
    return mask.reshape(-1).astype(bool), F[:3]


def verify_pair(
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    config: MatchConfig,
    F_known: np.ndarray | None = None,
) -> tuple[Pts, Pts, dict[str, int], str | None]:
    """MAGSAC + optional known-pose epipolar check.

    Returns:
        (pts_a, pts_b, counts {"raw", "magsac", "epipolar"}, warning or None).
    """
    pa = np.asarray(pts_a, np.float32).reshape(-1, 2)
    pb = np.asarray(pts_b, np.float32).reshape(-1, 2)
    counts = {"raw": len(pa)}
    if len(pa) < MIN_PAIR_MATCHES:
        counts.update(magsac=0, epipolar=0)
        return *no_matches(), counts, f"only {len(pa)} raw matches (< {MIN_PAIR_MATCHES}): pair left empty"
    mask, F = magsac_inliers(pa, pb, config.magsac_threshold, config.magsac_confidence)
    pa, pb = pa[mask], pb[mask]
    counts["magsac"] = len(pa)
    if F is None:
        counts["epipolar"] = 0
        return *no_matches(), counts, f"MAGSAC found no fundamental matrix for {counts['raw']} matches: pair left empty"
    if config.epipolar_check and F_known is not None:
        ok = epipolar_distance(pa, pb, F_known) < config.epipolar_threshold
        pa, pb = pa[ok], pb[ok]
    counts["epipolar"] = len(pa)
    warn = None
    if len(pa) < MIN_PAIR_MATCHES:
        warn = f"only {len(pa)} verified matches (< {MIN_PAIR_MATCHES}): pair left empty"
        pa, pb = no_matches()
    return pa, pb, counts, warn
