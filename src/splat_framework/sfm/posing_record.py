"""What the posing of a scene's photos left out, kept beside the scene (``posing.json``), so that a
later run on the scene can say whether its poses lack some photos (the matching prior's line on the
pairs it left empty, :func:`splat_framework.matching.report.warn_empty`). Torch-free.

``splat-process`` and ``--data PHOTOS`` (:mod:`.own_photos`, whose cached entry also keeps it in its
``summary.json``) write it; a dataset's own poses have none.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

POSING_RECORD = "posing.json"
"""The record's file name, in the posed scene folder."""


@dataclass(frozen=True)
class PosingRecord:
    """The photos a scene was posed from and those left out of it (file names), with what to try."""

    photos: list[str]
    left_out: list[str]
    retry: str
    """What may pose the photos left out (``more photos overlapping them, or --photos.mapper global``)."""


def write_posing_record(scene: Path, photos: list[str], left_out: list[str], matcher: str, mapper: str) -> None:
    """Write the record of a posing (``photos`` given, ``left_out`` of the scene, by file name; the
    ``matcher`` and ``mapper`` used) into the scene folder ``scene``."""
    from ..runtime.io import atomic_write_json

    atomic_write_json(Path(scene) / POSING_RECORD, {"photos": photos, "left_out": left_out, "matcher": matcher,
                                                    "mapper": mapper})


def posing_record(scene: Path) -> PosingRecord | None:
    """The record of how the scene folder ``scene`` was posed; None for a scene posed elsewhere (a
    dataset's poses, COLMAP run by hand) or whose record is unreadable (the record only words a line)."""
    from ..runtime.io import read_json

    scene = Path(scene)
    try:
        raw = read_json(scene / POSING_RECORD)
        photos, left_out = [str(p) for p in raw["photos"]], [str(p) for p in raw["left_out"]]
        matcher, mapper = str(raw["matcher"]), str(raw["mapper"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return PosingRecord(photos, left_out, retry_line(matcher, mapper, cached=_in_photo_cache(scene)))


def retry_line(matcher: str, mapper: str, cached: bool) -> str:
    """What may pose photos left out by a posing with ``matcher`` and ``mapper``: more overlapping
    photos, the learned matcher (after SIFT), the other mapper; the flags of ``--data PHOTOS``
    (``cached``: the scene is in the photos' cache) or of ``splat-process``."""
    other = "incremental" if mapper == "global" else "global"
    if cached:
        learned = "--photos.matcher aliked-lightglue, " if matcher == "sift" else ""
        return f"more photos overlapping them, {learned}or --photos.mapper {other}"
    learned = "--matcher aliked-lightglue or " if matcher == "sift" else ""
    return f"more photos overlapping them, or splat-process with {learned}--mapper {other}"


def _in_photo_cache(scene: Path) -> bool:
    """Whether ``scene`` is a posed entry of the photos' cache (:mod:`.own_photos`: under
    ``$SPLAT_CACHE/photos``), not a splat-process folder."""
    from ..data.cache_dir import user_cache_dir

    return scene.resolve().is_relative_to((user_cache_dir() / "photos").resolve())
