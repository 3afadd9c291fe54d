"""Your own photos (or a video) as ``--data``: posed once by structure from motion, then cached.

A folder that holds images and no dataset marker (see :func:`~.parsers.marked_format`), or a
video file, is posed as ``splat-process`` would pose it (:func:`splat_framework.sfm.estimate_scene`)
and the posed scene folder is kept in ``$SPLAT_CACHE/photos/<key>/scene``, where ``key`` hashes
the photos' names and bytes and the pose options: the next run on the same photos reads it
back, a changed, added or removed photo poses them again.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Literal

from ..config.data import PhotoPosesConfig
from .cache_dir import user_cache_dir
from .images import list_images
from .parsers import marked_format

PhotoSource = Literal["photos", "video"]
KEY_VERSION = "splat-photos-1"
"""Bumped when what the cache holds changes."""
SUMMARY = "summary.json"
"""Written last beside the cached scene: the entry is complete."""


def photo_source(path: Path) -> PhotoSource | None:
    """"photos" for a folder of images that is not a dataset, "video" for a video file, else None."""
    from ..sfm.video import VIDEO_SUFFIXES

    path = Path(path)
    if path.is_file():
        return "video" if path.suffix.lower() in VIDEO_SUFFIXES else None
    if path.is_dir() and marked_format(path) is None and list_images(path):
        return "photos"
    return None


def photos_key(files: list[Path], kind: PhotoSource, options: PhotoPosesConfig) -> str:
    """Hex digest of the files' names and bytes (in the given order) and of the pose options that apply."""
    used = options.model_dump(mode="json", exclude=set() if kind == "video" else {"frames"})
    h = hashlib.sha256(json.dumps([KEY_VERSION, kind, used], sort_keys=True).encode())
    for f in files:
        h.update(f"\0{f.name}\0{f.stat().st_size}\0".encode())
        with open(f, "rb") as src:
            for block in iter(lambda: src.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def posed_photos(path: Path, kind: PhotoSource, options: PhotoPosesConfig | None = None) -> Path:
    """The posed scene folder (COLMAP layout) of the photos in folder ``path`` or of the video ``path``:
    read from the cache, or estimated now (one line before, the summary after) and cached."""
    from ..console import say
    from ..files.work_folder import scratch
    from ..runtime.io import atomic_write_json, read_json
    from ..sfm.photos import list_images as list_photos
    from ..sfm.reconstruct import estimate_scene
    from ..sfm.video import pick_video_frames

    options = options or PhotoPosesConfig()
    path = Path(path)
    files = list_photos(path) if kind == "photos" else [path]
    entry = user_cache_dir() / "photos" / photos_key(files, kind, options)[:24]
    scene = entry / "scene"
    if (entry / SUMMARY).is_file() and (scene / "sparse" / "0").is_dir():
        say(f"{path}: poses from the cache ({read_json(entry / SUMMARY)['line']}; {scene})")
        return scene
    what = f"{len(files)} photos" if kind == "photos" else f"{options.frames} frames of the video"
    say(f"{path}: estimating the poses of {what} (pycolmap, {options.mapper} mapper, {options.matcher} matches); "
        f"cached for the next run in {entry}")
    kwargs = {"mapper": options.mapper, "matcher": options.matcher, "overwrite": True}
    if kind == "video":
        with scratch(scene) as work:  # beside the scene: a killed run's frames are removed by the next
            frames = pick_video_frames(path, options.frames, work / "frames")
            summary = estimate_scene(frames, scene, **kwargs)
    else:
        summary = estimate_scene(files, scene, **kwargs)
    line = summary.line(path)
    left_out = [f.stem for f in files if f.stem not in set(summary.registered)] if kind == "photos" else []
    atomic_write_json(entry / SUMMARY, {"line": line.removeprefix(f"{path}: "), "registered": summary.registered,
                                        "not_registered": left_out})
    say(line)
    if summary.unregistered:
        say(f"not registered (left out of the scene): {', '.join(left_out) or summary.unregistered}", "yellow")
    return scene


def is_own_photos(path: Path) -> bool:
    """Whether ``path`` is one's own photos: a folder of photos, a video, or a scene folder that
    splat-process (or this module's cache) wrote."""
    from ..files.output_paths import PROCESSED_SCENE

    path = Path(path)
    return photo_source(path) is not None or (path.is_dir() and PROCESSED_SCENE.is_ours(path))
