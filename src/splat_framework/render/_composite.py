"""Tile binning and front-to-back alpha compositing with a hand-written backward.

Layout: the image is cut into ``tile x tile`` tiles; every (tile, Gaussian) pair
whose opacity-aware footprint touches the tile is listed, sorted by (tile,
depth). Compositing walks the per-tile lists front to back in *rounds* of
``block`` pairs: one round evaluates a dense block [active_tiles, block,
tile*tile] (alpha via one small GEMM against a quadratic pixel basis), carries
the per-pixel transmittance into the next round, and drops tiles whose pixels
have all terminated (T < 1e-4) -- so early termination saves real work.

The backward replays the rounds (recomputing alpha from the stored per-round
indices and entry transmittance) and uses the closed form

    dL/dalpha_i = T_i h_i - S_i / (1 - alpha_i),
    h_i = f_i . g,   S_i = sum_{j > i} w_j h_j = total - prefix_i,

where ``total = sum_j w_j h_j`` is read off the forward output, so no big
intermediate is kept between forward and backward.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ._project import ALPHA_MIN

T_MIN = 1e-4  # early termination threshold on transmittance
ALPHA_MAX = 0.99
_DUMMY_LOGIT = -1.0e4  # exp() == 0 in float32 and float64


def pixel_basis(tile: int, device: torch.device, dtype: torch.dtype) -> Tensor:
    """[6, tile*tile] quadratic basis (1, lx, ly, lx^2, ly^2, lx*ly) of the pixel
    centres relative to the tile centre (row-major pixels within the tile)."""
    r = torch.arange(tile, device=device, dtype=dtype) + 0.5 - tile / 2.0
    ly, lx = torch.meshgrid(r, r, indexing="ij")
    lx = lx.reshape(-1)
    ly = ly.reshape(-1)
    return torch.stack([torch.ones_like(lx), lx, ly, lx * lx, ly * ly, lx * ly], dim=0)


class TileBins:
    """(tile, Gaussian) pairs sorted by (tile, depth)."""

    def __init__(
        self,
        pair_gid: Tensor,
        pair_tile: Tensor,
        tile_count: Tensor,
        tile_offset: Tensor,
        hit: Tensor,
        ntx: int,
        nty: int,
        tile: int,
    ) -> None:
        self.pair_gid = pair_gid
        self.pair_tile = pair_tile
        self.tile_count = tile_count
        self.tile_offset = tile_offset
        self.hit = hit  # [N] bool, Gaussian has at least one pair
        self.ntx = ntx
        self.nty = nty
        self.tile = tile

    @property
    def n_tiles(self) -> int:
        return self.ntx * self.nty


@torch.no_grad()
def bin_gaussians(
    means2d: Tensor,
    ext_x: Tensor,
    ext_y: Tensor,
    ok: Tensor,
    depths: Tensor,
    width: int,
    height: int,
    tile: int,
) -> TileBins:
    device = means2d.device
    n = means2d.shape[0]
    ntx = (width + tile - 1) // tile
    nty = (height + tile - 1) // tile
    u = means2d[:, 0].detach()
    v = means2d[:, 1].detach()
    # integer pixel index ranges whose centres (p + 0.5) may be inside the footprint
    px0 = torch.ceil(u - ext_x - 0.5)
    px1 = torch.floor(u + ext_x - 0.5)
    py0 = torch.ceil(v - ext_y - 0.5)
    py1 = torch.floor(v + ext_y - 0.5)
    inside = (
        ok
        & (px1 >= 0)
        & (px0 <= width - 1)
        & (py1 >= 0)
        & (py0 <= height - 1)
        & (px0 <= px1)
        & (py0 <= py1)
    )
    ids = torch.nonzero(inside).squeeze(1)
    ids = ids[torch.argsort(depths.detach()[ids])]  # front to back
    tx0 = (px0[ids].clamp(0, width - 1).long()) // tile
    tx1 = (px1[ids].clamp(0, width - 1).long()) // tile
    ty0 = (py0[ids].clamp(0, height - 1).long()) // tile
    ty1 = (py1[ids].clamp(0, height - 1).long()) // tile
    wdt = tx1 - tx0 + 1
    cnt = wdt * (ty1 - ty0 + 1)
    total = int(cnt.sum()) if ids.numel() else 0
    rank = torch.repeat_interleave(torch.arange(ids.numel(), device=device), cnt)
    start = torch.cumsum(cnt, 0) - cnt
    local = torch.arange(total, device=device) - start[rank]
    w_r = wdt[rank]
    tx = tx0[rank] + local % w_r
    ty = ty0[rank] + local // w_r
    tile_id = ty * ntx + tx
    # pairs are generated in depth order; a stable sort by tile keeps it per tile
    tile_sorted, perm = torch.sort(tile_id, stable=True)
    pair_gid = ids[rank[perm]]
    tile_count = torch.bincount(tile_sorted, minlength=ntx * nty)
    tile_offset = torch.cumsum(tile_count, 0) - tile_count
    hit = torch.zeros(n, dtype=torch.bool, device=device)
    hit[ids] = True
    return TileBins(pair_gid, tile_sorted, tile_count, tile_offset, hit, ntx, nty, tile)


def pair_coefficients(
    means2d: Tensor, conics: Tensor, opacities: Tensor, bins: TileBins
) -> Tensor:
    """[P, 6] per-pair coefficients c such that log(alpha_raw) over the tile's
    pixels is ``c @ basis`` (differentiable w.r.t. means2d, conics, opacities)."""
    gid = bins.pair_gid
    t = bins.tile
    tcx = (bins.pair_tile % bins.ntx).to(means2d.dtype) * t + t / 2.0
    tcy = (bins.pair_tile // bins.ntx).to(means2d.dtype) * t + t / 2.0
    m = means2d[gid]
    con = conics[gid]
    dx = tcx - m[:, 0]
    dy = tcy - m[:, 1]
    a, b, c = con.unbind(-1)
    logo = torch.log(opacities[gid])
    c0 = -0.5 * (a * dx * dx + 2.0 * b * dx * dy + c * dy * dy) + logo
    c1 = -(a * dx + b * dy)
    c2 = -(b * dx + c * dy)
    return torch.stack([c0, c1, c2, -0.5 * a, -0.5 * c, -b], dim=-1)


def _round_alpha(coef_blk: Tensor, basis: Tensor) -> tuple[Tensor, Tensor]:
    """alpha (clamped to 0.99, zeroed below 1/255) [nA, B, npx] and mask of unclamped."""
    na, b, _ = coef_blk.shape
    alpha = (coef_blk.reshape(na * b, 6) @ basis).reshape(na, b, -1)
    alpha.exp_()
    clamped = alpha >= ALPHA_MAX
    alpha.clamp_(max=ALPHA_MAX)
    alpha.masked_fill_(alpha < ALPHA_MIN, 0.0)
    return alpha, clamped


class _Composite(torch.autograd.Function):
    @staticmethod
    def forward(ctx, coef, feats, pair_gid, tile_count, tile_offset, basis, n_tiles, block):  # type: ignore[override]
        device, dtype = coef.device, coef.dtype
        p = coef.shape[0]
        n, f = feats.shape
        npx = basis.shape[1]
        dummy = torch.zeros(1, 6, device=device, dtype=dtype)
        dummy[0, 0] = _DUMMY_LOGIT
        coef_pad = torch.cat([coef.detach(), dummy], 0)
        feats_pad = torch.cat([feats.detach(), torch.zeros(1, f, device=device, dtype=dtype)], 0)
        gid_pad = torch.cat([pair_gid, torch.full((1,), n, device=device, dtype=pair_gid.dtype)])
        out = torch.zeros(n_tiles, npx, f, device=device, dtype=dtype)
        active = torch.nonzero(tile_count > 0).squeeze(1)
        t_carry = torch.ones(active.numel(), npx, device=device, dtype=dtype)
        ar = torch.arange(block, device=device)
        rounds = []
        r = 0
        while active.numel() > 0:
            slot = r * block + ar
            cnt = tile_count[active]
            idx = tile_offset[active][:, None] + slot[None, :]
            idx = torch.where(slot[None, :] < cnt[:, None], idx, p)
            alpha, _ = _round_alpha(coef_pad[idx], basis)
            om = 1.0 - alpha
            t_after = torch.cumprod(om, 1).mul_(t_carry[:, None, :])
            w = torch.where(t_after >= T_MIN, alpha * t_after / om, 0.0)
            fb = feats_pad[gid_pad[idx]]
            out[active] += torch.bmm(w.transpose(1, 2), fb)
            rounds.append((active, idx, t_carry))
            t_last = t_after[:, -1, :]
            t_carry = torch.where(t_last >= T_MIN, t_last, 0.0)
            keep = (cnt > (r + 1) * block) & (t_carry > 0).any(1)
            active = active[keep]
            t_carry = t_carry[keep]
            r += 1
        ctx.rounds = rounds
        ctx.save_for_backward(coef_pad, feats_pad, gid_pad, basis, out)
        ctx.shapes = (p, n, f, n_tiles)
        return out

    @staticmethod
    def backward(ctx, g_out):  # type: ignore[override]
        coef_pad, feats_pad, gid_pad, basis, out = ctx.saved_tensors
        p, n, f, n_tiles = ctx.shapes
        device, dtype = coef_pad.device, coef_pad.dtype
        g_out = g_out.contiguous()
        total = (out * g_out).sum(-1)  # [n_tiles, npx]
        prefix = torch.zeros_like(total)
        d_coef = torch.zeros(p + 1, 6, device=device, dtype=dtype)
        d_feats = torch.zeros(n + 1, f, device=device, dtype=dtype)
        basis_t = basis.T.contiguous()
        for active, idx, t_carry in ctx.rounds:
            alpha, clamped = _round_alpha(coef_pad[idx], basis)
            om = 1.0 - alpha
            t_after = torch.cumprod(om, 1).mul_(t_carry[:, None, :])
            incl = t_after >= T_MIN
            t_before = t_after / om
            w = torch.where(incl, alpha * t_before, 0.0)
            gb = g_out[active]  # [nA, npx, F]
            gids = gid_pad[idx]
            fb = feats_pad[gids]
            h = torch.bmm(fb, gb.transpose(1, 2))  # [nA, B, npx]
            cs = torch.cumsum(w * h, 1).add_(prefix[active][:, None, :])
            prefix[active] = cs[:, -1, :]
            s = total[active][:, None, :] - cs
            v = t_before * h - s / om
            dp = torch.where(incl & ~clamped, v * alpha, 0.0)
            na, b, npx = dp.shape
            d_coef[idx.reshape(-1)] = dp.reshape(na * b, npx) @ basis_t
            d_feats.index_add_(0, gids.reshape(-1), torch.bmm(w, gb).reshape(na * b, f))
        return d_coef[:p], d_feats[:n], None, None, None, None, None, None


def composite(
    coef: Tensor,
    feats: Tensor,
    bins: TileBins,
    basis: Tensor,
    block: int,
) -> Tensor:
    """[n_tiles, tile*tile, F] sum_i w_i f_i per pixel (tile-major layout)."""
    return _Composite.apply(
        coef, feats, bins.pair_gid, bins.tile_count, bins.tile_offset, basis, bins.n_tiles, block
    )


def tiles_to_image(x: Tensor, bins: TileBins, width: int, height: int) -> Tensor:
    """[n_tiles, tile*tile, F] -> [H, W, F]."""
    t = bins.tile
    f = x.shape[-1]
    img = x.reshape(bins.nty, bins.ntx, t, t, f).permute(0, 2, 1, 3, 4)
    return img.reshape(bins.nty * t, bins.ntx * t, f)[:height, :width]


__all__ = [
    "T_MIN",
    "ALPHA_MAX",
    "TileBins",
    "bin_gaussians",
    "composite",
    "pair_coefficients",
    "pixel_basis",
    "tiles_to_image",
]
