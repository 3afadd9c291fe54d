"""Differentiable Gaussian rendering: the shared rasterizer and SH evaluation."""

from ._kernels import compile_requested, compiled_or_eager, set_compile
from ._native import native_for
from ._project import quat_to_rotmat
from .rasterizer import RenderOutput, rasterize, request_absgrad
from .sh import eval_sh, rgb_to_sh, sh_to_color, sh_to_rgb

__all__ = [
    "RenderOutput",
    "compile_requested",
    "compiled_or_eager",
    "eval_sh",
    "native_for",
    "quat_to_rotmat",
    "rasterize",
    "request_absgrad",
    "rgb_to_sh",
    "set_compile",
    "sh_to_color",
    "sh_to_rgb",
]
