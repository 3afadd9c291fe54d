"""Evaluate a model on the held-out views: metrics, render FPS, and the pictures of each view."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..cameras import pose_differences
from ..console import track
from ..runtime.profiling import synchronize
from .metrics import DEPTH_KEYS, IMAGE_METRICS, STLPIPSMetric, depth_metrics, evaluate_images, lpips_metrics, psnr
from .pictures import colorize_depth, error_map, label_panel, to_uint8, write_png
from .pose_refine import refine_pose


def scored_views(datamanager) -> tuple[list, str]:
    """The views that are scored and pictured, and their split: the held-out views ("test", or "val"
    for a run scored on its validation views), or, where nothing is held out (a few photos of one's
    own, all trained on), the training views ("train")."""
    views = datamanager.eval_views()
    return (views, datamanager.scene.held_out) if views else (datamanager.train_views(), "train")


def view_name(datamanager, camera, index: int) -> str:
    """The name a view's metrics and pictures go by: its image's name (the camera's, else the file stem)."""
    return camera.name or Path(datamanager.scene.image_paths[index]).stem


@torch.no_grad()
def evaluate(model, datamanager, background: Tensor, render_dir: Path | None = None, pose_steps: int = 0) -> dict:
    """Render every test view and compute PSNR, SSIM, LPIPS with VGG and AlexNet (when available),
    AVG and ST-LPIPS (when its weights are installed), plus the depth error when the dataset has
    ground-truth depth (see :func:`depth_metrics`).

    With ``pose_steps`` > 0, each test camera's pose is first fitted to its photo by that many
    steps of :func:`splat_framework.evaluation.pose_refine.refine_pose` (the protocol of pose-free methods;
    for poses estimated from the training photos alone); per view, ``pose_refined_deg`` and
    ``pose_refined_shift`` record how far it moved and ``psnr_before_pose_fit`` the PSNR at the
    pose as given (also averaged in ``mean``).

    A scene with no held-out view (a few photos of one's own, all trained on) is scored on its
    training views instead, each per-view entry saying ``"split": "train"`` ("test", or "val" on a
    run scored on its validation views, otherwise).

    With ``render_dir``, writes per view ``<view>_render.png``, ``<view>_gt.png``,
    ``<view>_depth.png`` and a labelled ``<view>_grid.png`` (GT | render | depth | error);
    ``<view>`` is the image's name (its file stem).

    Returns:
        {"mean": {psnr, ssim, lpips, lpips_alex, avg, st_lpips, depth_abs_rel, depth_within_5pct,
        depth_coverage}, "per_view": [{"view": image name, "index", "split", metrics...}],
        "fps": float, "lpips_note": str | None (one line: why an LPIPS metric is missing)}.
        ``fps`` is rendering alone (no metrics, no file writing), after one untimed
        warm-up render of the first view.
        A mean is None when a metric is unavailable (no LPIPS package or weights, no GT depth,
        no ST-LPIPS weights).
    """
    lpips, lpips_note = lpips_metrics(background.device)
    st_lpips = STLPIPSMetric(device=background.device) if STLPIPSMetric.available()[0] else None
    per_view = []
    render_time = 0.0
    views, split = scored_views(datamanager)
    for i, (camera, batch) in enumerate(track(views, "evaluation", unit="views")):
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
        m = evaluate_images(pred, gt, mask=mask, lpips=lpips, st_lpips=st_lpips)
        m.update(depth_metrics(depth, out.alpha, batch.get("depth")))
        name = view_name(datamanager, camera, batch["index"])
        per_view.append({"view": name, "index": int(batch["index"]), "split": split, **m, **moved})
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
        "lpips_note": lpips_note,
    }
