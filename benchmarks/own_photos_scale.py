"""What a folder of one's own photos costs as it grows: the same capture at several photo counts (and
a clip made of its frames), each trained by one ``splat-train METHOD --data FOLDER`` launch to exit
on a fresh photo cache, so that the posing is measured, not read back.

For each count the photos are taken evenly spaced from the capture (in name order, as a camera
numbers them) and copied into a folder of their own; the clip is every frame of the capture, in
order, written as an MP4 (its row is ``clip-N``) and given as ``--data clip.mp4 --photos.frames N``. Each row records:
launch to exit, the posing (pairs matched of all pairs, photos registered, seconds), the prior's
matching (pairs and seconds), training seconds and the step time, Gaussians, and the held-out PSNR
(every 8th photo is held out beyond 8 photos; at 8 or fewer every photo trains and the PSNR is a
training-view one, marked so). The kernels are built before the first timed run, untimed.

Usage:
    python benchmarks/own_photos_scale.py --photos "$SPLAT_DATA/llff/horns/images_8" --counts 8 16 32 \\
        --clip 60 --out runs/scale [--method scgaussian] [--steps N] [-- EXTRA splat-train ARGS]

It writes ``OUT/scale.json`` and ``OUT/scale.md`` (the table, with the machine, its load and the date).

``-- --photos.pairs exhaustive`` poses every row on every pair (the comparison the chosen pairs are
measured against). Matching all of a clip's pairs takes about an hour at 60 frames, so
``--pair-sample N`` estimates it instead: after the clip's row, the learned matcher (its features
of every frame computed first, as in a posing) matches N of the chosen pairs and N pairs drawn at
random from all of them, in alternated batches in one process, and the clip's row gains
``exhaustive_estimate_s``: its posing with its matching scaled to every pair at the sampled rate
(the mapping's own growth with more matches left out, so the estimate is low, not high).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

PHOTO_SUFFIXES = {".png", ".jpg", ".jpeg"}
CLIP_FPS = 10
SPLAT_TRAIN = str(Path(sys.executable).with_name("splat-train"))
"""The splat-train of the Python running this script."""


def loadavg() -> float:
    """The machine's 1-minute load average (nan where /proc is missing)."""
    try:
        return float(Path("/proc/loadavg").read_text().split()[0])
    except OSError:
        return float("nan")


def capture(folder: Path) -> list[Path]:
    """The capture's photos in name order; a folder without any is a one-line exit."""
    photos = sorted(p for p in folder.iterdir() if p.suffix.lower() in PHOTO_SUFFIXES)
    if len(photos) < 2:
        raise SystemExit(f"{folder}: fewer than 2 photos")
    return photos


def evenly(photos: list[Path], n: int) -> list[Path]:
    """``n`` of ``photos`` evenly spaced, the first and last included."""
    if n > len(photos):
        raise SystemExit(f"--counts {n}: the capture has only {len(photos)} photos")
    return [photos[int(k)] for k in np.linspace(0, len(photos) - 1, n).round()]


def write_clip(photos: list[Path], path: Path) -> None:
    """``photos`` as an MP4 of their size, one frame each, at :data:`CLIP_FPS`."""
    import cv2

    first = cv2.imread(str(photos[0]))
    h, w = first.shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), CLIP_FPS, (w, h))
    for p in photos:
        frame = cv2.imread(str(p))
        writer.write(cv2.resize(frame, (w, h)) if frame.shape[:2] != (h, w) else frame)
    writer.release()


def _clock(h: str, m: str, sec: str) -> int:
    return 3600 * int(h) + 60 * int(m) + int(sec)


def parse_log(log: str) -> dict:
    """What the run's log says of its posing and its prior (its phase lines and summaries)."""
    row: dict = {}
    m = re.search(r"(\d+) of (\d+) images registered.*?, ([\d.]+) s \(", log)
    if m:
        n = int(m.group(2))
        row.update(registered=int(m.group(1)), photos_in=n, posing_s=float(m.group(3)), pose_all_pairs=n * (n - 1) // 2)
    m = re.search(r"matching the photos for their poses[^\n]*?(\d+)/(\d+) pairs, done in (\d+):(\d+):(\d+)", log)
    if m:
        row.update(pose_pairs=int(m.group(2)), pose_matching_s=_clock(*m.group(3, 4, 5)))
    m = re.search(r"matching the training views for the prior[^\n]*?(\d+)/(\d+) pairs, done in (\d+):(\d+):(\d+)", log)
    if m:
        row.update(prior_pairs=int(m.group(2)), prior_s=_clock(*m.group(3, 4, 5)))
    m = re.search(r"matching: (\d+) of the (\d+) pairs of training views", log)
    if m:
        row.update(prior_all_pairs=int(m.group(2)))
    return row


def run_one(label: str, data: Path, out: Path, args, env: dict, extra: list[str]) -> dict:
    """One timed ``splat-train`` of ``data`` into ``out/run-LABEL``; its row."""
    cmd = [SPLAT_TRAIN, args.method, "--data", str(data),
           "--output", str(out / f"run-{label}"), *extra]
    if args.steps:
        cmd += ["--steps", str(args.steps)]
    print(f"[{label}] {' '.join(cmd)}", flush=True)
    load = loadavg()
    t0 = time.perf_counter()
    rc, log = _shown_and_kept(cmd, env, out / f"run-{label}.log")
    wall = time.perf_counter() - t0
    row = {"label": label, "rc": rc, "wall_s": round(wall, 1), "load_before": load, **parse_log(log)}
    metrics_file = out / f"run-{label}" / "metrics.json"
    if rc == 0 and metrics_file.is_file():
        m = json.loads(metrics_file.read_text())
        timing, median = m.get("timing", {}), m.get("step_times", {}).get("median_s")
        row.update(
            steps=m.get("steps"), gaussians=m.get("num_gaussians"), psnr=m.get("mean", {}).get("psnr"),
            held_out=any(v.get("split") == "test" for v in m.get("per_view", [])),
            data_s=timing.get("data_s"), matching_s=timing.get("matching_s"), train_s=timing.get("train_s"),
            step_ms=round(1000 * median, 1) if median else None,
        )
    else:
        row["error"] = (log.strip().splitlines() or ["(no output)"])[-1]
    print(f"[{label}] {row}", flush=True)
    return row


def _shown_and_kept(cmd: list[str], env: dict, log: Path) -> tuple[int, str]:
    """Run ``cmd``; its output (stdout and stderr, as they come) is shown here and written to
    ``log``, so a run of minutes is never silent. (exit status, the output)."""
    lines = []
    with subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as proc, \
            log.open("w") as kept:
        for line in proc.stdout:
            lines.append(line)
            kept.write(line)
            print(f"    {line}", end="", flush=True)
    return proc.returncode, "".join(lines)


def sampled_pair_rate(images: list, chosen: list[tuple[int, int]], match, n: int, batch: int = 5,
                      seed: int = 0) -> dict:
    """Seconds a pair of ``match(img_a, img_b)`` on ``n`` of the ``chosen`` pairs and on ``n`` pairs
    drawn uniformly from every pair of ``images``, in alternated batches of ``batch`` (chosen first,
    then random first, ...); the features of every image are computed first, untimed (the pairs
    (i, i + 1)), as a posing computes each photo's once."""
    import random

    every = [(i, j) for i in range(len(images)) for j in range(i + 1, len(images))]
    rng = random.Random(seed)
    samples = {"chosen": rng.sample(chosen, min(n, len(chosen))), "random": rng.sample(every, min(n, len(every)))}
    for i in range(0, len(images) - 1, 2):
        match(images[i], images[i + 1])
    seconds: dict = {"chosen": [], "random": []}
    for k in range(0, n, batch):
        for name in ("chosen", "random") if (k // batch) % 2 == 0 else ("random", "chosen"):
            for a, b in samples[name][k:k + batch]:
                t0 = time.perf_counter()
                match(images[a], images[b])
                seconds[name].append(time.perf_counter() - t0)
    rate = {name: float(np.mean(v)) for name, v in seconds.items()}
    return {"sample": n, "s_per_pair": rate, "random_over_chosen": rate["random"] / rate["chosen"],
            "chosen_pairs": len(chosen), "all_pairs": len(every)}


def exhaustive_estimate(row: dict, rate: dict) -> float:
    """The clip row's posing seconds with its matching of the chosen pairs scaled to every pair at the
    sampled rate (:func:`sampled_pair_rate`)."""
    scale = rate["all_pairs"] * rate["random_over_chosen"] / rate["chosen_pairs"]
    return row["posing_s"] + row["pose_matching_s"] * (scale - 1)


def clip_pair_rate(clip: Path, frames: int, n: int, work: Path) -> dict:
    """:func:`sampled_pair_rate` of ALIKED + LightGlue on the ``frames`` frames a posing of ``clip``
    takes, over the pairs it chooses."""
    import cv2

    from splat_framework.config import match_config
    from splat_framework.matching.registry import MATCHERS
    from splat_framework.sfm.pair_selection import choose_pairs
    from splat_framework.sfm.video import pick_video_frames

    shutil.rmtree(work, ignore_errors=True)
    rgb = [cv2.imread(str(p))[..., ::-1].copy() for p in pick_video_frames(clip, frames, work)]
    shutil.rmtree(work)
    config = match_config("aliked-lightglue", max_matches=0, max_total_matches=0, cache=False)
    matcher = MATCHERS["aliked-lightglue"].from_config(config)
    return sampled_pair_rate(rgb, choose_pairs(rgb, ordered=True), matcher.match, n)


def cell_of(row: dict):
    """A function giving ``row[key]`` formatted, or a dash where it is missing."""
    return lambda key, fmt="{}": fmt.format(row[key]) if row.get(key) is not None else "–"


def table(rows: list[dict]) -> str:
    head = ("| photos | launch to exit (s) | posing (s) | pose pairs | registered | prior pairs | prior (s) "
            "| training (s) | median step (ms) | Gaussians | PSNR |\n|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|")
    lines = [head]
    for row in rows:
        r = {**row, "prior_s": row.get("prior_s", row.get("matching_s")), "posing_s": row.get("posing_s", row.get("data_s"))}
        g = cell_of(r)
        pairs = f"{g('pose_pairs')} of {g('pose_all_pairs')}"
        prior = g("prior_pairs") + (f" of {r['prior_all_pairs']}" if r.get("prior_all_pairs") else "")
        psnr = g("psnr", "{:.2f}") + ("" if r.get("held_out", True) else " (training views)")
        lines.append(f"| {r['label']} | {g('wall_s')} | {g('posing_s', '{:.0f}')} | {pairs} | {g('registered')} of {g('photos_in')} "
                     f"| {prior} | {g('prior_s', '{:.0f}')} | {g('train_s', '{:.0f}')} | {g('step_ms')} | {g('gaussians', '{:,}')} | {psnr} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> list[dict]:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--photos", type=Path, required=True, help="a folder holding the capture's photos")
    p.add_argument("--counts", type=int, nargs="*", default=[8, 16, 32])
    p.add_argument("--clip", type=int, default=0, help="also a clip of every photo, N frames taken from it (0: none)")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--method", default="scgaussian")
    p.add_argument("--steps", type=int, default=None, help="override the method's steps (default: its own)")
    p.add_argument("--pair-sample", type=int, default=0,
                   help="with --clip: estimate the clip's exhaustive posing from N chosen and N random pairs (0: not)")
    args = p.parse_args(argv)
    photos = capture(args.photos)
    args.out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, SPLAT_CACHE=str(args.out / "cache"))
    subprocess.run([SPLAT_TRAIN, "3dgs", "--data", "synthetic/forward-tiny",
                    "--steps", "1", "--output", str(args.out / "kernels"), "--overwrite", "--no-progress"],
                   env=env, capture_output=True, check=True)  # the kernels, untimed
    rows = []
    for n in args.counts:
        folder = args.out / f"photos-{n}"
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir()
        for src in evenly(photos, n):
            shutil.copyfile(src, folder / src.name)
        rows.append(run_one(str(n), folder, args.out, args, env, ["--overwrite", *extra]))
    if args.clip:
        clip = args.out / "clip.mp4"
        write_clip(photos, clip)
        rows.append(run_one(f"clip-{args.clip}", clip, args.out, args, env,
                            ["--photos.frames", str(args.clip), "--overwrite", *extra]))
        if args.pair_sample and "pose_matching_s" in rows[-1]:
            rate = clip_pair_rate(clip, args.clip, args.pair_sample, args.out / "frames")
            rows[-1].update(pair_rate=rate, exhaustive_estimate_s=round(exhaustive_estimate(rows[-1], rate), 1))
            print(f"[clip-{args.clip}] exhaustive posing estimated at {rows[-1]['exhaustive_estimate_s']} s "
                  f"(random pairs {rate['random_over_chosen']:.2f}x the chosen pairs' time each)", flush=True)
    stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    note = (f"{stamp}, {os.cpu_count()} cores, load before each run: "
            + ", ".join(f"{r['load_before']:.1f}" for r in rows) + f"; `{args.method}`" + (f" {' '.join(extra)}" if extra else ""))
    (args.out / "scale.json").write_text(json.dumps({"note": note, "rows": rows}, indent=1))
    (args.out / "scale.md").write_text(f"{note}\n\n{table(rows)}\n")
    print(f"\n{note}\n\n{table(rows)}")
    return rows


if __name__ == "__main__":
    sys.exit(0 if all(r.get("rc") == 0 for r in main()) else 1)
