"""Pictures of a run: 8-bit images, PNG files, depth and error colour maps, captions.

Images are [H, W, 3] float tensors in [0, 1] (channels last); depth and alpha [H, W, 1].
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from torch import Tensor


def colorize_depth(
    depth: Tensor, alpha: Tensor | None = None, inv_range: tuple[float, float] | None = None
) -> np.ndarray:
    """[H, W, 1] depth -> [H, W, 3] uint8 RGB colour map (inverse depth, turbo).

    Pixels with no coverage (alpha < 0.05) are black. The inverse-depth range
    mapped to the colour map is ``inv_range`` = (1/far, 1/near) when given
    (stable across video frames), else the 1st-99th percentile of the image.
    """
    import cv2

    d = depth[..., 0].detach().float().cpu().numpy()
    valid = d > 0
    if alpha is not None:
        valid &= alpha[..., 0].detach().cpu().numpy() > 0.05
    inv = np.zeros_like(d)
    inv[valid] = 1.0 / d[valid]
    if inv_range is not None:
        lo, hi = inv_range
        inv = np.clip((inv - lo) / max(hi - lo, 1e-8), 0, 1)
    elif valid.any():
        lo, hi = np.percentile(inv[valid], [1, 99])
        inv = np.clip((inv - lo) / max(hi - lo, 1e-8), 0, 1)
    img = cv2.applyColorMap((inv * 255).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
    img = img.copy()
    img[~valid] = 0
    return img


def label_panel(img: np.ndarray, text: str) -> np.ndarray:
    """Draw a small caption in the top-left corner of an RGB uint8 panel (in place; returns it)."""
    import cv2

    h = img.shape[0]
    scale = min(max(h / 400.0, 0.3), 1.0)
    thick = 1 if scale < 0.8 else 2
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    pad = max(1, int(round(2 * scale)))
    x1, y1 = min(tw + 2 * pad, img.shape[1]), min(th + base + 2 * pad, h)
    img[:y1, :x1] = (img[:y1, :x1].astype(np.uint16) * 2 // 5).astype(np.uint8)  # darkened backdrop
    cv2.putText(img, text, (pad, pad + th), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), thick, cv2.LINE_AA)
    return img


def to_uint8(img: Tensor) -> np.ndarray:
    """[H, W, 3] float image in [0, 1] -> uint8 numpy."""
    return (img.detach().clamp(0, 1).cpu().numpy() * 255 + 0.5).astype(np.uint8)


def write_png(path: Path, rgb: np.ndarray) -> None:
    """Write an RGB uint8 image (atomically)."""
    import cv2

    from ..runtime.io import atomic_write_bytes

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise RuntimeError(f"{path}: PNG encoding failed")
    atomic_write_bytes(path, buf.tobytes())


def error_map(pred: Tensor, gt: Tensor) -> np.ndarray:
    """[H, W, 3] uint8 colour map of the per-pixel absolute error (0..0.25 -> dark..bright)."""
    import cv2

    err = (pred - gt).abs().mean(-1).detach().cpu().numpy()
    err = np.clip(err / 0.25, 0, 1)
    return cv2.applyColorMap((err * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)[..., ::-1].copy()
