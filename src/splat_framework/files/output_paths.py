"""Where a command may write: one guard for every output path (torch-free).

Every command that writes (splat-train, splat-process, splat-scene, splat-export,
splat-render, splat-match, splat-sweep) checks its target here before any work:

- the target is new (or an empty folder), or recognisably written by the same
  command: a run folder (``config.json`` with our checksum), a folder carrying our
  marker file ``.splat-output.json``, a PLY or compressed PLY with our header comment, an SPZ
  with our gzip comment, a SOG whose ``meta.json`` names splat-export, a ``.splat`` (a format
  with no room for a mark: any file of whole, well-formed 32-byte records), a video or render
  folder inside a run folder;
- never an input (:class:`Input`), inside it, or a folder that holds it: the folders or files the
  command reads (``--data``'s folder, the photos), and for a command that reads a run folder the
  entries of its layout (checkpoints/, renders/, config.json, ...; :func:`run_inputs`) and its
  dataset folder. Paths are compared resolved (symlinks followed, ``..`` removed). The one
  exception: an entry that the same command writes by default (``splat-render RUN`` refreshes
  RUN/renders, ``splat-export RUN`` writes RUN/point_cloud.ply) may be the target itself;
- never a special file (FIFO, device node, socket), never below a path component
  that is a file, never in a folder the user cannot write;
- replacing an output of ours needs ``--overwrite``, and removes only the entries
  that command writes (:attr:`OutputKind.entries`); symlinks among them are
  unlinked, never followed. Anything else in the folder is kept.

Each refusal is a :class:`~splat_framework.errors.DataError` (one line, exit code 2),
or :class:`OutputNotWritable` (exit code 1: the machine, not the input).
"""

from __future__ import annotations

import json
import os
import shutil
import stat
from dataclasses import dataclass
from fnmatch import fnmatch
from pathlib import Path
from typing import Callable, Iterable

from ..errors import DataError
from .run_lock import LOCK_NAME

__all__ = [
    "MARKER", "PLY_COMMENT", "Input", "OutputKind", "OutputNotWritable", "RUN_FOLDER", "SCENE_FOLDER", "PROCESSED_SCENE",
    "PLY_FILE", "COMPRESSED_PLY_FILE", "SPZ_FILE", "SOG_FILE", "DOT_SPLAT_FILE", "EXPORT_FILES", "EXPORT_SUFFIXES",
    "SPZ_COMMENT", "SOG_GENERATOR", "RENDER_FOLDER", "VIDEO_FILE", "MATCH_FOLDER", "SWEEP_FOLDER", "check_path", "check_output",
    "clear_output", "mark_output", "claim_output", "install_output", "is_run_folder", "data_inputs", "run_inputs",
    "RUN_LAYOUT",
]

MARKER = ".splat-output.json"
"""File that a folder-writing command leaves in its output folder: ``{"written_by": ..., "kind": ...}``."""

PLY_COMMENT = "comment written by splat-export"
"""Header line of every PLY (and compressed PLY) that splat-export writes."""
SPZ_COMMENT = "written by splat-export"
"""The gzip header comment (FCOMMENT) of every SPZ that splat-export writes."""
SOG_GENERATOR = "splat-export"
"""``asset.generator`` in the ``meta.json`` of every SOG that splat-export writes."""


class OutputNotWritable(DataError):
    """The output path cannot be written (permissions, read-only file system): exit code 1."""

    cli_exit_code = 1


def _lstat(path: Path) -> os.stat_result | None:
    try:
        return os.lstat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None


def _is_regular(path: Path) -> bool:
    """A regular file, not a symlink (so that recognising a file never opens a FIFO or follows a link)."""
    st = _lstat(path)
    return st is not None and stat.S_ISREG(st.st_mode)


def _read_marker(folder: Path) -> dict:
    path = folder / MARKER
    if not _is_regular(path) or os.lstat(path).st_size > 4096:
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def is_run_folder(folder: Path) -> bool:
    """Whether ``folder`` holds a ``config.json`` written by splat-train (schema version, method, valid checksum)."""
    from ..config import read_config_json

    path = Path(folder) / "config.json"
    if not _is_regular(path):
        return False
    try:
        read_config_json(path)
    except (DataError, OSError, ValueError):
        return False
    return True


def _is_synthetic_scene(folder: Path) -> bool:
    """A scene folder splat-scene wrote before the marker existed: its ``scene.json`` names our generator."""
    path = folder / "scene.json"
    if not _is_regular(path) or os.lstat(path).st_size > 1 << 20:
        return False
    try:
        return json.loads(path.read_text(encoding="utf-8")).get("generator") == "splat_framework.data.synthetic"
    except (OSError, ValueError, AttributeError):
        return False


def _ply_is_ours(path: Path) -> bool:
    """Whether the PLY header (up to ``end_header``, first 64 KiB) holds :data:`PLY_COMMENT`."""
    if not _is_regular(path):
        return False
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
    except OSError:
        return False
    header = head.split(b"end_header", 1)[0]
    return head.startswith(b"ply") and PLY_COMMENT.encode() in header.splitlines()


def _spz_is_ours(path: Path) -> bool:
    """Whether the file starts with a gzip header whose only optional field is :data:`SPZ_COMMENT`."""
    if not _is_regular(path):
        return False
    try:
        with open(path, "rb") as f:
            head = f.read(10 + len(SPZ_COMMENT) + 1)
    except OSError:
        return False
    return head[:4] == b"\x1f\x8b\x08\x10" and head[10:] == SPZ_COMMENT.encode() + b"\x00"


def _sog_is_ours(path: Path) -> bool:
    """Whether the file is a zip whose ``meta.json`` (at most 1 MiB) names :data:`SOG_GENERATOR`."""
    import zipfile

    if not _is_regular(path):
        return False
    try:
        with zipfile.ZipFile(path) as z:
            info = z.getinfo("meta.json")
            if info.file_size > 1 << 20:
                return False
            meta = json.loads(z.read(info))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return False
    return isinstance(meta, dict) and isinstance(meta.get("asset"), dict) and meta["asset"].get("generator") == SOG_GENERATOR


def _is_splat_file(path: Path) -> bool:
    """Whether the file is a ``.splat``: whole 32-byte records, and in the first 4096 finite positions
    and finite, positive scales (the format has no header that a mark could go in)."""
    import numpy as np

    if not _is_regular(path):
        return False
    size = os.lstat(path).st_size
    if size == 0 or size % 32:
        return False
    try:
        with open(path, "rb") as f:
            head = np.frombuffer(f.read(32 * 4096), "<f4").reshape(-1, 8)
    except OSError:
        return False
    return bool(np.isfinite(head[:, :6]).all() and (head[:, 3:6] > 0).all())


@dataclass(frozen=True)
class OutputKind:
    """What a command writes and how an earlier output of it is recognised."""

    key: str
    """Identifier stored in the marker file."""
    name: str
    """What the user reads in messages ("run folder")."""
    command: str
    """The command that writes it ("splat-train")."""
    folder: bool
    """A folder (True) or a single file."""
    entries: tuple[str, ...] = ()
    """Glob patterns of the entries the command writes in the folder: all that ``--overwrite`` removes."""
    recognise: Callable[[Path], bool] | None = None
    """Recognises an output of ours without (or besides) the marker file."""
    exists_hint: str = "pass --overwrite to replace it"
    """How to go on when an output of ours is there (the message's last words)."""
    ignored: tuple[str, ...] = ()
    """Names that do not make a folder non-empty (a run folder's lock file)."""

    def is_empty(self, path: Path) -> bool:
        """Whether the folder ``path`` holds nothing but :attr:`ignored` names."""
        return all(p.name in self.ignored for p in Path(path).iterdir())

    def is_ours(self, path: Path) -> bool:
        if self.folder and _read_marker(path).get("kind") == self.key:
            return True
        return bool(self.recognise and self.recognise(path))


def _in_run_folder(path: Path) -> bool:
    return is_run_folder(Path(path).parent)


EXPORT_SUFFIXES = {"ply": ".ply", "spz": ".spz", "sog": ".sog", "splat": ".splat", "compressed-ply": ".compressed.ply"}
"""splat-export's formats -> their file extensions; its default files are RUN/point_cloud + each."""

RUN_FOLDER = OutputKind(
    "run", "run folder", "splat-train", True,
    entries=("config.json", "metrics.json", "checkpoints", "renders", "*.mp4", "point_cloud", "cameras.json",
             "train.log", *("point_cloud" + s for s in EXPORT_SUFFIXES.values()), "sweep.json", "sweep-spec.json",
             "sweep.log", MARKER),
    recognise=is_run_folder,
    exists_hint="use --resume to continue it or --overwrite to replace it",
    ignored=(LOCK_NAME,),
)
SCENE_FOLDER = OutputKind(
    "synthetic-scene", "scene folder", "splat-scene", True,
    entries=("images", "depths", "train", "test", "poses_bounds.npy", "transforms_*.json", "cameras.json",
             "scene.json"),
    recognise=_is_synthetic_scene,
)
PROCESSED_SCENE = OutputKind("processed-scene", "scene folder", "splat-process", True,
                             entries=("images", "sparse", "posing.json"))


def _export_kind(key: str, name: str, ours: Callable[[Path], bool]) -> OutputKind:
    """The file of splat-export's format ``key``: ``ours`` recognises it, and so does its default name
    (``point_cloud`` + its extension) in a run folder."""
    default = "point_cloud" + EXPORT_SUFFIXES[key]
    return OutputKind(key, name, "splat-export", False,
                      recognise=lambda p: ours(p) or (Path(p).name == default and _in_run_folder(p)))


PLY_FILE = _export_kind("ply", "PLY file", _ply_is_ours)
COMPRESSED_PLY_FILE = _export_kind("compressed-ply", "compressed PLY file", _ply_is_ours)
SPZ_FILE = _export_kind("spz", "SPZ file", _spz_is_ours)
SOG_FILE = _export_kind("sog", "SOG file", _sog_is_ours)
DOT_SPLAT_FILE = _export_kind("splat", ".splat file", _is_splat_file)
EXPORT_FILES: dict[str, OutputKind] = {
    "ply": PLY_FILE, "spz": SPZ_FILE, "sog": SOG_FILE, "splat": DOT_SPLAT_FILE, "compressed-ply": COMPRESSED_PLY_FILE,
}
"""splat-export's formats -> the output kind of each (extensions: :data:`EXPORT_SUFFIXES`)."""

RENDER_FOLDER = OutputKind(
    "renders", "render folder", "splat-render", True,
    entries=("*_render.png", "*_depth.png"),  # the trainer's *_gt.png, *_grid.png of a run's renders/ stay
    recognise=lambda p: Path(p).name == "renders" and _in_run_folder(p),
)
VIDEO_FILE = OutputKind("video", "video", "splat-render", False, recognise=_in_run_folder)
MATCH_FOLDER = OutputKind(
    "matches", "match folder", "splat-match", True,
    entries=("matches.npz", "matches_*_*.png"),  # the cache/ stays: it is keyed by the inputs
    recognise=lambda p: _is_regular(Path(p) / "matches.npz"),
)
def _is_legacy_sweep(folder: Path) -> bool:
    """A sweep folder written before the marker existed: its ``results.json`` (runs and rows), or a
    ``runs/`` folder and nothing but what a sweep writes (the runs of a sweep killed before its tables)."""
    folder = Path(folder)
    results = folder / "results.json"
    if _is_regular(results):
        try:
            payload = json.loads(results.read_text(encoding="utf-8"))
            return isinstance(payload, dict) and {"runs", "rows"} <= payload.keys()
        except (OSError, ValueError):
            return False
    names = [p.name for p in folder.iterdir()]
    return "runs" in names and all(any(fnmatch(n, pat) for pat in SWEEP_ENTRIES) for n in names)


SWEEP_ENTRIES = ("runs", "results.md", "results.csv", "figures", ".results.*.tmp")
SWEEP_FOLDER = OutputKind("sweep", "sweep folder", "splat-sweep", True, recognise=_is_legacy_sweep, ignored=(LOCK_NAME,))


def _describe_special(mode: int) -> str:
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device node"
    return "a special file"


@dataclass(frozen=True)
class Input:
    """A path a command reads, or a part of a run folder that another command manages: an output
    may not be it, lie inside it or hold it."""

    path: Path
    what: str = ""
    """How a refusal names it ("the run folder's checkpoints/ (managed by splat-train)"); default
    "the input PATH"."""
    writers: tuple[str, ...] = ()
    """The :attr:`OutputKind.key` of each kind whose output may be this very path (a run's renders/
    is splat-render's default folder); never inside it."""


def _overlaps(out: Path, kind: OutputKind, inputs: Iterable[Path | Input]) -> str | None:
    """How ``out`` overlaps the first input it is, lies inside or holds (paths resolved); None if none."""
    target = out.resolve()
    for given in inputs:
        given = given if isinstance(given, Input) else Input(Path(given))
        src = Path(given.path).resolve()
        what = given.what or f"the input {src}"
        if target == src and kind.key not in given.writers:
            return f"is {what}"
        if src in target.parents:
            return f"is inside {what}"
        if target in src.parents:
            return f"holds {what}"
    return None


def data_inputs(spec: str | Path) -> list[Path]:
    """The existing folder or file that a ``--data`` spec names, as given or under ``$SPLAT_DATA``
    (nothing is generated or posed: ``synthetic/...`` names no folder yet); empty when none."""
    path = Path(str(spec)).expanduser()
    env = os.environ.get("SPLAT_DATA")
    if not path.exists() and env and not path.is_absolute():
        path = Path(env).expanduser() / path
    return [path] if str(spec).strip() and path.exists() else []


RUN_LAYOUT: dict[str, tuple[str, ...]] = {
    **{name: () for name in (*RUN_FOLDER.entries, *RUN_FOLDER.ignored) if not any(c in name for c in "*?[")},
    **{"point_cloud" + EXPORT_SUFFIXES[k]: (kind.key,) for k, kind in EXPORT_FILES.items()},  # splat-export's defaults
    "renders": (RENDER_FOLDER.key,),  # splat-render's default folder
}
"""The named entries of a run folder's layout -> the keys of the outputs of other commands that may be
that very entry (videos, ``*.mp4``, are splat-render's own: no named entry)."""


def run_inputs(run_dir: Path) -> list[Input]:
    """What an output of a command reading the run folder ``run_dir`` must keep clear of: the entries
    of its layout (:data:`RUN_LAYOUT`) and its dataset folders (:func:`_run_data_folders`)."""
    run_dir = Path(run_dir)
    layout = [Input(run_dir / name, f"the run folder's {name}{'/' if (run_dir / name).is_dir() else ''} "
                    f"(managed by {RUN_FOLDER.command})", writers) for name, writers in RUN_LAYOUT.items()]
    return layout + [Input(p, f"the run's dataset folder {p.resolve()}") for p in _run_data_folders(run_dir)]


def _run_data_folders(run_dir: Path) -> list[Path]:
    """The dataset folders that the run's ``config.json`` records: the folder the run resolved, and
    the one its ``data`` spec names (:func:`data_inputs`; a folder of photos); none when the config
    cannot be read (the command then reports the run itself)."""
    from ..config import read_config_json

    try:
        config = read_config_json(Path(run_dir) / "config.json", trust_edits=True)[1]
    except (DataError, OSError, ValueError):
        return []
    record = config.get("resolved_data")
    recorded = record.get("path") if isinstance(record, dict) else None
    return ([Path(recorded)] if isinstance(recorded, str) else []) + data_inputs(config.get("data", ""))


def check_path(path: Path, kind: OutputKind, *, inputs: Iterable[Path | Input] = (), flag: str = "--out") -> None:
    """Refuse (one line) a target that can never be written, whoever wrote what is there.

    A path component that is a file, a folder that is not writable, a special file
    (FIFO, device node, socket) or a broken link at ``path``, a file where a folder
    is written or the other way round, and any overlap with ``inputs``.
    """
    path = Path(path)
    for parent in path.parents:  # the nearest existing folder above the target
        if _lstat(parent) is None:
            continue
        if not parent.is_dir():
            raise DataError(f"{path}: {parent} is not a folder ({flag} must name a path below a folder)")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise OutputNotWritable(f"{path}: cannot write in {parent} (permission denied or read-only)")
        break
    st = _lstat(path)
    if st is not None:
        if stat.S_ISLNK(st.st_mode):
            try:
                st = os.stat(path)
            except OSError:
                raise DataError(f"{path}: is a broken symbolic link; {flag} must name a {kind.name}") from None
        if stat.S_ISDIR(st.st_mode):
            if not kind.folder:
                raise DataError(f"{path}: is a folder; {flag} names the {kind.name} to write")
            if not os.access(path, os.W_OK | os.X_OK):
                raise OutputNotWritable(f"{path}: cannot write in it (permission denied or read-only)")
        elif not stat.S_ISREG(st.st_mode):
            raise DataError(f"{path}: is {_describe_special(st.st_mode)}; {flag} must name a {kind.name}")
        elif kind.folder:
            raise DataError(f"{path}: exists and is not a folder ({flag} names the {kind.name} to write)")
    overlap = _overlaps(path, kind, inputs)
    if overlap:
        raise DataError(f"{path}: {flag} {overlap}; choose a separate {kind.name}")


def check_output(path: Path, kind: OutputKind, *, overwrite: bool = False, keep: bool = False,
                 inputs: Iterable[Path | Input] = (), flag: str = "--out") -> bool:
    """Refuse (one line) a target that ``kind``'s command may not write; True when an output of
    ours is there and is to be replaced (the caller removes it with :func:`clear_output`).

    ``overwrite``: the user's ``--overwrite``. ``keep``: the command continues what is there
    (a sweep resumes; an output of ours is then kept, not replaced). ``inputs``: the folders or
    files the command reads (paths or :class:`Input` s), which the target must not be, be inside
    of, or hold.
    """
    path = Path(path)
    check_path(path, kind, inputs=inputs, flag=flag)
    if not os.path.lexists(path) or (kind.folder and kind.is_empty(path)):
        return False
    if not kind.is_ours(path):
        what = "is not empty and is not" if kind.folder else "exists and is not"
        raise DataError(f"{path}: {what} a {kind.name} written by {kind.command}; choose another {flag} "
                        f"(it is never replaced)")
    if keep:
        return False
    if not overwrite:
        if kind.folder:
            raise DataError(f"{path}: {kind.name} exists and is not empty ({kind.exists_hint})")
        raise DataError(f"{path}: {kind.name} exists ({kind.exists_hint})")
    return True


def _remove(path: Path) -> None:
    """Remove a file, a symlink (the link, never its target) or a folder tree (links inside unlinked)."""
    st = _lstat(path)
    if st is None:
        return
    if stat.S_ISDIR(st.st_mode):
        shutil.rmtree(path)  # rmtree unlinks the symlinks it meets, it never descends into them
    else:
        path.unlink()


def clear_output(path: Path, kind: OutputKind) -> None:
    """Remove what ``kind``'s command wrote in folder ``path`` (its :attr:`~OutputKind.entries` and the
    marker), or the file ``path``; nothing else in the folder is touched."""
    path = Path(path)
    if not kind.folder:
        _remove(path)
        return
    if not path.is_dir():
        return
    for pattern in (*kind.entries, MARKER):
        for entry in sorted(path.glob(pattern)):
            _remove(entry)


def mark_output(folder: Path, kind: OutputKind) -> None:
    """Write the marker that recognises ``folder`` as ``kind``'s output."""
    from ..runtime.io import atomic_write_text

    atomic_write_text(Path(folder) / MARKER, json.dumps({"written_by": kind.command, "kind": kind.key}) + "\n")


def claim_output(path: Path, kind: OutputKind, *, overwrite: bool = False, inputs: Iterable[Path | Input] = (),
                 flag: str = "--out") -> Path:
    """Check ``path`` (see :func:`check_output`), remove an earlier output of ours when
    ``overwrite``, and create the folder with its marker (folder kinds). Returns ``path``."""
    path = Path(path)
    if check_output(path, kind, overwrite=overwrite, inputs=inputs, flag=flag):
        clear_output(path, kind)
    if kind.folder:
        path.mkdir(parents=True, exist_ok=True)
        mark_output(path, kind)
    return path


def install_output(staged: Path, path: Path, kind: OutputKind) -> Path:
    """Move the finished folder ``staged`` to ``path`` (checked beforehand with :func:`check_output`):
    an earlier output of ours there is removed first, anything else in ``path`` is kept."""
    staged, path = Path(staged), Path(path)
    if not os.path.lexists(path):
        staged.rename(path)
    else:
        clear_output(path, kind)
        for entry in sorted(staged.iterdir()):
            entry.rename(path / entry.name)
    mark_output(path, kind)
    return path
