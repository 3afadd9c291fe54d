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

On a CPU while kernels are compiled, the native kernels (:mod:`._native`) take both steps: each
chunk's pairs are binned by ``native/binning.cpp`` (one pass over the chunk's Gaussians, then a
stable counting sort by tile: the same pairs in the same order as the torch binning) and composited
by ``native/composite.cpp`` instead of rounds: every pair of a tile's list against the tile's
pixels, the same rules and the same closed form; the backward replays each chunk from its entry
transmittance and the number of pairs each pixel included.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from ..runtime.profiling import section
from ..runtime.resources import available_cores
from ._kernels import ALPHA_MAX, T_MIN, gathering_bwd, get_kernels
from ._kernels import bwd_round as bwd_round_eager
from .settings import RenderSettings

_DUMMY_LOGIT = -1.0e4  # exp() == 0 in float32 and float64


def _at(x: Tensor, i: Tensor) -> Tensor:
    """``x[i]`` for a 1-D index ``i`` along dim 0, through ``index_select``: on CPU
    several times faster than advanced indexing (10x for a 1-D int64 gather of
    400k entries, 4.5x for [N, 6] rows; torch 2.13, one thread)."""
    return x.index_select(0, i)


def _sort_key(tile_id: Tensor, n_tiles: int) -> Tensor:
    """Tile ids in the narrowest integer type that holds them: a stable sort of
    int16 keys is ~2.7x faster than of int64 ones on CPU (400k keys)."""
    if n_tiles <= torch.iinfo(torch.int16).max:
        return tile_id.to(torch.int16)
    if n_tiles <= torch.iinfo(torch.int32).max:
        return tile_id.to(torch.int32)
    return tile_id


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
    ell: Tensor  # [V, 6] (u, v, cov_xx, cov_xy, cov_yy, qmax): the ellipse alpha >= 1/255
    hit: Tensor  # [N] bool
    rows: int | None = None  # the rectangles' tile rows summed (the torch binning reads it with V)
    area: int | None = None  # the rectangles' tiles summed: at least the pairs of all of them


@torch.no_grad()
def tile_footprints(
    means2d: Tensor,
    ext_x: Tensor,
    ext_y: Tensor,
    ok: Tensor,
    depths: Tensor,
    cov2d: Tensor,
    qmax: Tensor,
    grid: TileGrid,
    native=None,
) -> Footprints:
    """The visible Gaussians front to back and their tile rectangles; with ``native`` (the loaded
    kernels) all of it in one native pass, the same numbers (its depth order a radix sort: the
    same permutation as torch's stable argsort, ~10x faster on CPU)."""
    width, height, tile = grid.width, grid.height, grid.tile
    if native is not None:
        ids, tx0, tx1, ty0, ty1, ell, hit = native.footprints(
            means2d.detach(), ext_x.detach(), ext_y.detach(), ok, depths.detach(), cov2d.detach(), qmax.detach(),
            width, height, tile)
        return Footprints(ids, tx0, tx1, ty0, ty1, ell, hit)
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
    tx0 = px0.clamp(0, width - 1).long() // tile
    tx1 = px1.clamp(0, width - 1).long() // tile
    ty0 = py0.clamp(0, height - 1).long() // tile
    ty1 = py1.clamp(0, height - 1).long() // tile
    nrows = torch.where(hit, ty1 - ty0 + 1, 0)
    # the render's one host read: V, the tile rows and the tiles of the rectangles, together
    v, rows, area = torch.stack([hit.sum(), nrows.sum(), (nrows * (tx1 - tx0 + 1)).sum()]).tolist()
    # front to back, ties in index order; the others after them (a stable sort by depth of the hit
    # ones, as nonzero then a stable argsort, without reading their count apart)
    ids = torch.argsort(torch.where(hit, depths.detach(), torch.inf), stable=True)[:v]
    ell = _at(torch.cat([means2d.detach(), cov2d.detach(), qmax[:, None]], dim=1), ids)
    return Footprints(ids, _at(tx0, ids), _at(tx1, ids), _at(ty0, ids), _at(ty1, ids), ell, hit, rows, area)


def _alive_counts(tile_done: Tensor, fp: Footprints, pos: int, grid: TileGrid) -> Tensor:
    """Number of unfinished tiles in each rectangle of fp[pos:] (summed-area table)."""
    alive = (~tile_done).reshape(grid.nty, grid.ntx).to(torch.int64)
    w1 = grid.ntx + 1
    sat = torch.zeros(grid.nty + 1, w1, dtype=torch.int64, device=alive.device)
    sat[1:, 1:] = alive.cumsum(0).cumsum(1)
    flat = sat.reshape(-1)
    tx0, tx1, ty0, ty1 = fp.tx0[pos:], fp.tx1[pos:] + 1, fp.ty0[pos:], fp.ty1[pos:] + 1
    return _at(flat, ty1 * w1 + tx1) - _at(flat, ty0 * w1 + tx1) - _at(flat, ty1 * w1 + tx0) + _at(flat, ty0 * w1 + tx0)


def _iter_chunks(fp: Footprints, grid: TileGrid, chunk_pairs: int, tile_done: Tensor, native=None):
    """Yield per-chunk (gid_sorted, tile_count, tile_offset), front to back.

    Chunks hold ~chunk_pairs pairs with unfinished tiles; ``tile_done`` is read
    (it is updated by the caller between chunks): Gaussians whose rectangle holds
    only finished tiles are skipped, and iteration stops once every tile is done.
    ``native``: the native kernels bin each chunk (the same pairs in the same order), else torch ops.
    """
    v = fp.ids.numel()
    pos = 0
    first = True
    while pos < v:
        with section("binning"):
            if not first and bool(tile_done.all()):
                return
            if native is not None:
                gid_sorted, tile_count, tile_offset, pos = native.bin_chunk(
                    fp.ids, fp.tx0, fp.tx1, fp.ty0, fp.ty1, fp.ell, tile_done, pos, chunk_pairs, grid.tile,
                    grid.ntx, grid.nty, grid.width, grid.height)
                if gid_sorted.numel() == 0:
                    continue
                chunk = gid_sorted, tile_count, tile_offset
            else:
                chunk, pos = _torch_chunk(fp, grid, chunk_pairs, tile_done, pos, first)
                if chunk is None:
                    continue
        yield chunk
        first = False


def _torch_chunk(fp: Footprints, grid: TileGrid, chunk_pairs: int, tile_done: Tensor, pos: int, first: bool):
    """The chunk starting at ``pos`` binned with torch ops: ((gid_sorted, tile_count, tile_offset) or
    None when it holds no pair, the position after it)."""
    v = fp.ids.numel()
    if first and fp.area is not None and chunk_pairs >= fp.area:
        # every pair fits and every rectangle holds a tile: the chunk is all of them, binned with the
        # sizes the footprints read (no host read here)
        return _chunk_pairs(fp, torch.arange(pos, v, device=fp.ids.device), grid, tile_done, whole=True), v
    if first:
        cnt = (fp.tx1 - fp.tx0 + 1) * (fp.ty1 - fp.ty0 + 1)
    else:
        cnt = _alive_counts(tile_done, fp, pos, grid)
    cum = torch.cumsum(cnt, 0)
    limit = torch.tensor([chunk_pairs], device=cum.device, dtype=cum.dtype)
    take = max(int(torch.searchsorted(cum, limit, right=True)), 1)
    sel = pos + torch.nonzero(cnt[:take] > 0).squeeze(1)
    if sel.numel() == 0:
        return None, pos + take
    return _chunk_pairs(fp, sel, grid, tile_done), pos + take


def _row_columns(ell: Tensor, row: Tensor, grid: TileGrid) -> tuple[Tensor, Tensor]:
    """Tile columns [c0, c1] that the ellipse d^T cov^-1 d <= qmax reaches within
    tile row ``row`` (conservative: the whole band between the row's first and last
    pixel-centre lines). c1 < c0 when it reaches none."""
    t = grid.tile
    u, v, sxx, sxy, syy, q = ell.unbind(1)
    syy = syy.clamp_min(1e-12)
    sxx = sxx.clamp_min(1e-12)
    rowf = row.to(ell.dtype)
    ey = torch.sqrt(q * syy)
    dyl = torch.maximum(rowf * t + 0.5 - v, -ey)
    dyh = torch.minimum(torch.clamp_max(rowf * t + (t - 0.5), grid.height - 0.5) - v, ey)
    empty = dyl > dyh
    dyh = torch.maximum(dyh, dyl)
    k = sxy / syy
    w2 = torch.clamp_min(sxx - sxy * k, 0.0) / syy  # det / syy^2 * syy... conditional var / syy
    d_star = sxy * torch.sqrt(q / sxx)  # dy of the rightmost point (leftmost: -d_star)

    def half(dy):
        return torch.sqrt(torch.clamp_min(q * syy - dy * dy, 0.0) * w2)

    dr = torch.minimum(torch.maximum(d_star, dyl), dyh)
    dl = torch.minimum(torch.maximum(-d_star, dyl), dyh)
    x_hi = u + k * dr + half(dr)
    x_lo = u + k * dl - half(dl)
    margin = 1e-3 + 1e-5 * (x_hi.abs() + x_lo.abs())
    big = float(grid.width + t)
    p_lo = torch.ceil((x_lo - 0.5 - margin).clamp(-big, big))
    p_hi = torch.floor((x_hi - 0.5 + margin).clamp(-big, big))
    c0 = torch.div(p_lo.clamp(0, grid.width - 1), t, rounding_mode="floor").long()
    c1 = torch.div(p_hi.clamp(0, grid.width - 1), t, rounding_mode="floor").long()
    c1 = torch.where(empty | (p_hi < 0) | (p_lo > grid.width - 1) | (p_lo > p_hi), c0 - 1, c1)
    return c0, c1


def _chunk_pairs(fp: Footprints, sel: Tensor, grid: TileGrid, tile_done: Tensor, whole: bool = False):
    """Pairs (unfinished tile, Gaussian fp.ids[sel]) sorted by (tile, depth); sel ascending.

    Pairs are enumerated per (Gaussian, tile row) over the row's unfinished tiles
    only, so finished tiles cost nothing. ``whole``: sel is every Gaussian of ``fp`` and no tile is
    finished yet (the first chunk holding them all): the sizes are the ones ``fp`` read (its
    ``rows``, and its ``area`` as room for the pairs, the unused room sorted after the last tile),
    so binning reads nothing on the host.

    Returns (gid_sorted [Pc] (with ``whole``: [fp.area], the pairs then unused room),
    tile_count [n_tiles], tile_offset [n_tiles])."""
    device = fp.ids.device
    nty, ntx = grid.nty, grid.ntx
    alive = (~tile_done).reshape(nty, ntx)
    pre = torch.zeros(nty, ntx + 1, dtype=torch.int64, device=device)
    pre[:, 1:] = alive.cumsum(1)
    row_off = torch.cumsum(pre[:, -1], 0) - pre[:, -1]
    alive_ids = torch.arange(grid.n_tiles, device=device) if whole else torch.nonzero(alive.reshape(-1)).squeeze(1)
    ids = _at(fp.ids, sel)
    tx0, tx1, ty0, ty1 = _at(fp.tx0, sel), _at(fp.tx1, sel), _at(fp.ty0, sel), _at(fp.ty1, sel)
    # (Gaussian, tile row) segments
    nrows = ty1 - ty0 + 1
    n_seg = fp.rows if whole else int(nrows.sum())
    gr = torch.repeat_interleave(torch.arange(ids.numel(), device=device), nrows, output_size=n_seg)
    row = _at(ty0 - (torch.cumsum(nrows, 0) - nrows), gr) + torch.arange(n_seg, device=device)
    flat_pre = pre.reshape(-1)
    # tighten each row's column range to the ellipse's x extent within the row
    c0, c1 = _row_columns(_at(fp.ell, _at(sel, gr)), row, grid)
    c0 = torch.maximum(c0, _at(tx0, gr))
    c1 = torch.maximum(torch.minimum(c1, _at(tx1, gr)), c0 - 1)
    a = _at(flat_pre, row * (ntx + 1) + c0)
    cnt = _at(flat_pre, row * (ntx + 1) + c1 + 1) - a
    start = _at(row_off, row) + a
    ends = torch.cumsum(cnt, 0)
    if whole:  # room for fp.area pairs: entry k is segment seg's pair, or unused once k >= the pairs
        k = torch.arange(fp.area, device=device)
        seg = torch.searchsorted(ends, k, right=True)
        unused = seg >= n_seg
        seg = seg.clamp_max(n_seg - 1)
    else:
        total = int(ends[-1])
        seg = torch.repeat_interleave(torch.arange(n_seg, device=device), cnt, output_size=total)
        k, unused = torch.arange(total, device=device), None
    # pair k of segment s lies in the s-th row's alive tile number start[s] + k - (pairs before s)
    local = _at(start - (ends - cnt), seg) + k
    if unused is None:
        tile_id = _at(alive_ids, local)
    else:  # unused room: tile id n_tiles, sorted after every tile, counted in none
        tile_id = torch.where(unused, grid.n_tiles, _at(alive_ids, torch.where(unused, 0, local)))
    # pairs are generated in depth order; a stable sort by tile keeps that order per tile
    perm = torch.sort(_sort_key(tile_id, grid.n_tiles + 1), stable=True).indices
    gid_sorted = _at(ids, _at(gr, _at(seg, perm)))
    # a scatter, not bincount: on CUDA bincount reads the largest id on the host
    tile_count = torch.zeros(grid.n_tiles + 1, dtype=torch.int64, device=device).scatter_add_(
        0, tile_id, torch.ones_like(tile_id))[: grid.n_tiles]
    tile_offset = torch.cumsum(tile_count, 0) - tile_count
    return gid_sorted, tile_count, tile_offset


class _Composite(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, depths, background, fp, grid, basis, block, chunk_pairs, kernels,
                round_kernels, absgrad):  # type: ignore[override]
        ctx.set_materialize_grads(False)
        device, dtype = means2d.device, means2d.dtype
        n = means2d.shape[0]
        f = 5  # rgb, depth, 1 (alpha)
        npx = basis.shape[1]
        n_tiles = grid.n_tiles
        # per-Gaussian table (u, v, a, b, c, log o | r, g, b, z, 1); row n: dummy with alpha 0
        logo = torch.log(opacities.detach().clamp_min(1e-30))
        table = torch.cat(
            [
                means2d.detach(),
                conics.detach(),
                logo[:, None],
                colors.detach(),
                depths.detach()[:, None],
                torch.ones(n, 1, device=device, dtype=dtype),
            ],
            dim=1,
        )
        dummy = torch.zeros(1, 6 + f, device=device, dtype=dtype)
        dummy[0, 5] = _DUMMY_LOGIT
        table = torch.cat([table, dummy], 0)
        t_idx = torch.arange(n_tiles, device=device)
        tile_centers = torch.stack(
            [(t_idx % grid.ntx) * grid.tile, (t_idx // grid.ntx) * grid.tile], dim=1
        ).to(dtype) + grid.tile / 2.0

        out = torch.zeros(n_tiles, f, npx, device=device, dtype=dtype)
        t_state = torch.ones(n_tiles, npx, device=device, dtype=dtype)  # 0 once a pixel stopped
        tile_done = torch.zeros(n_tiles, dtype=torch.bool, device=device)
        keep_rounds = any(ctx.needs_input_grad[:6])  # the backward replays the rounds
        ctx.kernels = kernels
        ctx.round_kernels = round_kernels
        ctx.absgrad = absgrad
        if kernels is not None:
            ctx.rounds = _kernel_forward(kernels, table, fp, grid, chunk_pairs, tile_centers, t_state, out,
                                         tile_done, keep_rounds)
        else:
            ctx.rounds = _round_forward(round_kernels[0], table, fp, grid, chunk_pairs, tile_centers, basis, t_state,
                                        out, tile_done, keep_rounds, block)
        img = tiles_to_image(out, grid)  # [H, W, 5]
        alpha = img[..., 4:5]
        bg = background.detach()
        rgb = img[..., 0:3] + (1.0 - alpha) * bg
        ctx.save_for_backward(table, tile_centers, basis, out, opacities.detach(), bg, alpha)
        ctx.means2d = means2d  # an input: the backward leaves absgrad on it, no reference cycle
        ctx.nf = (n, f)
        ctx.grid = grid
        return rgb, img[..., 3:4].contiguous(), alpha.contiguous()

    @staticmethod
    @once_differentiable
    def backward(ctx, g_rgb, g_depth, g_alpha):  # type: ignore[override]
        with section("compositing backward"):
            return _Composite._backward(ctx, g_rgb, g_depth, g_alpha)

    @staticmethod
    def _backward(ctx, g_rgb, g_depth, g_alpha):
        table, tile_centers, basis, out, opac, bg, alpha = ctx.saved_tensors
        n, f = ctx.nf
        grid = ctx.grid
        h, w = grid.height, grid.width
        zeros = lambda c: torch.zeros(h, w, c, device=table.device, dtype=table.dtype)  # noqa: E731
        g_rgb = zeros(3) if g_rgb is None else g_rgb
        g_depth = zeros(1) if g_depth is None else g_depth
        g_alpha = zeros(1) if g_alpha is None else g_alpha
        # rgb = C + (1 - alpha) bg  ->  dL/dalpha gets -g_rgb . bg
        g_a = g_alpha - (g_rgb * bg).sum(-1, keepdim=True)
        d_bg = (g_rgb * (1.0 - alpha)).sum((0, 1))
        g_out = image_to_tiles(torch.cat([g_rgb, g_depth, g_a], -1), grid)  # [n_tiles, F, npx]
        total = (out * g_out).sum(1)  # [n_tiles, npx]
        prefix = torch.zeros_like(total)
        absgrad = ctx.absgrad
        width = 6 + f + (2 if absgrad else 0)  # the table's columns, then |dL/du|, |dL/dv| summed over pixels
        kernels = ctx.kernels
        if kernels is not None:
            # native: one [N + 1, width] table per core the process may use (no atomics), summed; slot s
            # adds the tiles s, s + slots, ... in order, whichever thread runs it: the gradients are the
            # same bits run after run (exact resume) and for any thread count the load leaves the run.
            # Triton: one table, atomic adds.
            n_slots = available_cores() if kernels.slots is None else kernels.slots
            slots = torch.zeros(n_slots, n + 1, width, device=table.device, dtype=table.dtype)
            for active, gid_sorted, tile_offset, t_entry, n_incl in ctx.rounds:
                kernels.composite.composite_backward(table, gid_sorted, tile_offset, active, tile_centers, t_entry,
                                                     n_incl, g_out, total, prefix, slots, grid.tile)
            grads = slots.sum(0)[:n] if n_slots > 1 else slots[0, :n]
        else:
            grads = _round_backward(ctx.round_kernels[1], ctx.rounds, table, tile_centers, basis, g_out, total, prefix,
                                    n, width, absgrad)
        if absgrad:
            ctx.means2d.absgrad = grads[:, 6 + f:]
        d_opac = torch.where(opac > 0, grads[:, 5] / opac.clamp_min(1e-30), 0.0)
        return (
            grads[:, 0:2],
            grads[:, 2:5],
            d_opac,
            grads[:, 6:9],
            grads[:, 9],
            d_bg,
            None,
            None,
            None,
            None,
            None,
            None,
            None,
            None,
        )


def _round_forward(fwd_round, table, fp, grid, chunk_pairs, tile_centers, basis, t_state, out, tile_done, keep_rounds,
                   block):
    """The chunks' per-round torch kernels (``fwd_round``: eager or torch.compile'd), state updated in
    place; the rounds the backward replays: [(active tiles, Gaussian ids [nA, B], entry transmittance)]."""
    n = table.shape[0] - 1
    ar = torch.arange(block, device=table.device)
    rounds = []
    for gid_sorted, tile_count, tile_offset in _iter_chunks(fp, grid, chunk_pairs, tile_done):
        gid_pad = torch.cat([gid_sorted, gid_sorted.new_full((1,), n)])
        active = torch.nonzero(tile_count > 0).squeeze(1)
        start = tile_offset.index_select(0, active)  # next pair of each active tile's list
        end = start + tile_count.index_select(0, active)
        while active.numel() > 0:
            gid, t_carry, more = fwd_round(table, gid_pad, start, end, ar, tile_centers, active, basis,
                                           t_state, out)
            if keep_rounds:
                rounds.append((active, gid, t_carry))
            more = torch.nonzero(more).squeeze(1)
            active, start, end = _at(active, more), _at(start, more) + block, _at(end, more)
        tile_done |= ~(t_state > 0).any(1)  # read by _iter_chunks before the next chunk
    return rounds


def _round_backward(bwd_kernel, rounds, table, tile_centers, basis, g_out, total, prefix, n, width, absgrad) -> Tensor:
    """[N, width] gradients of the table rows (width 6 + F), with ``absgrad`` two more columns
    (:func:`._kernels.abs_means_grads`), the rounds replayed front to back. The absolute sums are
    taken by the eager kernel (the compiled one does not compute them)."""
    # [width, N + 1]: Gaussians along the last dim, so adding a round's rows is one strided
    # index_add per column block (5-8 % less compositing backward than [N + 1, width] on CPU)
    grads_t = torch.zeros(width, n + 1, device=table.device, dtype=table.dtype)
    bwd_round = gathering_bwd(partial(bwd_round_eager, absgrad=True)) if absgrad else bwd_kernel
    for active, gid, t_carry in rounds:
        g_rows, new_prefix = bwd_round(table, gid, tile_centers, active, basis, t_carry, g_out, total, prefix)
        prefix.index_copy_(0, active, new_prefix)
        # eager: a Gaussian's pairs in several tiles add up (compiled, that needs atomics)
        grads_t.index_add_(1, gid.reshape(-1), g_rows.reshape(-1, width).T)
    return grads_t.T[:n]


def _kernel_forward(kernels, table, fp, grid, chunk_pairs, tile_centers, t_state, out, tile_done, keep_rounds):
    """The chunks composited by ``kernels`` (:class:`.backend.Kernels`: native or Triton; binned by
    the native kernels or torch ops), state updated in place; what the backward replays: [(active
    tiles, the chunk's ids, tile offsets, entry transmittance [nA, npx], pairs each pixel included
    [nA, npx])]."""
    chunks = []
    every_tile = torch.arange(grid.n_tiles, device=table.device) if kernels.every_tile else None
    for gid_sorted, tile_count, tile_offset in _iter_chunks(fp, grid, chunk_pairs, tile_done, kernels.binning):
        active = every_tile if every_tile is not None else torch.nonzero(tile_count > 0).squeeze(1)
        t_entry = _at(t_state, active) if keep_rounds else None
        n_incl = kernels.composite.composite_forward(table, gid_sorted, tile_offset, tile_count, active,
                                                     tile_centers, t_state, out, grid.tile)
        if keep_rounds:
            chunks.append((active, gid_sorted, tile_offset, t_entry, n_incl))
        tile_done |= ~(t_state > 0).any(1)  # read by _iter_chunks before the next chunk
    return chunks


def composite(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    colors: Tensor,
    depths: Tensor,
    background: Tensor,
    fp: Footprints,
    grid: TileGrid,
    basis: Tensor,
    block: int,
    chunk_pairs: int,
    kernels=None,
    round_kernels=None,
    absgrad: bool = False,
) -> tuple[Tensor, Tensor, Tensor]:
    """(rgb [H, W, 3] with background, accumulated depth [H, W, 1], alpha [H, W, 1]).

    ``kernels``: the compositing kernels (:func:`.backend.kernels_for`: native for CPU tensors,
    Triton for CUDA ones), or None for the per-round torch kernels ``round_kernels`` ((forward,
    backward) of :func:`._kernels.get_kernels`; None: the eager ones). ``absgrad``: the backward
    also leaves ``means2d.absgrad`` (:func:`.rasterizer.rasterize`)."""
    if kernels is None and round_kernels is None:
        round_kernels = get_kernels(RenderSettings())
    return _Composite.apply(
        means2d, conics, opacities, colors, depths, background, fp, grid, basis, block, chunk_pairs, kernels,
        round_kernels, bool(absgrad),
    )


def tiles_to_image(x: Tensor, grid: TileGrid) -> Tensor:
    """[n_tiles, F, tile*tile] -> [H, W, F]."""
    t = grid.tile
    f = x.shape[1]
    img = x.reshape(grid.nty, grid.ntx, f, t, t).permute(0, 3, 1, 4, 2)
    return img.reshape(grid.nty * t, grid.ntx * t, f)[: grid.height, : grid.width]


def image_to_tiles(img: Tensor, grid: TileGrid) -> Tensor:
    """[H, W, F] -> [n_tiles, F, tile*tile] (zero padded); inverse of ``tiles_to_image``."""
    t = grid.tile
    f = img.shape[-1]
    ph, pw = grid.nty * t - grid.height, grid.ntx * t - grid.width
    if ph or pw:
        img = torch.nn.functional.pad(img, (0, 0, 0, pw, 0, ph))
    x = img.reshape(grid.nty, t, grid.ntx, t, f).permute(0, 2, 4, 1, 3)
    return x.reshape(grid.n_tiles, f, t * t)


__all__ = [
    "T_MIN",
    "ALPHA_MAX",
    "Footprints",
    "TileGrid",
    "composite",
    "image_to_tiles",
    "pixel_basis",
    "tile_footprints",
    "tiles_to_image",
]
