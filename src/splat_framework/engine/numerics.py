"""Finiteness checks of a training step: which tensors a step updates, and the first that holds a NaN or inf."""

from __future__ import annotations

import torch
from torch import Tensor


def first_nonfinite(tensors: dict[str, Tensor | None]) -> str | None:
    """Name of the first tensor holding a NaN or inf (None when all are finite), with one host sync.

    Fast path: a sum is NaN or inf whenever a summand is, and one read of each tensor is several
    times cheaper than ``isfinite(...).all()`` (4.5 to 1 ms per step on fern's 48k-Gaussian SH
    coefficients, CPU). Only a non-finite sum (or one that overflowed) pays for the exact check, so
    an overflow never names a finite tensor."""
    names = [k for k, t in tensors.items() if t is not None]
    if not names:
        return None
    if bool(torch.stack([tensors[k].sum(dtype=torch.float32) for k in names]).isfinite().all()):
        return None
    ok = torch.stack([torch.isfinite(tensors[k]).all() for k in names]).tolist()
    return next((k for k, good in zip(names, ok) if not good), None)


def trainable_tensors(model) -> list[tuple[str, Tensor]]:
    """(name, tensor) of every per-row parameter and every network weight of ``model``."""
    return list(model.params.items()) + [(f"networks.{k}", p) for k, p in model.networks.named_parameters()]


def optimized_tensors(optimizers: dict) -> list[tuple[str, Tensor]]:
    """(optimizer name[.index], tensor) of every tensor an optimizer updates."""
    out = []
    for name, opt in optimizers.items():
        ps = [p for g in opt.param_groups for p in g["params"]]
        out += [(name if len(ps) == 1 else f"{name}.{i}", p) for i, p in enumerate(ps)]
    return out
