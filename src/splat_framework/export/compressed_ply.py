"""PlayCanvas's compressed PLY (SuperSplat's ``.compressed.ply``): the Gaussians in Morton order,
in chunks of 256 that each store their own ranges, every Gaussian in four 32-bit words.

Binary little-endian, three elements (the third only with SH degree > 0):

- ``chunk`` (ceil(N / 256) of them), 18 floats: ``min_x min_y min_z max_x max_y max_z``, the same of
  the log-scales (``min_scale_x`` ... ``max_scale_z``, clamped to [-20, 20]) and of the colours
  0.5 + SH_C0 * sh0 (``min_r`` ... ``max_b``);
- ``vertex`` (N), 4 uint: ``packed_position`` and ``packed_scale`` (11, 10, 11 bits of x, y, z
  across the chunk's range), ``packed_rotation`` (2 bits: the index of the unit quaternion's
  largest component, w x y z = 0..3; then the three others, made positive-largest, as 10-bit
  unorms of q * sqrt(1/2) + 0.5), ``packed_color`` (8 bits each of r, g, b across the chunk's range
  and of the linear opacity sigmoid(opacity));
- ``sh`` (N), uchar ``f_rest_0`` ... (the 3DGS PLY's channel-major order), each
  clamp(trunc((c / 8 + 0.5) * 256), 0, 255): a step of 1/32 over [-4, 4].

Each unorm of b bits stores floor(v * (2^b - 1) + 0.5) of v normalised to the chunk's range (the
writer of playcanvas/splat-transform, ``compressed-chunk.ts``). The header carries
:data:`~splat_framework.files.output_paths.PLY_COMMENT`, by which splat-export recognises it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..files.output_paths import PLY_COMMENT
from ..runtime.io import atomic_write_bytes
from .packing import SH_C0, as_arrays, morton_order, sigmoid, smallest_three, unit_quats

__all__ = ["CHUNK", "compressed_ply_bytes", "write_compressed_ply"]

CHUNK = 256
"""Gaussians per chunk."""

_CHUNK_PROPS = [f"{m}_{a}" for m in ("min", "max") for a in "xyz"] + [
    f"{m}_scale_{a}" for m in ("min", "max") for a in "xyz"] + [f"{m}_{c}" for m in ("min", "max") for c in "rgb"]


def _unorm(v: np.ndarray, bits: int) -> np.ndarray:
    top = (1 << bits) - 1
    return np.clip(np.floor(v * top + 0.5), 0, top).astype(np.uint32)


def _normalise(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """x [C, 256, 3] in [0, 1] across each chunk's range lo..hi [C, 1, 3] (0 for a range under 1e-5)."""
    span = hi - lo
    t = np.where(span < 1e-5, 0.0, (x - lo) / np.where(span < 1e-5, 1.0, span))
    return np.where(x <= lo, 0.0, np.where(x >= hi, 1.0, t))


def _pack_11_10_11(t: np.ndarray) -> np.ndarray:
    return (_unorm(t[..., 0], 11) << 21) | (_unorm(t[..., 1], 10) << 11) | _unorm(t[..., 2], 11)


def compressed_ply_bytes(gaussians: dict, path: Path | str = "compressed PLY") -> bytes:
    """The compressed PLY file of ``gaussians`` (keys of :func:`~splat_framework.export.ply.gaussians_for_export`)."""
    g = as_arrays(gaussians, path)
    n = len(g["means"])
    order = morton_order(g["means"])
    chunks = -(-n // CHUNK)
    pad = np.concatenate([order, np.full(chunks * CHUNK - n, order[-1])])  # the last chunk repeats its last Gaussian

    def chunked(a: np.ndarray) -> np.ndarray:
        return a.astype(np.float64)[pad].reshape(chunks, CHUNK, -1)

    position = chunked(g["means"])
    scale = chunked(g["scales"])
    colour = 0.5 + SH_C0 * chunked(g["sh0"].reshape(n, 3))
    # each range as the float32 the file stores, so that a reader's lerp ends exactly at its ends
    ranges = [(a.min(axis=1, keepdims=True), a.max(axis=1, keepdims=True)) for a in (position, scale, colour)]
    ranges[1] = tuple(np.clip(r, -20.0, 20.0) for r in ranges[1])
    ranges = [tuple(r.astype(np.float32).astype(np.float64) for r in pair) for pair in ranges]
    (plo, phi), (slo, shi), (clo, chi) = ranges
    table = np.concatenate([plo, phi, slo, shi, clo, chi], axis=2).reshape(chunks, 18).astype("<f4")

    largest, q = smallest_three(unit_quats(g["quats"])[pad])
    rotation = largest.astype(np.uint32)
    for i in range(4):
        rotation = np.where(largest != i, (rotation << 10) | _unorm(q[:, i] * np.sqrt(0.5) + 0.5, 10), rotation)
    c = _normalise(colour, clo, chi)
    alpha = sigmoid(g["opacities"])[pad].reshape(chunks, CHUNK)
    packed_colour = (_unorm(c[..., 0], 8) << 24) | (_unorm(c[..., 1], 8) << 16) | (_unorm(c[..., 2], 8) << 8) \
        | _unorm(alpha, 8)
    vertex = np.stack([
        _pack_11_10_11(_normalise(position, plo, phi)).reshape(-1),
        rotation,
        _pack_11_10_11(_normalise(scale, slo, shi)).reshape(-1),
        packed_colour.reshape(-1),
    ], axis=1)[:n].astype("<u4")

    k1 = g["shN"].shape[1]
    lines = ["ply", "format binary_little_endian 1.0", PLY_COMMENT, f"element chunk {chunks}"]
    lines += [f"property float {p}" for p in _CHUNK_PROPS]
    lines += [f"element vertex {n}"] + [f"property uint packed_{p}" for p in ("position", "rotation", "scale", "color")]
    sh = b""
    if k1:
        lines += [f"element sh {n}"] + [f"property uchar f_rest_{i}" for i in range(3 * k1)]
        rest = g["shN"][order].transpose(0, 2, 1).reshape(n, 3 * k1).astype(np.float64)  # channel-major, as the PLY
        sh = np.clip(np.trunc((rest / 8.0 + 0.5) * 256.0), 0, 255).astype(np.uint8).tobytes()
    header = ("\n".join(lines + ["end_header"]) + "\n").encode("ascii")
    return header + table.tobytes() + vertex.tobytes() + sh


def write_compressed_ply(path: Path, gaussians: dict) -> Path:
    """Write ``gaussians`` as a compressed PLY file at ``path``, atomically."""
    atomic_write_bytes(Path(path), compressed_ply_bytes(gaussians, path))
    return Path(path)
