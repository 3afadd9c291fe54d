"""Parameter + optimizer surgery for densification (after gsplat ``strategy/ops.py``).

Every operation here goes through ONE helper, ``_update_param_with_optimizer``,
which replaces each parameter and moves its Adam state along with it. The
per-row operations are:

- ``duplicate``: append copies of the masked rows (3DGS "clone").
- ``split``: the masked row stays in place and becomes the first child (new
  sampled mean, scales / 1.6); the second child is appended.
- ``remove``: drop the masked rows.
- ``append``: add new rows with given values (a strategy that grows something other
  than copies of existing rows, e.g. Scaffold-GS's anchors on a voxel grid).
- ``rewrite``: overwrite rows in place with given values and restart their optimizer
  state, as for a new Gaussian (gsplat's ``relocate``: MCMC moves dead Gaussians onto
  live ones; with ``append``, its ``sample_add`` too).
- ``reset_opa``: clamp opacities to at most ``value`` and zero their moments.
- ``decay_opa``: multiply every opacity by a factor, moments kept (no surgery).

Conventions:

- ``params`` is a ``torch.nn.ParameterDict`` or a plain dict of tensors, every
  entry with leading dim N. Entries without an optimizer must not require grad
  (e.g. a float flag ``"is_ray"``); they are resized like the others.
- ``optimizers`` maps a key of ``params`` to an optimizer (Adam) with a single
  param group holding exactly that parameter.
- ``state`` is the strategy's dict; every tensor in it with leading dim N
  (grad2d, count, radii) is resized along. Other entries are left alone.
- Adam moments (every optimizer-state tensor shaped like the parameter) of new
  rows are zero; moments of removed rows are dropped; ``step`` is kept.
- ``child_values`` (``duplicate``/``split``): ``{key: value}`` written into the
  appended rows of ``params[key]`` only, e.g. ``{"is_ray": 0.0}``.
- ``remove`` and ``append`` return a :class:`RowChange`: what a model hook that resized the
  rows outside the strategy returns, so that the strategy resizes its own state
  (``Strategy.rows_changed``); such a hook passes an empty ``state`` (``{}``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Mapping, MutableMapping

import torch
from torch import Tensor

from ..render import quat_to_rotmat  # one definition, shared with the rasterizer

Params = MutableMapping[str, Tensor]
Optimizers = Mapping[str, torch.optim.Optimizer]


def _rewrap(old: Tensor, new: Tensor) -> Tensor:
    if isinstance(old, torch.nn.Parameter):
        return torch.nn.Parameter(new, requires_grad=old.requires_grad)
    return new


@torch.no_grad()
def _update_param_with_optimizer(
    param_fn: Callable[[str, Tensor], Tensor],
    optimizer_fn: Callable[[str, Tensor], Tensor],
    params: Params,
    optimizers: Optimizers,
    names: list[str] | None = None,
) -> None:
    """Replace ``params[name]`` by ``param_fn(name, p)`` and remap its optimizer state.

    ``param_fn`` returns the new tensor data (wrapped here as a Parameter with the
    old ``requires_grad`` when the old entry was one). ``optimizer_fn(key, v)``
    maps each optimizer-state tensor shaped like the old parameter (``exp_avg``,
    ``exp_avg_sq``, ...) to the new one; scalar state such as ``step`` is kept.
    """
    names = list(params.keys()) if names is None else names
    for name in names:
        old = params[name]
        new = _rewrap(old, param_fn(name, old))
        params[name] = new
        opt = optimizers.get(name)
        if opt is None:
            if old.requires_grad:
                raise ValueError(f"params[{name!r}] requires grad but has no optimizer")
            continue
        if len(opt.param_groups) != 1 or len(opt.param_groups[0]["params"]) != 1:
            raise ValueError(f"optimizer {name!r} must hold exactly one param group with one parameter")
        if opt.param_groups[0]["params"][0] is not old:
            raise ValueError(f"optimizer {name!r} does not hold params[{name!r}]")
        pstate = opt.state.pop(old, None)
        opt.param_groups[0]["params"] = [new]
        if pstate is not None:
            for key, v in list(pstate.items()):
                if isinstance(v, Tensor) and v.shape == old.shape:
                    pstate[key] = optimizer_fn(key, v)
            opt.state[new] = pstate


def _resize_state(state: MutableMapping, n_old: int, fn: Callable[[Tensor], Tensor]) -> None:
    for k, v in state.items():
        if isinstance(v, Tensor) and v.dim() > 0 and v.shape[0] == n_old:
            state[k] = fn(v)


@dataclass(frozen=True)
class RowChange:
    """How the rows changed: the old rows where ``kept`` [N_old] (bool) is True stay, in order,
    then ``added`` new rows follow (``N_new = kept.sum() + added``)."""

    kept: Tensor
    added: int = 0

    @property
    def old_rows(self) -> int:
        return int(self.kept.shape[0])

    @property
    def new_rows(self) -> int:
        return int(self.kept.sum()) + self.added

    def resize(self, state: MutableMapping) -> None:
        """Resize, in place, every tensor of ``state`` with one row per old row (leading dim
        ``old_rows``): its kept rows, then ``added`` rows of zeros."""
        keep = torch.where(self.kept)[0]
        m = self.added

        def fn(v: Tensor) -> Tensor:
            v = v[keep]
            return torch.cat([v, v.new_zeros((m, *v.shape[1:]))]) if m else v

        _resize_state(state, self.old_rows, fn)


def _num_rows(params: Params) -> int:
    return next(iter(params.values())).shape[0]


def _apply_child_values(name: str, rows: Tensor, child_values: Mapping[str, float] | None) -> Tensor:
    if child_values and name in child_values:
        return torch.full_like(rows, float(child_values[name]))
    return rows


@torch.no_grad()
def duplicate(
    params: Params,
    optimizers: Optimizers,
    state: MutableMapping,
    mask: Tensor,
    child_values: Mapping[str, float] | None = None,
) -> None:
    """Append a copy of every row where ``mask`` [N] is True (new moments zero)."""
    sel = torch.where(mask)[0]
    n = _num_rows(params)

    def param_fn(name: str, p: Tensor) -> Tensor:
        return torch.cat([p, _apply_child_values(name, p[sel], child_values)])

    def optimizer_fn(key: str, v: Tensor) -> Tensor:
        return torch.cat([v, v.new_zeros((len(sel), *v.shape[1:]))])

    _update_param_with_optimizer(param_fn, optimizer_fn, params, optimizers)
    _resize_state(state, n, lambda v: torch.cat([v, v[sel]]))


@torch.no_grad()
def split(
    params: Params,
    optimizers: Optimizers,
    state: MutableMapping,
    mask: Tensor,
    revised_opacity: bool = False,
    child_values: Mapping[str, float] | None = None,
    generator: torch.Generator | None = None,
) -> None:
    """Split every row where ``mask`` [N] is True into two children.

    As in 3DGS, each child's mean is sampled from N(mean, R diag(s)^2 R^T) and
    its scales are the parent's / 1.6 (opacity kept, or 1 - sqrt(1 - o) with
    ``revised_opacity``). Unlike 3DGS the parent row is not removed: it is
    overwritten in place with the first child, so any identity it carries in
    other keys is kept; the second child is appended (and gets
    ``child_values``). The Adam moments of both children are zero. State rows
    are copied to the appended child.
    """
    sel = torch.where(mask)[0]
    n = _num_rows(params)
    scales = torch.exp(params["scales"][sel])
    rotmats = quat_to_rotmat(params["quats"][sel])
    noise = torch.randn(
        (2, len(sel), 3), generator=generator, device=scales.device, dtype=scales.dtype
    )
    samples = torch.einsum("nij,nj,bnj->bni", rotmats, scales, noise)  # [2, M, 3]

    def param_fn(name: str, p: Tensor) -> Tensor:
        if name == "means":
            first, second = p[sel] + samples[0], p[sel] + samples[1]
        elif name == "scales":
            first = second = torch.log(scales / 1.6).to(p.dtype)
        elif name == "opacities" and revised_opacity:
            first = second = torch.logit(1.0 - torch.sqrt(1.0 - torch.sigmoid(p[sel])))
        else:
            first, second = p[sel], p[sel]
        out = p.clone()
        out[sel] = first
        return torch.cat([out, _apply_child_values(name, second, child_values)])

    def optimizer_fn(key: str, v: Tensor) -> Tensor:
        out = v.clone()
        out[sel] = 0
        return torch.cat([out, v.new_zeros((len(sel), *v.shape[1:]))])

    _update_param_with_optimizer(param_fn, optimizer_fn, params, optimizers)
    _resize_state(state, n, lambda v: torch.cat([v, v[sel]]))


@torch.no_grad()
def append(params: Params, optimizers: Optimizers, state: MutableMapping, rows: Mapping[str, Tensor]) -> RowChange:
    """Append new rows: ``rows[key]`` [M, ...] for every key of ``params`` (new moments zero,
    per-row state tensors padded with zeros); the change."""
    missing = set(params) - set(rows)
    if missing:
        raise ValueError(f"append: no new rows for {sorted(missing)}")
    n = _num_rows(params)
    m = {v.shape[0] for v in rows.values()}
    if len(m) != 1:
        raise ValueError(f"append: new rows of different counts {sorted(m)}")
    m = m.pop()

    def param_fn(name: str, p: Tensor) -> Tensor:
        return torch.cat([p, rows[name].to(p.device, p.dtype)])

    def optimizer_fn(key: str, v: Tensor) -> Tensor:
        return torch.cat([v, v.new_zeros((m, *v.shape[1:]))])

    _update_param_with_optimizer(param_fn, optimizer_fn, params, optimizers)
    change = RowChange(torch.ones(n, dtype=torch.bool, device=next(iter(params.values())).device), m)
    change.resize(state)
    return change


@torch.no_grad()
def rewrite(
    params: Params, optimizers: Optimizers, state: MutableMapping, rows: Tensor, values: Mapping[str, Tensor]
) -> None:
    """Overwrite rows ``rows`` [M] (int64, distinct) as new Gaussians, the row count kept.

    ``values[key]`` [M, ...] replaces ``params[key][rows]`` for each key it names (any
    subset of ``params``; the other keys keep their rows). For every key of ``params``
    the Adam moments of these rows are zeroed, and so are the rows of every per-row
    tensor of ``state`` (e.g. accumulated gradients): what was learnt about the old
    Gaussian does not carry over to the one written in its place.
    """
    unknown = set(values) - set(params)
    if unknown:
        raise ValueError(f"rewrite: {sorted(unknown)} not in params")
    rows = rows.to(device=next(iter(params.values())).device, dtype=torch.long)
    if rows.unique().numel() != rows.numel():
        raise ValueError("rewrite: rows must be distinct")
    for key, v in values.items():
        if v.shape[0] != rows.numel():
            raise ValueError(f"rewrite: values[{key!r}] has {v.shape[0]} rows for {rows.numel()} rows")
    n = _num_rows(params)

    def param_fn(name: str, p: Tensor) -> Tensor:
        if name not in values:
            return p
        out = p.clone()
        out[rows] = values[name].to(p.device, p.dtype)
        return out

    def zero_rows(v: Tensor) -> Tensor:
        out = v.clone()
        out[rows] = 0
        return out

    _update_param_with_optimizer(param_fn, lambda _, v: zero_rows(v), params, optimizers)
    _resize_state(state, n, zero_rows)


@torch.no_grad()
def remove(params: Params, optimizers: Optimizers, state: MutableMapping, mask: Tensor) -> RowChange:
    """Drop every row where ``mask`` [N] is True, with its moments and state; the change."""
    keep = torch.where(~mask)[0]
    _update_param_with_optimizer(lambda _, p: p[keep], lambda _, v: v[keep], params, optimizers)
    change = RowChange(~mask)
    change.resize(state)
    return change


@torch.no_grad()
def reset_opa(params: Params, optimizers: Optimizers, state: MutableMapping, value: float) -> None:
    """Clamp ``sigmoid(opacities)`` to at most ``value`` and zero the opacity moments."""
    max_logit = torch.logit(torch.tensor(value, dtype=torch.float64)).item()

    def param_fn(name: str, p: Tensor) -> Tensor:
        return torch.clamp(p, max=max_logit)

    _update_param_with_optimizer(
        param_fn, lambda _, v: torch.zeros_like(v), params, optimizers, names=["opacities"]
    )


@torch.no_grad()
def decay_opa(params: Params, factor: float) -> None:
    """Multiply ``sigmoid(opacities)`` by ``factor`` in (0, 1] in place; the Adam moments are kept.

    In log space, ``logit(s f) = log s + log f - log(1 - s f)``, so a logit far below zero stays
    finite (``torch.logit(torch.sigmoid(x) * f)`` underflows to -inf below x of about -88)."""
    opa = params["opacities"]
    opa.copy_(torch.nn.functional.logsigmoid(opa) + math.log(factor) - torch.log1p(-torch.sigmoid(opa) * factor))
