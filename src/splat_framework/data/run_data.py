"""The data of a training config: the scene it names, and the record of it that makes a run
folder self-contained (``TrainConfig.resolved_data``, written into ``config.json``).

A run records the absolute dataset folder and its split by image name when it starts
(:func:`record_data`); reopening it (:func:`load_config_scene`) reads that folder with that
split from any shell. A run folder written before the record existed resolves ``data`` as
it did then (``$SPLAT_DATA``, the split rules).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from ..config.data import ResolvedData, absolute, source_of
from .parsers import load_scene
from .parsers.common import scene_extent
from .pose_file import apply_pose_file
from .resolve import resolve_data_path
from .scene import DataError, SceneData


def load_config_scene(config) -> SceneData:
    """The scene a training config names (``data``, ``format``, ``views``, ``downscale``; a folder of
    photos or a video posed with ``photos``), its training cameras replaced from ``train_poses`` when
    set. With ``resolved_data`` recorded for these fields: its folder (``data`` again where that
    folder is gone) and its split, by image name."""
    record = config.resolved_data if config.resolved_data is not None and config.resolved_data.resolves(config) else None
    if record is not None and Path(record.path).is_dir():
        root = Path(record.path)
    else:
        try:
            root = resolve_data_path(config.data, config.photos)
        except DataError as e:
            if record is None:
                raise
            raise DataError(f"{record.path}: the run's dataset folder is gone, and {e}") from None
    scene = load_scene(root, format=config.format, views=config.views, downscale=config.downscale)
    if record is not None:
        scene = with_split(scene, record.train, record.test)
    poses = record.train_poses if record is not None else config.train_poses
    return apply_pose_file(scene, poses) if poses is not None else scene


def with_split(scene: SceneData, train: list[str], test: list[str]) -> SceneData:
    """``scene`` trained on the images named ``train`` and tested on those named ``test`` (camera
    names); a DataError naming the first name the scene does not hold."""
    index = {c.name: i for i, c in enumerate(scene.cameras)}
    for name in (*train, *test):
        if name not in index:
            raise DataError(f"{scene.root}: the run's image {name!r} is not in the dataset")
    train_idx, test_idx = [index[n] for n in train], [index[n] for n in test]
    if (train_idx, test_idx) == (scene.train_indices, scene.test_indices):
        return scene
    center, radius = scene_extent(scene.cameras, train_idx)
    return replace(scene, train_indices=train_idx, test_indices=test_idx, scene_center=center, scene_radius=radius)


def record_data(config, scene: SceneData):
    """``config`` with ``resolved_data`` recording ``scene``: its absolute folder, its split by image name."""
    record = ResolvedData(
        path=absolute(scene.root),
        train=[scene.cameras[i].name for i in scene.train_indices],
        test=[scene.cameras[i].name for i in scene.test_indices],
        train_poses=absolute(config.train_poses) if config.train_poses is not None else None,
        source=source_of(config),
    )
    return config.model_copy(update={"resolved_data": record})


def describe_split(scene: SceneData) -> str | None:
    """One line naming the photos that train and those that test, for a scene of one's own photos
    (COLMAP format: splat-process or photos given as --data); None for a benchmark dataset."""
    if scene.format != "colmap":
        return None
    names = [c.name for c in scene.cameras]
    train = [names[i] for i in scene.train_indices]
    which = f"all {len(names)} photos" if len(train) == len(names) else f"{len(train)} of {len(names)} photos"
    line = f"training on {which}: {', '.join(train)}"
    if not scene.test_indices:
        return line + "; nothing is held out, so the metrics are training-view metrics"
    return line + f"; testing on {len(scene.test_indices)}: {', '.join(names[i] for i in scene.test_indices)}"
