"""Where the framework keeps what it generates or computes once (every layer may use it).

The cache folder is checked before anything is read from it or written to it
(:func:`~splat_framework.runtime.trusted.untrusted_reason`): one that belongs to another user or
that others may write is refused with one warning line, and a private folder of the user's own
under the system's temporary folder is used instead.
"""

from __future__ import annotations

import os
import tempfile
import warnings
from pathlib import Path

from ..runtime.trusted import private_folder, untrusted_reason

_REFUSED: dict[Path, Path] = {}
"""Configured cache folder -> the folder used instead (warned once per process)."""


def _configured() -> Path:
    env = os.environ.get("SPLAT_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "splat"


def _fallback() -> Path:
    uid = os.geteuid() if hasattr(os, "geteuid") else "user"
    folder = Path(tempfile.gettempdir()) / f"splat-cache-{uid}"
    private_folder(folder)
    if untrusted_reason(folder) is None:
        return folder
    return Path(tempfile.mkdtemp(prefix="splat-cache-"))  # someone else holds that name: a new one per process


def user_cache_dir() -> Path:
    """Where generated scenes, match caches and compiled kernels go: ``$SPLAT_CACHE``, else
    ``~/.cache/splat``, created private when missing; when it belongs to someone else or others may
    write it, a private folder under the temporary folder (one warning naming the reason)."""
    folder = _configured()
    if folder in _REFUSED:
        return _REFUSED[folder]
    try:
        private_folder(folder)
    except OSError:
        pass  # cannot create it (read-only parent): the check below says so
    reason = untrusted_reason(folder)
    if reason is None:
        return folder
    _REFUSED[folder] = used = _fallback()
    warnings.warn(f"cache folder refused: {reason}; using {used} instead", stacklevel=2)
    return used
