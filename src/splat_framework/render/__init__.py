"""Differentiable Gaussian rendering: the shared rasterizer, its settings and SH evaluation."""

from ._kernels import compiled_or_eager
from ._project import quat_to_rotmat
from .backend import backend_name, native_for
from .proving import prepare_kernels
from .rasterizer import RenderOutput, rasterize
from .settings import RASTERIZERS, RenderSettings
from .sh import eval_sh, rgb_to_sh, sh_to_color, sh_to_rgb

__all__ = [
    "RASTERIZERS",
    "RenderOutput",
    "RenderSettings",
    "backend_name",
    "compiled_or_eager",
    "eval_sh",
    "native_for",
    "prepare_kernels",
    "quat_to_rotmat",
    "rasterize",
    "rgb_to_sh",
    "sh_to_color",
    "sh_to_rgb",
]
