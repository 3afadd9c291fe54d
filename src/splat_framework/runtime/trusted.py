"""What may be loaded from a cache: folders and files only the user can change, checked against
the sha256 recorded when they were written (torch-free; the threat model is in docs/reliability.md).

Two rules, as ssh applies to its key files:

- **Ownership and permissions**: a cache folder, every folder below it on the way to a file, and
  the file itself must belong to the current user (or root) and be writable by nobody else.
  :func:`untrusted_reason` says why a path fails; :func:`private_folder` creates folders that pass
  (mode 0700, whatever the umask) and :func:`make_private` removes the group's and others' write
  permission from a file the user just wrote (a umask of 002 would otherwise leave it open).
- **Manifests**: whatever the project builds or saves and later *executes or unpickles* (the
  native kernels' library, saved compiled graphs) is recorded with its sha256 in a manifest
  written at build time (:func:`write_manifest`); :func:`manifest_mismatch` says why files do not
  match it (missing manifest, another digest, an unreadable file). A mismatch means: build again,
  never load.
- **Signatures**: a manifest is signed with a secret of this user's (HMAC-SHA256, the key in
  :func:`signing_key_path`, 0600 in a 0700 folder outside every cache, made on first use), so a
  cache copied or unpacked from elsewhere, or a planted file with a manifest regenerated from the
  public source, does not vouch for itself; links inside a cache are refused, not followed.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import secrets
import stat
import warnings
from pathlib import Path

MANIFEST = "manifest.json"
"""The file, beside the artefacts it records, that maps each artefact's name to its sha256."""
_FORMAT = "splat-manifest-2"
_KEY: dict[str, bytes] = {}  # the signing key, read once
_UNUSABLE: dict[str, str] = {}  # key file -> why it is not used (this process signs with its own key)


def signing_key_path() -> Path:
    """Where this user's manifest signing key lives: ``$XDG_CONFIG_HOME/splat/cache-key`` (default
    ``~/.config/splat/cache-key``), outside every cache."""
    base = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    return Path(base) / "splat" / "cache-key"


def _signing_key() -> bytes:
    """This user's secret (32 random bytes), made 0600 on first use. Where it cannot be made or used
    (:func:`key_problem`), a secret of this process only, with one warning naming the file, what is
    wrong and the command that fixes it (once a process): the caches it signs vouch for nothing in
    the next process, whose kernels are built again until the key is fixed."""
    path = signing_key_path()
    if str(path) in _KEY:
        return _KEY[str(path)]
    key, problem = None, None
    try:
        if not os.path.lexists(path):  # written aside, then linked in: two processes starting at once agree on one key
            private_folder(path.parent)
            fresh = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}")
            fd = os.open(fresh, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            with os.fdopen(fd, "w") as f:
                f.write(secrets.token_hex(32))
            try:
                os.link(fresh, path)
            except FileExistsError:
                pass
            finally:
                fresh.unlink()
    except OSError as e:
        problem = (f"cannot be made ({e.strerror or type(e).__name__})",
                   f"make {path.parent} a folder of yours, or set XDG_CONFIG_HOME to one")
    if problem is None:
        key, problem = _read_key(path)
    if problem is not None:
        _UNUSABLE[str(path)] = f"{path}: {problem[0]}"
        warnings.warn(f"{path}: unusable cache signing key: {problem[0]}; this process signs with a key of its own, "
                      f"so every process builds the cached kernels again until it is fixed: {problem[1]}", stacklevel=3)
    _KEY[str(path)] = key if key is not None else secrets.token_bytes(32)
    return _KEY[str(path)]


KEY_BYTES = 32
"""The signing key's length: a file holds its 64 hex digits."""


def _read_key(path: Path) -> tuple[bytes | None, tuple[str, str] | None]:
    """(the key in ``path``, None), or (None, (what is wrong, the command that fixes it)): the file
    must be a regular file (never a link, a folder, a FIFO or a device: none is opened), of this user
    alone (mode 0600), in a folder nobody else may write, and hold 64 hex digits."""
    remove = f"rm -r '{path}' (the next run makes a new key)"
    try:
        st = os.lstat(path)
    except OSError as e:
        return None, (f"cannot be read ({e.strerror or type(e).__name__})", remove)
    kind = _file_kind(st.st_mode)
    if kind:
        return None, (f"a {kind}, not a file", remove)
    folder = untrusted_reason(path.parent)
    if folder:
        return None, (f"its folder {folder}: anyone who may write it may swap the key",
                      f"chmod 700 '{path.parent}' && {remove}")
    if not _owner_ok(st.st_uid):
        return None, (f"belongs to another user (uid {st.st_uid})", remove)
    if stat.S_IMODE(st.st_mode) & 0o077:
        return None, (f"mode {stat.S_IMODE(st.st_mode):o}: others may read it and sign for you", remove)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
        with os.fdopen(fd, "rb") as f:
            if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):  # swapped since the lstat
                return None, ("not a regular file", remove)
            text = f.read(4 * KEY_BYTES)
    except OSError as e:
        return None, (f"cannot be read ({e.strerror or type(e).__name__})", remove)
    try:
        key = bytes.fromhex(text.decode("ascii").strip())
    except (UnicodeDecodeError, ValueError):
        key = b""
    if len(key) != KEY_BYTES:
        return None, (f"does not hold a key ({2 * KEY_BYTES} hex digits)", remove)
    return key, None


def _file_kind(mode: int) -> str | None:
    """What a path of ``mode`` is when it is not a regular file (``symbolic link``, ``folder``, ``FIFO``...)."""
    if stat.S_ISREG(mode):
        return None
    kinds = {stat.S_ISLNK: "symbolic link", stat.S_ISDIR: "folder", stat.S_ISFIFO: "FIFO", stat.S_ISSOCK: "socket"}
    return next((name for test, name in kinds.items() if test(mode)), "device or special file")


def _key_note() -> str:
    """How the manifest check's failure reads: whose key did not sign it (this user's, or, where the
    key file is unusable, this process's own)."""
    path = str(signing_key_path())
    _signing_key()
    if path in _UNUSABLE:
        return f"not signed by this process's key (the signing key {_UNUSABLE[path]})"
    return "not signed by this user's key"


def _signature(entries: dict[str, str]) -> str:
    body = json.dumps({"format": _FORMAT, "files": entries}, sort_keys=True, separators=(",", ":")).encode()
    return hmac.new(_signing_key(), body, hashlib.sha256).hexdigest()


def _owner_ok(uid: int) -> bool:
    return uid in (os.geteuid(), 0)


def untrusted_reason(path: Path, root: Path | None = None) -> str | None:
    """Why ``path`` (and each folder from ``root`` down to it) may not be trusted, else None.

    A path fails when it belongs to another user (root excepted) or when its group or others may
    write it. ``root`` must be ``path`` or a folder above it; folders above ``root`` are not checked
    (``/tmp`` may hold a private cache). Where the platform has no owners (Windows), nothing fails.
    """
    if not hasattr(os, "geteuid"):
        return None
    path = Path(path)
    chain = [path]
    if root is not None:
        root = Path(root)
        chain = [root, *[root.joinpath(*path.relative_to(root).parts[:i]) for i in range(1, len(path.relative_to(root).parts) + 1)]]
    for p in chain:
        try:
            st = p.stat()
        except OSError as exc:
            return f"{p}: cannot be read ({exc.strerror or type(exc).__name__})"
        if not _owner_ok(st.st_uid):
            return f"{p}: belongs to another user (uid {st.st_uid})"
        if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
            return f"{p}: writable by {'others' if st.st_mode & stat.S_IWOTH else 'its group'} (mode {stat.S_IMODE(st.st_mode):o})"
    return None


def private_folder(path: Path) -> Path:
    """``path`` created (with its missing parents) readable and writable by the user alone."""
    path = Path(path)
    missing = []
    p = path
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    for p in reversed(missing):
        try:
            p.mkdir(mode=0o700)
        except FileExistsError:  # another process made it meanwhile
            pass
        else:
            os.chmod(p, 0o700)  # mkdir's mode is masked by the umask
    return path


def make_private(path: Path) -> None:
    """Remove the group's and others' write permission from a file or folder the user owns."""
    mode = stat.S_IMODE(os.stat(path).st_mode)
    if mode & (stat.S_IWGRP | stat.S_IWOTH):
        os.chmod(path, mode & ~(stat.S_IWGRP | stat.S_IWOTH))


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_manifest(folder: Path, names: list[str]) -> None:
    """Record the sha256 of ``folder/name`` for each name in ``folder/manifest.json`` (atomically;
    an existing manifest's other entries are kept), and make the files and the manifest private."""
    from .io import atomic_write_json

    folder = Path(folder)
    entries = _read_entries(folder) or {}
    for name in names:
        make_private(folder / name)
        entries[name] = sha256_file(folder / name)
    atomic_write_json(folder / MANIFEST, {"format": _FORMAT, "files": entries, "signature": _signature(entries)})
    make_private(folder / MANIFEST)


def _read_entries(folder: Path) -> dict[str, str] | None:
    """The manifest's entries when it is well-formed and signed with this user's key, else None."""
    from .io import read_json

    try:
        data = read_json(Path(folder) / MANIFEST, require_checksum=True)
    except Exception:
        return None
    files = data.get("files") if data.get("format") == _FORMAT else None
    if not isinstance(files, dict) or not isinstance(data.get("signature"), str):
        return None
    return files if hmac.compare_digest(data["signature"], _signature(files)) else None


def manifest_mismatch(folder: Path, names: list[str], root: Path | None = None) -> str | None:
    """Why the files ``folder/name`` may not be loaded, else None: a file or folder fails
    :func:`untrusted_reason` (checked from ``root``), the manifest is missing or unreadable, it does
    not list a file, or a file's sha256 differs from the one recorded."""
    folder = Path(folder)
    entries = _read_entries(folder)
    if entries is None:
        return (f"{folder / MANIFEST}: missing, unreadable or {_key_note()} (the files were not "
                "built by this user's runs of this version)")
    for name in names:
        if (folder / name).is_symlink():
            return f"{folder / name}: a symbolic link"
        reason = untrusted_reason(folder / name, root if root is not None else folder)
        if reason:
            return reason
        if name not in entries:
            return f"{folder / name}: not in {MANIFEST}"
        try:
            digest = sha256_file(folder / name)
        except OSError as exc:
            return f"{folder / name}: cannot be read ({exc.strerror or type(exc).__name__})"
        if digest != entries[name]:
            return f"{folder / name}: its content differs from the one recorded in {MANIFEST} when it was built"
    return None


def _files_under(folder: Path) -> list[str]:
    """Every file below ``folder`` (links included, not followed) but its manifest, as relative
    POSIX paths."""
    out = []
    for parent, dirs, files in os.walk(folder):
        for name in files + [d for d in dirs if os.path.islink(os.path.join(parent, d))]:
            rel = Path(parent, name).relative_to(folder).as_posix()
            if rel != MANIFEST:
                out.append(rel)
    return sorted(out)


def write_folder_manifest(folder: Path) -> None:
    """Record every file below ``folder`` in its manifest (see :func:`write_manifest`)."""
    write_manifest(folder, _files_under(folder))


def folder_mismatch(folder: Path, root: Path | None = None) -> str | None:
    """Why the files below ``folder`` may not be used, else None: what :func:`manifest_mismatch`
    finds, a file the manifest does not list or lists but is gone, or a symbolic link."""
    folder = Path(folder)
    entries = _read_entries(folder)
    if entries is None:
        return (f"{folder / MANIFEST}: missing, unreadable or {_key_note()} (the folder was not "
                "written by this user's runs of this version)")
    present = _files_under(folder)
    for name in present:
        if (folder / name).is_symlink():
            return f"{folder / name}: a symbolic link"
    for name in sorted(set(entries) - set(present)):
        return f"{folder / name}: missing"
    return manifest_mismatch(folder, present, root)


__all__ = ["MANIFEST", "folder_mismatch", "make_private", "manifest_mismatch", "private_folder",
           "sha256_file", "untrusted_reason", "write_folder_manifest", "write_manifest"]
