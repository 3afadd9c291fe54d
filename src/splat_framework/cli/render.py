"""``splat-render RUN_DIR``: render test views, or a spiral/orbit video of novel views."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

from tyro.conf import Positional, arg


@dataclass
class RenderArgs:
    run_dir: Annotated[Positional[Path], arg(metavar="RUN_DIR")]
    """Run folder written by splat-train."""
    path: Literal["test", "spiral", "orbit", "auto"] = "test"
    """What to render: the test views (PNGs), or a camera path video (auto: spiral for forward-facing scenes, orbit for object scenes)."""
    frames: int = 120
    """Frames of the camera path."""
    fps: int = 30
    """Video frame rate."""
    out: Path | None = None
    """Output folder for PNGs, or the video file (default RUN_DIR/renders, or RUN_DIR/<spiral|orbit>.mp4). A new path, or one splat-render wrote (with --overwrite)."""
    overwrite: bool = False
    """Replace --out when splat-render wrote it (the defaults inside RUN_DIR are always replaced); only its own PNGs are removed from a folder."""
    depth: bool = False
    """Also write a colour-mapped depth video next to the RGB one (<out>_depth.mp4)."""
    device: str | None = None
    """Torch device (default: the run's)."""
    trust_edited_config: bool = False
    """Use the run's config.json even when its checksum is missing or does not match (edited by hand)."""


def camera_path(kind: str, dm, frames: int) -> tuple[str, list]:
    """(resolved kind, cameras) of a novel-view path around the run's views."""
    from ..export.camera_paths import orbit_path, spiral_path

    if kind == "auto":
        kind = "orbit" if dm.scene.format in ("blender", "dtu") else "spiral"
    cams = [c.to("cpu") for c, _ in dm.train_views()] + [c.to("cpu") for c, _ in dm.eval_views()]
    if kind == "spiral":
        return kind, spiral_path(cams, frames)
    return kind, orbit_path(cams, dm.scene.scene_center, frames)


def main(args: RenderArgs) -> Path:
    from ..errors import DataError
    from ..files.output_paths import RENDER_FOLDER, VIDEO_FILE, check_output, run_inputs
    from ..files.run_lock import owned, writes_inside

    if args.frames < 1:
        raise DataError(f"--frames must be >= 1, got {args.frames}")
    if args.fps < 1:
        raise DataError(f"--fps must be >= 1, got {args.fps}")
    replace = args.overwrite or args.out is None  # the defaults inside RUN_DIR are the run's own
    inputs = run_inputs(args.run_dir)  # its checkpoints/, config.json, ... and its dataset folder

    def check_video(out: Path) -> None:
        for target in video_targets(out, args.depth):
            check_output(target, VIDEO_FILE, overwrite=replace, inputs=inputs)

    if args.path == "test":
        out = args.out or args.run_dir / "renders"
        check_output(out, RENDER_FOLDER, overwrite=replace, inputs=inputs)
    elif args.out is not None:  # checked before anything loads; the default name waits for --path auto
        check_video(args.out)

    # the default outputs lie in the run folder (own it meanwhile); an --out elsewhere only reads the run
    with owned(args.run_dir, writes=args.out is None or writes_inside(args.run_dir, args.out)):
        return render_run(args, replace, check_video, inputs)


def render_run(args: RenderArgs, replace: bool, check_video, inputs) -> Path:
    """Load the run and write what ``args`` asks for (its targets already checked against ``inputs``,
    or checked by ``check_video`` once ``--path auto`` names the video)."""
    from ..console import starting, track

    with starting():
        import torch

        from ..engine.run import load_run
        from ..evaluation.held_out import scored_views, view_name
        from ..evaluation.pictures import colorize_depth, to_uint8, write_png
        from ..files.output_paths import RENDER_FOLDER, claim_output
        from ..pipeline.scene import background_for

    config, dm, model = load_run(args.run_dir, args.device, args.trust_edited_config)
    bg = background_for(dm.scene, config.device)
    if args.path == "test":
        out = args.out or args.run_dir / "renders"
        claim_output(out, RENDER_FOLDER, overwrite=replace, inputs=inputs)
        views, split = scored_views(dm)
        with torch.no_grad():
            for cam, batch in track(views, f"rendering {split} views", unit="views"):
                o = model.get_outputs(cam, bg)
                name = view_name(dm, cam, batch["index"])
                write_png(out / f"{name}_render.png", to_uint8(o.rgb))
                write_png(out / f"{name}_depth.png", colorize_depth(o.expected_depth, o.alpha))
        print(f"wrote {len(views)} views to {out}")
        return out
    kind, cams = camera_path(args.path, dm, args.frames)
    out = args.out or args.run_dir / f"{kind}.mp4"
    check_video(out)
    return write_video(model, cams, bg, out, args.fps, args.depth)


def video_targets(out: Path, depth: bool) -> list[Path]:
    """The files a video render writes: ``out``, and ``<out>_depth.mp4`` with ``depth``."""
    out = Path(out)
    return [out] + ([out.with_name(out.stem + "_depth.mp4")] if depth else [])


def write_video(model, cams, bg, out: Path, fps: int, depth: bool) -> Path:
    """Render ``cams`` and encode an mp4 (and optionally ``<out>_depth.mp4``), atomically.

    The depth video maps inverse expected depth over the cameras' [near, far]
    range, the same for every frame (no flicker). Nothing is left behind on failure.
    """
    import os

    import torch

    from ..console import track
    from ..evaluation.pictures import colorize_depth, to_uint8
    from ..export.video import open_video

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    w, h = cams[0].width, cams[0].height
    targets = video_targets(out, depth)
    tmps = [t.with_name("." + t.name + ".tmp.mp4") for t in targets]
    inv_range = (1.0 / max(c.far for c in cams), 1.0 / min(c.near for c in cams))
    writers = []
    try:
        for t in tmps:
            writers.append(open_video(t, fps, w, h))
        with torch.no_grad():
            for cam in track(cams, f"rendering {out.name}", unit="frames"):
                o = model.get_outputs(cam.to(bg.device), bg)
                writers[0].write(to_uint8(o.rgb))
                if depth:
                    writers[1].write(colorize_depth(o.expected_depth, o.alpha, inv_range))
        for wr in writers:
            wr.close()
        for tmp, target in zip(tmps, targets):
            os.replace(tmp, target)
            print(f"wrote {target}")
    finally:
        for wr in writers:
            wr.close()
        for tmp in tmps:
            if tmp.exists():
                tmp.unlink()
    return out


def entrypoint() -> None:
    from .common import parse_cli, run_cli

    run_cli(lambda: main(parse_cli(RenderArgs, prog="splat-render")))


if __name__ == "__main__":
    entrypoint()
