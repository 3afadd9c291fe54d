"""``splat-render RUN_DIR``: render test views, or a spiral/orbit video of novel views."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Literal


@dataclass
class RenderArgs:
    run_dir: Path
    """Run folder written by splat-train."""
    path: Literal["test", "spiral", "orbit", "auto"] = "test"
    """What to render: the test views (PNGs), or a camera path video (auto: spiral for forward-facing scenes, orbit for object scenes)."""
    frames: int = 120
    """Frames of the camera path."""
    fps: int = 30
    """Video frame rate."""
    out: Path | None = None
    """Output folder for PNGs or the video file (default RUN_DIR/renders or RUN_DIR/video.mp4)."""
    depth: bool = False
    """Also write a depth video (colour-mapped) next to the RGB one."""
    device: str | None = None
    """Torch device (default: the run's)."""


def main(args: RenderArgs) -> Path:
    import torch
    from rich.progress import track

    from ..camera_paths import orbit_path, spiral_path
    from ..evaluation import colorize_depth, to_uint8, write_png
    from ..run import background_for, load_run

    config, dm, model = load_run(args.run_dir, args.device)
    bg = background_for(dm.scene, config.device)
    if args.path == "test":
        out = args.out or args.run_dir / "renders"
        with torch.no_grad():
            for cam, batch in track(dm.eval_views(), description="rendering test views"):
                o = model.get_outputs(cam, bg)
                write_png(out / f"{cam.name or batch['index']}_render.png", to_uint8(o.rgb))
                write_png(out / f"{cam.name or batch['index']}_depth.png", colorize_depth(o.depth, o.alpha))
        print(f"wrote {len(dm.eval_views())} views to {out}")
        return out
    kind = args.path
    if kind == "auto":
        kind = "orbit" if dm.scene.format in ("blender", "dtu") else "spiral"
    train_cams = [c for c, _ in dm.train_views()] + [c for c, _ in dm.eval_views()]
    cams = spiral_path(train_cams, args.frames) if kind == "spiral" else orbit_path(train_cams, dm.scene.scene_center, args.frames)
    out = args.out or args.run_dir / f"{kind}.mp4"
    return write_video(model, cams, bg, out, args.fps, args.depth)


def write_video(model, cams, bg, out: Path, fps: int, depth: bool) -> Path:
    """Render ``cams`` and encode an mp4 (and optionally ``<out>_depth.mp4``), atomically."""
    import os

    import cv2
    import torch
    from rich.progress import track

    from ..evaluation import colorize_depth, to_uint8

    out.parent.mkdir(parents=True, exist_ok=True)
    w, h = cams[0].width, cams[0].height
    targets = [out] + ([out.with_name(out.stem + "_depth.mp4")] if depth else [])
    tmps = [t.with_name("." + t.name + ".tmp.mp4") for t in targets]
    writers = [cv2.VideoWriter(str(t), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h)) for t in tmps]
    if not all(wr.isOpened() for wr in writers):
        raise RuntimeError(f"{out}: OpenCV cannot open an mp4 writer")
    with torch.no_grad():
        for cam in track(cams, description=f"rendering {out.name}"):
            o = model.get_outputs(cam.to(bg.device), bg)
            writers[0].write(to_uint8(o.rgb)[..., ::-1].copy())
            if depth:
                writers[1].write(colorize_depth(o.depth, o.alpha)[..., ::-1].copy())
    for wr, tmp, target in zip(writers, tmps, targets):
        wr.release()
        os.replace(tmp, target)
        print(f"wrote {target}")
    return out


def entrypoint() -> None:
    import tyro

    from .common import run_cli

    args = tyro.cli(RenderArgs, args=sys.argv[1:], prog="splat-render")
    run_cli(lambda: main(args))


if __name__ == "__main__":
    entrypoint()
