"""Atomic, checksummed file writes: a crash or a full disk never leaves a half-written file.

Every run artefact goes through :func:`atomic_write_bytes`: the data is written
to a temporary file in the destination folder, flushed and fsynced, then
renamed over the destination (``os.replace`` is atomic on POSIX and Windows).
On any error, disk full included, the temporary file is removed and the
previous content of the destination is left untouched.

JSON results (``metrics.json``, ``config.json``) carry their own checksum:
:func:`atomic_write_json` adds ``"checksum": "sha256:<hex>"`` computed over the
canonical JSON form of the other keys, and :func:`read_json` verifies it.
Torch-free: the CLIs import this module.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

from ..errors import DataError

_UMASK: dict[str, int] = {}
CHECKSUM_KEY = "checksum"
"""Key of the embedded checksum in JSON results."""


def _fsync_dir(folder: Path) -> None:
    """Make a rename durable (best effort: not every platform can open folders)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _new_file_mode(folder: Path) -> int:
    """The mode a file written into ``folder`` gets: what ``open`` would give it (0666 less the
    umask: a user's results follow the umask like any file they write), except in a private folder
    (no permission for the group or others: the caches') where it stays 0600."""
    try:
        if os.stat(folder).st_mode & 0o077 == 0:
            return 0o600
    except OSError:
        pass
    return 0o666 & ~_process_umask()


def _process_umask() -> int:
    """The process's umask, read once (``os.umask`` can only be read by setting it, which would
    race with other threads creating files)."""
    if "umask" not in _UMASK:
        _UMASK["umask"] = os.umask(0o022)
        os.umask(_UMASK["umask"])
    return _UMASK["umask"]


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder, then rename. The file
    gets the mode a plain ``open`` would give it (:func:`_new_file_mode`), not the temporary's 0600.

    On any error (disk full included) the temporary file is removed, the
    previous content of ``path``, if any, is left untouched, and the error
    (an ``OSError`` with ``filename`` set to ``path``) propagates.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, _new_file_mode(path.parent))
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(e, OSError) and e.filename is None:
            e.filename = str(path)
        raise
    _fsync_dir(path.parent)


def atomic_write_text(path: Path, text: str) -> None:
    """Text version of :func:`atomic_write_bytes` (UTF-8)."""
    atomic_write_bytes(path, text.encode("utf-8"))


def json_checksum(obj: dict) -> str:
    """``"sha256:<hex>"`` of the canonical JSON form of ``obj`` without its checksum key."""
    body = {k: v for k, v in obj.items() if k != CHECKSUM_KEY}
    canon = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return "sha256:" + hashlib.sha256(canon.encode("utf-8")).hexdigest()


def atomic_write_json(path: Path, obj: dict, checksum: bool = True) -> None:
    """Write ``obj`` as indented JSON, atomically, with an embedded checksum by default."""
    payload = {k: v for k, v in obj.items() if k != CHECKSUM_KEY}
    if checksum:
        # round-trip first so that the checksum covers exactly what a reader will parse
        payload = json.loads(json.dumps(payload, allow_nan=True))
        payload[CHECKSUM_KEY] = json_checksum(payload)
    atomic_write_text(path, json.dumps(payload, indent=2, allow_nan=True) + "\n")


def read_json(path: Path, require_checksum: bool = False, verify: bool = True) -> dict:
    """Read a JSON object written by :func:`atomic_write_json` and verify its checksum.

    Files without a checksum are accepted unless ``require_checksum``; ``verify=False``
    skips the checksum entirely (a file the user edited on purpose). Raises
    DataError (one line) when the file is unreadable, not JSON, or its checksum
    does not match (truncated, corrupt or edited by hand).
    """
    path = Path(path)
    try:
        payload = json.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise DataError(f"{path}: cannot read ({e.strerror or e})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise DataError(f"{path}: not valid JSON, truncated or corrupt ({e})") from None
    except RecursionError:  # [[[[...]]]] deeper than the interpreter's stack
        raise DataError(f"{path}: JSON nested too deeply to be a file splat wrote") from None
    if not isinstance(payload, dict):
        raise DataError(f"{path}: expected a JSON object")
    stored = payload.get(CHECKSUM_KEY)
    if not verify:
        return payload
    if stored is None:
        if require_checksum:
            raise DataError(f"{path}: no checksum")
        return payload
    if stored != json_checksum(payload):
        raise DataError(f"{path}: checksum mismatch (truncated, corrupt or edited file)")
    return payload
