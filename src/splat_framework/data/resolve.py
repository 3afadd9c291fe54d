"""Find what a user's ``--data`` argument names (a folder of photos or a video is posed by
:func:`splat_framework.sfm.own_photos.resolve_data_path`)."""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import DataError, did_you_mean
from ..files.output_paths import data_inputs
from .builtin_scenes import NAMED_SCENES, SYNTHETIC_PREFIX, builtin_scene_name, unknown_scene_message


def locate_data(spec: str | Path) -> Path:
    """The existing path that a dataset spec names (nothing is posed).

    Order: the path as given; ``synthetic/<name>`` -> the generated scene from
    :func:`splat_framework.data.synthetic.ensure_scene`; a relative path under
    ``$SPLAT_DATA``. Raises DataError when none exists.
    """
    text = str(spec)
    if not text.strip():
        raise DataError("data: empty dataset path")
    path = Path(text).expanduser()
    if path.exists():
        return path
    name = builtin_scene_name(text)
    if name is not None:
        if not name:
            raise DataError(f"{text}: missing synthetic scene name (synthetic/<name>)")
        from . import synthetic  # lazy: written separately, heavy

        return Path(synthetic.ensure_scene(name))
    found = data_inputs(text)  # under $SPLAT_DATA
    if found:
        return found[0]
    raise DataError(missing_data_message(text, path))


def check_data(spec: str | Path) -> None:
    """Raise the DataError that :func:`locate_data` would for ``spec``, without generating a built-in
    scene: what ``splat-train`` refuses before PyTorch loads (a mistyped folder or built-in name)."""
    text = str(spec)
    name = builtin_scene_name(text)
    if name is None or Path(text).expanduser().exists():
        locate_data(text)
    elif refused := unknown_scene_message(name):
        raise DataError(refused)


def missing_data_message(text: str, path: Path) -> str:
    """The one line for a ``--data`` that names nothing: an absolute path suggests only its own
    siblings; a relative name also says where ``$SPLAT_DATA`` points, or how to set it."""
    if path.is_absolute():
        return f"{text}: no such dataset folder{did_you_mean(path.name, [p.name for p in _folders(path.parent)])}"
    env = os.environ.get("SPLAT_DATA")
    hint = did_you_mean(text.replace("\\", "/").rstrip("/"), dataset_names(path, Path(env).expanduser() if env else None))
    if env:
        return f"{text}: no such dataset folder{hint} (also looked in $SPLAT_DATA={env})"
    return (f"{text}: no such dataset folder{hint}; a relative name is also looked up under $SPLAT_DATA, which is "
            "not set: export SPLAT_DATA=/path/to/your/datasets (docs/data.md)")


def dataset_names(asked: Path, data_root: Path | None) -> list[str]:
    """Names that ``--data asked`` could have meant: the folders beside ``asked`` (from the current
    folder and from ``data_root``, ``$SPLAT_DATA``), those one and two levels under ``data_root``
    (``llff/fern``), and the synthetic scenes."""
    names = [SYNTHETIC_PREFIX + n for n in NAMED_SCENES]
    for root in (Path.cwd(), data_root):
        if root is not None:
            names += [(asked.parent / p.name).as_posix() for p in _folders(root / asked.parent)]
    if data_root is not None:
        for top in _folders(data_root):
            names += [top.name] + [f"{top.name}/{p.name}" for p in _folders(top)]
    return names


def _folders(folder: Path) -> list[Path]:
    """The visible sub-folders of ``folder`` (none when it cannot be listed)."""
    try:
        return [p for p in folder.iterdir() if p.is_dir() and not p.name.startswith(".")]
    except OSError:
        return []
