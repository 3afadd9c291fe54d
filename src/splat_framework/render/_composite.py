"""Tile binning and front-to-back alpha compositing with a hand-written backward.

Layout: the image is cut into ``tile x tile`` tiles. Visible Gaussians are
sorted by depth once and cut into depth *chunks* of about ``chunk_pairs``
(tile, Gaussian) pairs. For each chunk, front to back, the pairs whose tile is
not finished yet are listed and sorted by (tile, depth) (a stable sort by tile
of pairs generated in depth order). Each chunk's per-tile lists are then walked
in *rounds* of ``block`` pairs: one round evaluates a dense block
[active_tiles, block, tile*tile] of alphas (one small GEMM of per-pair
coefficients against a quadratic pixel basis, then exp), carries the per-pixel
transmittance to the next round, and drops tiles whose pixels have all
terminated (T < 1e-4). Finished tiles are skipped by all later chunks, so
Gaussians hidden behind opaque layers cost (almost) nothing.

The backward replays the rounds (recomputing alpha from the stored per-round
Gaussian ids and entry transmittance) and uses the closed form

    dL/dalpha_i = T_i h_i - S_i / (1 - alpha_i),
    h_i = f_i . g,   S_i = sum_{j > i} w_j h_j = total - prefix_i,

where ``total = sum_j w_j h_j`` is read off the forward output, so nothing of
size [pairs, pixels] is kept between forward and backward.
"""

from __future__ import annotations

from dataclasses import dataclass

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


@dataclass
class TileGrid:
    tile: int
    ntx: int
    nty: int
    width: int
    height: int

    @property
    def n_tiles(self) -> int:
        return self.ntx * self.nty


@dataclass
class Footprints:
    """Depth-sorted visible Gaussians and their tile rectangles (inclusive)."""

    ids: Tensor  # [V] Gaussian indices, front to back
    tx0: Tensor
    tx1: Tensor
    ty0: Tensor
    ty1: Tensor
    hit: Tensor  # [N] bool


@torch.no_grad()
def tile_footprints(
    means2d: Tensor,
    ext_x: Tensor,
    ext_y: Tensor,
    ok: Tensor,
    depths: Tensor,
    grid: TileGrid,
) -> Footprints:
    width, height, tile = grid.width, grid.height, grid.tile
    u = means2d[:, 0].detach()
    v = means2d[:, 1].detach()
    # integer pixel index ranges whose centres (p + 0.5) may be inside the footprint
    px0 = torch.ceil(u - ext_x - 0.5)
    px1 = torch.floor(u + ext_x - 0.5)
    py0 = torch.ceil(v - ext_y - 0.5)
    py1 = torch.floor(v + ext_y - 0.5)
    hit = (
        ok
        & (px1 >= 0)
        & (px0 <= width - 1)
        & (py1 >= 0)
        & (py0 <= height - 1)
        & (px0 <= px1)
        & (py0 <= py1)
    )
    ids = torch.nonzero(hit).squeeze(1)
    ids = ids[torch.argsort(depths.detach()[ids], stable=True)]  # front to back
    tx0 = px0[ids].clamp(0, width - 1).long() // tile
    tx1 = px1[ids].clamp(0, width - 1).long() // tile
    ty0 = py0[ids].clamp(0, height - 1).long() // tile
    ty1 = py1[ids].clamp(0, height - 1).long() // tile
    return Footprints(ids, tx0, tx1, ty0, ty1, hit)


def _chunk_bounds(cnt: Tensor, chunk_pairs: int) -> list[tuple[int, int]]:
    """Split depth-sorted Gaussians (pair counts ``cnt``) into runs of ~chunk_pairs pairs."""
    v = cnt.numel()
    if v == 0:
        return []
    cum = torch.cumsum(cnt, 0)
    total = int(cum[-1])
    if total <= chunk_pairs:
        return [(0, v)]
    marks = torch.arange(chunk_pairs, total, chunk_pairs, device=cnt.device, dtype=cum.dtype)
    cuts = torch.searchsorted(cum, marks, right=True).tolist()
    edges = [0] + cuts + [v]
    bounds = [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]
    return bounds


def _chunk_pairs(fp: Footprints, g0: int, g1: int, grid: TileGrid, tile_done: Tensor | None):
    """Pairs of Gaussians fp.ids[g0:g1] with unfinished tiles, sorted by (tile, depth).

    Returns (gid_sorted [Pc], tile_count [n_tiles], tile_offset [n_tiles])."""
    device = fp.ids.device
    ids = fp.ids[g0:g1]
    tx0, tx1, ty0, ty1 = fp.tx0[g0:g1], fp.tx1[g0:g1], fp.ty0[g0:g1], fp.ty1[g0:g1]
    wdt = tx1 - tx0 + 1
    cnt = wdt * (ty1 - ty0 + 1)
    total = int(cnt.sum())
    rank = torch.repeat_interleave(torch.arange(ids.numel(), device=device), cnt, output_size=total)
    start = torch.cumsum(cnt, 0) - cnt
    local = torch.arange(total, device=device) - start[rank]
    w_r = wdt[rank]
    tile_id = (ty0[rank] + local // w_r) * grid.ntx + tx0[rank] + local % w_r
    if tile_done is not None:
        keep = ~tile_done[tile_id]
        tile_id = tile_id[keep]
        rank = rank[keep]
    # pairs are generated in depth order; a stable sort by tile keeps that order per tile
    tile_sorted, perm = torch.sort(tile_id, stable=True)
    gid_sorted = ids[rank[perm]]
    tile_count = torch.bincount(tile_sorted, minlength=grid.n_tiles)
    tile_offset = torch.cumsum(tile_count, 0) - tile_count
    return gid_sorted, tile_count, tile_offset


def _coefficients(gp: Tensor, tc: Tensor) -> Tensor:
    """Per-pair coefficients [nA, B, 6] of log(opacity * G) on the pixel basis.

    gp: [nA, B, 6] gathered (u, v, a, b, c, log o); tc: [nA, 2] tile centres."""
    dx = tc[:, None, 0] - gp[..., 0]
    dy = tc[:, None, 1] - gp[..., 1]
    a, b, c = gp[..., 2], gp[..., 3], gp[..., 4]
    bdy = b * dy
    c0 = -0.5 * (a * dx * dx + 2.0 * bdy * dx + c * dy * dy) + gp[..., 5]
    c1 = -(a * dx + bdy)
    c2 = -(b * dx + c * dy)
    return torch.stack([c0, c1, c2, -0.5 * a, -0.5 * c, -b], dim=-1)


def _coefficients_backward(gp: Tensor, tc: Tensor, coef: Tensor, gc: Tensor) -> Tensor:
    """Chain [nA, B, 6] coefficient grads back to (u, v, a, b, c, log o)."""
    dx = tc[:, None, 0] - gp[..., 0]
    dy = tc[:, None, 1] - gp[..., 1]
    a, b, c = gp[..., 2], gp[..., 3], gp[..., 4]
    g0, g1, g2, g3, g4, g5 = gc.unbind(-1)
    ga = -0.5 * dx * dx * g0 - dx * g1 - 0.5 * g3
    gb = -dx * dy * g0 - dy * g1 - dx * g2 - g5
    gcc = -0.5 * dy * dy * g0 - dy * g2 - 0.5 * g4
    gdx = coef[..., 1] * g0 - a * g1 - b * g2
    gdy = coef[..., 2] * g0 - b * g1 - c * g2
    return torch.stack([-gdx, -gdy, ga, gb, gcc, g0], dim=-1)


def _alpha(coef: Tensor, basis: Tensor) -> Tensor:
    """alpha [nA, B, npx]: min(0.99, exp(coef @ basis)), zeroed below 1/255."""
    na, b, _ = coef.shape
    alpha = (coef.reshape(na * b, 6) @ basis).reshape(na, b, -1)
    alpha.exp_().clamp_(max=ALPHA_MAX)
    return alpha.masked_fill_(alpha < ALPHA_MIN, 0.0)


def _transmittance(alpha: Tensor, t_carry: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """(1 - alpha, T after each pair, T before each pair) for one round."""
    om = 1.0 - alpha
    t_after = torch.cumprod(om, 1).mul_(t_carry[:, None, :])
    t_before = torch.cat([t_carry[:, None, :], t_after[:, :-1]], 1)
    return om, t_after, t_before


class _Composite(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, feats, fp, grid, basis, block, chunk_pairs):  # type: ignore[override]
        device, dtype = means2d.device, means2d.dtype
        n, f = feats.shape
        npx = basis.shape[1]
        n_tiles = grid.n_tiles
        # per-Gaussian table (u, v, a, b, c, log o | features); row n is a dummy with alpha 0
        logo = torch.log(opacities.detach().clamp_min(1e-30))
        table = torch.cat(
            [means2d.detach(), conics.detach(), logo[:, None], feats.detach()], dim=1
        )
        dummy = torch.zeros(1, 6 + f, device=device, dtype=dtype)
        dummy[0, 5] = _DUMMY_LOGIT
        table = torch.cat([table, dummy], 0)
        t_idx = torch.arange(n_tiles, device=device)
        tile_centers = torch.stack(
            [(t_idx % grid.ntx) * grid.tile, (t_idx // grid.ntx) * grid.tile], dim=1
        ).to(dtype) + grid.tile / 2.0

        out = torch.zeros(n_tiles, npx, f, device=device, dtype=dtype)
        t_state = torch.ones(n_tiles, npx, device=device, dtype=dtype)  # 0 once a pixel stopped
        tile_done = torch.zeros(n_tiles, dtype=torch.bool, device=device)
        ar = torch.arange(block, device=device)
        rounds = []
        cnt = (fp.tx1 - fp.tx0 + 1) * (fp.ty1 - fp.ty0 + 1)
        for ci, (g0, g1) in enumerate(_chunk_bounds(cnt, chunk_pairs)):
            gid_sorted, tile_count, tile_offset = _chunk_pairs(
                fp, g0, g1, grid, tile_done if ci > 0 else None
            )
            gid_pad = torch.cat([gid_sorted, torch.full((1,), n, device=device, dtype=gid_sorted.dtype)])
            pc = gid_sorted.numel()
            active = torch.nonzero(tile_count > 0).squeeze(1)
            r = 0
            while active.numel() > 0:
                slot = r * block + ar
                cnt_a = tile_count[active]
                idx = tile_offset[active][:, None] + slot[None, :]
                gid = gid_pad[torch.where(slot[None, :] < cnt_a[:, None], idx, pc)]
                t_carry = t_state[active]
                rows = table[gid]  # [nA, B, 6 + F]
                alpha = _alpha(_coefficients(rows[..., :6], tile_centers[active]), basis)
                om, t_after, t_before = _transmittance(alpha, t_carry)
                w = torch.where(t_after >= T_MIN, alpha.mul_(t_before), 0.0)
                out[active] += torch.bmm(w.transpose(1, 2), rows[..., 6:])
                rounds.append((active, gid, t_carry))
                t_last = t_after[:, -1, :]
                t_new = torch.where(t_last >= T_MIN, t_last, 0.0)
                t_state[active] = t_new
                alive = (t_new > 0).any(1)
                tile_done[active[~alive]] = True
                active = active[(cnt_a > (r + 1) * block) & alive]
                r += 1
        ctx.rounds = rounds
        ctx.save_for_backward(table, tile_centers, basis, out, opacities.detach())
        ctx.nf = (n, f)
        return out

    @staticmethod
    def backward(ctx, g_out):  # type: ignore[override]
        table, tile_centers, basis, out, opac = ctx.saved_tensors
        n, f = ctx.nf
        g_out = g_out.contiguous()
        total = (out * g_out).sum(-1)  # [n_tiles, npx]
        prefix = torch.zeros_like(total)
        grads = torch.zeros(n + 1, 6 + f, device=table.device, dtype=table.dtype)
        basis_t = basis.T.contiguous()
        for active, gid, t_carry in ctx.rounds:
            rows = table[gid]
            gp = rows[..., :6]
            tc = tile_centers[active]
            coef = _coefficients(gp, tc)
            alpha = _alpha(coef, basis)
            om, t_after, t_before = _transmittance(alpha, t_carry)
            use = (t_after >= T_MIN) & (alpha < ALPHA_MAX)  # clamped alpha has zero grad
            w = torch.where(t_after >= T_MIN, alpha * t_before, 0.0)
            gb = g_out[active]  # [nA, npx, F]
            h = torch.bmm(rows[..., 6:], gb.transpose(1, 2))  # [nA, B, npx]
            cs = torch.cumsum(w * h, 1).add_(prefix[active][:, None, :])
            prefix[active] = cs[:, -1, :]
            s = total[active][:, None, :] - cs
            # dL/dlogit = alpha * dL/dalpha = w h - alpha S / (1 - alpha)
            dp = torch.where(use, w * h - alpha * s / om, 0.0)
            na, b, npx = dp.shape
            gc = (dp.reshape(na * b, npx) @ basis_t).reshape(na, b, 6)
            g_rows = torch.cat(
                [_coefficients_backward(gp, tc, coef, gc), torch.bmm(w, gb)], dim=-1
            )
            grads.index_add_(0, gid.reshape(-1), g_rows.reshape(na * b, 6 + f))
        grads = grads[:n]
        d_opac = torch.where(opac > 0, grads[:, 5] / opac.clamp_min(1e-30), 0.0)
        return grads[:, 0:2], grads[:, 2:5], d_opac, grads[:, 6:], None, None, None, None, None


def composite(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    feats: Tensor,
    fp: Footprints,
    grid: TileGrid,
    basis: Tensor,
    block: int,
    chunk_pairs: int,
) -> Tensor:
    """[n_tiles, tile*tile, F] sum_i w_i f_i per pixel (tile-major layout)."""
    return _Composite.apply(means2d, conics, opacities, feats, fp, grid, basis, block, chunk_pairs)


def tiles_to_image(x: Tensor, grid: TileGrid) -> Tensor:
    """[n_tiles, tile*tile, F] -> [H, W, F]."""
    t = grid.tile
    f = x.shape[-1]
    img = x.reshape(grid.nty, grid.ntx, t, t, f).permute(0, 2, 1, 3, 4)
    return img.reshape(grid.nty * t, grid.ntx * t, f)[: grid.height, : grid.width]


__all__ = [
    "T_MIN",
    "ALPHA_MAX",
    "Footprints",
    "TileGrid",
    "composite",
    "pixel_basis",
    "tile_footprints",
    "tiles_to_image",
]
