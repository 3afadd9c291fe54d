"""The data of a training config: its views, and the record of its scene that makes a run
folder self-contained (``TrainConfig.resolved_data``, written into ``config.json``).

A run settles its views when it starts (:func:`resolve_views`: the format's default where
``--views`` is not given), and records the absolute dataset folder and its split by image name
(:func:`record_data`); reopening it (:func:`splat_framework.pipeline.scene.load_config_scene`)
reads that folder with that split (:func:`with_split`) from any shell. A run folder written
before the record existed resolves ``data`` as it did then (``$SPLAT_DATA``, the split rules).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from ..config.data import ResolvedData, absolute, source_of
from .parsers import detect_format
from .parsers.common import scene_extent
from .photos import photo_source
from .resolve import locate_data
from .scene import DataError, SceneData
from .splits import FEW_SHOT_FORMATS, LLFF_HOLDOUT, default_views, llff_split


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


EVERY_KTH_FORMATS = ("llff", "colmap", "transforms")
"""The formats whose test views are every K-th image (K = 8; ``--test-every K``); Blender's and
DTU's are their protocols' own lists."""


def every_kth_split(scene: SceneData, test_every: int | None, views) -> SceneData:
    """``scene`` holding out every ``test_every``-th image (the first, the ``test_every``+1-th, ...,
    in the scene's name order) as a test view at any image count, ``views`` of the rest trained on
    (the LLFF rule, :func:`~.splits.llff_split`); unchanged when ``test_every`` is None. A DataError
    naming the folder for a format whose test views are a protocol's list (Blender, DTU)."""
    if test_every is None:
        return scene
    if scene.format not in EVERY_KTH_FORMATS:
        raise DataError(f"{scene.root}: --test-every holds out every K-th image of LLFF, COLMAP and transforms.json "
                        f"scenes (one's own photos); a {scene.format} scene's test views are its protocol's")
    train, test = llff_split(len(scene.cameras), views, test_every)
    return with_split(scene, [scene.cameras[i].name for i in train], [scene.cameras[i].name for i in test])


def held_out_views(scene: SceneData, split: str) -> SceneData:
    """``scene`` scoring the views of ``split``: its test views ("test", unchanged), or its
    validation views ("val": :attr:`SceneData.validation_indices`, neither trained nor tested) in
    their place; a DataError naming the folder when it has none."""
    if split == "test":
        return scene
    val = scene.validation_indices
    if not val:
        raise DataError(f"{scene.root}: no validation views (every view is a training or a test view); "
                        "score the test views (--eval-split test)")
    return replace(scene, test_indices=val, held_out="val")


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


def resolve_views(config, strict: bool = True):
    """``config`` with ``views`` settled where it is unset (None, no ``--views``): a resumed run's
    own (its config.json), else the default of its data's format (:func:`~.splits.default_views`:
    few-shot on the benchmarks, every view on one's own scenes). The one place the default applies;
    config.json then records the views. ``strict=False`` (the trainer, before the output checks)
    leaves them unset when the data cannot be recognised: loading it says why, after those checks."""
    if config.views is not None:
        return config
    views = resumed_views(config)
    if views is None:
        try:
            views = default_views(data_format(config))
        except DataError:
            if strict:
                raise
            return config
    return config.model_copy(update={"views": views})


def data_format(config) -> str:
    """The format of the data ``config`` names: ``format`` when given, else recognised from the folder
    (a folder of photos or a video is posed into a COLMAP scene); a DataError when there is none."""
    if config.format != "auto":
        return config.format
    path = locate_data(config.data)
    return "colmap" if photo_source(path) is not None else detect_format(path)


def resumed_views(config):
    """The views that the run ``--resume`` continues recorded in its config.json; None when there is
    no such file to read (the resume check says what is wrong with one)."""
    saved = Path(config.output) / "config.json" if config.resume and config.output is not None else None
    if saved is None or not saved.is_file():
        return None
    from ..config.persist import read_config_json

    try:
        return read_config_json(saved, trust_edits=True)[1].get("views")
    except DataError:
        return None


NAMED_VIEWS = 8
"""Up to this many training (or test) views, the line describing the split names them."""
SCENE_KINDS = {"colmap": "a COLMAP scene", "transforms": "a transforms.json scene", "llff": "an LLFF scene"}


def describe_split(scene: SceneData, views, test_every: int | None = None) -> str | None:
    """One line saying how many views train and how many are held out for testing (naming them when
    few; every ``test_every``-th image when given, else every 8th) and, where ``views`` is the
    format's default, that it is and how to ask for another; for a scene of one's own (COLMAP:
    splat-process or photos given as --data; transforms.json), or any scene split by
    ``--test-every``. None for the benchmarks otherwise, whose few-shot split is the papers'."""
    if scene.format in FEW_SHOT_FORMATS and test_every is None:
        return None
    kind = SCENE_KINDS.get(scene.format, f"a {scene.format} scene")
    line = f"training on {'all ' if views == 'all' else ''}{_counted(scene.train_indices, 'view')} of {kind}"
    if views == default_views(scene.format):
        line += " (its default; --views N for a few-shot split)"
    line += _names(scene, scene.train_indices)
    if not scene.test_indices:
        return line + ("; nothing is held out, so the metrics are training-view metrics (--test-every K holds out "
                       "every K-th image)")
    if scene.held_out == "val":
        return line + f"; {_counted(scene.test_indices, 'validation view')} scored (neither trained on nor tested)"
    held_out = _counted(scene.test_indices, "test view")
    every = ordinal(test_every or LLFF_HOLDOUT)
    return line + f"; {held_out} held out (every {every} image){_names(scene, scene.test_indices)}"


def ordinal(k: int) -> str:
    """``2nd``, ``3rd``, ``8th``, ``11th``, ``21st``."""
    suffix = "th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")
    return f"{k}{suffix}"


def _counted(indices: list[int], noun: str) -> str:
    """``"3 views"``, ``"1 view"``."""
    return f"{len(indices)} {noun}{'' if len(indices) == 1 else 's'}"


def _names(scene: SceneData, indices: list[int]) -> str:
    """``": a, b, c"``: the cameras' names, when there are at most :data:`NAMED_VIEWS`; else ""."""
    if len(indices) > NAMED_VIEWS:
        return ""
    return ": " + ", ".join(scene.cameras[i].name for i in indices)
