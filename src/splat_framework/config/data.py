"""Where a run's data comes from (torch-free: read for ``--help``): how a folder of photos or a
video given as ``--data`` is posed (:class:`PhotoPosesConfig`), and the dataset a run resolved
(:class:`ResolvedData`), which ``config.json`` records so that a run folder is self-contained."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field

from .base import SplatConfig

PairChoice = Literal["auto", "exhaustive"]
"""Which pairs of photos posing matches (see :class:`PhotoPosesConfig`'s ``pairs``)."""
MAX_FRAMES = 1000
"""Largest number of frames taken from a video."""


class PhotoPosesConfig(SplatConfig):
    """Pose estimation (pycolmap, as splat-process) when --data is a folder of photos or a video."""

    matcher: str = "auto"
    """Photo matcher: auto, sift or a registered one (aliked-lightglue, ...)."""
    mapper: Literal["incremental", "global"] = "incremental"
    """COLMAP's incremental mapper, or the global one (GLOMAP)."""
    frames: Annotated[int, Field(ge=2, le=MAX_FRAMES)] = 10
    """Frames taken from a video (the sharpest of each equal span)."""
    pairs: PairChoice = "auto"
    """Pairs matched: auto (every pair up to 10 photos; above, each photo's 5 most similar photos, and for a video each frame's 3 next frames too) or exhaustive (every pair)."""


SOURCE_FIELDS = ("data", "format", "views", "downscale", "eval_split", "test_every", "train_poses", "photos")
"""The TrainConfig fields a :class:`ResolvedData` was resolved from."""


class ResolvedData(SplatConfig):
    """The dataset as a run resolved it: the folder and the split, by image name."""

    path: str
    """Absolute path of the dataset folder (for photos or a video: the posed scene in the cache)."""
    train: list[str]
    """Names of the training images (camera names: the file stems)."""
    test: list[str]
    """Names of the held-out test images."""
    train_poses: str | None = None
    """Absolute path of the pose file that replaced the training poses, if any."""
    source: dict[str, Any]
    """The config fields it was resolved from (SOURCE_FIELDS): a config whose fields differ resolves its data anew."""

    def resolves(self, config) -> bool:
        """Whether this record is the data of ``config`` (its SOURCE_FIELDS unchanged)."""
        return self.source == source_of(config)


def source_of(config) -> dict[str, Any]:
    """The JSON values of ``config``'s SOURCE_FIELDS."""
    dumped = config.model_dump(mode="json", include=set(SOURCE_FIELDS))
    return {k: dumped.get(k) for k in SOURCE_FIELDS}


def absolute(path: str | Path) -> str:
    """``path`` made absolute against the current folder (symlinks kept)."""
    return str(Path(path).expanduser().absolute())
