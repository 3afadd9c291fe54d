"""Check a device name against what this torch build and machine have (one-line errors): ``--device``
and every other device field of a config (:func:`resolve_config_devices`)."""

from __future__ import annotations

from typing import Iterator

import torch

from .errors import DataError

__all__ = ["resolve_device", "resolve_config_devices"]


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


def device_fields(config, prefix: str = "") -> Iterator[tuple[str, str]]:
    """(dotted field path, device name) of every field of ``config`` (a SplatConfig, nested configs
    included) annotated with :data:`splat_framework.config.Device`."""
    from .config import DEVICE_MARKER, SplatConfig

    for name, info in type(config).model_fields.items():
        value = getattr(config, name)
        path = f"{prefix}{name}"
        if isinstance(value, SplatConfig):
            yield from device_fields(value, f"{path}.")
        elif isinstance(value, str) and any(m is DEVICE_MARKER for m in info.metadata):
            yield path, value


def resolve_config_devices(config, source: str | None = None) -> dict[str, torch.device]:
    """Every device field of ``config`` checked by :func:`resolve_device`: dotted path -> device.

    A field is named in the error as ``--field.path`` (or ``source: field.path`` when the config
    came from a file), so ``--model.matching.device cuda:7`` fails like ``--device cuda:7``."""
    return {
        path: resolve_device(name, f"{source}: {path}" if source else f"--{path.replace('_', '-')}")
        for path, name in device_fields(config)
    }
