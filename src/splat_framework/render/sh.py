"""Real spherical harmonics up to degree 3, with the constants of the 3DGS reference.

``eval_sh`` returns the raw SH expansion (like ``utils/sh_utils.eval_sh`` in the
reference); the colour the rasterizer composites is ``sh_to_color`` =
``max(eval_sh + 0.5, 0)``, which is what the reference CUDA code computes in
``computeColorFromSH`` (the clamp has zero gradient where it is active).
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["SH_C0", "eval_sh", "num_sh_bases", "rgb_to_sh", "sh_to_rgb", "sh_to_color"]

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def num_sh_bases(degree: int) -> int:
    """Number of SH coefficients per channel for ``degree`` (1, 4, 9, 16)."""
    return (degree + 1) ** 2


def eval_sh(degree: int, coeffs: Tensor, dirs: Tensor) -> Tensor:
    """Evaluate real spherical harmonics (raw value, no +0.5 offset).

    Args:
        degree: active SH degree, 0..3. Only the first ``(degree + 1) ** 2``
            coefficients are used.
        coeffs: [N, K, 3] coefficients, K >= (degree + 1) ** 2, in the 3DGS
            ordering (band by band, m = -l..l).
        dirs: [N, 3] unit viewing directions (camera centre -> Gaussian).

    Returns:
        [N, 3] SH expansion. Add 0.5 and clamp at 0 for the 3DGS colour
        (``sh_to_color``).
    """
    if not 0 <= degree <= 3:
        raise ValueError(f"SH degree must be in 0..3, got {degree}")
    need = num_sh_bases(degree)
    if coeffs.shape[-2] < need:
        raise ValueError(f"degree {degree} needs {need} SH coefficients, got {coeffs.shape[-2]}")
    result = SH_C0 * coeffs[..., 0, :]
    if degree == 0:
        return result
    x = dirs[..., 0:1]
    y = dirs[..., 1:2]
    z = dirs[..., 2:3]
    result = (
        result
        - SH_C1 * y * coeffs[..., 1, :]
        + SH_C1 * z * coeffs[..., 2, :]
        - SH_C1 * x * coeffs[..., 3, :]
    )
    if degree == 1:
        return result
    xx, yy, zz = x * x, y * y, z * z
    xy, yz, xz = x * y, y * z, x * z
    result = (
        result
        + SH_C2[0] * xy * coeffs[..., 4, :]
        + SH_C2[1] * yz * coeffs[..., 5, :]
        + SH_C2[2] * (2.0 * zz - xx - yy) * coeffs[..., 6, :]
        + SH_C2[3] * xz * coeffs[..., 7, :]
        + SH_C2[4] * (xx - yy) * coeffs[..., 8, :]
    )
    if degree == 2:
        return result
    result = (
        result
        + SH_C3[0] * y * (3.0 * xx - yy) * coeffs[..., 9, :]
        + SH_C3[1] * xy * z * coeffs[..., 10, :]
        + SH_C3[2] * y * (4.0 * zz - xx - yy) * coeffs[..., 11, :]
        + SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * coeffs[..., 12, :]
        + SH_C3[4] * x * (4.0 * zz - xx - yy) * coeffs[..., 13, :]
        + SH_C3[5] * z * (xx - yy) * coeffs[..., 14, :]
        + SH_C3[6] * x * (xx - 3.0 * yy) * coeffs[..., 15, :]
    )
    return result


def sh_to_color(degree: int, coeffs: Tensor, dirs: Tensor) -> Tensor:
    """[N, 3] 3DGS colour: ``clamp_min(eval_sh(degree, coeffs, dirs) + 0.5, 0)``."""
    return torch.clamp_min(eval_sh(degree, coeffs, dirs) + 0.5, 0.0)


def rgb_to_sh(rgb: Tensor) -> Tensor:
    """DC coefficient whose degree-0 colour is ``rgb``: ``(rgb - 0.5) / SH_C0``."""
    return (rgb - 0.5) / SH_C0


def sh_to_rgb(sh_dc: Tensor) -> Tensor:
    """Inverse of ``rgb_to_sh``: ``sh_dc * SH_C0 + 0.5``."""
    return sh_dc * SH_C0 + 0.5
