"""The native kernels, built once per machine for the tests (a build takes about 25 s on 2 idle cores:
docs/figures.toml) and loaded from :func:`tiers.machine_cache` by every later session and worker."""

from __future__ import annotations

import os
import shutil
import time
import warnings
from pathlib import Path

import pytest

# Triton's interpreter runs the Triton kernels on CPU tensors (test_triton.py); it must be on before
# triton is first imported in the process (collection imports this file before any test runs). Only
# renders that ask for triton by name use it: "auto" on a CPU is the native or torch kernels.
os.environ.setdefault("TRITON_INTERPRET", "1")

HAVE_TOOLCHAIN = bool((shutil.which("c++") or shutil.which("g++")) and shutil.which("ninja"))


@pytest.fixture(scope="session")
def native_module():
    """The loaded extension (render/native/*.cpp), from this machine's test cache: built there when
    its sources, flags, torch or compiler changed, else loaded (the product's cache rules)."""
    from splat_framework.render import _native
    from tiers import machine_cache, note

    if not HAVE_TOOLCHAIN:
        pytest.skip("no C++ compiler or ninja on this machine: the native kernels cannot be built here")
    t0 = time.time()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = _native.native_kernels(machine_cache())
    assert module is not None, [str(w.message) for w in caught]  # with a toolchain the build must work
    library = Path(module.__file__)
    built = library.stat().st_mtime >= t0
    note(f"native kernels: {'built' if built else 'loaded'} ({time.time() - t0:.1f} s), {library.parent}")
    return module
