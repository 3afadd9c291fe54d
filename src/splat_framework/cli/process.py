"""``splat-process images DIR --out SCENE`` / ``splat-process video FILE --out SCENE``: your own photos
(or a video) as a posed COLMAP scene that ``splat-train METHOD --data SCENE`` reads."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, Union

from tyro.conf import Positional, arg, subcommand

from ..config.data import PairChoice


@dataclass
class ImagesArgs:
    folder: Annotated[Positional[Path], arg(metavar="DIR")]
    """Folder of photos of one scene (jpg, png, ...), all of one size."""
    out: Path
    """Scene folder to write (COLMAP layout: images/, sparse/0/)."""
    mapper: Literal["incremental", "global"] = "incremental"
    """COLMAP's incremental mapper, or the global one (GLOMAP)."""
    pairs: PairChoice = "auto"
    """Pairs matched: auto (every pair up to 10 photos; above, each photo's 5 most similar photos, and for a video each frame's 3 next frames too) or exhaustive (every pair)."""
    matcher: str = "auto"
    """Correspondences COLMAP maps from: "sift" (COLMAP's own), a learned matcher that a plugin registers (aliked-lightglue, disk-lightglue from SCGaussian), or "auto": aliked-lightglue where registered and its weights are installed, else sift (one-line notice). From 3 photos the learned matches register more and better: DTU scan37's 3 views 0 of 3 with SIFT, 3 of 3 with aliked-lightglue; fern's 3 views rotations 1.9 -> 0.9 degrees off, focal 9.2 -> 1.5 %."""
    overwrite: bool = False
    """Replace --out when it is a scene folder that splat-process wrote (only its images/ and sparse/ are removed)."""


@dataclass
class VideoArgs:
    video: Annotated[Positional[Path], arg(metavar="FILE")]
    """Video of one scene (any format OpenCV decodes)."""
    out: Path
    """Scene folder to write (COLMAP layout: images/, sparse/0/)."""
    frames: int = 10
    """Frames to use: the sharpest of each of this many equal spans of the video."""
    mapper: Literal["incremental", "global"] = "incremental"
    """COLMAP's incremental mapper, or the global one (GLOMAP)."""
    pairs: PairChoice = "auto"
    """Pairs matched: auto (every pair up to 10 photos; above, each photo's 5 most similar photos, and for a video each frame's 3 next frames too) or exhaustive (every pair)."""
    matcher: str = "auto"
    """Correspondences COLMAP maps from: "sift" (COLMAP's own), a learned matcher that a plugin registers (aliked-lightglue, disk-lightglue from SCGaussian), or "auto": aliked-lightglue where registered and its weights are installed, else sift (one-line notice). From 3 photos the learned matches register more and better: DTU scan37's 3 views 0 of 3 with SIFT, 3 of 3 with aliked-lightglue; fern's 3 views rotations 1.9 -> 0.9 degrees off, focal 9.2 -> 1.5 %."""
    overwrite: bool = False
    """Replace --out when it is a scene folder that splat-process wrote (only its images/ and sparse/ are removed)."""


Args = Union[
    Annotated[ImagesArgs, subcommand("images", description="a folder of photos")],
    Annotated[VideoArgs, subcommand("video", description="a video: frames picked for sharpness and spread")],
]


def main(args: ImagesArgs | VideoArgs):
    from ..files.output_paths import PROCESSED_SCENE, check_output

    source = args.video if isinstance(args, VideoArgs) else args.folder
    check_output(args.out, PROCESSED_SCENE, overwrite=args.overwrite, inputs=[source])  # before any work

    from ..files.work_folder import scratch
    from ..sfm import estimate_scene, list_images, pick_video_frames
    if isinstance(args, VideoArgs):
        with scratch(args.out) as work:  # beside --out: a killed run's frames are removed by the next
            photos = pick_video_frames(args.video, args.frames, work / "frames")
            summary = estimate_scene(photos, args.out, mapper=args.mapper, overwrite=args.overwrite, matcher=args.matcher,
                                     ordered=True, pairs=args.pairs)  # the frames in time order: their neighbours are paired too
    else:
        photos = list_images(args.folder)
        summary = estimate_scene(photos, args.out, mapper=args.mapper, overwrite=args.overwrite, matcher=args.matcher,
                                 pairs=args.pairs)
    print(summary.line(args.out))
    for line in summary.not_registered_lines():
        print(line)
    print(f"next: splat-train scgaussian --data {args.out}  (or in one step: splat-train scgaussian --data "
          f"{args.video if isinstance(args, VideoArgs) else args.folder})")
    return summary


def entrypoint() -> None:
    from .common import parse_cli, run_cli

    run_cli(lambda: main(parse_cli(
        Args, prog="splat-process",
        description="Estimate camera poses of your own photos or video (pycolmap) and write a scene folder that "
                    "splat-train reads.")))


if __name__ == "__main__":
    entrypoint()
