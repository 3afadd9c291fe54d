"""Evaluate a model on the held-out views: metrics, render FPS, pictures."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .metrics import LPIPSMetric, evaluate_images


def colorize_depth(depth: Tensor, alpha: Tensor | None = None) -> np.ndarray:
    """[H, W, 1] depth -> [H, W, 3] uint8 RGB colour map (inverse depth, turbo).

    Pixels with no coverage (alpha < 0.05) are black.
    """
    import cv2

    d = depth[..., 0].detach().float().cpu().numpy()
    valid = d > 0
    if alpha is not None:
        valid &= alpha[..., 0].detach().cpu().numpy() > 0.05
    inv = np.zeros_like(d)
    inv[valid] = 1.0 / d[valid]
    if valid.any():
        lo, hi = np.percentile(inv[valid], [1, 99])
        inv = np.clip((inv - lo) / max(hi - lo, 1e-8), 0, 1)
    img = cv2.applyColorMap((inv * 255).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
    img = img.copy()
    img[~valid] = 0
    return img


def to_uint8(img: Tensor) -> np.ndarray:
    """[H, W, 3] float image in [0, 1] -> uint8 numpy."""
    return (img.detach().clamp(0, 1).cpu().numpy() * 255 + 0.5).astype(np.uint8)


def write_png(path: Path, rgb: np.ndarray) -> None:
    """Write an RGB uint8 image (atomically)."""
    import cv2

    from .io import atomic_write_bytes

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


@torch.no_grad()
def evaluate(model, datamanager, background: Tensor, render_dir: Path | None = None) -> dict:
    """Render every test view and compute PSNR, SSIM, LPIPS (when available) and AVG.

    Returns:
        {"mean": {...}, "per_view": [...], "fps": float, "lpips_note": str | None}
    """
    lpips = LPIPSMetric(device=background.device)
    available, reason = lpips.available()
    per_view = []
    render_time = 0.0
    for camera, batch in datamanager.eval_views():
        t0 = time.perf_counter()
        out = model.get_outputs(camera, background)
        render_time += time.perf_counter() - t0
        pred, gt = out.rgb.clamp(0, 1), batch["image"]
        mask = batch.get("mask") if datamanager.scene.masked_metrics else None
        m = evaluate_images(pred, gt, mask=mask, lpips=lpips if available else None)
        name = camera.name or f"view{batch['index']:03d}"
        per_view.append({"view": name, "index": int(batch["index"]), **m})
        if render_dir is not None:
            grid = np.concatenate(
                [to_uint8(gt), to_uint8(pred), colorize_depth(out.depth, out.alpha), error_map(pred, gt)],
                axis=1,
            )
            write_png(render_dir / f"{name}_grid.png", grid)
            write_png(render_dir / f"{name}_render.png", to_uint8(pred))
            write_png(render_dir / f"{name}_depth.png", colorize_depth(out.depth, out.alpha))
    mean = {}
    for key in ("psnr", "ssim", "lpips", "avg"):
        vals = [v[key] for v in per_view if v.get(key) is not None]
        mean[key] = float(np.mean(vals)) if vals and len(vals) == len(per_view) else None
    n = max(len(per_view), 1)
    return {
        "mean": mean,
        "per_view": per_view,
        "fps": n / render_time if render_time > 0 else None,
        "lpips_note": None if available else reason,
    }
