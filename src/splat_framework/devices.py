"""Check a device name against what this torch build and machine have (one-line errors)."""

from __future__ import annotations

import torch

from .errors import DataError

__all__ = ["resolve_device"]


def resolve_device(name: str, source: str = "--device") -> torch.device:
    """``torch.device(name)`` after checking that torch can use it here.

    Raises DataError (the CLIs print it in one line and exit 2) naming ``source`` (the
    option or file the name came from) when the name is not a device, the backend is
    not available in this torch build, or the index is past the devices present.
    """
    try:
        dev = torch.device(name)
    except RuntimeError:
        raise DataError(f"{source}: {name!r} is not a torch device (use cpu, cuda, cuda:N, mps)") from None
    if dev.type == "cpu":
        return dev
    backend = getattr(torch, dev.type, None)
    if dev.type == "mps":
        available, count = torch.backends.mps.is_available(), 1
    elif backend is not None and hasattr(backend, "is_available"):
        available = backend.is_available()
        count = backend.device_count() if available else 0
    else:
        available, count = False, 0
    if not available:
        raise DataError(f"{source}: device {name!r} is not available in this torch build or machine (use cpu)")
    if dev.index is not None and dev.index >= count:
        raise DataError(f"{source}: device {name!r} does not exist ({count} {dev.type} device(s): indices 0-{count - 1})")
    return dev
