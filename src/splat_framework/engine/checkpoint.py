"""Checkpoints: atomic, checksummed, with fallback to the previous good one.

File layout: ``b"SPLATCKPT1\\n"`` + 64 hex chars of the SHA-256 of the payload
+ ``b"\\n"`` + the payload (a ``torch.save`` archive, read back with
``weights_only=True``: loading a checkpoint never executes code). A truncated
or corrupt file fails the checksum and is reported, and :func:`load_latest`
falls back to the newest checkpoint that verifies.

Writing goes through :func:`splat_framework.runtime.io.atomic_write_bytes`, so a crash
or a full disk while saving leaves the previous checkpoints intact; old files
are deleted only after the new one is safely on disk. Parameters with NaN/inf
values are never written.
"""

from __future__ import annotations

import hashlib
import io
import re
import warnings
from pathlib import Path
from typing import Callable, Mapping, TypeVar

import torch
from torch import Tensor

from ..errors import CheckpointError  # noqa: F401  (re-exported)
from ..runtime.io import atomic_write_bytes

MAGIC = b"SPLATCKPT1\n"
KEEP = 2
_NAME = re.compile(r"^step-(\d+)\.ckpt$")
T = TypeVar("T")


def checkpoint_path(folder: Path, step: int) -> Path:
    return Path(folder) / f"step-{step:07d}.ckpt"


def checkpoint_step(path: Path) -> int:
    """The step number in a checkpoint's file name."""
    m = _NAME.match(Path(path).name)
    if m is None:
        raise ValueError(f"{path}: not a checkpoint file name")
    return int(m.group(1))


class CheckpointWriteError(CheckpointError):
    """The machine refused the write (disk full, read-only, quota): exit code 1 in the CLIs."""

    cli_exit_code = 1


def _nonfinite(payload: dict) -> str | None:
    """The name of the first parameter or network weight of ``payload`` holding NaN/inf, or None."""
    for group in ("params", "networks"):
        tensors = payload.get(group)
        for name, t in (tensors.items() if isinstance(tensors, dict) else ()):
            if torch.is_tensor(t) and t.is_floating_point() and not torch.isfinite(t).all():
                return f"{group}[{name!r}]"
    return None


def _check_finite(step: int, payload: dict) -> None:
    bad = _nonfinite(payload)
    if bad is not None:
        raise CheckpointError(f"refusing to save step {step}: {bad} has non-finite values")


def _check_step(path: Path, ck: dict, max_step: int | None = None) -> int:
    """The payload's step, an int in [0, max_step] (default: config.MAX_STEPS) equal to the step in the
    file's name (when it has one)."""
    from ..config import MAX_STEPS

    top = MAX_STEPS if max_step is None else min(max_step, MAX_STEPS)
    step = ck.get("step")
    if isinstance(step, bool) or not isinstance(step, int) or not 0 <= step <= top:
        raise CheckpointError(f"{path}: step {step!r} is not an iteration of this run (0 to {top})")
    named = _NAME.match(Path(path).name)
    if named is not None and int(named.group(1)) != step:
        raise CheckpointError(f"{path}: holds step {step}, its name says {int(named.group(1))}")
    return step


def save_checkpoint(folder: Path, step: int, payload: dict, keep: int = KEEP) -> Path:
    """Write ``payload`` for ``step`` atomically and keep only the newest ``keep`` files.

    Raises CheckpointError (one line) when the payload holds non-finite values
    or the file cannot be written (disk full, read-only folder...); the
    previous checkpoints are then left as they were. Checkpoints of later
    steps (an abandoned timeline, e.g. after resuming from an older file) are
    removed once this one is written.
    """
    _check_finite(step, payload)
    buf = io.BytesIO()
    torch.save(payload, buf)
    data = buf.getvalue()
    digest = hashlib.sha256(data).hexdigest().encode()
    path = checkpoint_path(folder, step)
    try:
        atomic_write_bytes(path, MAGIC + digest + b"\n" + data)
    except OSError as e:
        reason = e.strerror or str(e)
        kept = [p for p in list_checkpoints(folder) if p != path] if folder.is_dir() else []
        what = f"{kept[-1].name} (the newest checkpoint) is kept" if kept else "no checkpoint was written yet"
        raise CheckpointWriteError(f"{path}: cannot write checkpoint ({reason}); {what}") from None
    existing = list_checkpoints(folder)
    # later steps belong to an abandoned timeline (resumed from an older file)
    stale = [p for p in existing if checkpoint_step(p) > step]
    current = [p for p in existing if checkpoint_step(p) <= step]
    for old in stale + current[:-keep]:
        if old != path:
            old.unlink(missing_ok=True)
    remove_stale_temporaries(folder)
    return path


def remove_stale_temporaries(folder: Path) -> list[Path]:
    """Delete the hidden ``.NAME.*.tmp`` files of atomic writes that a killed process left in
    ``folder`` (never a complete file: those are renamed into place). Returns what was removed."""
    removed = []
    for stale in Path(folder).glob(".*.tmp") if Path(folder).is_dir() else ():
        if stale.is_file():
            stale.unlink(missing_ok=True)
            removed.append(stale)
    return removed


def list_checkpoints(folder: Path) -> list[Path]:
    """Checkpoint files in ``folder``, oldest (lowest step) first."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted((p for p in folder.iterdir() if _NAME.match(p.name)), key=checkpoint_step)


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
    try:
        payload = torch.load(io.BytesIO(data), map_location=map_location, weights_only=True)
    except Exception as e:  # verified bytes that still do not load: incompatible writer
        raise CheckpointError(f"{path}: cannot load checkpoint ({type(e).__name__})") from None
    if not isinstance(payload, dict) or "params" not in payload or "step" not in payload:
        raise CheckpointError(f"{path}: checkpoint payload lacks 'step' or 'params'")
    return payload


def _warn(message: str) -> None:
    warnings.warn(message, stacklevel=3)


def check_structure(path: Path, ck: dict, like: Mapping[str, Tensor] | None = None,
                    max_step: int | None = None) -> None:
    """Raise CheckpointError (one line naming ``path``) unless the payload has the layout
    training and rendering rely on: ``step`` an iteration in [0, max_step] (the run's total
    iterations; at most config.MAX_STEPS) matching the file name, ``params`` a non-empty dict of finite float32 tensors with one
    common row count (one row per Gaussian), ``networks`` (model-wide modules' weights) a
    dict of tensors, each optimizer named after a parameter or a network, a parameter's
    optimizer's moments shaped like it, and, given ``like`` (a model's parameters), the same names and per-row shapes.
    A checksum proves the bytes are what was written, not that the writer was this code
    (nor that the values are usable: NaN parameters with a valid checksum are refused here,
    so :func:`load_latest` falls back to the previous checkpoint)."""
    _check_step(path, ck, max_step)
    params = ck.get("params")
    if not isinstance(params, dict) or not params or not all(torch.is_tensor(v) for v in params.values()):
        raise CheckpointError(f"{path}: 'params' is not a dict of tensors")
    for k, v in params.items():
        if v.dtype != torch.float32 or v.dim() == 0:
            raise CheckpointError(f"{path}: params[{k!r}] is {v.dtype} {tuple(v.shape)}, expected float32 rows")
    rows = {v.shape[0] for v in params.values()}
    if len(rows) != 1:
        raise CheckpointError(f"{path}: params have different row counts {sorted(rows)}")
    if like is not None:
        if set(params) != set(like):
            raise CheckpointError(f"{path}: params {sorted(params)} do not match the model's {sorted(like)}")
        for k, v in params.items():
            if v.shape[1:] != like[k].shape[1:]:
                raise CheckpointError(
                    f"{path}: params[{k!r}] rows are {tuple(v.shape[1:])}, the model's {tuple(like[k].shape[1:])}"
                )
    networks = ck.get("networks") or {}
    if not isinstance(networks, dict) or not all(isinstance(k, str) and torch.is_tensor(v) for k, v in networks.items()):
        raise CheckpointError(f"{path}: 'networks' is not a dict of tensors")
    bad = _nonfinite(ck)
    if bad is not None:
        raise CheckpointError(f"{path}: {bad} has non-finite values")
    modules = {k.split(".")[0] for k in networks}
    optimizers = ck.get("optimizers", {})
    if not isinstance(optimizers, dict):
        raise CheckpointError(f"{path}: 'optimizers' is not a dict")
    for k, o in optimizers.items():
        states = o.get("state", {}) if isinstance(o, dict) else None
        if not isinstance(states, dict) or (k not in params and k not in modules):
            raise CheckpointError(f"{path}: optimizer {k!r} has no parameter or no state")
        if k not in params:  # a network's optimizer: its moments are checked by load_state_dict
            continue
        for st in states.values():
            for name, t in (st.items() if isinstance(st, dict) else ()):
                if torch.is_tensor(t) and t.dim() > 0 and t.shape != params[k].shape:
                    raise CheckpointError(f"{path}: optimizer {k!r} {name} is {tuple(t.shape)}, "
                                          f"params[{k!r}] {tuple(params[k].shape)}")


def load_latest(
    folder: Path,
    map_location="cpu",
    report: Callable[[str], None] | None = None,
    accept: Callable[[Path, dict], T] | None = None,
) -> tuple[Path, T] | None:
    """The newest checkpoint in ``folder`` that verifies, or None when none does.

    ``accept(path, payload)`` (default: :func:`check_structure`, returning the payload)
    turns a verified payload into what the caller needs and may raise CheckpointError
    to reject it. Each rejected file is reported through ``report(message)`` (default:
    a warning) before the previous one is tried.
    """
    report = report or _warn
    for path in reversed(list_checkpoints(folder)):
        try:
            ck = load_checkpoint(path, map_location)
            if accept is None:
                check_structure(path, ck)
                return path, ck
            return path, accept(path, ck)
        except CheckpointError as e:
            report(f"{e}; trying the previous checkpoint")
    return None
