"""Which kernels a render runs: ``RenderSettings.rasterizer`` (auto, native, triton, torch), made once
from ``--rasterizer`` / ``SPLAT_RASTERIZER`` (:mod:`.settings`).

- ``native``: the C++ kernels of ``native/`` (binning, compositing, projection, loss), CPU tensors;
- ``triton``: the Triton compositing kernels of :mod:`._triton`, CUDA tensors (CPU tensors under
  Triton's interpreter, ``TRITON_INTERPRET=1``: how they are tested without a GPU);
- ``torch``: the per-round torch kernels (the reference and the fallback), ``torch.compile``'d while
  kernels are compiled (``--compile``), else eager;
- ``auto`` (the default): while kernels are compiled, native on a CPU, Triton on CUDA where triton
  imports, torch elsewhere; eager torch otherwise (tests, ``--no-compile``).

A backend asked for that cannot run on the render's device says so in one line and the render takes
what ``auto`` takes there, except ``triton`` asked for by name, which is an error (one line, exit 2
in the commands).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch

from ..errors import DataError
from .settings import RASTERIZERS, RenderSettings

_WARNED: set[str] = set()
_TRITON: dict = {}


@dataclass(frozen=True)
class Kernels:
    """The compositing kernels of a render and what else they bring.

    name: "native" or "triton".
    composite: the object with ``composite_forward`` / ``composite_backward`` (:mod:`._composite`).
    binning: the object with ``footprints`` / ``bin_chunk``, or None for the torch binning.
    slots: gradient tables of the backward: None = one per core the process may use (the native
        kernels' fixed order), else that many (Triton's atomic adds: 1).
    chunk_pairs_per_tile: the default depth chunk (pairs per tile): the native kernels skip tiles
        finished by nearer chunks; one chunk a render keeps Triton at one launch a pass.
    every_tile: a chunk's kernels run over every tile, those without pairs included (they leave
        them as they were), so the host never reads which tiles have pairs (Triton: a host read
        would wait for the device); else over the tiles with pairs only.
    """

    name: str
    composite: object
    binning: object | None
    slots: int | None
    chunk_pairs_per_tile: int
    every_tile: bool = False


def _warn_once(message: str) -> None:
    if message not in _WARNED:
        _WARNED.add(message)
        warnings.warn(message, stacklevel=3)


def triton_unavailable(device: torch.device) -> str | None:
    """Why the Triton kernels cannot render on ``device`` (one line), None when they can."""
    from . import _triton

    why = _triton.available()
    if why is not None:
        return why
    if device.type == "cuda":
        return None
    if device.type == "cpu" and _triton.interpreting():
        return None
    return f"the Triton kernels run on CUDA tensors (or CPU tensors under TRITON_INTERPRET=1), not on {device.type}"


def _auto(device: torch.device, settings: RenderSettings) -> str:
    if not settings.compile:
        return "torch"
    if device.type == "cpu":
        return "native"
    if device.type == "cuda":
        why = triton_unavailable(device)
        if why is None:
            return "triton"
        _warn_once(f"{why}: rendering with the torch kernels")
    return "torch"


def choose(device: torch.device, settings: RenderSettings) -> str:
    """"native", "triton" or "torch": what renders on ``device`` with ``settings`` take (see the
    module's rules). Raises DataError where ``triton`` was asked for by name and cannot run."""
    asked = settings.rasterizer
    if asked == "torch":
        return "torch"
    if asked == "triton":
        why = triton_unavailable(device)
        if why is not None:
            raise DataError(f"rasterizer triton: {why}; use --rasterizer auto or torch")
        return "triton"
    if asked == "native" and device.type != "cpu":
        chosen = _auto(device, settings)
        _warn_once(f"rasterizer native: the native kernels run on CPU tensors; rendering on {device.type} "
                   f"with the {chosen} kernels")
        return chosen
    if asked == "native":
        return "native"
    return _auto(device, settings)


def native_for(device: torch.device, settings: RenderSettings):
    """The loaded native extension where renders on ``device`` with ``settings`` take it, else None
    (also when it cannot be built here: one warning, then the torch kernels)."""
    if choose(device, settings) != "native":
        return None
    from ._native import native_kernels

    return native_kernels(settings.cache_dir)


def kernels_for(device: torch.device, settings: RenderSettings) -> Kernels | None:
    """The compositing kernels of a render on ``device`` with ``settings``, None for the per-round
    torch kernels."""
    chosen = choose(device, settings)
    if chosen == "triton":
        return Kernels("triton", _triton_kernels(settings.cache_dir), None, 1, 1 << 20, every_tile=True)
    native = native_for(device, settings) if chosen == "native" else None
    if native is None:
        return None
    return Kernels("native", native, native, None, 128)


def _triton_kernels(cache_dir):
    """One :class:`._triton.TritonKernels` per mode (compiled or interpreted) and cache folder per process."""
    from . import _triton

    key = (_triton.interpreting(), cache_dir)
    if key not in _TRITON:
        _TRITON[key] = _triton.TritonKernels(cache_dir)
    return _TRITON[key]


def backend_name(device: torch.device, settings: RenderSettings) -> str:
    """What renders on ``device`` with ``settings`` run, for summaries and metrics.json: "native",
    "triton", "torch (compiled)" or "torch (eager)"."""
    kernels = kernels_for(device, settings)
    if kernels is not None:
        return kernels.name
    return "torch (compiled)" if settings.compile else "torch (eager)"


__all__ = ["RASTERIZERS", "Kernels", "RenderSettings", "backend_name", "choose", "kernels_for", "native_for",
           "triton_unavailable"]
