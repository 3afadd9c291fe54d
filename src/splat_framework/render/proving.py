"""The kernels made ready before a run renders (:func:`prepare_kernels`), and a backend proving
itself once per machine and version before a run uses it.

The native and Triton kernels are tested against the torch reference, but a machine the tests never
ran on (a new GPU, compiler or CPU) could still make them disagree. Before a run renders with them,
:func:`proven` renders a small fixed scene forward and backward with them and with the eager torch
kernels; a backend whose image or gradients differ is refused with one line naming the differences,
and the run renders with the torch kernels. The verdict is kept in the settings' cache folder
(``proofs/``), keyed by backend, version and device, so later runs on the machine read it.
"""

from __future__ import annotations

import hashlib
import platform
import warnings
from pathlib import Path

import torch

from ..console import phase
from ..runtime.io import atomic_write_json, read_json
from ..runtime.trusted import manifest_mismatch, private_folder, write_manifest
from ._kernels import use_inductor_cache
from .backend import choose, kernels_for, native_for
from .rasterizer import rasterize
from .settings import RenderSettings

TOLERANCE = 1e-3
"""Largest difference allowed, relative to the largest magnitude of the reference's tensor (at least 1)."""

_VERDICTS: dict[tuple, str] = {}
"""(cache folder, backend, key) -> "" (agrees) or the differences, for this process."""

_SOURCES = ("rasterizer.py", "_composite.py", "_project.py", "_kernels.py", "_triton.py", "_native.py")


def _version_key(backend: str, device: torch.device) -> str:
    """What a verdict depends on: the backend, its sources (Python and C++), torch, triton and the device."""
    folder = Path(__file__).parent
    h = hashlib.sha256(backend.encode() + torch.__version__.encode())
    for name in _SOURCES:
        h.update((folder / name).read_bytes())
    for path in sorted((folder / "native").glob("*.[ch]*")):
        h.update(path.read_bytes())
    try:
        import triton

        h.update(triton.__version__.encode())
    except ImportError:
        pass
    h.update(_device_words(device, backend).encode())
    return h.hexdigest()[:16]


def _device_words(device: torch.device, backend: str) -> str:
    if device.type == "cuda":
        index = device.index if device.index is not None else torch.cuda.current_device()
        major, minor = torch.cuda.get_device_capability(index)
        return f"cuda {torch.cuda.get_device_name(index)} sm_{major}{minor}"
    words = f"{device.type} {platform.machine()} {torch.backends.cpu.get_cpu_capability()}"
    return f"{words} (Triton interpreted)" if backend == "triton" else words


def _scene(device: torch.device) -> dict:
    """Twelve Gaussians in front of a 24x20 camera, overlapping (so the blending order matters), from a
    fixed generator: the same scene on every machine, the process's random state untouched."""
    g = torch.Generator().manual_seed(105)
    n = 12
    rand = lambda *shape: torch.rand(*shape, generator=g)  # noqa: E731
    means = torch.cat([(rand(n, 2) - 0.5) * 1.2, 2.5 + rand(n, 1) * 2.0], 1)
    tensors = {
        "means": means,
        "quats": rand(n, 4) - 0.5,
        "scales": 0.1 + rand(n, 3) * 0.3,
        "opacities": 0.3 + rand(n) * 0.65,
        "colors": rand(n, 3),
        "weights": rand(20, 24, 5),  # the loss: a fixed weighted sum of rgb, depth and alpha
    }
    tensors = {k: v.to(device) for k, v in tensors.items()}
    tensors["K"] = torch.tensor([[20.0, 0.0, 12.0], [0.0, 20.0, 10.0], [0.0, 0.0, 1.0]], device=device)
    return tensors


def _render(scene: dict, settings: RenderSettings) -> dict[str, torch.Tensor]:
    """The image, depth and alpha of the scene and the gradients of a fixed loss of them."""
    inputs = {k: scene[k].clone().requires_grad_(True) for k in ("means", "quats", "scales", "opacities", "colors")}
    out = rasterize(inputs["means"], inputs["quats"], inputs["scales"], inputs["opacities"], inputs["colors"],
                    torch.eye(4, device=scene["K"].device), scene["K"], 24, 20, settings=settings)
    image = torch.cat([out.rgb, out.depth, out.alpha], -1)
    (image * scene["weights"]).sum().backward()
    return {"image": image.detach()} | {f"grad of {k}": v.grad for k, v in inputs.items()}


def differences(device: torch.device, settings: RenderSettings) -> str:
    """"" where renders with ``settings`` agree with the eager torch kernels on ``device``, else the
    disagreeing tensors and their largest differences, one line."""
    scene = _scene(device)
    got = _render(scene, settings)
    want = _render(scene, RenderSettings(rasterizer="torch"))
    wrong = []
    for name, ref in want.items():
        value = got[name]
        if value is None or not torch.isfinite(value).all():
            wrong.append(f"{name}: not finite")
            continue
        diff = float((value - ref).abs().max())
        if diff > TOLERANCE * max(1.0, float(ref.abs().max())):
            wrong.append(f"{name}: off by up to {diff:.3g}")
    return ", ".join(wrong)


def proven(device: torch.device, settings: RenderSettings) -> RenderSettings:
    """``settings`` where the kernels they choose on ``device`` agree with the torch reference (or are
    the torch kernels), else the same settings with the torch kernels, after one warning line naming
    the differences. Proved once per machine and version: the verdict is read from (or written to)
    ``settings.cache_dir/proofs``."""
    kernels = kernels_for(device, settings)
    if kernels is None:
        return settings
    key = _version_key(kernels.name, device)
    slot = (settings.cache_dir, kernels.name, key)
    if slot not in _VERDICTS:
        _VERDICTS[slot] = _kept(settings.cache_dir, kernels.name, key, device, settings)
    found = _VERDICTS[slot]
    if not found:
        return settings
    warnings.warn(f"rasterizer {kernels.name}: refused, it disagrees with the torch reference on "
                  f"{_device_words(device, kernels.name)} ({found}); rendering with the torch kernels", stacklevel=2)
    return settings.replace(rasterizer="torch")


def _kept(cache_dir: Path | None, backend: str, key: str, device: torch.device, settings: RenderSettings) -> str:
    """The verdict kept under ``cache_dir`` for (backend, key), else proved now and kept there."""
    path = None if cache_dir is None else Path(cache_dir) / "proofs" / f"{backend}-{key}.json"
    # a verdict is loaded only when this user's signed manifest vouches for it, as the kernels are
    if path is not None and path.is_file() and manifest_mismatch(path.parent, [path.name]) is None:
        try:
            return str(read_json(path, require_checksum=True)["differences"])
        except (OSError, ValueError, KeyError, TypeError):
            pass  # unreadable: prove again and write it anew
    with phase(f"proving the {backend} rasterizer kernels against the torch reference (once per machine)"):
        found = differences(device, settings)
    if path is not None:
        try:
            private_folder(path.parent)
            atomic_write_json(path, {"backend": backend, "device": _device_words(device, backend), "differences": found})
            write_manifest(path.parent, [path.name])
        except OSError:
            pass  # a read-only cache: proved again by the next process
    return found


def prepare_kernels(device: torch.device, settings: RenderSettings) -> RenderSettings:
    """Build or load the native kernels, or compile the Triton ones (one tiny render, a phase line;
    Triton keeps what it compiled in its cache), so that no training step pays for it; then prove
    them against the torch reference once per machine (:func:`proven`). Returns the
    settings renders take: ``settings``, or the torch kernels where the chosen ones were refused.
    Raises DataError where a rasterizer asked for by name cannot run."""
    chosen = choose(device, settings)
    use_inductor_cache(settings)  # before anything compiles
    if chosen == "native":
        native_for(device, settings)
    elif chosen == "triton":
        with phase("compiling the Triton rasterizer kernels (cached after the first run)"):
            _warm_up(device, settings)
    return proven(device, settings)


def _warm_up(device: torch.device, settings: RenderSettings) -> None:
    """One 16x16 render of two Gaussians, forward and backward, in float32 on ``device``."""
    means = torch.tensor([[0.0, 0.0, 3.0], [0.2, 0.1, 4.0]], device=device, requires_grad=True)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 2, device=device)
    scales = torch.full((2, 3), 0.3, device=device)
    viewmat = torch.eye(4, device=device)
    K = torch.tensor([[16.0, 0.0, 8.0], [0.0, 16.0, 8.0], [0.0, 0.0, 1.0]], device=device)
    out = rasterize(means, quats, scales, torch.full((2,), 0.8, device=device), torch.ones(2, 3, device=device),
                    viewmat, K, 16, 16, settings=settings)
    (out.rgb.sum() + out.depth.sum()).backward()


__all__ = ["TOLERANCE", "differences", "prepare_kernels", "proven"]
