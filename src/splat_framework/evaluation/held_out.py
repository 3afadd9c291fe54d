"""Evaluate a model on the held-out views: metrics, render FPS, pictures."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .metrics import IMAGE_METRICS, LPIPSMetric, STLPIPSMetric, evaluate_images, psnr
from ..cameras import pose_differences
from ..console import track
from .pose_refine import refine_pose
from ..engine.profiling import synchronize


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


DEPTH_KEYS = ("depth_abs_rel", "depth_within_5pct", "depth_coverage")
"""Geometry metrics of :func:`depth_metrics` (None where the dataset has no GT depth)."""


def depth_metrics(depth: Tensor, alpha: Tensor, gt_depth: Tensor | None, min_alpha: float = 0.5) -> dict:
    """Error of a rendered expected depth against ground truth (camera z).

    Evaluated over the pixels with ``alpha > min_alpha`` and GT depth > 0.

    Returns:
        depth_abs_rel: mean |d - gt| / gt;
        depth_within_5pct: fraction of those pixels with |d - gt| / gt < 0.05;
        depth_coverage: fraction of the GT-valid pixels that were evaluated
        (rendered alpha above ``min_alpha``).
        All None when there is no GT; the first two None when no pixel qualifies.
    """
    if gt_depth is None:
        return dict.fromkeys(DEPTH_KEYS)
    gt = gt_depth[..., 0].float()
    has_gt = gt > 0
    sel = has_gt & (alpha[..., 0] > min_alpha)
    n_gt = int(has_gt.sum())
    out = {"depth_coverage": float(sel.sum()) / n_gt if n_gt else None}
    if not bool(sel.any()):
        return {"depth_abs_rel": None, "depth_within_5pct": None, **out}
    rel = (depth[..., 0].float()[sel] - gt[sel]).abs() / gt[sel]
    return {"depth_abs_rel": float(rel.mean()), "depth_within_5pct": float((rel < 0.05).float().mean()), **out}


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

    from ..files.io import atomic_write_bytes

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
def evaluate(model, datamanager, background: Tensor, render_dir: Path | None = None, pose_steps: int = 0) -> dict:
    """Render every test view and compute PSNR, SSIM, LPIPS (when available) and AVG,
    plus the depth error when the dataset has ground-truth depth (see :func:`depth_metrics`).

    With ``pose_steps`` > 0, each test camera's pose is first fitted to its photo by that many
    steps of :func:`splat_framework.evaluation.pose_refine.refine_pose` (the protocol of pose-free methods;
    for poses estimated from the training photos alone); per view, ``pose_refined_deg`` and
    ``pose_refined_shift`` record how far it moved and ``psnr_before_pose_fit`` the PSNR at the
    pose as given (also averaged in ``mean``).

    With ``render_dir``, writes per view ``<view>_render.png``, ``<view>_gt.png``,
    ``<view>_depth.png`` and a labelled ``<view>_grid.png`` (GT | render | depth | error).

    Returns:
        {"mean": {psnr, ssim, lpips, avg, st_lpips, depth_abs_rel, depth_within_5pct,
        depth_coverage}, "per_view": [...], "fps": float, "lpips_note": str | None}.
        ``fps`` is rendering alone (no metrics, no file writing), after one untimed
        warm-up render of the first view.
        A mean is None when a metric is unavailable (no LPIPS package, no GT depth;
        ST-LPIPS is computed only when LPIPS is unavailable and its weights are installed).
    """
    lpips = LPIPSMetric(device=background.device)
    available, reason = lpips.available()
    # ST-LPIPS stands in (under its own name) where LPIPS cannot be computed
    st_lpips = STLPIPSMetric(device=background.device) if not available and STLPIPSMetric.available()[0] else None
    if st_lpips is not None:
        reason += "; ST-LPIPS reported instead (not comparable with papers' LPIPS)"
    per_view = []
    render_time = 0.0
    for i, (camera, batch) in enumerate(track(datamanager.eval_views(), "evaluation", unit="views")):
        moved = {}
        mask = batch.get("mask") if datamanager.scene.masked_metrics else None
        if pose_steps > 0:  # fitted where the metric looks
            given = model.get_outputs(camera, background).rgb.clamp(0, 1)
            refined = refine_pose(model, camera, batch["image"], background, pose_steps, mask=mask)
            deg, shift = pose_differences(*(c.world_to_cam.detach().double().cpu().numpy()[None] for c in (camera, refined)))
            camera, moved = refined, {"pose_refined_deg": float(deg[0]), "pose_refined_shift": float(shift[0]),
                                      "psnr_before_pose_fit": psnr(given, batch["image"], mask=mask)}
        if i == 0:  # untimed: the first render of a process pays torch.compile and allocator warm-up
            model.get_outputs(camera, background)
        t0 = time.perf_counter()
        out = model.get_outputs(camera, background)
        synchronize(background.device)
        render_time += time.perf_counter() - t0
        pred, gt = out.rgb.clamp(0, 1), batch["image"]
        depth = out.expected_depth
        m = evaluate_images(pred, gt, mask=mask, lpips=lpips if available else None, st_lpips=st_lpips)
        m.update(depth_metrics(depth, out.alpha, batch.get("depth")))
        name = camera.name or f"view{batch['index']:03d}"
        per_view.append({"view": name, "index": int(batch["index"]), **m, **moved})
        if render_dir is not None:
            gt8, pred8, depth8 = to_uint8(gt), to_uint8(pred), colorize_depth(depth, out.alpha)
            write_png(render_dir / f"{name}_render.png", pred8)
            write_png(render_dir / f"{name}_gt.png", gt8)
            write_png(render_dir / f"{name}_depth.png", depth8)
            depth_label = "depth" if m["depth_abs_rel"] is None else f"depth rel {m['depth_abs_rel']:.3f}"
            panels = [
                label_panel(gt8.copy(), "GT"),
                label_panel(pred8.copy(), f"render {m['psnr']:.2f}dB"),
                label_panel(depth8.copy(), depth_label),
                label_panel(error_map(pred, gt), "|error|"),
            ]
            write_png(render_dir / f"{name}_grid.png", np.concatenate(panels, axis=1))
    mean = {}
    for key in IMAGE_METRICS:
        vals = [v[key] for v in per_view if v.get(key) is not None]
        mean[key] = float(np.mean(vals)) if vals and len(vals) == len(per_view) else None
    if pose_steps > 0 and per_view:
        mean["psnr_before_pose_fit"] = float(np.mean([v["psnr_before_pose_fit"] for v in per_view]))
    for key in DEPTH_KEYS:
        # views where nothing qualified (no pixel with alpha > 0.5) lower depth_coverage instead
        vals = [v[key] for v in per_view if v.get(key) is not None]
        mean[key] = float(np.mean(vals)) if vals else None
    n = max(len(per_view), 1)
    return {
        "mean": mean,
        "per_view": per_view,
        "fps": n / render_time if render_time > 0 else None,
        "lpips_note": None if available else reason,
    }
