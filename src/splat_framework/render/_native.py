"""The native CPU binning and compositing kernels (``native/*.cpp``), built once per machine.

While kernels are compiled (``RenderSettings.compile``: training and rendering runs), CPU
renders bin and composite each depth chunk with these C++ kernels instead of the torch binning
and the per-round ``torch.compile`` kernels: the same rules and backward, one pass over each
tile's pairs with the transmittance in registers (`docs/rasterizer.md`). They are built with the C++ compiler that
``torch.compile`` already needs (and ninja, a dependency, as ``torch.utils.cpp_extension`` builds), the first
time on a machine, into ``$SPLAT_CACHE/native`` (or torch's extension folder); later processes
load the built library in well under a second. Any failure to build or load (no compiler, no
ninja) falls back to the ``torch.compile`` kernels with a one-line warning.
"""

from __future__ import annotations

import functools
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import torch

from ..console import phase, say
from ..runtime.io import atomic_write_bytes
from ..runtime.trusted import manifest_mismatch, private_folder, write_manifest

_FOLDER = Path(__file__).with_name("native")
_SOURCES = ("module.cpp", "binning.cpp", "composite.cpp", "project.cpp", "loss.cpp")  # module.cpp includes the others: one unit
_STATE: dict = {"module": None, "failed": False}
_NAME = "splat_native"


def _openmp() -> bool:
    """Whether the compiler takes ``-fopenmp``: not Apple's clang (macOS), where the kernels are
    built without it and ``at::parallel_for`` runs them on one thread."""
    return sys.platform != "darwin"


def _flags() -> list[str]:
    """Optimisation flags: the CPU's own vector instructions (the build folder is keyed by
    torch's view of them, so a cache shared between machines never loads a wrong build), and
    OpenMP where the compiler has it (:func:`_openmp`)."""
    flags = ["-O3", "-fno-math-errno", "-fno-trapping-math"] + (["-fopenmp"] if _openmp() else [])
    if sys.platform != "darwin" and platform.machine() in ("x86_64", "AMD64", "aarch64", "arm64"):
        flags.append("-march=native")
    return flags


@functools.cache
def _compiler() -> str:
    """The C++ compiler torch's extension builder runs (``$CXX``, else ``c++``): its resolved path
    and the first line of its ``--version`` ("" where it cannot be run), part of the build's key."""
    found = shutil.which(os.environ.get("CXX", "c++"))
    if found is None:
        return ""
    try:
        out = subprocess.run([found, "--version"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        out = ""
    return f"{os.path.realpath(found)} {(out.splitlines() or [''])[0]}"


def _build_dir(cache_dir: Path | None) -> Path | None:
    """``cache_dir/native/kernels-KEY-COMPILER``: KEY over the sources, the flags, torch and the CPU,
    COMPILER over the compiler (:func:`_compiler`)."""
    if cache_dir is None:
        return None
    key = hashlib.sha256(
        b"".join((_FOLDER / name).read_bytes() for name in _SOURCES) + " ".join(_flags()).encode() + torch.__version__.encode()
        + torch.backends.cpu.get_cpu_capability().encode() + platform.machine().encode()
    ).hexdigest()[:16]
    return Path(cache_dir) / "native" / f"kernels-{key}-{hashlib.sha256(_compiler().encode()).hexdigest()[:8]}"


def _built_by_any_compiler(build: Path) -> Path:
    """Where no compiler can be run (nothing could be built), the newest folder built from the same
    sources, flags, torch and CPU by whichever compiler built it; ``build`` when there is none."""
    key = build.name.rsplit("-", 1)[0]
    built = sorted(build.parent.glob(f"{key}-*/{_NAME}.so"), key=lambda p: p.stat().st_mtime_ns)
    return built[-1].parent if built else build


def _staged_sources(build: Path | None) -> Path:
    """The source file to build from: with a cache, the package's sources copied into
    ``build/src`` (rewritten only where their bytes differ, so an unchanged copy keeps its time),
    so that the build rules name the same path from every checkout or environment sharing the
    cache. Built from the package's own folder instead, a second checkout's path made ninja
    rebuild the library, and a process loading it meanwhile found it missing and fell back to the
    torch kernels. Without a cache, the package's folder."""
    if build is None:
        return _FOLDER / _SOURCES[0]
    staged = build / "src"
    for name in _SOURCES:
        data = (_FOLDER / name).read_bytes()
        target = staged / name
        if not target.is_file() or target.read_bytes() != data:
            atomic_write_bytes(target, data)
    return staged / _SOURCES[0]


def _ninja_on_path() -> None:
    """torch's extension builder runs ``ninja`` from PATH: add the ninja package's (a dependency)
    where no ninja is found, e.g. a virtual environment's tools run without activating it."""
    if shutil.which("ninja") is None:
        try:
            import ninja
        except ImportError:
            return
        os.environ["PATH"] = os.pathsep.join([ninja.BIN_DIR, os.environ.get("PATH", "")])


def _build_guard(build: Path):
    """An exclusive operating-system lock on ``native/kernels-KEY.building`` (beside the build
    folder), held while this process checks, builds or loads that folder: the system drops it
    when its holder dies (a killed build, kill -9), so a waiting process never waits on a dead
    one. A process that finds another holding it says so and waits (the phase line shows the
    time). Under the guard, a ``lock`` file of torch's extension builder in the folder was left by
    a build that was killed (torch's builder would wait for it forever, without a word): removed."""
    from filelock import FileLock, Timeout

    guard = FileLock(build.parent / f"{build.name}.building", mode=0o600)
    try:
        guard.acquire(timeout=0)
    except Timeout:  # one line even where progress is off, then the phase's elapsed time
        say(f"note: another process is building the native rasterizer kernels; waiting for it ({guard.lock_file})")
        with phase("waiting for another process building the native rasterizer kernels"):
            guard.acquire()
    baton = build / "lock"
    if baton.exists():
        say(f"note: {baton}: removed a build lock left by a build that did not finish")
        baton.unlink(missing_ok=True)
    return guard


def _checked_build(build: Path, root: Path) -> Path:
    """``build`` when it holds no library or a library its manifest vouches for; else (one warning
    naming the file and why) ``build`` emptied for a new build, or a fresh private folder when it
    cannot be emptied. Nothing in a folder that fails the check is loaded."""
    libraries = sorted(p.name for p in build.glob("*.so"))
    if not libraries:
        return build
    reason = manifest_mismatch(build, libraries, root)
    if reason is None:
        return build
    warnings.warn(f"native rasterizer kernels not loaded: {reason}; building them again")
    try:
        shutil.rmtree(build)
        private_folder(build)
        return build
    except OSError:
        return Path(tempfile.mkdtemp(prefix="splat-native-"))


def _import_library(library: Path):
    """The built extension at ``library``, imported as it is: its folder is keyed by the sources,
    flags, torch, the CPU and the compiler (:func:`_build_dir`) and its manifest was checked, so nothing is asked of
    ninja. Asking it (``cpp_extension.load`` on a built folder) rebuilt the library in every later
    process once its ``.ninja_deps`` was cut short (a build killed while writing it): 60-75 s a run."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(_NAME, library)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def native_kernels(cache_dir: Path | None = None):
    """The loaded extension (``composite_forward``, ``composite_backward``, ``bin_chunk``, ...), built
    when missing; None when it cannot be built on this machine (warned once).

    A library in the cache is loaded only when it and its folders belong to the user, nobody else
    may write them, and its sha256 is the one recorded in the folder's manifest when it was built
    (:mod:`splat_framework.runtime.trusted`); otherwise it is built again."""
    if _STATE["module"] is not None or _STATE["failed"]:
        return _STATE["module"]
    from torch.utils import cpp_extension

    _ninja_on_path()
    build = _build_dir(cache_dir)
    if build is not None and not _compiler():
        build = _built_by_any_compiler(build)
    guard, doing = None, "build"
    try:
        if build is not None:
            private_folder(build)
            guard = _build_guard(build)
            build = _checked_build(build, Path(cache_dir))
        library = build / f"{_NAME}.so" if build is not None else None
        if library is not None and library.is_file():  # vouched for by its manifest (_checked_build)
            doing = "load"
            with phase("loading the native rasterizer kernels"):
                _STATE["module"] = _import_library(library)
            return _STATE["module"]
        if not _openmp():
            say("note: the native rasterizer kernels are built without OpenMP here (Apple's compiler has none): "
                "they run on one thread")
        with phase("building the native rasterizer kernels (once per machine)"):
            _STATE["module"] = cpp_extension.load(
                name=_NAME, sources=[str(_staged_sources(build))], extra_cflags=_flags(),
                extra_ldflags=["-fopenmp"] if _openmp() else [],
                build_directory=str(build) if build is not None else None, verbose=False,
            )
        if build is not None:  # built just now (a checked library was imported above)
            write_manifest(build, sorted(p.name for p in build.glob("*.so")))
    except Exception as exc:  # depends on the toolchain
        _STATE["failed"] = True
        first = (str(exc).strip().splitlines() or [""])[0][:200]
        warnings.warn(f"could not {doing} the native rasterizer kernels ({type(exc).__name__}: {first}); "
                      "using the torch ones")
    finally:
        if guard is not None:
            guard.release()
    return _STATE["module"]


__all__ = ["native_kernels"]
