"""Dataset parsers: folder -> :class:`SceneData` (cameras, image paths, split).

Every dataset format is a dataparser registered in the entry-point group
``splat_framework.dataparsers`` (:mod:`splat_framework.data.dataparsers`), the built-ins too;
``load_scene`` detects the format from the folder contents, trying them in order:

- ``poses_bounds.npy``                     -> llff
- ``transforms_train.json``                -> blender
- ``cameras_sphere.npz``                   -> dtu
- ``transforms.json`` (nerfstudio, instant-ngp) -> transforms
- ``sparse/0/``, ``sparse/`` or ``colmap/sparse/0/`` with ``cameras.bin|txt`` -> colmap
- then a plugin's formats.

(nerfstudio's ns-process-data writes both of the last two: its ``transforms.json`` is read.)

Every failure is a :class:`DataError` with a one-line message naming the file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Literal

from ...entry_points import IMPORT_FAILURES, load_object, raised
from ...errors import did_you_mean
from ..dataparsers import dataparsers, listed
from ..scene import DataError, SceneData
from ..splits import check_views


def _loader(fmt: str) -> Callable[..., SceneData]:
    """The load function of the dataparser named ``fmt`` (a DataError naming the registered ones)."""
    parsers = dataparsers()
    if fmt not in parsers:
        raise DataError(f"unknown dataset format {fmt!r} (choose auto, {', '.join(parsers)})"
                        f"{did_you_mean(fmt, ['auto', *parsers])}")
    return load_object(parsers[fmt].load)


def marked_format(path: Path) -> str | None:
    """The dataset format that recognises folder ``path`` (the first, in detection order), or None; a
    DataError naming the dataparser whose check raises (an OSError passes: the folder's trouble)."""
    path = Path(path)
    for name, spec in dataparsers().items():
        try:
            if spec.recognises(path):
                return name
        except OSError:
            raise
        except IMPORT_FAILURES as e:  # a plugin's check: one line naming it, never a traceback
            raise DataError(f"{path}: dataparser '{name}' failed while recognising it ({raised(e)})") from None
    return None


def detect_format(path: Path) -> str:
    """The dataset format of folder ``path`` (raises DataError when unknown)."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such dataset folder")
    if not path.is_dir():
        raise DataError(f"{path}: not a folder; splat-process turns your own photos or video into a scene folder")
    fmt = marked_format(path)
    if fmt is not None:
        return fmt
    try:
        empty = not any(path.iterdir())
    except OSError as e:
        raise DataError(f"{path}: cannot list folder ({e.strerror or e})") from None
    if empty:
        raise DataError(f"{path}: empty folder, no dataset found")
    markers = listed([spec.marker for spec in dataparsers().values()])
    raise DataError(
        f"{path}: neither a dataset ({markers}) nor a folder of photos; "
        "splat-process turns your own photos or video into a scene folder"
    )


def load_scene(
    path: Path | str,
    *,
    format: str = "auto",
    views: int | Literal["all"] = "all",
    downscale: float | None = None,
) -> SceneData:
    """Parse a dataset folder.

    Args:
        path: dataset folder.
        format: "auto" (detect) or a registered dataparser's name
            (:func:`~splat_framework.data.dataparsers.dataparsers`).
        views: number of training views under the dataset's few-shot
            protocol (see :mod:`splat_framework.data.splits`), or "all".
        downscale: image downscale factor relative to full resolution.
            Defaults: llff 8 (when ``images_8/`` exists), blender 2, dtu 4
            (when ``images_4/`` exists), otherwise 1. A folder
            ``images_F/`` is used when present, else ``images/`` is resized
            on load (``SceneData.image_scale``).

    Raises:
        DataError: for any problem with the folder or its files.
    """
    path = Path(path)
    views = check_views(views)
    try:
        fmt = detect_format(path) if format == "auto" else format
        loader = _loader(fmt)
        if format != "auto" and not path.is_dir():
            raise DataError(f"{path}: no such dataset folder")
        return loader(path, views=views, downscale=downscale)
    except OSError as e:  # file-system trouble not caught closer to the source
        name = e.filename if e.filename is not None else path
        raise DataError(f"{name}: {e.strerror or e}") from None


__all__ = ["detect_format", "load_scene", "marked_format"]
