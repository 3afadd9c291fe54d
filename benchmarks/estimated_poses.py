"""Few-shot training on poses estimated from the training photos alone, against the dataset's poses.

LLFF's poses come from COLMAP on all 20 photos of a scene; a user with 3 photos has only
those. For an LLFF scene, this script runs :func:`splat_framework.sfm.estimate_scene` on
the K training views alone (the photos as stored at the training resolution; camera model
SIMPLE_PINHOLE, so that the photos need no undistortion; by default the largest stored
photos, ``--sfm-downscale``), aligns the
estimated cameras to the dataset's training cameras with the similarity (Sim(3)) that best
maps their centres onto the dataset's (pycolmap.estimate_sim3d: Umeyama), and writes a copy
of the scene (images linked, ``poses_bounds.npy`` rewritten) whose training views carry
the aligned estimated poses and focal length while the test views keep the dataset's poses:
the usual protocol of pose-free methods, which evaluate the test views in the training
cameras' aligned frame. It then trains each method on the dataset's scene and on the
estimated one, for each seed, and tabulates test PSNR / SSIM and the pose errors
(rotation after alignment, relative translation direction between pairs of views).
Each run is scored twice: with the test poses as they are, and with each test camera's
pose first fitted to its photo with the model frozen (``--test-pose-steps``, the test-time
photometric pose optimisation of BARF, NoPe-NeRF and CF-3DGS), which separates image
quality from the misregistration of the test cameras.

Usage:
    SPLAT_DATA=../shared/data python benchmarks/estimated_poses.py --data llff/fern --views 3 \\
        --methods scgaussian --seeds 0 1 2 --out /tmp/estimated --json benchmarks/results/estimated_poses.json
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np


def pose_errors(est_w2c: np.ndarray, true_w2c: np.ndarray) -> dict:
    """Rotation errors after Sim(3) alignment and relative translation-direction errors (degrees)."""
    from splat_framework.sfm import camera_centers, sim3_errors

    rot, center = sim3_errors(est_w2c, true_w2c)

    def direction(w2c, i, j):  # where camera j lies, seen from camera i
        c = camera_centers(w2c)
        t = w2c[i, :3, :3] @ (c[j] - c[i])
        return t / np.linalg.norm(t)

    dirs = [float(np.degrees(np.arccos(np.clip(direction(est_w2c, i, j) @ direction(true_w2c, i, j), -1, 1))))
            for i, j in itertools.permutations(range(len(est_w2c)), 2)]
    true_c = camera_centers(true_w2c)
    spread = np.linalg.norm(true_c.max(0) - true_c.min(0))
    return {"rotation_deg": rot.tolist(), "translation_direction_deg": dirs,
            "center_error_rel_spread": (center / spread).tolist()}


def estimated_scene(data: str, views: int, out: Path, sfm_downscale: float | None,
                    matcher: str = "sift") -> tuple[Path, dict]:
    """Write the LLFF or DTU scene with the training views' poses estimated from those views alone
    (photos at ``sfm_downscale``, None: the training resolution)."""
    from splat_framework.data import load_scene
    from splat_framework.data.parsers.colmap import load_colmap
    from splat_framework.data.resolve import resolve_data_path
    from splat_framework.sfm import align_sim3, estimate_scene

    root = resolve_data_path(data)
    scene = load_scene(root, views=views)
    if scene.format not in ("llff", "dtu"):
        raise SystemExit(f"{data}: only LLFF and DTU scenes are supported (their camera files are rewritten)")
    train = list(scene.train_indices)
    photos_of = load_scene(root, views=views, downscale=sfm_downscale) if sfm_downscale else scene
    photos = [Path(photos_of.image_paths[i]) for i in train]
    summary = estimate_scene(photos, out / "sfm", overwrite=True, camera_model="SIMPLE_PINHOLE", matcher=matcher)
    if len(summary.registered) < len(photos):
        raise SystemExit(f"{data}: {len(summary.registered)} of {len(photos)} training views registered")
    est = load_colmap(out / "sfm")
    by_name = {Path(p).stem: c for p, c in zip(est.image_paths, est.cameras)}
    est_cams = [by_name[p.stem] for p in photos]
    est_w2c = np.stack([c.world_to_cam.double().numpy() for c in est_cams])
    true_w2c = np.stack([scene.cameras[i].world_to_cam.double().numpy() for i in train])
    errors = pose_errors(est_w2c, true_w2c)

    aligned = align_sim3(est_w2c, true_w2c)  # the estimated cameras in the dataset's frame
    dst = out / "scene"
    dst.mkdir(parents=True, exist_ok=True)
    camera_file = "poses_bounds.npy" if scene.format == "llff" else "cameras_sphere.npz"
    for entry in root.iterdir():  # image folders linked, poses rewritten
        link = dst / entry.name
        if entry.name != camera_file and not link.exists():
            os.symlink(entry.resolve(), link)
    if scene.format == "dtu":
        write_dtu_cameras(root / camera_file, dst / camera_file, train, aligned, est_cams)
    else:
        write_llff_poses(root / camera_file, dst / camera_file, train, aligned, est_cams)
    focal_true = float(scene.cameras[train[0]].K[0, 0])
    info = {"registered": len(summary.registered), "views": len(photos), "points": summary.points,
            "reprojection_px": summary.reprojection_px, "sfm_seconds": summary.seconds, "matcher": matcher,
            "focal_estimated": [float(c.K[0, 0]) * scene.cameras[i].width / c.width for c, i in zip(est_cams, train)],
            "focal_dataset": focal_true, **errors}  # focal lengths in pixels of the training resolution
    return dst, info


def write_dtu_cameras(src: Path, dst: Path, train: list[int], aligned: np.ndarray, est_cams) -> None:
    """A copy of DTU's cameras_sphere.npz whose training views' world_mat is the aligned estimate
    (intrinsics at the original 1600x1200, as the file stores them; the parser's inverse)."""
    from splat_framework.data.parsers.dtu import FULL_H, FULL_W

    cams = dict(np.load(src))
    for k, i in enumerate(train):
        c = est_cams[k]
        sx, sy = c.width / FULL_W, c.height / FULL_H
        fx, fy, cx, cy = (float(c.K[0, 0]), float(c.K[1, 1]), float(c.K[0, 2]), float(c.K[1, 2]))
        K_full = np.array([[fx / sx, 0, cx / sx - 0.5], [0, fy / sy, cy / sy - 0.5], [0, 0, 1]])
        P = np.eye(4)
        P[:3, :4] = K_full @ aligned[k, :3, :4]  # the normalised frame (after scale_mat)
        cams[f"world_mat_{i}"] = P @ np.linalg.inv(cams.get(f"scale_mat_{i}", np.eye(4)))
    np.savez(dst, **cams)


def write_llff_poses(src: Path, dst: Path, train: list[int], aligned: np.ndarray, est_cams) -> None:
    """A copy of LLFF's poses_bounds.npy whose training views carry the aligned estimated poses and focal."""
    from splat_framework.sfm import camera_centers

    pb = np.load(src)
    for k, i in enumerate(train):
        c2w_cv = aligned[k, :3, :3].T  # camera-to-world rotation, OpenCV axes
        center = camera_centers(aligned[k : k + 1])[0]
        pose = pb[i, :15].reshape(3, 5).copy()
        w_full = pose[1, 4]  # LLFF hwf: height, width, focal at full resolution
        llff_rot = np.stack([c2w_cv[:, 1], c2w_cv[:, 0], -c2w_cv[:, 2]], axis=1)  # inverse of the parser's mapping
        pose[:, :3] = llff_rot
        pose[:, 3] = center
        pose[2, 4] = float(est_cams[k].K[0, 0]) * w_full / est_cams[k].width
        pb[i, :15] = pose.reshape(-1)
    np.save(dst, pb)


def train(method: str, data: Path | str, views: int, seed: int, steps: int | None, out: Path,
          pose_steps: int = 0) -> dict:
    """Train one run (skipped when its metrics exist); with ``pose_steps``, also score it with the
    test poses refined (``splat-eval --test-pose-steps``; the unrefined metrics are kept beside)."""
    run = out / f"{method}-s{seed}"
    cmd = [sys.executable, "-m", "splat_framework.cli.train", method, "--data", str(data), "--views", str(views),
           "--seed", str(seed), "--output", str(run), "--overwrite"] + (["--steps", str(steps)] if steps else [])
    if not (run / "metrics.json").is_file():
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    unrefined = run / "metrics-unrefined.json"
    if not unrefined.is_file():
        unrefined.write_bytes((run / "metrics.json").read_bytes())
    m = json.loads(unrefined.read_text())
    r = {"psnr": m["mean"]["psnr"], "ssim": m["mean"]["ssim"]}
    if pose_steps > 0:
        if json.loads((run / "metrics.json").read_text()).get("test_pose_steps") != pose_steps:
            subprocess.run([sys.executable, "-m", "splat_framework.cli.eval", str(run), "--no-renders",
                            "--test-pose-steps", str(pose_steps)], check=True, stdout=subprocess.DEVNULL)
        refined = json.loads((run / "metrics.json").read_text())
        r.update(psnr_refined=refined["mean"]["psnr"], ssim_refined=refined["mean"]["ssim"],
                 test_pose_moved_deg=[v["pose_refined_deg"] for v in refined["per_view"]])
    return r


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default="llff/fern")
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--methods", nargs="+", default=["scgaussian"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--steps", type=int, default=None, help="iterations (default: each method's own)")
    ap.add_argument("--poses", nargs="+", choices=["dataset", "estimated"], default=["dataset", "estimated"])
    ap.add_argument("--sfm-downscale", type=float, default=4.0,
                    help="photos given to SfM: LLFF's images_F folder (fern ships images_4 and images_8; "
                         "more pixels, more SIFT points); 0 = the training resolution")
    ap.add_argument("--test-pose-steps", type=int, default=200,
                    help="also score every run with each test camera's pose fitted to its photo by this many "
                         "steps, the model frozen (splat-eval --test-pose-steps; 0 = off)")
    ap.add_argument("--matcher", default="sift",
                    help="correspondences of the SfM (splat-process --matcher; the recorded results used sift)")
    ap.add_argument("--out", type=Path, default=Path("outputs/estimated-poses"))
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    scene, info = estimated_scene(args.data, args.views, args.out, args.sfm_downscale or None, args.matcher)
    print(json.dumps({k: v for k, v in info.items()}, indent=1))
    results = []
    for method, poses, seed in itertools.product(args.methods, args.poses, args.seeds):
        data = scene if poses == "estimated" else args.data
        r = train(method, data, args.views, seed, args.steps, args.out / poses, args.test_pose_steps)
        results.append({"method": method, "poses": poses, "seed": seed, **r})
        refined = f", test poses refined: PSNR {r['psnr_refined']:.2f} SSIM {r['ssim_refined']:.3f}" if "psnr_refined" in r else ""
        print(f"{method} {poses} seed {seed}: PSNR {r['psnr']:.2f} SSIM {r['ssim']:.3f}{refined}", flush=True)
    payload = {"data": args.data, "views": args.views, "sfm": info, "runs": results}
    if args.json is not None:
        args.json.write_text(json.dumps(payload, indent=1))
    return payload


if __name__ == "__main__":
    main()
