"""Triton compositing kernels for CUDA: the GPU counterpart of ``native/composite.cpp``.

The same rules and the same closed-form backward as the native CPU kernels and the per-round
torch kernels (alpha = min(o exp(-q/2), 0.99), alphas below 1/255 skipped, a pair included while
T (1 - alpha) >= 1e-4, pixel centres at +0.5), with the same call signatures as the native module's
``composite_forward`` / ``composite_backward``, so :mod:`._composite` drives both alike. One
program per active tile of a depth chunk, one launch per chunk and pass: the tile's pixels are
one vector, its list of pairs is walked front to back ``BATCH`` pairs at a time (an
[BATCH, pixels] block of alphas; the transmittance across the block by a cumulative product,
the backward's running sum of w h by a cumulative sum), and the walk stops once every pixel of
the tile has stopped. The backward adds each pair's gradients into one [N + 1, W] table with
atomic adds (a Gaussian appears once in a tile's list, so no two lanes of one add collide).

Where they run: CUDA tensors (Triton ships with torch's CUDA wheels; nothing to build with nvcc),
or CPU tensors under Triton's interpreter (``TRITON_INTERPRET=1``), which is how they are tested
on machines without a GPU. The kernels are compiled by Triton on first use in a process and kept
in Triton's cache (``$SPLAT_CACHE/triton`` unless ``TRITON_CACHE_DIR`` is set).

Shapes (T tiles, P = tile * tile pixels, R = 11 table columns, F = 5 features, A active tiles):
    table   [N + 1, R]  (u, v, a, b, c, log o | r, g, b, z, 1)
    gid     [Pc]        int64, the chunk's Gaussian rows sorted by (tile, depth)
    offset  [T], count [T] int64, each tile's list in gid
    active  [A]         int64, the tiles with pairs in this chunk
    centers [T, 2]      tile centres in pixels
    t_state [T, P], out [T, F, P]: updated in place by the forward
    n_incl  [A, P]      int32, pairs of the tile's list each pixel included (forward's result)
    grads   [1, N + 1, R] or [1, N + 1, R + 2] (with the absolute positional sums)
"""

from __future__ import annotations

import math
import os
import types
from functools import cache
from pathlib import Path

import torch
from torch import Tensor

try:  # the kernels' language; the kernels are made into Triton functions on first use (_jit)
    import triton.language as tl
except Exception:  # no triton, or a broken install: available() says why
    tl = None

F = 5
R = 6 + F
ALPHA_MIN = 1.0 / 255.0
LOG_ALPHA_MAX = math.log(0.99)
T_MIN = 1e-4
BATCH = 16
"""Pairs of a tile's list evaluated per step of a program (performance only)."""
NUM_WARPS = 2
"""Warps per program: 64 threads for an 8x8 tile (performance only)."""


# The kernels' helpers and the kernels are plain functions here; _jit makes them Triton functions of
# one kind (compiled or interpreted), the kernels seeing the helpers of their own kind.


def _tile_pixels(centers, t, TILE: tl.constexpr, BLOCK_P: tl.constexpr):
    """(lanes [BLOCK_P], lanes that are pixels, pixel centres x, y) of tile ``t``, row-major."""
    pix = tl.arange(0, BLOCK_P)
    half = TILE / 2.0 - 0.5
    px = tl.load(centers + 2 * t) + (pix % TILE).to(tl.float32) - half
    py = tl.load(centers + 2 * t + 1) + (pix // TILE).to(tl.float32) - half
    return pix, pix < TILE * TILE, px, py


def _tile_features(base, P, pm):
    """The five [BLOCK_P] feature planes (r, g, b, z, 1) of a tile's [F, P] block at ``base``."""
    return (tl.load(base, mask=pm, other=0.0), tl.load(base + P, mask=pm, other=0.0),
            tl.load(base + 2 * P, mask=pm, other=0.0), tl.load(base + 3 * P, mask=pm, other=0.0),
            tl.load(base + 4 * P, mask=pm, other=0.0))


def _pair_alphas(row, km, px, py, ALPHA_MIN: tl.constexpr, LMAX: tl.constexpr):
    """For the [BATCH] table rows at ``row`` (masked by ``km``: past the list, alpha 0) against the
    tile's pixels: (a, b, c [BATCH], dx, dy, log(o G), alpha [BATCH, BLOCK_P]), alpha = min(o G,
    0.99) and 0 below 1/255, the one function the forward and the backward take their alphas from."""
    u = tl.load(row, mask=km, other=0.0)
    v = tl.load(row + 1, mask=km, other=0.0)
    a = tl.load(row + 2, mask=km, other=0.0)
    b = tl.load(row + 3, mask=km, other=0.0)
    c = tl.load(row + 4, mask=km, other=0.0)
    lo = tl.load(row + 5, mask=km, other=-1.0e4)
    dx = px[None, :] - u[:, None]
    dy = py[None, :] - v[:, None]
    logit = lo[:, None] - 0.5 * (a[:, None] * dx * dx + c[:, None] * dy * dy) - b[:, None] * dx * dy
    alpha = tl.exp(tl.minimum(logit, LMAX))
    return a, b, c, dx, dy, logit, tl.where(alpha < ALPHA_MIN, 0.0, alpha)


def _forward(tab, gid, offset, count, active, centers, t_state, out, n_incl,
             TILE: tl.constexpr, BLOCK_P: tl.constexpr, BATCH: tl.constexpr,
             ALPHA_MIN: tl.constexpr, LMAX: tl.constexpr, T_MIN: tl.constexpr):
    ai = tl.program_id(0)
    t = tl.load(active + ai)
    P = TILE * TILE
    pix, pm, px, py = _tile_pixels(centers, t, TILE, BLOCK_P)
    T = tl.load(t_state + t * P + pix, mask=pm, other=0.0)
    base = out + t * 5 * P + pix
    acc0, acc1, acc2, acc3, acc4 = _tile_features(base, P, pm)
    inc = tl.zeros([BLOCK_P], dtype=tl.int32)
    start = tl.load(offset + t)
    n = tl.load(count + t)
    k = 0
    alive = tl.max(T, axis=0) > 0
    while (k < n) & alive:
        kk = k + tl.arange(0, BATCH)
        km = kk < n
        g = tl.load(gid + start + kk, mask=km, other=0)
        row = tab + g * 11
        a, b, c, dx, dy, logit, alpha = _pair_alphas(row, km, px, py, ALPHA_MIN, LMAX)
        om = 1.0 - alpha
        t_after = T[None, :] * tl.cumprod(om, axis=0)  # [BATCH, BLOCK_P]
        incl = (t_after >= T_MIN) & km[:, None]  # a prefix of the block for each pixel (t_after never grows)
        w = tl.where(incl, alpha * (t_after / om), 0.0)  # alpha T_before (om >= 0.01)
        acc0 += tl.sum(w * tl.load(row + 6, mask=km, other=0.0)[:, None], axis=0)
        acc1 += tl.sum(w * tl.load(row + 7, mask=km, other=0.0)[:, None], axis=0)
        acc2 += tl.sum(w * tl.load(row + 8, mask=km, other=0.0)[:, None], axis=0)
        acc3 += tl.sum(w * tl.load(row + 9, mask=km, other=0.0)[:, None], axis=0)
        acc4 += tl.sum(w * tl.load(row + 10, mask=km, other=0.0)[:, None], axis=0)
        n_in = tl.sum(incl.to(tl.int32), axis=0)
        inc += n_in
        # every pair of the block included: T leaves at the last (smallest) t_after; else stopped
        T = tl.where(n_in == tl.sum(km.to(tl.int32), axis=0), tl.min(t_after, axis=0), 0.0)
        k += BATCH
        alive = tl.max(T, axis=0) > 0
    tl.store(t_state + t * P + pix, T, mask=pm)
    tl.store(base, acc0, mask=pm)
    tl.store(base + P, acc1, mask=pm)
    tl.store(base + 2 * P, acc2, mask=pm)
    tl.store(base + 3 * P, acc3, mask=pm)
    tl.store(base + 4 * P, acc4, mask=pm)
    tl.store(n_incl + ai * P + pix, inc, mask=pm)


def _backward(tab, gid, offset, active, centers, t_entry, n_incl, g_out, total, prefix, grads,
              TILE: tl.constexpr, BLOCK_P: tl.constexpr, BATCH: tl.constexpr, W: tl.constexpr,
              ALPHA_MIN: tl.constexpr, LMAX: tl.constexpr):
    ai = tl.program_id(0)
    t = tl.load(active + ai)
    P = TILE * TILE
    pix, pm, px, py = _tile_pixels(centers, t, TILE, BLOCK_P)
    T = tl.load(t_entry + ai * P + pix, mask=pm, other=0.0)
    cs = tl.load(prefix + t * P + pix, mask=pm, other=0.0)
    tt = tl.load(total + t * P + pix, mask=pm, other=0.0)
    inc = tl.load(n_incl + ai * P + pix, mask=pm, other=0)
    g0, g1, g2, g3, g4 = _tile_features(g_out + t * 5 * P + pix, P, pm)
    start = tl.load(offset + t)
    n_max = tl.max(inc, axis=0)
    k = 0
    while k < n_max:
        kk = k + tl.arange(0, BATCH)
        km = kk < n_max
        g = tl.load(gid + start + kk, mask=km, other=0)
        row = tab + g * 11
        a, b, c, dx, dy, logit, alpha = _pair_alphas(row, km, px, py, ALPHA_MIN, LMAX)
        f0 = tl.load(row + 6, mask=km, other=0.0)
        f1 = tl.load(row + 7, mask=km, other=0.0)
        f2 = tl.load(row + 8, mask=km, other=0.0)
        f3 = tl.load(row + 9, mask=km, other=0.0)
        f4 = tl.load(row + 10, mask=km, other=0.0)
        om = 1.0 - alpha
        incl = kk[:, None] < inc[None, :]  # the pairs the forward included, a prefix per pixel
        t_after = T[None, :] * tl.cumprod(om, axis=0)
        tb = t_after / om
        w = tl.where(incl, alpha * tb, 0.0)
        h = (f0[:, None] * g0[None, :] + f1[:, None] * g1[None, :] + f2[:, None] * g2[None, :]
             + f3[:, None] * g3[None, :] + f4[:, None] * g4[None, :])
        wh = w * h
        csk = cs[None, :] + tl.cumsum(wh, axis=0)  # prefix through each pair
        # dL/dlogit = alpha (T h - S / (1 - alpha)), S = total - prefix through the pair
        dp = tl.where(incl & (logit < LMAX), alpha * (tb * h - (tt[None, :] - csk) / om), 0.0)
        cs += tl.sum(wh, axis=0)
        T = tl.where(tl.sum(incl.to(tl.int32), axis=0) == tl.sum(km.to(tl.int32), axis=0),
                     tl.min(t_after, axis=0), 0.0)
        du = dp * (a[:, None] * dx + b[:, None] * dy)
        dv = dp * (b[:, None] * dx + c[:, None] * dy)
        dst = grads + g * W
        tl.atomic_add(dst, tl.sum(du, axis=1), mask=km)
        tl.atomic_add(dst + 1, tl.sum(dv, axis=1), mask=km)
        tl.atomic_add(dst + 2, -0.5 * tl.sum(dp * dx * dx, axis=1), mask=km)
        tl.atomic_add(dst + 3, -tl.sum(dp * dx * dy, axis=1), mask=km)
        tl.atomic_add(dst + 4, -0.5 * tl.sum(dp * dy * dy, axis=1), mask=km)
        tl.atomic_add(dst + 5, tl.sum(dp, axis=1), mask=km)
        tl.atomic_add(dst + 6, tl.sum(w * g0[None, :], axis=1), mask=km)
        tl.atomic_add(dst + 7, tl.sum(w * g1[None, :], axis=1), mask=km)
        tl.atomic_add(dst + 8, tl.sum(w * g2[None, :], axis=1), mask=km)
        tl.atomic_add(dst + 9, tl.sum(w * g3[None, :], axis=1), mask=km)
        tl.atomic_add(dst + 10, tl.sum(w * g4[None, :], axis=1), mask=km)
        if W == 13:  # AbsGS: per-pixel |dL/du|, |dL/dv| summed
            tl.atomic_add(dst + 11, tl.sum(tl.abs(du), axis=1), mask=km)
            tl.atomic_add(dst + 12, tl.sum(tl.abs(dv), axis=1), mask=km)
        k += BATCH
    tl.store(prefix + t * P + pix, cs, mask=pm)


def available() -> str | None:
    """None when Triton imports, else why not (one line)."""
    try:
        import triton  # noqa: F401
        import triton.language  # noqa: F401
    except Exception as exc:  # ImportError, or a broken install
        return f"triton cannot be imported ({type(exc).__name__}: {str(exc).strip().splitlines()[0][:120] if str(exc).strip() else ''})"
    return None


def interpreting() -> bool:
    """Whether Triton's interpreter runs the kernels (``TRITON_INTERPRET=1``): on CPU tensors. The
    variable must be set before triton is first imported in the process: triton.language's own
    functions (``tl.sum``, ``tl.cumprod``, ...) are made for the interpreter or the compiler then."""
    return os.environ.get("TRITON_INTERPRET", "").strip().lower() in ("1", "true", "yes", "on")


def language_interpreted() -> bool:
    """Whether triton.language was imported for the interpreter (TRITON_INTERPRET=1 at its import)."""
    from triton.runtime.interpreter import InterpretedFunction

    return isinstance(tl.sum, InterpretedFunction)


def jit_functions(interpret: bool | None = None) -> dict:
    """``{"forward": ..., "backward": ...}``: the kernels as Triton functions, compiled for the GPU
    (``JITFunction``) or run by the interpreter (``interpret``, default :func:`interpreting`)."""
    return _jit(interpreting() if interpret is None else bool(interpret))


@cache
def _jit(interpret: bool) -> dict:
    from triton.runtime.interpreter import InterpretedFunction
    from triton.runtime.jit import JITFunction

    kind = InterpretedFunction if interpret else JITFunction
    helpers = {name: kind(fn) for name, fn in
               (("_tile_pixels", _tile_pixels), ("_tile_features", _tile_features), ("_pair_alphas", _pair_alphas))}

    def made(fn):  # fn with the module's globals but the helpers of this kind
        scope = dict(fn.__globals__, **helpers)
        return kind(types.FunctionType(fn.__code__, scope, fn.__name__, fn.__defaults__, fn.__closure__))

    return {"forward": made(_forward), "backward": made(_backward)}


def _cache_dir(root: Path | None) -> None:
    """Triton's compiled kernels under ``root/triton`` (the render settings' cache folder) unless
    TRITON_CACHE_DIR names a folder."""
    if os.environ.get("TRITON_CACHE_DIR"):
        return
    if root is not None:
        os.environ["TRITON_CACHE_DIR"] = str(Path(root) / "triton")


def _block_p(tile: int) -> int:
    return 1 << max(0, (tile * tile - 1).bit_length())


def _consts(tile: int) -> dict:
    return {"TILE": tile, "BLOCK_P": _block_p(tile), "BATCH": BATCH, "ALPHA_MIN": ALPHA_MIN, "LMAX": LOG_ALPHA_MAX}


class TritonKernels:
    """``composite_forward`` / ``composite_backward`` with the native module's signatures."""

    name = "triton"

    def __init__(self, cache_dir: Path | None = None, interpret: bool | None = None):
        self.interpret = interpreting() if interpret is None else interpret
        if not self.interpret:
            _cache_dir(cache_dir)
        self.fns = jit_functions(self.interpret)

    def _check(self, table: Tensor) -> None:
        if table.device.type == "cpu" and not self.interpret:
            raise RuntimeError("the Triton rasterizer runs CUDA tensors (CPU tensors only under TRITON_INTERPRET=1)")
        if table.dtype not in (torch.float32, torch.float64) or table.dim() != 2 or table.shape[1] != R:
            raise RuntimeError(f"the Triton rasterizer takes a float32 or float64 [N + 1, {R}] table, got "
                               f"{table.dtype} {tuple(table.shape)}")

    def composite_forward(self, table: Tensor, gid: Tensor, offset: Tensor, count: Tensor, active: Tensor,
                          centers: Tensor, t_state: Tensor, out: Tensor, tile: int) -> Tensor:
        """(t_state, out updated in place) -> n_incl [A, P] int32."""
        self._check(table)
        n_incl = torch.zeros(active.shape[0], tile * tile, dtype=torch.int32, device=table.device)
        if active.shape[0]:
            self.fns["forward"][(active.shape[0],)](
                table.contiguous(), gid.contiguous(), offset.contiguous(), count.contiguous(), active.contiguous(),
                centers.contiguous(), t_state, out, n_incl, T_MIN=T_MIN, num_warps=NUM_WARPS, **_consts(tile))
        return n_incl

    def composite_backward(self, table: Tensor, gid: Tensor, offset: Tensor, active: Tensor, centers: Tensor,
                           t_entry: Tensor, n_incl: Tensor, g_out: Tensor, total: Tensor, prefix: Tensor,
                           grads: Tensor, tile: int) -> None:
        """(prefix [T, P] and grads [1, N + 1, W] updated in place; W = 11, or 13 with the absolute sums)."""
        self._check(table)
        if active.shape[0]:
            self.fns["backward"][(active.shape[0],)](
                table.contiguous(), gid.contiguous(), offset.contiguous(), active.contiguous(), centers.contiguous(),
                t_entry.contiguous(), n_incl.contiguous(), g_out.contiguous(), total.contiguous(), prefix, grads,
                W=grads.shape[2], num_warps=NUM_WARPS, **_consts(tile))


def compile_for(capability: int, tile: int = 8) -> dict:
    """Every kernel compiled ahead of time for an NVIDIA GPU of compute ``capability`` (80: Ampere,
    90: Hopper) without one: ``{name: compiled kernel}`` (its ``asm`` holds the PTX and cubin).
    Raises what Triton raises when a kernel does not compile for that target; RuntimeError in a
    process whose triton was imported for the interpreter (TRITON_INTERPRET=1)."""
    import triton
    from triton.backends.compiler import GPUTarget
    from triton.compiler import ASTSource

    if language_interpreted():
        raise RuntimeError("compile_for needs a process without TRITON_INTERPRET=1 (triton was imported for the "
                           "interpreter)")
    fns = jit_functions(False)
    consts = _consts(tile)
    pointers = {
        "forward": {"tab": "*fp32", "gid": "*i64", "offset": "*i64", "count": "*i64", "active": "*i64",
                    "centers": "*fp32", "t_state": "*fp32", "out": "*fp32", "n_incl": "*i32"},
        "backward": {"tab": "*fp32", "gid": "*i64", "offset": "*i64", "active": "*i64", "centers": "*fp32",
                     "t_entry": "*fp32", "n_incl": "*i32", "g_out": "*fp32", "total": "*fp32", "prefix": "*fp32",
                     "grads": "*fp32"},
    }
    variants = {"forward": [dict(consts, T_MIN=T_MIN)],
                "backward": [dict(consts, W=R), dict(consts, W=R + 2)]}
    built = {}
    for name, sigs in pointers.items():
        for k, constexprs in enumerate(variants[name]):
            signature = dict(sigs, **{c: "constexpr" for c in constexprs})
            src = ASTSource(fn=fns[name], signature=signature, constexprs=constexprs)
            built[f"{name}{k}"] = triton.compile(src, target=GPUTarget("cuda", capability, 32),
                                                 options={"num_warps": NUM_WARPS})
    return built


__all__ = ["BATCH", "NUM_WARPS", "TritonKernels", "available", "compile_for", "interpreting", "jit_functions"]
