"""How well the posing's chosen pairs (``sfm.pair_selection``) find the photos that overlap, on
scenes with known poses: for each photo its true nearest photos (the smallest angles between the
cameras' viewing directions), and how many of those the chosen pairs hold (recall), with the pair
count and whether the chosen pairs connect every photo; for several neighbour counts k.

Usage:
    python benchmarks/pair_selection.py --data blender/lego llff/fern --photos 24 [--k 3 5 8] [--true 3]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", nargs="+", default=["blender/lego"])
    p.add_argument("--photos", type=int, default=24, help="photos taken from the scene's training views, evenly spaced")
    p.add_argument("--k", type=int, nargs="+", default=[3, 5, 8])
    p.add_argument("--true", type=int, default=3, help="true neighbours per photo (smallest viewing-direction angles)")
    args = p.parse_args(argv)
    from splat_framework.data import load_scene
    from splat_framework.data.images import load_image
    from splat_framework.data.resolve import locate_data
    from splat_framework.sfm.pair_selection import linked_groups, pairs_from_similarity, word_histograms

    out = []
    for data in args.data:
        scene = load_scene(locate_data(data), views="all")
        picks = np.linspace(0, len(scene.train_indices) - 1, args.photos).round().astype(int)
        idx = [int(scene.train_indices[k]) for k in picks]
        images = [(np.clip(load_image(scene.image_paths[i], white_background=scene.white_background), 0, 1) * 255).astype(np.uint8)
                  for i in idx]
        dirs = np.stack([scene.cameras[i].cam_to_world[:3, 2].cpu().numpy() for i in idx])
        angles = np.degrees(np.arccos(np.clip(dirs @ dirs.T, -1, 1)))
        np.fill_diagonal(angles, np.inf)
        truth = {(min(i, j), max(i, j)) for i in range(len(idx)) for j in np.argsort(angles[i])[: args.true]}
        t0 = time.perf_counter()
        hist = word_histograms(images)
        seconds = time.perf_counter() - t0
        for k in args.k:
            pairs = pairs_from_similarity(hist @ hist.T, neighbours=k)
            row = {"data": data, "photos": len(idx), "k": k, "pairs": len(pairs), "all_pairs": len(idx) * (len(idx) - 1) // 2,
                   "recall": len(truth & set(pairs)) / len(truth), "connected": len(linked_groups(list(range(len(idx))), pairs)) == 1,
                   "similarity_s": round(seconds, 2)}
            out.append(row)
            print(row, flush=True)
    return out


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
