"""EWA projection of 3D Gaussians to screen space (differentiable, plain torch autograd).

While kernels are compiled (``compile_requested()``: training runs), a render that needs
gradients projects with ``project_and_shade`` compiled by ``torch.compile`` (dynamic sizes: one
graph whatever the number of Gaussians): the projection and SH colours' few dozen passes over
the Gaussians become a few fused loops, forward and backward (on fern's 48k Gaussians,
2 CPU threads, 21 -> 11 ms per step). The values are the eager ones.
"""

from __future__ import annotations

import contextlib
import functools
from dataclasses import dataclass

import math

import torch
from torch import Tensor

from ._kernels import ALPHA_MIN  # a pixel receives a Gaussian only if alpha >= 1/255
from ._kernels import compile_requested, compiled_or_eager
from ..runtime.profiling import section
from .sh import sh_to_color



@dataclass
class Projected:
    means2d: Tensor  # [N, 2] pixel coordinates (graph tensor)
    conics: Tensor  # [N, 3] inverse 2D covariance (a, b, c): q = a dx^2 + 2 b dx dy + c dy^2
    cov2d: Tensor  # [N, 3] 2D covariance (xx, xy, yy), dilated by eps2d
    depths: Tensor  # [N] camera z
    valid: Tensor  # [N] bool, inside [near, far] and non-degenerate


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """[N, 4] (w, x, y, z), not necessarily normalised -> [N, 3, 3] rotation matrices."""
    q = quats / quats.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(q.shape[:-1] + (3, 3))


def project_gaussians(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    near_plane: float,
    far_plane: float,
    eps2d: float,
) -> Projected:
    """Project Gaussians with the EWA local affine approximation (3DGS / gsplat)."""
    dtype = means.dtype
    viewmat = viewmat.to(dtype)
    K = K.to(dtype)
    Rw = viewmat[:3, :3]
    tw = viewmat[:3, 3]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]

    p = means @ Rw.T + tw  # [N, 3] camera space
    x, y, z = p.unbind(-1)
    valid = (z >= near_plane) & (z <= far_plane)
    zs = torch.where(valid, z, torch.ones_like(z))  # keeps culled entries finite

    # Clamp the position used in the Jacobian (gsplat's asymmetric version of the
    # reference's 1.3 * tan_fov; identical when the principal point is centred).
    tan_fovx = 0.5 * width / fx
    tan_fovy = 0.5 * height / fy
    lim_x_pos = (width - cx) / fx + 0.3 * tan_fovx
    lim_x_neg = cx / fx + 0.3 * tan_fovx
    lim_y_pos = (height - cy) / fy + 0.3 * tan_fovy
    lim_y_neg = cy / fy + 0.3 * tan_fovy
    txz = torch.minimum(torch.maximum(x / zs, -lim_x_neg), lim_x_pos)
    tyz = torch.minimum(torch.maximum(y / zs, -lim_y_neg), lim_y_pos)

    inv_z = 1.0 / zs
    zero = torch.zeros_like(zs)
    # J = [[fx/z, 0, -fx tx/z^2], [0, fy/z, -fy ty/z^2]] with tx = z * txz
    J = torch.stack(
        [fx * inv_z, zero, -fx * txz * inv_z, zero, fy * inv_z, -fy * tyz * inv_z], dim=-1
    ).reshape(-1, 2, 3)

    R = quat_to_rotmat(quats)
    M = R * scales[:, None, :]  # R diag(s)
    T = J @ Rw @ M  # [N, 2, 3]  (J W R S)
    cov = T @ T.transpose(1, 2)  # [N, 2, 2]
    cxx = cov[:, 0, 0] + eps2d
    cxy = cov[:, 0, 1]
    cyy = cov[:, 1, 1] + eps2d
    det = cxx * cyy - cxy * cxy
    valid = valid & (det > 0)
    det_s = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([cyy / det_s, -cxy / det_s, cxx / det_s], dim=-1)
    means2d = torch.stack([fx * x * inv_z + cx, fy * y * inv_z + cy], dim=-1)
    cov2d = torch.stack([cxx, cxy, cyy], dim=-1)
    return Projected(means2d=means2d, conics=conics, cov2d=cov2d, depths=z, valid=valid)


def project_and_shade(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    colors: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    near_plane: float,
    far_plane: float,
    eps2d: float,
    sh_degree: int | None,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Projection plus per-Gaussian colour.

    Returns (means2d [N, 2], conics [N, 3], cov2d [N, 3], depths [N], valid [N] bool,
    rgb [N, 3]); rgb is ``colors`` itself for [N, 3] input, or the SH colour
    max(SH(dir) + 0.5, 0) for [N, K, 3] coefficients, dir = unit(mean - camera centre).
    """
    if colors.dim() == 3:
        deg = int(math.isqrt(colors.shape[1])) - 1 if sh_degree is None else int(sh_degree)
        R = viewmat[:3, :3]
        cam_center = -R.T @ viewmat[:3, 3]
        dirs = means - cam_center
        dirs = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        rgb = sh_to_color(deg, colors, dirs)
    else:
        rgb = colors
    p = project_gaussians(means, quats, scales, viewmat, K, width, height, near_plane, far_plane, eps2d)
    return p.means2d, p.conics, p.cov2d, p.depths, p.valid, rgb


def all_sh_bands(colors: Tensor, sh_degree: int | None) -> tuple[Tensor, int | None]:
    """SH coefficients [N, K, 3] of degree ``sh_degree`` as degree 3: the active bands followed by zeros
    ([N, 16, 3]), so that the compiled projection sees one shape and one degree whatever the degree
    (3DGS raises it during training). The colour is the same: an absent band adds exact zeros, and
    the inactive coefficients' gradient is zero, as when they are left out. [N, 3] colours pass."""
    if colors.dim() != 3:
        return colors, sh_degree
    degree = int(math.isqrt(colors.shape[1])) - 1 if sh_degree is None else int(sh_degree)
    used = colors[:, : (degree + 1) ** 2]
    return torch.nn.functional.pad(used, (0, 0, 0, 16 - used.shape[1])), 3


@functools.cache
def _compiled_projection():
    """``project_and_shade`` compiled once per process (dynamic sizes), eager after any failure."""
    return compiled_or_eager(project_and_shade, "the projection", context=_no_donated_buffers, dynamic=True)


def _no_donated_buffers():
    """ProjectFn's backward keeps the graph (a caller may backpropagate twice), which a compiled
    backward allows only without donated buffers; it is compiled at its first call, so the forward
    and the backward both run under this."""
    import torch._functorch.config as functorch_config

    return functorch_config.patch(donated_buffer=False)


class ProjectFn(torch.autograd.Function):
    """``project_and_shade`` as one autograd node.

    Forward records the projection's graph internally (the compiled projection while kernels are
    compiled); backward replays it with ``torch.autograd.grad`` inside the rasterizer's CPU thread
    policy, so the projection backward also runs with the thread count chosen for the rasterizer
    (see ``threads``), as one timed section."""

    @staticmethod
    def forward(ctx, means, quats, scales, colors, viewmat, K, cfg):  # type: ignore[override]
        ctx.set_materialize_grads(False)
        inputs = (means, quats, scales, colors, viewmat, K)
        # compiled where it is measured and tested: on a CPU, beside the native kernels
        compiled = compile_requested() and means.device.type == "cpu"
        project = _compiled_projection() if compiled else project_and_shade
        ctx.compiled = compiled
        with torch.enable_grad():
            leaves = tuple(
                t.detach().requires_grad_(bool(need)) for t, need in zip(inputs, ctx.needs_input_grad)
            )
            if compiled:  # one graph for every SH degree: a new degree mid-run would compile again
                colors, degree = all_sh_bands(leaves[3], cfg[-1])
                outs = project(*leaves[:3], colors, *leaves[4:], *cfg[:-1], degree)
            else:
                outs = project(*leaves, *cfg)
        ctx.leaves = leaves
        ctx.outs = outs
        # rgb may be the colours input itself: return a copy, never an input
        ret = tuple(o.detach().clone() if o is leaves[3] else o.detach() for o in outs)
        ctx.mark_non_differentiable(ret[4])
        return ret

    @staticmethod
    def backward(ctx, *grads):  # type: ignore[override]
        with section("projection backward"):
            pairs = [
                (o, g) for o, g in zip(ctx.outs, grads) if g is not None and o.requires_grad
            ]
            wanted = [i for i, leaf in enumerate(ctx.leaves) if leaf.requires_grad]
            result = [None] * (len(ctx.leaves) + 1)
            if not pairs or not wanted:
                return tuple(result)
            with _no_donated_buffers() if ctx.compiled else contextlib.nullcontext():
                got = torch.autograd.grad(
                    [o for o, _ in pairs],
                    [ctx.leaves[i] for i in wanted],
                    [g for _, g in pairs],
                    allow_unused=True,
                    retain_graph=True,
                )
            for i, g in zip(wanted, got):
                result[i] = g
            return tuple(result)


def footprint(
    cov2d: Tensor, opacities: Tensor, valid: Tensor
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Opacity-aware half extents of the region where alpha >= 1/255.

    The region is the ellipse d^T cov^-1 d <= 2 ln(255 opacity); its axis-aligned
    half extents are sqrt(q_max * cov_xx), sqrt(q_max * cov_yy). Returned with a
    small safety margin (the per-pixel test is exact).

    Returns:
        (ext_x [N], ext_y [N], ok [N] bool, qmax [N]) -- ok is False where the
        Gaussian can never reach 1/255; qmax = 2 ln(255 opacity) (with margin).
    """
    with torch.no_grad():
        o = opacities.detach().to(cov2d.dtype)
        qmax = 2.0 * torch.log(torch.clamp_min(o * 255.0, 1e-30))
        ok = valid & (o >= ALPHA_MIN)
        qmax = torch.clamp_min(qmax, 0.0)
        c = cov2d.detach()
        ext_x = torch.sqrt(qmax * c[:, 0]) * (1.0 + 1e-4) + 1e-3
        ext_y = torch.sqrt(qmax * c[:, 2]) * (1.0 + 1e-4) + 1e-3
    return ext_x, ext_y, ok, qmax * (1.0 + 1e-4) + 1e-6


def reference_radii(cov2d: Tensor, active: Tensor) -> Tensor:
    """[N] int32 radius as in the 3DGS reference: ceil(3 sqrt(lambda_max)), 0 where inactive."""
    with torch.no_grad():
        c = cov2d.detach()
        mid = 0.5 * (c[:, 0] + c[:, 2])
        disc = torch.sqrt(torch.clamp_min(mid * mid - (c[:, 0] * c[:, 2] - c[:, 1] ** 2), 0.1))
        lam = mid + disc
        r = torch.ceil(3.0 * torch.sqrt(torch.clamp_min(lam, 0.0)))
        r = torch.where(active, r, torch.zeros_like(r))
        r = torch.nan_to_num(r, nan=0.0, posinf=float(2**30), neginf=0.0).clamp(0, 2**30)
    return r.to(torch.int32)


__all__ = [
    "ALPHA_MIN",
    "Projected",
    "ProjectFn",
    "footprint",
    "project_and_shade",
    "project_gaussians",
    "quat_to_rotmat",
    "reference_radii",
]
