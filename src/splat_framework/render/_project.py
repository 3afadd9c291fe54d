"""EWA projection of 3D Gaussians to screen space (differentiable, plain torch autograd).

While kernels are compiled (``RenderSettings.compile``: training and rendering runs), a CPU render
projects with the native kernels (``native/project.cpp``, built once per machine with the
compositing kernels): one loop over the Gaussians forward and one backward, for any number of
Gaussians and any SH degree, with nothing traced or compiled in the process (100k Gaussians at SH
degree 3, 2 threads: 6 + 15 ms against 52 + 160 ms eager). Elsewhere ``project_and_shade`` runs in
torch (the reference the native kernels are tested against).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..runtime.profiling import section
from ._kernels import ALPHA_MIN  # a pixel receives a Gaussian only if alpha >= 1/255
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


def native_projection(device: torch.device, settings):
    """The native kernels' projection (``project_forward`` / ``project_backward``, native/project.cpp:
    no tracing, any number of Gaussians and SH degree, the same result for any thread count) where
    renders on ``device`` with ``settings`` (:class:`.settings.RenderSettings`) take the native
    kernels and they could be built; else None."""
    from . import backend

    native = backend.native_for(device, settings)
    return native if native is not None and hasattr(native, "project_forward") else None


def native_cfg(colors: Tensor, cfg: tuple) -> tuple:
    """``cfg`` = (width, height, near, far, eps2d, sh_degree) as the native projection takes it: the SH
    degree resolved (-1 for [N, 3] colours)."""
    *head, sh_degree = cfg
    if colors.dim() != 3:
        return (*head, -1)
    return (*head, int(math.isqrt(colors.shape[1])) - 1 if sh_degree is None else int(sh_degree))


def project(means: Tensor, quats: Tensor, scales: Tensor, colors: Tensor, viewmat: Tensor, K: Tensor,
            cfg: tuple, settings) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor]:
    """``project_and_shade(*inputs, *cfg)`` without gradients: by the native kernels where they run."""
    native = native_projection(means.device, settings)
    if native is not None:
        return native.project_forward(means, quats, scales, colors, viewmat, K, *native_cfg(colors, cfg))
    return project_and_shade(means, quats, scales, colors, viewmat, K, *cfg)


class ProjectFn(torch.autograd.Function):
    """``project_and_shade`` as one autograd node, its backward one timed section.

    By the native kernels (:func:`native_projection`) where they run and the camera is a constant;
    otherwise forward records the eager projection's graph and backward replays it with
    ``torch.autograd.grad``."""

    @staticmethod
    def forward(ctx, means, quats, scales, colors, viewmat, K, cfg, settings):  # type: ignore[override]
        ctx.set_materialize_grads(False)
        inputs = (means, quats, scales, colors, viewmat, K)
        # the native kernels take the camera as a constant: a refined pose or intrinsics use torch
        ctx.native = None if any(ctx.needs_input_grad[4:6]) else native_projection(means.device, settings)
        if ctx.native is not None:
            ctx.cfg = native_cfg(colors, cfg)
            ctx.save_for_backward(*inputs)
            outs = ctx.native.project_forward(*inputs, *ctx.cfg)
            ctx.mark_non_differentiable(outs[4])
            return outs
        with torch.enable_grad():
            leaves = tuple(
                t.detach().requires_grad_(bool(need)) for t, need in zip(inputs, ctx.needs_input_grad)
            )
            outs = project_and_shade(*leaves, *cfg)
        ctx.leaves = leaves
        ctx.outs = outs
        # rgb may be the colours input itself: return a copy, never an input
        ret = tuple(o.detach().clone() if o is leaves[3] else o.detach() for o in outs)
        ctx.mark_non_differentiable(ret[4])
        return ret

    @staticmethod
    def backward(ctx, *grads):  # type: ignore[override]
        with section("projection backward"):
            if ctx.native is not None:
                inputs = ctx.saved_tensors
                n = inputs[0].shape[0]
                shapes = [(n, 2), (n, 3), (n, 3), (n,), None, (n, 3)]  # valid [N] has no gradient
                grads = [g if g is not None else inputs[0].new_zeros(shape) for g, shape in zip(grads, shapes) if shape]
                got = ctx.native.project_backward(*inputs, *ctx.cfg, *grads)
                return (*(g if need else None for g, need in zip(got, ctx.needs_input_grad)), None, None, None, None)
            pairs = [
                (o, g) for o, g in zip(ctx.outs, grads) if g is not None and o.requires_grad
            ]
            wanted = [i for i, leaf in enumerate(ctx.leaves) if leaf.requires_grad]
            result = [None] * (len(ctx.leaves) + 2)
            if not pairs or not wanted:
                return tuple(result)
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
    "project",
    "project_and_shade",
    "project_gaussians",
    "quat_to_rotmat",
    "reference_radii",
]
