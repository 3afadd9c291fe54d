"""Full-run benchmark: train methods on a scene and record quality and wall time per phase.

    python benchmarks/full_run.py --data llff/fern --views 3 --methods scgaussian 3dgs \
        --out runs/fern-full

Each method trains with its default schedule (or --steps) in its own run folder;
the script writes ``<out>/full_run.json`` and ``<out>/full_run.md`` with test
PSNR/SSIM/LPIPS, Gaussian count, iterations and seconds per phase (data,
matching, warm-up, training, evaluation, total), plus the machine it ran on.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path


def machine() -> str:
    import os

    import torch

    cpu = platform.processor() or "cpu"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, torch {torch.__version__}, {torch.get_num_threads()} threads"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default="llff/fern")
    ap.add_argument("--views", default="3")
    ap.add_argument("--methods", nargs="+", default=["scgaussian", "3dgs"])
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--downscale", type=float, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("runs/full-run"))
    args = ap.parse_args()

    from splat_framework.engine.trainer import train
    from splat_framework.registry import get_method

    rows = []
    for method in args.methods:
        views = "all" if args.views == "all" else int(args.views)
        cfg = get_method(method).default_config().model_copy(
            update=dict(data=args.data, views=views, steps=args.steps, downscale=args.downscale, seed=args.seed,
                        output=args.out / "runs" / method, overwrite=True)
        )
        t0 = time.perf_counter()
        m = train(cfg)
        rows.append({"method": method, "wall_s": time.perf_counter() - t0, **{k: m[k] for k in ("mean", "timing", "num_gaussians", "steps", "render_fps")},
                     "init_stats": m.get("init_stats", {}), "model_report": m.get("model_report", {})})
    result = {"data": args.data, "views": args.views, "machine": machine(), "runs": rows}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "full_run.json").write_text(json.dumps(result, indent=2))
    fmt = lambda v, p=2: "n/a" if v is None else f"{v:.{p}f}"  # noqa: E731
    lines = [
        f"Scene `{args.data}`, {args.views} views; machine: {result['machine']}",
        "",
        "| method | PSNR | SSIM | LPIPS | ST-LPIPS | Gaussians | iters | matching s | warm-up s | training s | eval s | total s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        t, mean = r["timing"], r["mean"]
        lines.append(
            f"| {r['method']} | {fmt(mean['psnr'])} | {fmt(mean['ssim'], 3)} | {fmt(mean['lpips'], 3)} | {fmt(mean.get('st_lpips'), 3)} | {r['num_gaussians']} | {r['steps']} "
            f"| {fmt(t.get('matching_s'), 1)} | {fmt(t.get('warmup_s'), 1)} | {fmt(t.get('train_s'), 1)} | {fmt(t.get('eval_s'), 1)} | {fmt(t.get('total_s'), 1)} |"
        )
    (args.out / "full_run.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
