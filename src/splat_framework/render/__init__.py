"""Differentiable Gaussian rendering: the shared rasterizer and SH evaluation."""

from ._kernels import set_compile
from .rasterizer import RenderOutput, rasterize
from .sh import eval_sh, rgb_to_sh, sh_to_color, sh_to_rgb

__all__ = ["RenderOutput", "eval_sh", "rasterize", "rgb_to_sh", "set_compile", "sh_to_color", "sh_to_rgb"]
