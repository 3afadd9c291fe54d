"""The rasterizer tests' set-up: Triton's interpreter (the native kernels' fixture, ``native_module``,
is the whole suite's: ``tests/conftest.py``)."""

from __future__ import annotations

import os

# Triton's interpreter runs the Triton kernels on CPU tensors (test_triton.py); it must be on before
# triton is first imported in the process (collection imports this file before any test runs). Only
# renders that ask for triton by name use it: "auto" on a CPU is the native or torch kernels.
os.environ.setdefault("TRITON_INTERPRET", "1")
