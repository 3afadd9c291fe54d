"""Per-round compositing kernels (forward and hand-derived backward).

One *round* is a dense block of ``B`` (tile, Gaussian) pairs for each of ``nA``
active tiles, evaluated against the tile's ``npx`` pixels. The functions here
are pure tensor code: eager, or their pixel-major twins compiled with
``torch.compile`` (``RenderSettings.compile``, the default for training runs),
which fuse a whole round into one loop. Any failure
to compile falls back to eager with a one-line warning.

Shapes:
    rows:    [nA, B, 6 + F] per-pair Gaussian data (u, v, a, b, c, log o | features)
    tc:      [nA, 2] tile centres in pixels
    basis:   [6, npx] quadratic pixel basis (1, lx, ly, lx^2, ly^2, lx*ly)
    t_carry: [nA, npx] transmittance entering the round (0 = pixel terminated)
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import torch
from torch import Tensor

from ..console import phase
from .precompiled import Precompiled
from .settings import RenderSettings

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
_LOG_ALPHA_MAX = math.log(ALPHA_MAX)


def coefficients(gp: Tensor, tc: Tensor) -> Tensor:
    """[nA, B, 6] coefficients of log(o G) on the pixel basis.

    gp: [nA, B, 6] (u, v, a, b, c, log o) with q = a dx^2 + 2 b dx dy + c dy^2."""
    dx = tc[:, None, 0] - gp[..., 0]
    dy = tc[:, None, 1] - gp[..., 1]
    a, b, c = gp[..., 2], gp[..., 3], gp[..., 4]
    bdy = b * dy
    c0 = -0.5 * (a * dx * dx + 2.0 * bdy * dx + c * dy * dy) + gp[..., 5]
    c1 = -(a * dx + bdy)
    c2 = -(b * dx + c * dy)
    return torch.stack([c0, c1, c2, -0.5 * a, -0.5 * c, -b], dim=-1)


def coefficients_backward(gp: Tensor, tc: Tensor, coef: Tensor, gc: Tensor) -> Tensor:
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


def _alpha_logits(coef: Tensor, basis: Tensor) -> Tensor:
    na, b, _ = coef.shape
    return torch.mm(coef.reshape(na * b, 6), basis).reshape(na, b, -1)


# --------------------------------------------------------------------------- eager
# In-place, few passes over the [nA, B, npx] blocks; used when not compiling.

_THRESH: dict[torch.dtype, float] = {}


def _alpha_threshold(dtype: torch.dtype) -> float:
    """Largest value below 1/255 in ``dtype``: threshold_(x, t, 0) keeps x >= 1/255."""
    if dtype not in _THRESH:
        a = torch.tensor(ALPHA_MIN, dtype=dtype)
        _THRESH[dtype] = float(torch.nextafter(a, torch.tensor(0.0, dtype=dtype)))
    return _THRESH[dtype]


def _alpha_eager(logits: Tensor) -> Tensor:
    alpha = logits.exp_().clamp_(max=ALPHA_MAX)
    return torch.nn.functional.threshold_(alpha, _alpha_threshold(alpha.dtype), 0.0)


def _transmittance_eager(alpha: Tensor, t_carry: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    om = torch.rsub(alpha, 1.0)
    t_after = torch.cumprod(om, 1).mul_(t_carry[:, None, :])
    t_before = torch.cat([t_carry[:, None, :], t_after[:, :-1]], 1)
    return om, t_after, t_before


def fwd_round(rows: Tensor, tc: Tensor, basis: Tensor, t_carry: Tensor) -> tuple[Tensor, Tensor]:
    """Returns (contribution [nA, F, npx] = sum_b w f, transmittance leaving the round
    [nA, npx] with 0 for pixels that terminated)."""
    alpha = _alpha_eager(_alpha_logits(coefficients(rows[..., :6], tc), basis))
    om, t_after, t_before = _transmittance_eager(alpha, t_carry)
    w = alpha.mul_(t_before).masked_fill_(t_after < T_MIN, 0.0)
    contrib = torch.bmm(rows[..., 6:].transpose(1, 2), w)
    t_last = t_after[:, -1, :]
    return contrib, t_last.masked_fill_(t_last < T_MIN, 0.0)


def bwd_round(
    rows: Tensor,
    tc: Tensor,
    basis: Tensor,
    t_carry: Tensor,
    g_t: Tensor,
    total: Tensor,
    prefix: Tensor,
    absgrad: bool = False,
) -> tuple[Tensor, Tensor]:
    """Backward of one round.

    g_t: [nA, F, npx] output gradient; total: [nA, npx] sum_j w_j (f_j . g) over
    the whole pixel list; prefix: [nA, npx] the same sum over earlier rounds.

    Returns (grads [nA, B, 6 + F] w.r.t. rows, new prefix [nA, npx]); with ``absgrad``
    the grads have two more columns: :func:`abs_means_grads`.

    With h_i = f_i . g and S_i = sum_{j>i} w_j h_j = total - prefix_i:
    dL/dlogit_i = alpha_i dL/dalpha_i = alpha_i (T_i h_i - S_i / (1 - alpha_i)),
    zero where the pair is excluded (terminated) or alpha is clamped at 0.99.
    """
    gp = rows[..., :6]
    coef = coefficients(gp, tc)
    logits = _alpha_logits(coef, basis)
    dead = logits >= _LOG_ALPHA_MAX  # clamped: no gradient through alpha
    alpha = _alpha_eager(logits)
    om, t_after, t_before = _transmittance_eager(alpha, t_carry)
    excluded = t_after < T_MIN  # early termination
    w = (alpha * t_before).masked_fill_(excluded, 0.0)
    dead |= excluded
    h = torch.bmm(rows[..., 6:], g_t)  # [nA, B, npx]
    cs = torch.cumsum(w * h, 1).add_(prefix[:, None, :])
    s = torch.sub(total[:, None, :], cs).div_(om)
    dp = t_before.mul_(h).sub_(s).mul_(alpha).masked_fill_(dead, 0.0)
    na, b, npx = dp.shape
    gc = torch.mm(dp.reshape(na * b, npx), basis.T).reshape(na, b, 6)
    g_feat = torch.bmm(g_t, w.transpose(1, 2)).transpose(1, 2)  # [nA, B, F]
    g_rows = torch.cat([coefficients_backward(gp, tc, coef, gc), g_feat], dim=-1)
    if absgrad:
        g_rows = torch.cat([g_rows, abs_means_grads(dp, gp, tc, basis)], dim=-1)
    return g_rows, cs[:, -1, :]


def abs_means_grads(dp: Tensor, gp: Tensor, tc: Tensor, basis: Tensor) -> Tensor:
    """[nA, B, 2] sums over the tile's pixels of |dL/du| and |dL/dv| of each pixel (AbsGS's
    densification criterion), from dp [nA, B, npx] = dL/dlogit per pixel and gp [nA, B, 6]."""
    dx = (tc[:, None, 0] - gp[..., 0])[..., None] + basis[1]  # pixel centre - u: [nA, B, npx]
    dy = (tc[:, None, 1] - gp[..., 1])[..., None] + basis[2]
    a, b, c = gp[..., 2, None], gp[..., 3, None], gp[..., 4, None]
    return torch.stack([(dp * (a * dx + b * dy)).abs().sum(-1), (dp * (b * dx + c * dy)).abs().sum(-1)], dim=-1)


# --------------------------------------------------------------------------- fused
# Pixel-major versions for torch.compile: the round's B pairs are unrolled (B is
# static) and each step works on [nA, npx] arrays, so inductor fuses the whole
# round into one loop over (tile, pixel) that keeps alpha, T and the running sums
# in registers instead of writing [nA, B, npx] intermediates between a dozen eager
# kernels. Same math as the eager functions above (equal to float rounding).


def _logit_px(coef: Tensor, basis: Tensor, b: int) -> Tensor:
    """[nA, npx] log(o G) of pair ``b`` at the tile's pixels (coef [nA, B, 6])."""
    c = coef[:, b, :]
    return (
        c[:, 0:1]
        + c[:, 1:2] * basis[1]
        + c[:, 2:3] * basis[2]
        + c[:, 3:4] * basis[3]
        + c[:, 4:5] * basis[4]
        + c[:, 5:6] * basis[5]
    )


def _alpha_fused(logit: Tensor) -> Tensor:
    alpha = torch.exp(torch.clamp(logit, max=_LOG_ALPHA_MAX))
    return torch.where(alpha < ALPHA_MIN, 0.0, alpha)


def fwd_round_fused(rows: Tensor, tc: Tensor, basis: Tensor, t_carry: Tensor) -> tuple[Tensor, Tensor]:
    coef = coefficients(rows[..., :6], tc)
    feat = rows[..., 6:]
    t = t_carry
    contrib = t_carry.new_zeros(t_carry.shape[0], feat.shape[2], t_carry.shape[1])
    for b in range(rows.shape[1]):
        alpha = _alpha_fused(_logit_px(coef, basis, b))
        t_after = t * (1.0 - alpha)
        w = torch.where(t_after >= T_MIN, alpha * t, 0.0)
        contrib = contrib + feat[:, b, :, None] * w[:, None, :]
        t = t_after
    return contrib, torch.where(t >= T_MIN, t, 0.0)


def bwd_round_fused(
    rows: Tensor,
    tc: Tensor,
    basis: Tensor,
    t_carry: Tensor,
    g_t: Tensor,
    total: Tensor,
    prefix: Tensor,
) -> tuple[Tensor, Tensor]:
    gp = rows[..., :6]
    coef = coefficients(gp, tc)
    feat = rows[..., 6:]
    t = t_carry
    cs = prefix
    dps, ws = [], []
    for b in range(rows.shape[1]):
        logit = _logit_px(coef, basis, b)
        alpha = _alpha_fused(logit)
        om = 1.0 - alpha
        t_after = t * om
        incl = t_after >= T_MIN
        w = torch.where(incl, alpha * t, 0.0)
        h = (feat[:, b, :, None] * g_t).sum(1)
        cs = cs + w * h
        dps.append(torch.where(incl & (logit < _LOG_ALPHA_MAX), alpha * (t * h - (total - cs) / om), 0.0))
        ws.append(w)
        t = t_after
    # the reductions over pixels as two small GEMMs (one fused loop would keep
    # a dozen [nA, npx] temporaries per pair alive)
    dp = torch.stack(dps, 1)
    w = torch.stack(ws, 1)
    na, b, npx = dp.shape
    gc = torch.mm(dp.reshape(na * b, npx), basis.T).reshape(na, b, 6)
    g_feat = torch.bmm(g_t, w.transpose(1, 2)).transpose(1, 2)
    g_rows = torch.cat([coefficients_backward(gp, tc, coef, gc), g_feat], dim=-1)
    return g_rows, cs


# --------------------------------------------------------------------------- gathers
# What the compositing loop calls: a round's inputs gathered from the per-Gaussian table and
# the per-tile state, then the kernel. Compiled, the gathers become indirect loads inside the
# fused loop instead of separate index_select passes.


def gathering_fwd(round_fn):
    """One forward round with its bookkeeping, state updated in place.

    (table [N+1, 6+F], gid_pad [Pc+1] the chunk's Gaussian ids in (tile, depth) order then the
    dummy row's id, start/end [nA] each active tile's next and end position in gid_pad,
    ar [B] = arange(B), tile_centers [T, 2], active [nA], basis, t_state [T, npx], out [T, F, npx])
    -> (gid [nA, B] padded with the dummy, transmittance entering [nA, npx],
    more [nA] bool: the tile has pairs left and unterminated pixels).
    ``out`` gains the round's contribution and ``t_state`` the transmittance leaving it."""

    def run(table: Tensor, gid_pad: Tensor, start: Tensor, end: Tensor, ar: Tensor, tile_centers: Tensor,
            active: Tensor, basis: Tensor, t_state: Tensor, out: Tensor):
        idx = start[:, None] + ar
        gid = gid_pad[torch.where(idx < end[:, None], idx, gid_pad.shape[0] - 1)]
        t_carry = t_state[active]
        contrib, t_new = round_fn(table[gid], tile_centers[active], basis, t_carry)
        out[active] = out[active] + contrib  # active tiles are distinct: a plain store, no atomics
        t_state[active] = t_new
        more = (start + ar.shape[0] < end) & (t_new > 0).any(1)
        return gid, t_carry, more

    return run


def gathering_bwd(round_fn):
    """(table, gid [nA, B], tile_centers, active [nA], basis, t_carry [nA, npx], g_out [T, F, npx],
    total [T, npx], prefix [T, npx]) -> (grads [nA, B, 6+F] of the gathered rows, new prefix [nA, npx])."""

    def run(table: Tensor, gid: Tensor, tile_centers: Tensor, active: Tensor, basis: Tensor, t_carry: Tensor,
            g_out: Tensor, total: Tensor, prefix: Tensor):
        return round_fn(table[gid], tile_centers[active], basis, t_carry, g_out[active], total[active], prefix[active])

    return run


_KERNELS: dict[Path | None, tuple] = {}
"""The compiled round kernels per cache folder (built once per process)."""


def _fwd_static(args: tuple) -> tuple:
    """The sizes a compiled forward round is specialised on: pairs per round, pixels per tile, features."""
    return args[4].shape[0], args[7].shape[1], args[9].shape[1]


def _bwd_static(args: tuple) -> tuple:
    """The same for a backward round (gid [nA, B], basis [6, npx], g_out [T, F, npx])."""
    return args[1].shape[1], args[4].shape[1], args[6].shape[1]


def _compiled(name: str, fn, static, which: str, folder: Path | None):
    """``fn`` compiled: loaded from (or saved to) the cache folder when there is one and this torch
    can save compiled graphs, else traced in this process by ``torch.compile`` (torch 2.11, say,
    has no ``aot_compile`` on a compiled function: each process then compiles, without a warning)."""
    traced = torch.compile(fn, dynamic=True)
    if folder is None or not hasattr(traced, "aot_compile"):
        return traced
    return Precompiled(name, fn, static, Path(folder) / "precompiled", traced, which)


def use_inductor_cache(settings: RenderSettings) -> None:
    """Inductor's generated code under ``settings.cache_dir/inductor`` while kernels are compiled
    (``TORCHINDUCTOR_CACHE_DIR``, left alone when the user set it)."""
    if settings.compile and settings.cache_dir is not None:
        os.environ.setdefault("TORCHINDUCTOR_CACHE_DIR", str(Path(settings.cache_dir) / "inductor"))


def get_kernels(settings: RenderSettings):
    """(fwd_round, bwd_round): compiled with ``settings.compile``, else eager. The compiled ones
    keep their graphs under ``settings.cache_dir/precompiled`` and inductor's generated code under
    ``settings.cache_dir/inductor`` (:func:`use_inductor_cache`), so a later run loads them in seconds instead of tracing and compiling again."""
    eager = (gathering_fwd(fwd_round), gathering_bwd(bwd_round))
    if not settings.compile:
        return eager
    folder = settings.cache_dir
    if folder not in _KERNELS:
        use_inductor_cache(settings)
        try:
            _KERNELS[folder] = (
                _with_fallback(_compiled("fwd", gathering_fwd(fwd_round_fused), _fwd_static, "forward", folder),
                               eager[0], 6, "forward"),
                _with_fallback(_compiled("bwd", gathering_bwd(bwd_round_fused), _bwd_static, "backward", folder),
                               eager[1], 3, "backward"),
            )
        except Exception as exc:  # pragma: no cover - depends on the toolchain
            warnings.warn(f"compiling the rasterizer kernels: torch.compile unavailable ({exc}); using eager")
            _KERNELS[folder] = eager
    return _KERNELS[folder]



def _with_fallback(compiled, eager, active_arg: int, which: str):
    """The round kernels' :func:`with_fallback`: eager for single-tile rounds (a size-1 dimension
    would make torch.compile specialise and compile again); ``args[active_arg]`` is the round's
    [nA] active tiles, ``which`` the kernel (forward, backward)."""
    return with_fallback(compiled, eager, f"the rasterizer kernels ({which})",
                         eligible=lambda args: args[active_arg].shape[0] > 1,
                         compiled_once=isinstance(compiled, Precompiled))


def compiled_or_eager(fn, what: str, context=None, **compile_kwargs):
    """``fn`` compiled by ``torch.compile(fn, **compile_kwargs)`` behind :func:`with_fallback`
    (eager after any failure, one warning line), each call inside ``context()`` when given; ``fn``
    itself where this torch or Python has no torch.compile. Callers hold the result in a
    ``functools.cache`` so a process compiles once."""
    try:
        compiled = torch.compile(fn, **compile_kwargs)
    except Exception:  # pragma: no cover - depends on the torch build and Python version
        return fn
    if context is not None:
        inner = compiled

        def compiled(*args):
            with context():
                return inner(*args)

    return with_fallback(compiled, fn, what)


def with_fallback(compiled, eager, what: str, eligible=None, compiled_once: bool = False):
    """``compiled``, or ``eager`` after any failure (one warning line) and for the calls that
    ``eligible(args)`` turns away. The first compiled call (the compilation, or loading it from
    inductor's cache) runs as a phase of its own, "compiling ``what`` for this process", unless
    ``compiled_once`` (a :class:`Precompiled` kernel names its own phases: loading, or compiling
    once per machine)."""
    state = {"ok": True, "compiled_once": compiled_once}

    def run(*args):
        if state["ok"] and (eligible is None or eligible(args)):
            try:
                if not state["compiled_once"]:
                    with phase(f"compiling {what} for this process"):
                        out = compiled(*args)
                    state["compiled_once"] = True
                    return out
                return compiled(*args)
            except Exception as exc:  # pragma: no cover - depends on the toolchain
                state["ok"] = False
                first = (str(exc).strip().splitlines() or [""])[0][:200]
                warnings.warn(f"could not compile {what} ({type(exc).__name__}: {first}); using eager")
        return eager(*args)

    return run
