"""The scene a run's training config names: its ``--data`` found (one's own photos posed by
:mod:`splat_framework.sfm`), read with the run's recorded split and training poses."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import torch

from ..config import resolve_steps
from ..data.parsers import load_scene
from ..data.pose_file import apply_pose_file
from ..data.run_data import every_kth_split, held_out_views, resolve_views, with_split
from ..data.scene import DataError, SceneData
from ..sfm.own_photos import resolve_data_path


def load_config_scene(config) -> SceneData:
    """The scene a training config names (``data``, ``format``, ``views``, ``downscale``; a folder of
    photos or a video posed with ``photos``; every ``test_every``-th image held out when set),
    scoring the views ``eval_split`` names, its training cameras replaced from ``train_poses`` when set. With ``resolved_data`` recorded for these fields: its folder (``data`` again where that
    folder is gone) and its split, by image name. Unset ``views`` are settled first (:func:`resolve_views`)."""
    config = resolve_views(config)
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
    if record is not None:  # its test views are the views it scored, validation views included
        scene = with_split(scene, record.train, record.test)
        scene = replace(scene, held_out=config.eval_split)
    else:
        scene = held_out_views(every_kth_split(scene, config.test_every, config.views), config.eval_split)
    poses = record.train_poses if record is not None else config.train_poses
    return apply_pose_file(scene, poses) if poses is not None else scene


def background_for(scene: SceneData, device) -> torch.Tensor:
    """[3] the colour renders of ``scene`` composite over: white for a white backdrop, else black."""
    return torch.full((3,), 1.0 if scene.white_background else 0.0, device=device)


def resolve_run_config(config, defaults):
    """``config`` as a run trains it: its unset ``views`` settled from its data
    (:func:`~splat_framework.data.run_data.resolve_views`; left unset when the data cannot be
    recognised yet: loading it says why), then its schedule rescaled to ``--steps`` and the views
    (:func:`~splat_framework.config.resolve_steps`; the iteration counts that differ from
    ``defaults`` are the user's and keep their numbers). Views first: more may lengthen the schedule."""
    return resolve_steps(resolve_views(config, strict=False), defaults)
