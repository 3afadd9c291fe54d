"""Your own photos (or a video) as ``--data``: posed once by structure from motion, then cached.

A folder that holds images and no dataset marker, or a video file
(:func:`splat_framework.data.photos.photo_source`), is posed as ``splat-process`` would pose it
(:func:`.reconstruct.estimate_scene`) and the posed scene folder is kept in
``$SPLAT_CACHE/photos/<key>/scene``, where ``key`` hashes the photos' names and bytes and the pose
options: the next run on the same photos reads it back, a changed, added or removed photo poses
them again. An entry is written whole or not at all (built beside its place, then renamed), with a
manifest of every file's sha256 (poses, images, the posing's matches); an entry whose files do not
match it (edited, emptied, added, unreadable) is posed again, with one warning naming the file.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import warnings
from pathlib import Path

from ..config.data import PhotoPosesConfig
from ..data.cache_dir import user_cache_dir
from ..data.photos import PhotoSource, photo_source
from ..data.resolve import locate_data
from ..runtime.trusted import folder_mismatch, private_folder, write_folder_manifest

KEY_VERSION = "splat-photos-1"
"""Bumped when what the cache holds changes."""
SUMMARY = "summary.json"
"""Written last beside the cached scene: the entry is complete."""


def resolve_data_path(spec: str | Path, photos: PhotoPosesConfig | None = None) -> Path:
    """The dataset folder a ``--data`` spec names: :func:`~splat_framework.data.resolve.locate_data`,
    then, for a folder of photos or a video, the scene posed from them (:func:`posed_photos`, with
    the pose options ``photos``; cached). Raises DataError when none exists."""
    path = locate_data(spec)
    kind = photo_source(path)
    return posed_photos(path, kind, photos) if kind is not None else path


def photos_key(files: list[Path], kind: PhotoSource, options: PhotoPosesConfig) -> str:
    """Hex digest of the files' names and bytes (in the given order), of the pose options that apply
    and of the thread count the learned matching runs on (:func:`machine_thread_count`: its matches,
    so the poses, differ in their last bits from one count to another, as the prior's do)."""
    from ..runtime.threads import machine_thread_count

    used = options.model_dump(mode="json", exclude=set() if kind == "video" else {"frames"})
    h = hashlib.sha256(json.dumps([KEY_VERSION, kind, used, machine_thread_count()], sort_keys=True).encode())
    for f in files:
        h.update(f"\0{f.name}\0{f.stat().st_size}\0".encode())
        with open(f, "rb") as src:
            for block in iter(lambda: src.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def posed_photos(path: Path, kind: PhotoSource, options: PhotoPosesConfig | None = None) -> Path:
    """The posed scene folder (COLMAP layout) of the photos in folder ``path`` or of the video ``path``:
    read from the cache, or estimated now (one line before, the summary after) and cached; either way
    one line per photo left out, with its verified matches with each other photo by file name."""
    from ..console import say
    from ..files.work_folder import building
    from ..runtime.io import atomic_write_json, read_json
    from .photos import list_images as list_photos
    from .reconstruct import estimate_scene
    from .video import pick_video_frames

    options = options or PhotoPosesConfig()
    path = Path(path)
    files = list_photos(path) if kind == "photos" else [path]
    root = user_cache_dir()
    entry = root / "photos" / photos_key(files, kind, options)[:24]
    scene = entry / "scene"
    if entry.exists():
        reason = folder_mismatch(entry, root)
        if reason is None:
            cached = read_json(entry / SUMMARY)
            say(f"{path}: poses from the cache ({cached['line']}; {scene})")
            _say_left_out(cached.get("not_registered_lines", []))
            return scene
        warnings.warn(f"{path}: cached poses not used ({reason}); estimating them again", stacklevel=2)
        shutil.rmtree(entry, ignore_errors=True)
    what = f"{len(files)} photos" if kind == "photos" else f"{options.frames} frames of the video"
    say(f"{path}: estimating the poses of {what} (pycolmap, {options.mapper} mapper, {options.matcher} matches)")
    kwargs = {"mapper": options.mapper, "matcher": options.matcher, "pairs": options.pairs, "overwrite": True}
    private_folder(entry.parent)
    with building(entry, _install_private) as work:
        if kind == "video":
            frames = pick_video_frames(path, options.frames, work / "frames")
            summary = estimate_scene(frames, work / "scene", ordered=True, **kwargs)  # frames in time order
            shutil.rmtree(work / "frames")
        else:
            summary = estimate_scene(files, work / "scene", **kwargs)
        line, left_out = summary.line(path), summary.not_registered_lines()
        atomic_write_json(work / SUMMARY, {"line": line.removeprefix(f"{path}: "), "registered": summary.registered,
                                           "not_registered": summary.left_out, "not_registered_lines": left_out})
    say(line)
    say(f"poses cached for the next run in {entry}")
    _say_left_out(left_out)
    return scene


def _say_left_out(lines: list[str]) -> None:
    """Say, in yellow, the lines naming the photos left out of the scene
    (:meth:`~splat_framework.sfm.reconstruct.SfmSummary.not_registered_lines`)."""
    from ..console import say

    for line in lines:
        say(line, "yellow")


def _install_private(work: Path, entry: Path) -> None:
    """Move a finished cache entry into place, readable by the user alone, with the manifest of its files.

    Two runs posing the same photos at once both build the entry; the one that finishes second
    keeps the first one's when it verifies (the same photos and options: an equal estimate), and
    its own work folder is removed with the rest of its scratch."""
    write_folder_manifest(work)
    os.chmod(work, 0o700)
    try:
        os.replace(work, entry)
    except OSError:
        if not entry.is_dir() or folder_mismatch(entry, entry.parent.parent) is not None:
            raise

