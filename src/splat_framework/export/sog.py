"""PlayCanvas's SOG (version 2): the Gaussians as lossless WebP textures plus a ``meta.json``,
bundled in one uncompressed zip (``.sog``), the layout that playcanvas/splat-transform reads.

Texel i of every texture (W x H, both multiples of 4, W about sqrt(N)) is Gaussian i in Morton
order; RGBA channels:

=====================  ========================================================================
``means_l``/``means_u``  the low / high byte of 16 bits per axis of sign(x) * ln(|x| + 1) across
                         its range (``meta.means.mins``/``maxs``): a relative step of 1/65535 of it
``quats``                three components of the unit quaternion (w, x, y, z), the largest left out
                         and made positive, as 8-bit (v * sqrt(2) + 1) / 2; alpha 252 + its index
``scales``               the 256-entry ``meta.scales.codebook`` index of each log-scale
``sh0``                  the 256-entry ``meta.sh0.codebook`` index of each degree-0 SH coefficient;
                         alpha round(sigmoid(opacity) * 255)
``shN_labels``           the Gaussian's palette entry (16 bits: R low byte, G high byte)
``shN_centroids``        64 palette entries a row, one texel per higher SH coefficient, R, G, B the
                         ``meta.shN.codebook`` index of each channel's value
=====================  ========================================================================

Each codebook is 1-D k-means of the values, sparse values weighing more
(:func:`~splat_framework.export.packing.codebook_1d`; all of them when they take at most 256); the
palette holds every Gaussian's own SH up to 65,536 Gaussians, else 65,536 groups of neighbouring
SH vectors (median splits, :func:`~splat_framework.export.packing.palette`). WebP's lossless
encoder keeps no colour under a zero alpha: a Gaussian whose opacity byte is 0 keeps no sh0 (as in
splat-transform's own files). ``meta.asset.generator`` is
:data:`~splat_framework.files.output_paths.SOG_GENERATOR`, by which splat-export recognises it.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import cv2
import numpy as np

from ..errors import DataError
from ..files.output_paths import SOG_GENERATOR
from ..runtime.io import atomic_write_bytes
from .packing import (
    as_arrays,
    codebook_1d,
    morton_order,
    nearest_codes,
    palette,
    sh_degree,
    sigmoid,
    smallest_three,
    unit_quats,
)

__all__ = ["PALETTE", "sog_bytes", "sog_files", "write_sog"]

PALETTE = 65536
"""The most SH palette entries (16-bit labels)."""
_MAX_SIDE = 16383  # WebP's largest width or height


def _webp(texels: np.ndarray, width: int, height: int) -> bytes:
    """Lossless WebP of ``texels`` [M, 4] uint8 RGBA laid row by row (padded with zeros)."""
    image = np.zeros((width * height, 4), np.uint8)
    image[: len(texels)] = texels
    ok, buf = cv2.imencode(".webp", image.reshape(height, width, 4)[..., [2, 1, 0, 3]], [cv2.IMWRITE_WEBP_QUALITY, 101])
    if not ok:
        raise RuntimeError("OpenCV could not encode a WebP image")
    return buf.tobytes()


def _rgba(*channels: np.ndarray, alpha: np.ndarray | int = 255) -> np.ndarray:
    n = len(channels[0])
    out = np.zeros((n, 4), np.uint8)
    for i, c in enumerate(channels):
        out[:, i] = c
    out[:, 3] = alpha
    return out


def _log_transform(x: np.ndarray) -> np.ndarray:
    return np.sign(x) * np.log1p(np.abs(x))


def sog_files(gaussians: dict, path: Path | str = "SOG") -> dict[str, bytes]:
    """The files of the SOG of ``gaussians`` (keys of :func:`~splat_framework.export.ply.gaussians_for_export`):
    ``meta.json`` and its WebP textures, by name."""
    g = as_arrays(gaussians, path)
    n = len(g["means"])
    order = morton_order(g["means"])
    width = -(-int(np.ceil(np.sqrt(n))) // 4) * 4
    height = -(-n // width // 4) * 4
    if width > _MAX_SIDE or height > _MAX_SIDE:
        raise DataError(f"{path}: {n} Gaussians do not fit SOG's WebP textures (at most {_MAX_SIDE} texels a side)")
    files: dict[str, bytes] = {}

    t = _log_transform(g["means"][order].astype(np.float64))
    mins, maxs = t.min(axis=0), t.max(axis=0)
    q16 = np.round((t - mins) / np.where(maxs > mins, maxs - mins, 1.0) * 65535.0).astype(np.uint32)
    files["means_l.webp"] = _webp(_rgba(*(q16 & 0xFF).T), width, height)
    files["means_u.webp"] = _webp(_rgba(*(q16 >> 8).T), width, height)

    largest, q = smallest_three(unit_quats(g["quats"][order]))
    kept = np.stack([np.delete(np.arange(4), i) for i in range(4)])[largest]  # [N, 3] the other components
    three = np.take_along_axis(q, kept, axis=1) * np.sqrt(2.0)
    packed = np.clip(np.round((three * 0.5 + 0.5) * 255.0), 0, 255).astype(np.uint8)
    files["quats.webp"] = _webp(_rgba(*packed.T, alpha=252 + largest), width, height)

    scales = g["scales"][order]
    scale_codes = codebook_1d(scales)
    files["scales.webp"] = _webp(_rgba(*nearest_codes(scales, scale_codes).T), width, height)

    sh0 = g["sh0"][order].reshape(n, 3)
    sh0_codes = codebook_1d(sh0)
    opacity = np.clip(np.round(sigmoid(g["opacities"][order]) * 255.0), 0, 255)
    files["sh0.webp"] = _webp(_rgba(*nearest_codes(sh0, sh0_codes).T, alpha=opacity), width, height)

    meta = {
        "version": 2,
        "asset": {"generator": SOG_GENERATOR},
        "count": n,
        "means": {"mins": mins.tolist(), "maxs": maxs.tolist(), "files": ["means_l.webp", "means_u.webp"]},
        "scales": {"codebook": scale_codes.tolist(), "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": sh0_codes.tolist(), "files": ["sh0.webp"]},
    }
    degree = sh_degree(g["shN"])
    if degree:
        k1 = g["shN"].shape[1]
        rest = g["shN"][order].transpose(0, 2, 1).reshape(n, 3 * k1)  # channel-major, as the PLY's f_rest
        centroids, labels = palette(rest, PALETTE)
        rest_codes = codebook_1d(centroids)
        entry = nearest_codes(centroids, rest_codes).reshape(len(centroids), 3, k1).transpose(0, 2, 1)  # [M, k1, RGB]
        rows = -(-len(centroids) // 64)
        files["shN_centroids.webp"] = _webp(_rgba(*entry.reshape(-1, 3).T), 64 * k1, rows)
        files["shN_labels.webp"] = _webp(_rgba(labels & 0xFF, labels >> 8), width, height)
        meta["shN"] = {"count": len(centroids), "bands": degree, "codebook": rest_codes.tolist(),
                       "files": ["shN_centroids.webp", "shN_labels.webp"]}
    return {"meta.json": json.dumps(meta).encode("utf-8"), **files}


def sog_bytes(gaussians: dict, path: Path | str = "SOG") -> bytes:
    """The ``.sog`` bundle: :func:`sog_files` in one uncompressed zip, ``meta.json`` first, dated 1980-01-01
    (the same Gaussians give the same bytes)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:
        for name, data in sog_files(gaussians, path).items():
            z.writestr(zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0)), data)
    return buf.getvalue()


def write_sog(path: Path, gaussians: dict) -> Path:
    """Write ``gaussians`` as a ``.sog`` bundle at ``path``, atomically."""
    atomic_write_bytes(Path(path), sog_bytes(gaussians, path))
    return Path(path)
