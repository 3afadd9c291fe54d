"""The numeric pieces the compressed splat formats share (numpy, torch-free): the Gaussians as float32
arrays, a spatial (Morton) order, 256-value codebooks, a palette of SH vectors, smallest-three
quaternions.

Every array follows the parameter conventions of :func:`splat_framework.export.ply.gaussians_for_export`:
means [N, 3], quats [N, 4] wxyz (unnormalised), scales [N, 3] log, opacities [N] logit,
sh0 [N, 1, 3], shN [N, K-1, 3].
"""

from __future__ import annotations

import numpy as np

from ..errors import DataError

__all__ = [
    "SH_C0", "as_arrays", "codebook_1d", "morton_order", "nearest_codes", "palette", "sh_degree", "sigmoid",
    "smallest_three", "unit_quats",
]

SH_C0 = 0.28209479177387814
"""The degree-0 SH basis constant: colour = 0.5 + SH_C0 * sh0."""


def as_arrays(gaussians: dict, path) -> dict[str, np.ndarray]:
    """``gaussians`` (tensors or arrays) as contiguous float32 numpy arrays; DataError (one line,
    naming ``path``) when there are none or any value is not finite."""
    g = {}
    for k in ("means", "quats", "scales", "opacities", "sh0", "shN"):
        v = gaussians[k]
        v = v.detach().cpu().numpy() if hasattr(v, "detach") else np.asarray(v)
        g[k] = np.ascontiguousarray(v, dtype=np.float32)
    n = g["means"].shape[0]
    g["shN"] = g["shN"].reshape(n, -1, 3)
    g["sh0"] = g["sh0"].reshape(n, 1, 3)
    g["opacities"] = g["opacities"].reshape(n)
    if n == 0:
        raise DataError(f"{path}: the model has no Gaussians to export")
    if not all(np.isfinite(v).all() for v in g.values()):
        raise DataError(f"{path}: refusing to export non-finite Gaussian parameters")
    return g


def sh_degree(shN: np.ndarray) -> int:
    """The SH degree of ``shN`` [N, K-1, 3] (K-1 = 0, 3, 8, 15 -> 0..3)."""
    k1 = shN.shape[1]
    if k1 not in (0, 3, 8, 15):
        raise ValueError(f"{k1} higher SH coefficients is not a degree up to 3")
    return {0: 0, 3: 1, 8: 2, 15: 3}[k1]


def sigmoid(x: np.ndarray) -> np.ndarray:
    """The logistic function without overflow warnings (float64)."""
    return 0.5 * (1.0 + np.tanh(0.5 * np.asarray(x, np.float64)))


def unit_quats(quats: np.ndarray) -> np.ndarray:
    """[N, 4] unit quaternions (float64; a zero quaternion becomes the identity, w first)."""
    q = np.asarray(quats, np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    identity = np.zeros_like(q)
    identity[:, 0] = 1.0
    return np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), identity)


def smallest_three(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(index of the largest-magnitude component [N], the unit quaternion [N, 4] signed so that it is
    positive): the three other components then lie in [-1/sqrt(2), 1/sqrt(2)]."""
    largest = np.abs(q).argmax(axis=1)
    sign = np.where(q[np.arange(len(q)), largest] < 0, -1.0, 1.0)
    return largest, q * sign[:, None]


def _spread_bits(v: np.ndarray) -> np.ndarray:
    """10-bit integers with two zero bits inserted after each bit (for a 30-bit Morton code)."""
    v = v.astype(np.uint32) & 0x3FF
    v = (v | (v << 16)) & 0x030000FF
    v = (v | (v << 8)) & 0x0300F00F
    v = (v | (v << 4)) & 0x030C30C3
    return (v | (v << 2)) & 0x09249249


def morton_order(means: np.ndarray, bucket: int = 256) -> np.ndarray:
    """[N] permutation visiting the Gaussians along a Morton (Z-order) curve of their positions, 10
    bits per axis over their bounding box, each run of more than ``bucket`` Gaussians in one cell
    ordered again over its own box (as splat-transform orders them; ties keep their order): neighbours
    in the order are neighbours in space, which the chunks and textures need for precision and size."""
    order = np.arange(len(means))
    todo = [(0, len(means))]
    while todo:
        start, end = todo.pop()
        idx = order[start:end]
        p = means[idx].astype(np.float64)
        lo, hi = p.min(axis=0), p.max(axis=0)
        if not (hi > lo).any():
            continue  # all in one point
        cells = np.minimum(np.floor((p - lo) * np.where(hi > lo, 1024.0 / np.where(hi > lo, hi - lo, 1.0), 0.0)), 1023)
        code = _spread_bits(cells[:, 0]) | (_spread_bits(cells[:, 1]) << 1) | (_spread_bits(cells[:, 2]) << 2)
        sort = np.argsort(code, kind="stable")
        order[start:end] = idx[sort]
        code = code[sort]
        edges = np.flatnonzero(np.diff(code)) + 1
        runs = zip(np.concatenate([[0], edges]), np.concatenate([edges, [len(code)]]))
        todo.extend((start + a, start + b) for a, b in runs if b - a > bucket)
    return order


def codebook_1d(values: np.ndarray, size: int = 256, bins: int = 4096, alpha: float = 0.5,
                iterations: int = 50) -> np.ndarray:
    """At most ``size`` sorted float32 values fitted to ``values`` (any shape): all of them when they
    take no more than ``size`` distinct values; else 1-D k-means over a ``bins``-bin histogram of
    their range, each bin (at the mean of its values) weighing its count to the power ``alpha``, so
    that sparse tails (the few large scales a scene's look depends on) get entries of their own, as
    splat-transform's codebooks weigh them (Lloyd's iterations from the weighted quantiles)."""
    v = np.asarray(values, np.float64).ravel()
    distinct = np.unique(v)
    if len(distinct) <= size:
        return distinct.astype(np.float32)
    lo, hi = distinct[0], distinct[-1]
    index = np.minimum(((v - lo) / (hi - lo) * bins).astype(np.int64), bins - 1)
    counts = np.bincount(index, minlength=bins)
    occupied = counts > 0
    x = np.bincount(index, weights=v, minlength=bins)[occupied] / counts[occupied]
    if len(x) <= size:
        return x.astype(np.float32)
    w = counts[occupied].astype(np.float64) ** alpha
    cumulative = np.cumsum(w)
    centres = np.unique(x[np.searchsorted(cumulative, (np.arange(size) + 0.5) / size * cumulative[-1])])
    for _ in range(iterations):
        labels = np.searchsorted((centres[1:] + centres[:-1]) / 2, x)
        weight = np.bincount(labels, weights=w, minlength=len(centres))
        moved = np.where(weight > 0, np.bincount(labels, weights=w * x, minlength=len(centres))
                         / np.maximum(weight, 1e-300), centres)
        if np.array_equal(moved, centres):
            break
        centres = np.unique(moved)
    return centres.astype(np.float32)


def nearest_codes(values: np.ndarray, codebook: np.ndarray) -> np.ndarray:
    """The index (uint8) of the nearest ``codebook`` entry (sorted, at most 256) for each value."""
    c = np.asarray(codebook, np.float64)
    labels = np.searchsorted((c[1:] + c[:-1]) / 2, np.asarray(values, np.float64))
    return labels.astype(np.uint8)


def palette(vectors: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """(centroids [M, D] float32, labels [N] int64) with M <= ``size``: every vector its own entry
    when there are no more than ``size`` of them; else the vectors split in halves at the median of
    their widest dimension, recursively, to ``size`` groups (a power of two) of neighbouring
    vectors, each represented by its mean."""
    x = np.asarray(vectors, np.float64)
    n = len(x)
    if n <= size:
        return x.astype(np.float32), np.arange(n)
    levels = int(np.log2(size))
    x32 = x.astype(np.float32)  # enough to choose each group's widest dimension and its median
    order = np.arange(n)
    starts = np.array([0])
    for _ in range(levels):
        lengths = np.diff(np.append(starts, n))
        group = np.repeat(np.arange(len(starts)), lengths)
        xs = x32[order]
        mean = np.add.reduceat(xs, starts) / lengths[:, None]
        spread = np.add.reduceat(xs * xs, starts) / lengths[:, None] - mean * mean
        widest = spread.argmax(axis=1)
        key = xs[np.arange(n), widest[group]]
        order = order[np.lexsort((key, group))]  # each group sorted along its widest dimension
        starts = np.sort(np.concatenate([starts, starts + lengths // 2]))
    lengths = np.diff(np.append(starts, n))
    labels = np.empty(n, np.int64)
    labels[order] = np.repeat(np.arange(len(starts)), lengths)
    centroids = np.add.reduceat(x[order], starts) / lengths[:, None]
    return centroids.astype(np.float32), labels
