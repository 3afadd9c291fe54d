"""The optimiser of every trained tensor: Adam, fused where this torch has a fused Adam for the device.

A fused Adam runs each parameter's update as one kernel instead of a dozen element-wise passes:
on CPU (torch >= 2.4) the optimiser phase of a fern ``scgaussian`` step (48k Gaussians, six
tensors) fell from 8-10 ms to 1 ms, with updates equal to float rounding. Where the device has
none (torch 2.3 on CPU) the ordinary Adam is used. The choice is this process's: a checkpoint
written by another machine's optimiser is loaded with this one's flags (``load_state_dict``
would otherwise take the saved ones).
"""

from __future__ import annotations

from typing import Any, Iterable

import torch


def adam(groups: Iterable[dict[str, Any]], lr: float, eps: float = 1e-15) -> torch.optim.Adam:
    """``torch.optim.Adam(groups, lr=lr, eps=eps)``, fused when the device supports it."""
    groups = list(groups)
    try:
        opt = torch.optim.Adam(groups, lr=lr, eps=eps, fused=True)
    except (RuntimeError, ValueError):  # no fused Adam for this device in this torch
        opt = torch.optim.Adam(groups, lr=lr, eps=eps)
    flags = {key: opt.defaults.get(key) for key in ("fused", "foreach")}

    def keep_flags(optimizer: torch.optim.Optimizer) -> None:
        for group in optimizer.param_groups:
            group.update(flags)

    opt.register_load_state_dict_post_hook(keep_flags)
    return opt


__all__ = ["adam"]
