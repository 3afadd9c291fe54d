"""Which kernels a render runs: ``--rasterizer`` / ``SPLAT_RASTERIZER`` (auto, native, triton, torch).

- ``native``: the C++ kernels of ``native/`` (binning, compositing, projection, loss), CPU tensors;
- ``triton``: the Triton compositing kernels of :mod:`._triton`, CUDA tensors (CPU tensors under
  Triton's interpreter, ``TRITON_INTERPRET=1``: how they are tested without a GPU);
- ``torch``: the per-round torch kernels (the reference and the fallback), ``torch.compile``'d while
  kernels are compiled (``--compile``), else eager;
- ``auto`` (the default): while kernels are compiled, native on a CPU, Triton on CUDA where triton
  imports, torch elsewhere; eager torch otherwise (tests, ``--no-compile``).

A backend asked for that cannot run on the render's device says so in one line and the render takes
what ``auto`` takes there, except ``triton`` asked for by name, which is an error (one line, exit 2
in the commands). ``--rasterizer`` other than auto wins over the variable.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass

import torch

from ..environment import rasterizer_setting as parse_setting
from ..errors import DataError
from ._kernels import compile_requested, kernel_cache_dir

RASTERIZERS = ("auto", "native", "triton", "torch")
_SETTING: dict[str, str] = {"rasterizer": "auto"}
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


def set_rasterizer(name: str) -> None:
    """The process's rasterizer choice (``TrainConfig.rasterizer``); "auto" leaves it to ``SPLAT_RASTERIZER``."""
    if name not in RASTERIZERS:
        raise DataError(f"--rasterizer {name!r}: expected one of {', '.join(RASTERIZERS)}")
    _SETTING["rasterizer"] = name


def rasterizer_setting() -> str:
    """What was asked: ``set_rasterizer``'s choice unless "auto", then ``SPLAT_RASTERIZER``, then "auto"."""
    chosen = _SETTING["rasterizer"]
    if chosen != "auto":
        return chosen
    return parse_setting(os.environ.get("SPLAT_RASTERIZER")) or "auto"


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


def _auto(device: torch.device) -> str:
    if not compile_requested():
        return "torch"
    if device.type == "cpu":
        return "native"
    if device.type == "cuda":
        why = triton_unavailable(device)
        if why is None:
            return "triton"
        _warn_once(f"{why}: rendering with the torch kernels")
    return "torch"


def choose(device: torch.device) -> str:
    """"native", "triton" or "torch": what renders on ``device`` take (see the module's rules).
    Raises DataError where ``triton`` was asked for by name and cannot run."""
    asked = rasterizer_setting()
    if asked == "torch":
        return "torch"
    if asked == "triton":
        why = triton_unavailable(device)
        if why is not None:
            raise DataError(f"rasterizer triton: {why}; use --rasterizer auto or torch")
        return "triton"
    if asked == "native" and device.type != "cpu":
        chosen = _auto(device)
        _warn_once(f"rasterizer native: the native kernels run on CPU tensors; rendering on {device.type} "
                   f"with the {chosen} kernels")
        return chosen
    if asked == "native":
        return "native"
    return _auto(device)


def native_for(device: torch.device):
    """The loaded native extension where renders on ``device`` take it, else None (also when it
    cannot be built here: one warning, then the torch kernels)."""
    if choose(device) != "native":
        return None
    from ._native import native_kernels

    return native_kernels(kernel_cache_dir())


def kernels_for(device: torch.device) -> Kernels | None:
    """The compositing kernels of a render on ``device``, None for the per-round torch kernels."""
    chosen = choose(device)
    if chosen == "triton":
        return Kernels("triton", _triton_kernels(), None, 1, 1 << 20, every_tile=True)
    native = native_for(device) if chosen == "native" else None
    if native is None:
        return None
    return Kernels("native", native, native, None, 128)


def _triton_kernels():
    """One :class:`._triton.TritonKernels` per mode (compiled or interpreted) per process."""
    from . import _triton

    key = _triton.interpreting()
    if key not in _TRITON:
        _TRITON[key] = _triton.TritonKernels()
    return _TRITON[key]


def backend_name(device: torch.device) -> str:
    """What renders on ``device`` run, for summaries and metrics.json: "native", "triton",
    "torch (compiled)" or "torch (eager)"."""
    kernels = kernels_for(device)
    if kernels is not None:
        return kernels.name
    return "torch (compiled)" if compile_requested() else "torch (eager)"


__all__ = ["RASTERIZERS", "Kernels", "backend_name", "choose", "kernels_for", "native_for", "set_rasterizer",
           "triton_unavailable"]
