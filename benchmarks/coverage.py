"""Where a trained run's test error is: pixels some training view sees against pixels none sees,
and how sharp the render is against the photo.

    python benchmarks/coverage.py RUN [RUN ...] [--tolerance 0.05] [--json PATH]

A test pixel is *covered* when the point its rendered depth puts it at projects inside some
training view, in front of it, and agrees with that view's own rendered depth there within
``--tolerance`` (relative): some training photo saw that surface. For each run the script
prints, averaged over the test views, PSNR and SSIM (kornia, 11-pixel window) over the covered
pixels, the uncovered ones and all of them, the covered share, and the *sharpness*: the mean
squared Laplacian of the render's grey image over the covered pixels divided by the photo's (1 = as
sharp as the photo; below 1, softer). On scenes scored with masks (DTU) every number is taken
inside the object mask; on objects against white (Blender) inside the pixels where the render or
the photo shows the object. A diagnostic: it reads the run's newest checkpoint and changes nothing.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch
from torch import Tensor


def covered_pixels(test_camera, depth: Tensor, training: list[tuple[object, Tensor]], tolerance: float) -> Tensor:
    """[H, W] bool: the test pixels whose rendered-depth point some training view sees.

    depth: [H, W] the test view's rendered camera depth (0 where nothing was rendered);
    training: (camera, its rendered depth [h, w]) per training view."""
    height, width = depth.shape
    v, u = torch.meshgrid(torch.arange(height, device=depth.device), torch.arange(width, device=depth.device),
                          indexing="ij")
    points = test_camera.unproject_depth(torch.stack([u, v], -1).to(depth) + 0.5, depth)
    covered = torch.zeros(height, width, dtype=torch.bool, device=depth.device)
    for camera, seen in training:
        uv, z = camera.project(points)
        iu, iv = uv[..., 0].floor().long(), uv[..., 1].floor().long()
        inside = (z > 0) & (iu >= 0) & (iu < camera.width) & (iv >= 0) & (iv < camera.height) & (depth > 0)
        there = seen[iv.clamp(0, camera.height - 1), iu.clamp(0, camera.width - 1)]
        covered |= inside & ((z - there).abs() <= tolerance * there.abs().clamp_min(1e-6))
    return covered


def sharpness(render: Tensor, photo: Tensor, where: Tensor) -> float:
    """Mean squared Laplacian of ``render``'s grey image over ``where`` [H, W] divided by the
    photo's (images [H, W, 3] in [0, 1]); nan where ``where`` is empty or the photo is flat."""
    import kornia

    def energy(image: Tensor) -> Tensor:
        grey = image.mean(-1)[None, None]
        return kornia.filters.laplacian(grey, 3)[0, 0].square()

    photo_energy = energy(photo)[where].mean()
    return float(energy(render)[where].mean() / photo_energy) if where.any() and photo_energy > 0 else float("nan")


def split_scores(render: Tensor, photo: Tensor, covered: Tensor, mask: Tensor | None = None) -> dict:
    """PSNR / SSIM / share over the covered, uncovered and all pixels (inside ``mask`` when given),
    and the covered pixels' sharpness."""
    import kornia

    inside = torch.ones_like(covered) if mask is None else mask.reshape(covered.shape) > 0.5
    error = (render - photo).square().mean(-1)
    ssim = kornia.metrics.ssim(render.permute(2, 0, 1)[None], photo.permute(2, 0, 1)[None], 11)[0].mean(0)
    scores = {}
    for name, where in (("covered", covered & inside), ("uncovered", ~covered & inside), ("all", inside)):
        scores[name] = {"psnr": float(-10 * torch.log10(error[where].mean())) if where.any() else float("nan"),
                        "ssim": float(ssim[where].mean()) if where.any() else float("nan"),
                        "share": float(where.sum() / inside.sum())}
    scores["sharpness"] = sharpness(render, photo, covered & inside)
    return scores


def run_scores(run: Path, tolerance: float) -> dict:
    """The test views' :func:`split_scores` of one run folder, and their mean."""
    from splat_framework.engine.run import load_run
    from splat_framework.pipeline.scene import background_for

    config, datamanager, model = load_run(run)
    background = background_for(datamanager.scene, config.device)
    masked = datamanager.scene.masked_metrics
    views = []
    with torch.no_grad():
        training = [(camera, model.get_outputs(camera, background).depth[..., 0]) for camera, _ in datamanager.train_views()]
        for camera, batch in datamanager.eval_views():
            out = model.get_outputs(camera, background)
            covered = covered_pixels(camera, out.depth[..., 0], training, tolerance)
            mask = batch.get("mask") if masked else None
            if datamanager.scene.white_background:  # an object on white: the object's pixels, rendered or photographed
                mask = (out.alpha[..., 0] > 0.5) | (batch["image"] < 0.99).any(-1)
            views.append(split_scores(out.rgb.clamp(0, 1), batch["image"], covered, mask))
    mean = {name: {key: sum(v[name][key] for v in views) / len(views) for key in views[0][name]}
            for name in ("covered", "uncovered", "all")}
    mean["sharpness"] = sum(v["sharpness"] for v in views) / len(views)
    return {"run": str(run), "scene": config.data, "method": config.method, "views": views, "mean": mean}


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--tolerance", type=float, default=0.05, help="relative depth agreement (default 0.05)")
    parser.add_argument("--json", type=Path, help="write every view's numbers here")
    args = parser.parse_args(argv)
    results = [run_scores(run, args.tolerance) for run in args.runs]
    print("| run | scene | covered share | covered PSNR / SSIM | uncovered PSNR / SSIM | all PSNR / SSIM | sharpness |")
    print("|---|---|--:|--:|--:|--:|--:|")
    for r in results:
        m = r["mean"]
        print(f"| {Path(r['run']).name} | {r['scene']} | {m['covered']['share']:.0%} | "
              f"{m['covered']['psnr']:.2f} / {m['covered']['ssim']:.3f} | {m['uncovered']['psnr']:.2f} / "
              f"{m['uncovered']['ssim']:.3f} | {m['all']['psnr']:.2f} / {m['all']['ssim']:.3f} | {m['sharpness']:.2f} |")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return results


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
