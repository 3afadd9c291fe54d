"""The native kernels, built once per test session (a build takes about 25 s on 2 idle cores: docs/figures.toml)."""

from __future__ import annotations

import os
import shutil
import warnings

import pytest

# Triton's interpreter runs the Triton kernels on CPU tensors (test_triton.py); it must be on before
# triton is first imported in the process (collection imports this file before any test runs). Only
# renders that ask for triton by name use it: "auto" on a CPU is the native or torch kernels.
os.environ.setdefault("TRITON_INTERPRET", "1")

HAVE_TOOLCHAIN = bool((shutil.which("c++") or shutil.which("g++")) and shutil.which("ninja"))


@pytest.fixture(scope="session")
def native_module(tmp_path_factory):
    """The loaded extension (render/native/*.cpp), built into this session's temporary folder."""
    from splat_framework.render import _native

    if not HAVE_TOOLCHAIN:
        pytest.skip("no C++ compiler or ninja on this machine: the native kernels cannot be built here")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = _native.native_kernels(tmp_path_factory.mktemp("native-cache"))
    assert module is not None, [str(w.message) for w in caught]  # with a toolchain the build must work
    return module
