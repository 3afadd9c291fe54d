"""Where the framework keeps what it generates or computes once (no other imports: every layer may use it)."""

from __future__ import annotations

import os
from pathlib import Path


def user_cache_dir() -> Path:
    """Where generated scenes, match caches and compiled kernels go: ``$SPLAT_CACHE``, else ``~/.cache/splat``."""
    env = os.environ.get("SPLAT_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "splat"
