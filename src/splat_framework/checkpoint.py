"""Checkpoints: atomic, checksummed, with fallback to the previous good one.

File layout: ``b"SPLATCKPT1\\n"`` + 64 hex chars of the SHA-256 of the payload
+ ``b"\\n"`` + the payload (a ``torch.save`` archive). A truncated or corrupt
file fails the checksum and is reported, and :func:`load_latest` falls back to
the newest checkpoint that verifies.
"""

from __future__ import annotations

import hashlib
import io
import warnings
from pathlib import Path

import torch

from .io import atomic_write_bytes

MAGIC = b"SPLATCKPT1\n"
KEEP = 2


from .errors import CheckpointError  # noqa: F401  (re-exported)


def checkpoint_path(folder: Path, step: int) -> Path:
    return Path(folder) / f"step-{step:07d}.ckpt"


def save_checkpoint(folder: Path, step: int, payload: dict, keep: int = KEEP) -> Path:
    """Write ``payload`` for ``step`` atomically and keep only the newest ``keep`` files."""
    for name, t in payload.get("params", {}).items():
        if not torch.isfinite(t).all():
            raise CheckpointError(f"refusing to save step {step}: parameter '{name}' has non-finite values")
    buf = io.BytesIO()
    torch.save(payload, buf)
    data = buf.getvalue()
    digest = hashlib.sha256(data).hexdigest().encode()
    path = checkpoint_path(folder, step)
    atomic_write_bytes(path, MAGIC + digest + b"\n" + data)
    for old in list_checkpoints(folder)[:-keep]:
        old.unlink(missing_ok=True)
    return path


def list_checkpoints(folder: Path) -> list[Path]:
    """Checkpoint files in ``folder``, oldest first."""
    return sorted(Path(folder).glob("step-*.ckpt"))


def load_checkpoint(path: Path, map_location="cpu") -> dict:
    """Read and verify one checkpoint; raises CheckpointError if it does not verify."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise CheckpointError(f"{path}: cannot read checkpoint ({e.strerror})") from None
    head = len(MAGIC) + 65
    if not raw.startswith(MAGIC) or len(raw) < head:
        raise CheckpointError(f"{path}: not a splat checkpoint or truncated header")
    digest, data = raw[len(MAGIC) : head - 1], raw[head:]
    if hashlib.sha256(data).hexdigest().encode() != digest:
        raise CheckpointError(f"{path}: checksum mismatch (truncated or corrupt checkpoint)")
    return torch.load(io.BytesIO(data), map_location=map_location, weights_only=True)


def load_latest(folder: Path, map_location="cpu") -> tuple[Path, dict] | None:
    """The newest checkpoint in ``folder`` that verifies (warning about each bad one), or None."""
    for path in reversed(list_checkpoints(folder)):
        try:
            return path, load_checkpoint(path, map_location)
        except CheckpointError as e:
            warnings.warn(f"{e}; trying the previous checkpoint", stacklevel=2)
    return None
