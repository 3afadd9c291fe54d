"""Your own photos (or a video) as ``--data``: what is one, recognised without posing it
(:mod:`splat_framework.sfm.own_photos` poses it)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from .images import list_images
from .parsers import marked_format

PhotoSource = Literal["photos", "video"]
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg")
"""File suffixes that ``splat-train --data`` reads as a video (any format OpenCV decodes works with splat-process video)."""


def photo_source(path: Path) -> PhotoSource | None:
    """"photos" for a folder of images that is not a dataset, "video" for a video file, else None."""
    path = Path(path)
    if path.is_file():
        return "video" if path.suffix.lower() in VIDEO_SUFFIXES else None
    if path.is_dir() and marked_format(path) is None and list_images(path):
        return "photos"
    return None
