"""Differentiable Gaussian rendering: the shared rasterizer and SH evaluation."""

from ._kernels import compile_requested, compiled_or_eager, set_compile
from ._project import quat_to_rotmat
from .backend import RASTERIZERS, backend_name, native_for, set_rasterizer
from .rasterizer import RenderOutput, prepare_kernels, rasterize, request_absgrad
from .sh import eval_sh, rgb_to_sh, sh_to_color, sh_to_rgb

__all__ = [
    "RASTERIZERS",
    "backend_name",
    "set_rasterizer",
    "RenderOutput",
    "compile_requested",
    "compiled_or_eager",
    "eval_sh",
    "native_for",
    "prepare_kernels",
    "quat_to_rotmat",
    "rasterize",
    "request_absgrad",
    "rgb_to_sh",
    "set_compile",
    "sh_to_color",
    "sh_to_rgb",
]
