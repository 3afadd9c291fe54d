"""Spatially balanced, seeded thinning of matches."""

from __future__ import annotations

import numpy as np

def balanced_sample(
    points: np.ndarray,
    count: int,
    width: int | None = None,
    height: int | None = None,
    cell: int = 16,
    seed: int | np.random.Generator = 0,
) -> np.ndarray:
    """Spatially balanced random subset of ``points``.

    The image is cut into ``cell`` x ``cell`` pixel cells; the smallest quota k
    such that taking ``min(n_cell, k)`` points of every cell reaches ``count``
    is found, every cell keeps a random ``min(n_cell, k - 1)`` of its points and
    the remainder is drawn at random among the k-th points. No cell ends with
    more than k points, so dense clusters cannot crowd out sparse regions.

    Args:
        points: [N, 2] continuous pixel coordinates (x, y).
        count: number to keep (all are kept when N <= count).
        width, height: image size (default: from the points' extent).
        cell: cell side in pixels.
        seed: int seed or numpy Generator; the same seed gives the same subset.

    Returns:
        sorted int64 indices into ``points``, ``min(N, count)`` of them.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    n = len(pts)
    if count <= 0 or n == 0:
        return np.zeros(0, np.int64)
    if n <= count:
        return np.arange(n, dtype=np.int64)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    w = width if width is not None else int(np.ceil(pts[:, 0].max())) + 1
    h = height if height is not None else int(np.ceil(pts[:, 1].max())) + 1
    ncx, ncy = max(1, int(np.ceil(w / cell))), max(1, int(np.ceil(h / cell)))
    cx = np.clip(np.floor(pts[:, 0] / cell).astype(np.int64), 0, ncx - 1)
    cy = np.clip(np.floor(pts[:, 1] / cell).astype(np.int64), 0, ncy - 1)
    cid = cy * ncx + cx
    perm = rng.permutation(n)
    order = perm[np.argsort(cid[perm], kind="stable")]  # grouped by cell, random within
    sc = cid[order]
    starts = np.r_[0, np.flatnonzero(np.diff(sc)) + 1]
    group_len = np.diff(np.r_[starts, n])
    rank = np.arange(n) - np.repeat(starts, group_len)
    counts = group_len
    # smallest k with sum(min(counts, k)) >= count (binary search; f is monotonic)
    lo, hi = 1, int(counts.max())
    while lo < hi:
        mid = (lo + hi) // 2
        if np.minimum(counts, mid).sum() >= count:
            hi = mid
        else:
            lo = mid + 1
    k = lo
    keep = order[rank < k - 1]
    extra = order[rank == k - 1]
    need = count - len(keep)
    if need > 0:
        keep = np.concatenate([keep, rng.choice(extra, size=need, replace=False)])
    return np.sort(keep).astype(np.int64)
