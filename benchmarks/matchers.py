"""Matching prior per matcher: verified matches per pair and matching time on CPU.

The first half of the paper's "robustness to matching models" table: for each
scene and each matcher (``dense``, ``sift``, ``disk-lightglue``,
``aliked-lightglue``; each also a config variant ``scgaussian-<matcher>`` whose
PSNR/SSIM come from ``benchmarks/ablation.py --methods scgaussian-<matcher>``),
the matches that survive MAGSAC and the known-pose epipolar check between every
pair of the few-shot training views, and the wall time of matching (uncached,
networks built once per scene and matcher, features detected once per view).

Usage:
    SPLAT_DATA=../shared/data python benchmarks/matchers.py \\
        --data llff/fern:3 blender/lego:8 dtu/scan37:3 [--matchers dense sift ...] \\
        [--threads 2] [--json docs/measurements/matchers.json] [--readme README.md]
    python benchmarks/matchers.py --data dtu/scan37:3 --json /tmp/m.json \\
        --matchers aliked-lightglue:learned_resize=0,max_keypoints=4096 aliked-lightglue

``--readme`` replaces the block between ``<!-- ablation:KEY -->`` and
``<!-- /ablation:KEY -->`` (``--key``, default ``matchers``; the README's table
of the default ``auto`` uses ``--key matchers-auto``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

MATCHER_ROWS = ["dense", "sift", "disk-lightglue", "aliked-lightglue"]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", nargs="+", default=["llff/fern:3", "blender/lego:8", "dtu/scan37:3"],
                   help="SCENE:VIEWS entries (as splat-train --data / --views)")
    p.add_argument("--matchers", nargs="+", default=MATCHER_ROWS,
                   help="matcher names, each optionally with fields of its config: NAME[:key=value,...]")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: all cores)")
    p.add_argument("--json", type=Path, default=Path("docs/measurements/matchers.json"))
    p.add_argument("--readme", type=Path, default=None, help="splice the table into this file's matcher markers")
    p.add_argument("--key", default="matchers", help="README marker key: <!-- ablation:KEY --> ... <!-- /ablation:KEY -->")
    return p.parse_args(argv)


def training_views(data: str, views: int):
    """(images float32 [H, W, 3], cameras, dataset ids, alpha masks or None) of the few-shot training views,
    as training sees them."""
    from splat_framework.data.images import load_alpha, load_image
    from splat_framework.data.parsers import load_scene
    from splat_framework.sfm import resolve_data_path

    scene = load_scene(resolve_data_path(data), views=views)
    ids = [int(i) for i in scene.train_indices]
    imgs = [load_image(scene.image_paths[i], scale=scene.image_scale, white_background=scene.white_background)
            for i in ids]
    masks = [load_alpha(scene.image_paths[i], scale=scene.image_scale) for i in ids]
    return imgs, [scene.cameras[i] for i in ids], ids, masks


def match_config(spec: str):
    """``NAME[:key=value,...]`` -> the matcher NAME's config, e.g. ``aliked-lightglue:learned_resize=0,max_keypoints=4096``."""
    from splat_framework.config import match_config as config_of

    name, _, rest = spec.partition(":")
    fields = dict(kv.split("=", 1) for kv in rest.split(",") if kv)
    return config_of(name, cache=False, **fields)


def measure(data: str, views: int, matcher: str) -> dict:
    from splat_framework.matching import compute_matches

    imgs, cams, ids, masks = training_views(data, views)
    config = match_config(matcher)
    t0 = time.perf_counter()
    ms = compute_matches(imgs, cams, ids, config, masks=masks)
    seconds = time.perf_counter() - t0
    per_pair = {f"{a}-{b}": int(c["final"]) for (a, b), c in ms.stats.items()}
    return {"data": data, "views": views, "matcher": matcher, "seconds": seconds, "total": ms.total(),
            "per_pair": per_pair, "raw": {f"{a}-{b}": int(c["raw"]) for (a, b), c in ms.stats.items()}}


def markdown(records: list[dict], command: str) -> str:
    lines = [
        "| Scene | Matcher | Pairs with matches | Verified per pair (min / median / max) | Total | Time (s) |",
        "|---|---|--:|--:|--:|--:|",
    ]
    for r in records:
        counts = list(r["per_pair"].values())
        spread = f"{min(counts):,} / {statistics.median(counts):,.0f} / {max(counts):,}"
        matched = sum(c > 0 for c in counts)
        lines.append(f"| `{r['data']}` ({r['views']} views) | `{r['matcher']}` | {matched} of {len(counts)} | "
                     f"{spread} | {r['total']:,} | {r['seconds']:.1f} |")
    from ablation import footer

    return "\n".join(lines + footer(command, records[0].get("threads") if records else None))


def main(argv: list[str] | None = None) -> Path:
    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from ablation import publish

    args = parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    records = []
    for entry in args.data:
        data, _, views = entry.partition(":")
        for matcher in args.matchers:
            rec = measure(data, int(views or 3), matcher)
            rec["threads"] = torch.get_num_threads()
            records.append(rec)
            print(f"{data} {matcher}: {rec['total']} matches {rec['per_pair']} in {rec['seconds']:.1f} s", flush=True)
    command = "python benchmarks/matchers.py " + " ".join(sys.argv[1:] if argv is None else argv)
    publish(args.json, records, markdown(records, command), args.readme, args.key)
    return args.json


if __name__ == "__main__":
    main()
