"""Niantic's SPZ (version 3): a gzip stream of a 16-byte header and the Gaussians' quantised
attributes, one block per attribute (the layout of nianticlabs/spz's ``load-spz.cc``).

Header (little-endian): magic ``NGSP`` (0x5053474e), version 3, the Gaussian count, the SH degree,
the fractional bits of the positions (12), flags (0: not antialiased), a reserved byte. Then, N
Gaussians per block:

=========  ===================================================================================
positions  3 x 24-bit signed fixed point, 12 fractional bits: a step of 1/4096, |x| < 2048
alphas     uint8: round(sigmoid(opacity) * 255), the linear opacity
colours    uint8: round(sh0 * 0.15 * 255 + 127.5), the degree-0 SH coefficient (not SH_C0)
scales     uint8: round((log scale + 10) * 16), a log step of 1/16 over [-10, 5.94]
rotations  uint32: the unit quaternion's largest component's index (x, y, z, w = 0..3) in the top
           2 bits, then the three others as sign bit + 9-bit magnitude of |q| / sqrt(1/2)
sh         uint8 per coefficient, channel fastest: round(c * 128) + 128, degree 1 kept to 5 bits
           (a step of 1/16), degrees 2-3 to 4 bits (1/8), as Niantic's default packing; [-1, 1]
=========  ===================================================================================

Positions and rotations are stored as given (no axis flip), as Niantic's ``ply_to_spz`` and
PlayCanvas's splat-transform write a PLY's. The gzip header carries the comment
:data:`~splat_framework.files.output_paths.SPZ_COMMENT`, by which splat-export recognises its
own files (readers skip it). Version 3 because every reader reads it (version 4 moved to ZSTD).
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..files.output_paths import SPZ_COMMENT
from ..runtime.io import atomic_write_bytes
from .packing import as_arrays, sh_degree, sigmoid, smallest_three, unit_quats

__all__ = ["spz_bytes", "write_spz"]

MAGIC = 0x5053474E
VERSION = 3
FRACTIONAL_BITS = 12
COLOR_SCALE = 0.15
SH1_BITS, SH_REST_BITS = 5, 4


def _u8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.round(x), 0, 255).astype(np.uint8)


def _positions(means: np.ndarray, path) -> np.ndarray:
    fixed = np.round(means.astype(np.float64) * (1 << FRACTIONAL_BITS))
    limit = 1 << 23
    outside = int((np.abs(fixed) >= limit).any(axis=1).sum())
    if outside:
        raise DataError(f"{path}: {outside} Gaussians lie {2 ** (23 - FRACTIONAL_BITS)} or more units from the "
                        "origin, beyond SPZ's 24-bit positions; export them as another format")
    return fixed.astype("<i4").view(np.uint8).reshape(-1, 3, 4)[:, :, :3].reshape(-1)


def _rotations(quats: np.ndarray) -> np.ndarray:
    q = unit_quats(quats)[:, [1, 2, 3, 0]]  # SPZ's order: x, y, z, w
    largest, q = smallest_three(q)
    packed = largest.astype(np.uint32)
    for i in range(4):
        other = largest != i
        mag = np.floor(511.0 * np.abs(q[:, i]) / np.sqrt(0.5) + 0.5).astype(np.uint32)
        sign = (q[:, i] < 0).astype(np.uint32)
        packed = np.where(other, (packed << 10) | (sign << 9) | np.minimum(mag, 511), packed)
    return packed.astype("<u4").view(np.uint8)


def _sh(shN: np.ndarray) -> np.ndarray:
    q = np.round(shN.astype(np.float64) * 128.0) + 128.0  # [N, K-1, 3]: coefficient-major, channel fastest
    bucket = np.full(q.shape[1], 1 << (8 - SH_REST_BITS), np.float64)
    bucket[:3] = 1 << (8 - SH1_BITS)
    q = np.floor((q + bucket[None, :, None] / 2) / bucket[None, :, None]) * bucket[None, :, None]
    return np.clip(q, 0, 255).astype(np.uint8).reshape(-1)


def _gzip(data: bytes, comment: str) -> bytes:
    """One gzip member (RFC 1952) with an FCOMMENT field and no timestamp."""
    header = b"\x1f\x8b\x08\x10" + struct.pack("<I", 0) + b"\x00\xff" + comment.encode("latin-1") + b"\x00"
    deflate = zlib.compressobj(6, zlib.DEFLATED, -zlib.MAX_WBITS)  # zlib's default, as Niantic's
    body = deflate.compress(data) + deflate.flush()
    return header + body + struct.pack("<II", zlib.crc32(data) & 0xFFFFFFFF, len(data) & 0xFFFFFFFF)


def spz_bytes(gaussians: dict, path: Path | str = "SPZ") -> bytes:
    """The SPZ file of ``gaussians`` (keys of :func:`~splat_framework.export.ply.gaussians_for_export`)."""
    g = as_arrays(gaussians, path)
    n = len(g["means"])
    header = struct.pack("<IIIBBBB", MAGIC, VERSION, n, sh_degree(g["shN"]), FRACTIONAL_BITS, 0, 0)
    blocks = [
        _positions(g["means"], path),
        _u8(sigmoid(g["opacities"]) * 255.0),
        _u8(g["sh0"].reshape(n, 3).astype(np.float64) * (COLOR_SCALE * 255.0) + 127.5).reshape(-1),
        _u8((g["scales"].astype(np.float64) + 10.0) * 16.0).reshape(-1),
        _rotations(g["quats"]),
        _sh(g["shN"]),
    ]
    return _gzip(header + b"".join(b.tobytes() for b in blocks), SPZ_COMMENT)


def write_spz(path: Path, gaussians: dict) -> Path:
    """Write ``gaussians`` as an SPZ file at ``path``, atomically."""
    atomic_write_bytes(Path(path), spz_bytes(gaussians, path))
    return Path(path)
