"""Kernels compiled once per machine and kept on disk, so that a later process starts in seconds.

``torch.compile`` traces a function with dynamo the first time each process calls it, even when
inductor's cache already holds the generated code: for the rasterizer's unrolled round kernels
that is tens of seconds of every run's start on a 2-core CPU. ``torch.compile(f).aot_compile``
keeps the traced graph and its guards in one file that a later process loads without tracing
(the generated code itself stays in inductor's cache beside it).

:class:`Precompiled` wraps one kernel: each call runs the first loaded graph whose guards accept
the arguments; when none does, it loads a saved graph of the arguments' static signature (device,
dtype, the sizes the graph is specialised on, and the thread count, which inductor's CPU code is
built for), or compiles one and saves it atomically. Sizes that vary from call to call (active
tiles, Gaussians, image size) stay symbolic, and equal sizes are not merged (no duck sizing), so
a graph serves every round of every image of a run. Where the torch build lacks the API, or
anything in it fails, the kernel falls back to plain ``torch.compile`` once, with one warning
line.
"""

from __future__ import annotations

import hashlib
import sys
import warnings
from pathlib import Path
from typing import Callable

import torch
from torch import Tensor

from ..console import phase
from ..runtime.trusted import manifest_mismatch, private_folder, write_manifest

_SOURCE = Path(__file__).with_name("_kernels.py")
GRAPHS_PER_SIGNATURE = 4
"""Graphs kept per static signature (each with its own guards on the sizes that vary)."""


def supported() -> bool:
    """Whether this torch build can save and load compiled graphs (``aot_compile``)."""
    return hasattr(torch.compiler, "load_compiled_function") and hasattr(
        getattr(torch, "_dynamo", None), "config") and hasattr(torch._dynamo.config, "enable_aot_compile")


def build_tag() -> str:
    """What a saved graph depends on beside its arguments: torch, Python, and the kernels' source."""
    h = hashlib.sha256()
    for part in (torch.__version__, sys.version, _SOURCE.read_bytes()):
        h.update(part if isinstance(part, bytes) else part.encode())
    return h.hexdigest()[:16]


class Precompiled:
    """One kernel, compiled ahead of time per static signature and kept under ``folder``.

    Args:
        name: the kernel's file-name stem ("fwd", "bwd").
        fn: the pure tensor function to compile.
        static: args -> the sizes the compiled graph is specialised on (e.g. the round's pair count).
        folder: where the graphs are kept (created on first save).
        fallback: called instead once the ahead-of-time path failed (plain ``torch.compile``).
        which: the kernel's name in the phase lines ("forward").
    """

    def __init__(self, name: str, fn: Callable, static: Callable[[tuple], tuple], folder: Path,
                 fallback: Callable, which: str = ""):
        self.name, self.fn, self.static, self.folder, self.fallback = name, fn, static, Path(folder), fallback
        self.which = which or name
        self.graphs: list = []
        self.failed = not supported()
        self._tag = None

    def stem_for(self, args: tuple) -> str:
        """The file-name stem of the graphs for ``args``' static signature: the device, the dtype, the
        sizes the graph is specialised on, and what its guards and generated code depend on beside
        the arguments (the thread count, which inductor's CPU code is built for, and grad mode)."""
        first = next(a for a in args if isinstance(a, Tensor))
        self._tag = self._tag or build_tag()
        key = repr((first.device.type, str(first.dtype), self.static(args), torch.get_num_threads(),
                    torch.is_grad_enabled()))
        return f"{self.name}-{self._tag}-{hashlib.sha256(key.encode()).hexdigest()[:12]}"

    def __call__(self, *args):
        if not self.failed:
            for graph in self.graphs:
                if graph.guard_check(*args):
                    return graph(*args)
            try:
                graph = self._load_or_compile(args)
            except Exception as exc:  # pragma: no cover - depends on the torch build and toolchain
                self.failed = True
                first = (str(exc).strip().splitlines() or [""])[0][:200]
                warnings.warn(f"saved rasterizer kernels unavailable ({type(exc).__name__}: {first}); "
                              "compiling in this process instead", stacklevel=2)
            else:
                if hasattr(graph, "disable_guard_check"):  # its guards were just checked: once per call is enough
                    graph.disable_guard_check()
                self.graphs.append(graph)
                return graph(*args)
        return self.fallback(*args)

    def _load_or_compile(self, args: tuple):
        """A saved graph of ``args``' signature whose guards accept them, else a new one, saved
        beside the others (at most :data:`GRAPHS_PER_SIGNATURE`; the last is then replaced).

        A saved graph is unpickled only when it and its folder belong to the user, nobody else may
        write them and its sha256 is the one the folder's manifest recorded when it was saved;
        any other file, and any failure to load, is reported in one line and compiled again."""
        stem = self.stem_for(args)
        saved = sorted(self.folder.glob(f"{stem}-*.bin")) if self.folder.is_dir() else []
        for path in saved:
            reason = manifest_mismatch(self.folder, [path.name])
            if reason is not None:
                warnings.warn(f"compiled rasterizer kernels not loaded: {reason}; compiling them again", stacklevel=3)
                path.unlink(missing_ok=True)  # never loaded, so never asked again
                continue
            try:
                with phase(f"loading the compiled rasterizer kernels ({self.which})"), open(path, "rb") as f:
                    graph = torch.compiler.load_compiled_function(f)
                if graph.guard_check(*args):
                    return graph
            except Exception as exc:  # a graph of another torch build: compile it again
                first = (str(exc).strip().splitlines() or [""])[0][:200]
                warnings.warn(f"{path}: compiled rasterizer kernels not loaded ({type(exc).__name__}: {first}); "
                              "compiling them again", stacklevel=3)
        with phase(f"compiling the rasterizer kernels ({self.which}): once per machine, later runs load them"):
            graph = self._compile(args)
        kept = [p for p in saved if p.exists()]
        self._save(graph, self.folder / f"{stem}-{min(len(kept), GRAPHS_PER_SIGNATURE - 1)}.bin")
        return graph

    def _compile(self, args: tuple):
        import torch._dynamo.config as dynamo_config
        import torch.fx.experimental._config as fx_config

        example = tuple(a.clone() if isinstance(a, Tensor) else a for a in args)  # kernels write in place
        with dynamo_config.patch(specialize_float=True), fx_config.patch(use_duck_shape=False):
            return torch.compile(self.fn, dynamic=True, fullgraph=True).aot_compile((example, {}))

    def _save(self, graph, path: Path) -> None:
        """Keep the graph (torch writes it atomically, so a process writing the same file beside
        this one is harmless); a failure to write costs only the next process the compilation."""
        try:
            private_folder(path.parent)
            graph.save_compiled_function(str(path))
            write_manifest(path.parent, [path.name])
        except Exception as exc:  # a full disk, or a graph torch cannot serialise: only the next start pays
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else (str(exc).splitlines() or [""])[0]
            warnings.warn(f"{path.parent}: cannot keep the compiled rasterizer kernels ({reason[:200]})", stacklevel=3)
