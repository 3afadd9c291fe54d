"""antimatter15's ``.splat`` (the WebGL viewer's format): no header, 32 bytes per Gaussian,
little-endian, largest first (by exp(scale_0 + scale_1 + scale_2) * opacity, as its ``convert.py``
orders them, so that a viewer streaming the file shows the big ones first)::

    bytes  0-11  position x, y, z            float32, exact
    bytes 12-23  scale x, y, z               float32, linear (exp of the log-scales), exact
    bytes 24-27  red, green, blue, alpha     uint8: round(clip(0.5 + SH_C0 * sh0, 0, 1) * 255),
                                             round(sigmoid(opacity) * 255)
    bytes 28-31  rotation w, x, y, z         uint8: round(q * 128 + 128) of the unit quaternion, clipped

No higher SH coefficients: the colour is the view-independent one, clipped to [0, 1].
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..runtime.io import atomic_write_bytes
from .packing import SH_C0, as_arrays, sigmoid, unit_quats

__all__ = ["RECORD", "splat_bytes", "write_splat"]

RECORD = np.dtype([("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rotation", "u1", 4)])
"""One Gaussian of a ``.splat`` file (32 bytes)."""


def splat_bytes(gaussians: dict, path: Path | str = ".splat") -> bytes:
    """The ``.splat`` file of ``gaussians`` (keys of :func:`~splat_framework.export.ply.gaussians_for_export`)."""
    g = as_arrays(gaussians, path)
    n = len(g["means"])
    opacity = sigmoid(g["opacities"])
    order = np.argsort(-np.exp(g["scales"].astype(np.float64).sum(axis=1)) * opacity, kind="stable")
    out = np.empty(n, RECORD)
    out["position"] = g["means"][order]
    out["scale"] = np.exp(g["scales"][order].astype(np.float64))
    colour = np.clip(0.5 + SH_C0 * g["sh0"].reshape(n, 3).astype(np.float64), 0.0, 1.0) * 255.0
    rgba = np.concatenate([colour, opacity[:, None] * 255.0], axis=1)[order]
    out["rgba"] = np.clip(np.round(rgba), 0, 255)
    out["rotation"] = np.clip(np.round(unit_quats(g["quats"])[order] * 128.0 + 128.0), 0, 255)
    return out.tobytes()


def write_splat(path: Path, gaussians: dict) -> Path:
    """Write ``gaussians`` as a ``.splat`` file at ``path``, atomically."""
    atomic_write_bytes(Path(path), splat_bytes(gaussians, path))
    return Path(path)
