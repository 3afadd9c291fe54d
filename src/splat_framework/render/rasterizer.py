"""The shared differentiable Gaussian rasterizer (contract; implementation in progress).

See ``rasterize`` for the full contract.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from torch import Tensor


@dataclass
class RenderOutput:
    """Result of ``rasterize``.

    Attributes:
        rgb: [H, W, 3] composited colour (background blended in).
        depth: [H, W, 1] sum_i w_i z_i (camera z), or that divided by alpha
            when ``depth_mode="expected"``.
        alpha: [H, W, 1] accumulated opacity sum_i w_i.
        meta: "means2d" [N, 2] pixel-space centres whose ``.grad`` after
            backward holds the screen-space positional gradient; "radii" [N]
            int pixel radius (0 = not rendered); "visible" [N] bool;
            "depths" [N] camera z; "width", "height" ints.
    """

    rgb: Tensor
    depth: Tensor
    alpha: Tensor
    meta: dict = field(default_factory=dict)


def rasterize(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    colors: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    *,
    sh_degree: int | None = None,
    background: Tensor | None = None,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    depth_mode: Literal["accumulated", "expected"] = "accumulated",
    eps2d: float = 0.3,
) -> RenderOutput:
    raise NotImplementedError
