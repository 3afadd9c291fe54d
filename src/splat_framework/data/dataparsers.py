"""Dataparsers: the dataset formats a ``--data`` folder is read in, registered in the entry-point group
``splat_framework.dataparsers`` like every other part (the built-ins below too, declared in the
framework's pyproject.toml).

An entry names a :class:`DataparserSpec`: how the format recognises a folder (a cheap check of its
files, run for every ``--data``) and the ``module:function`` that loads one into a
:class:`~splat_framework.data.scene.SceneData`. ``--format auto`` tries the registered
dataparsers in :attr:`DataparserSpec.order` (registration order among equals) and takes the
first that recognises the folder: the built-ins in the order llff, blender, dtu, transforms,
colmap (a folder with both ``transforms.json`` and ``sparse/0/``, as nerfstudio's ns-process-data
writes, is read as transforms.json), then a plugin's.

A torch-free module: the built-ins recognise a folder without importing their parser modules.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Callable

BUILTIN_ORDER = 50
"""The last :attr:`DataparserSpec.order` of a built-in dataparser: a plugin's default comes after."""


@dataclass(frozen=True)
class DataparserSpec:
    """One dataset format, as the entry-point group ``splat_framework.dataparsers`` names it
    (``NAME = "module:spec"``; the entry point's name is the format's, e.g. ``--format llff``).

    Attributes:
        marker: what a folder of the format holds, as the message for an unrecognised folder lists
            it (``poses_bounds.npy``).
        recognises: ``folder -> bool``: whether a folder is of this format (cheap and torch-free: it
            runs for every ``--data`` until one recognises it).
        load: ``"module:function"`` of the loader, ``(folder, *, views, downscale) -> SceneData``
            (imported when a folder of the format loads); every failure a one-line DataError.
        order: where ``--format auto`` tries it, lowest first (the built-ins 10 to 50; a plugin's
            after them unless it says otherwise).
    """

    marker: str
    recognises: Callable[[Path], bool]
    load: str
    order: int = BUILTIN_ORDER + 50


SPARSE_DIRS = ("sparse/0", "sparse", "colmap/sparse/0")
"""Where a scene folder's COLMAP model may be, in order: COLMAP's own layout, a single model, and
nerfstudio's ns-process-data layout (``images/`` beside ``colmap/``)."""
TRANSFORMS = "transforms.json"
"""The file of a nerfstudio or instant-ngp scene."""


def find_sparse_dir(root: Path) -> Path | None:
    """The first of :data:`SPARSE_DIRS` under ``root`` holding ``cameras.bin`` or ``cameras.txt``, or None."""
    for d in (root / sub for sub in SPARSE_DIRS):
        if any((d / f"cameras{ext}").is_file() for ext in (".bin", ".txt")):
            return d
    return None


def _holds(name: str) -> Callable[[Path], bool]:
    """``folder -> bool``: whether the folder holds the file ``name``."""
    return lambda folder: (Path(folder) / name).is_file()


PARSERS = "splat_framework.data.parsers"
llff = DataparserSpec("poses_bounds.npy", _holds("poses_bounds.npy"), f"{PARSERS}.llff:load_llff", order=10)
"""LLFF's forward-facing scenes (:mod:`splat_framework.data.parsers.llff`)."""
blender = DataparserSpec("transforms_train.json", _holds("transforms_train.json"), f"{PARSERS}.blender:load_blender",
                         order=20)
"""The NeRF synthetic (Blender) scenes (:mod:`splat_framework.data.parsers.blender`)."""
dtu = DataparserSpec("cameras_sphere.npz", _holds("cameras_sphere.npz"), f"{PARSERS}.dtu:load_dtu", order=30)
"""DTU in the IDR / NeuS layout (:mod:`splat_framework.data.parsers.dtu`)."""
transforms = DataparserSpec(TRANSFORMS, _holds(TRANSFORMS), f"{PARSERS}.transforms:load_transforms", order=40)
"""nerfstudio and instant-ngp scenes (:mod:`splat_framework.data.parsers.transforms`)."""
colmap = DataparserSpec("sparse/0/cameras.bin|txt", lambda folder: find_sparse_dir(Path(folder)) is not None,
                        f"{PARSERS}.colmap:load_colmap", order=BUILTIN_ORDER)
"""COLMAP models, one's own photos posed (:mod:`splat_framework.data.parsers.colmap`)."""


def _check(name: str, spec: object) -> str | None:
    return None if isinstance(spec, DataparserSpec) else f"not a DataparserSpec ({type(spec).__name__})"


@cache
def dataparsers() -> dict[str, DataparserSpec]:
    """Format name -> :class:`DataparserSpec` of every registered dataparser, in the order ``--format
    auto`` tries them (:attr:`DataparserSpec.order`, then registration order). One that fails to
    import or is not a spec is left out with one warning naming it (:class:`~splat_framework.entry_points.Parts`)."""
    from ..entry_points import DATAPARSER_ENTRY_POINT_GROUP, Parts

    parts: dict[str, DataparserSpec] = Parts("dataparser").load(DATAPARSER_ENTRY_POINT_GROUP, _check).parts
    return dict(sorted(parts.items(), key=lambda item: item[1].order))


def listed(items: list[str]) -> str:
    """``a, b or c``."""
    return items[0] if len(items) < 2 else f"{', '.join(items[:-1])} or {items[-1]}"
