"""The native kernels, built once per test session (a build takes about a minute on 2 cores)."""

from __future__ import annotations

import shutil
import warnings

import pytest

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
