"""Count the host syncs a piece of code would make on CUDA, on any device (a CPU included).

A CUDA step is fastest when the host never waits for the device: the host queues the next kernels
while the device runs the last ones. Every read of a device value on the host (``.item()``,
``float(t)``, ``bool(t)``, ``if t.any():``, ``.tolist()``, ``.cpu()``) and every operation whose
output size depends on the values (``nonzero``, one-argument ``where``, indexing by a bool mask,
``unique``, ``repeat_interleave`` without ``output_size``) makes the host wait for the device to
finish everything queued before it. :func:`count_host_syncs` sees those calls through a
``TorchFunctionMode``, so a test on a CPU counts what the same code would sync on a GPU::

    with count_host_syncs() as syncs:
        trainer.train_step(step)
    syncs.total()                      # every call
    syncs.by_place()                   # {("nonzero", "rasterizer.py:141"): 1, ...}

The count is what the code asks for, whatever the device: a ``.tolist()`` of a tensor that lives on
the host in a CUDA run too (a CPU random generator's draw) is counted as well, so a test names the
places it allows. ``.to(device)`` is not counted (on a CPU the run's device and the host look alike):
copy to the host with ``.cpu()``, which is.
"""

from __future__ import annotations

import os
import traceback
from collections import Counter
from contextlib import contextmanager
from typing import Iterator

import torch
from torch.overrides import TorchFunctionMode

__all__ = ["HostSyncs", "count_host_syncs"]

READS = frozenset({"__bool__", "__float__", "__int__", "__index__", "__complex__", "item", "tolist", "numpy", "cpu"})
"""Tensor methods that copy a device value to the host."""
SIZED_BY_VALUES = frozenset({"nonzero", "argwhere", "masked_select", "unique", "unique_consecutive", "bincount"})
"""Operations whose output size the host must read from the device."""
_TORCH = os.path.dirname(torch.__file__)


def _bool_index(index) -> bool:
    items = index if isinstance(index, (tuple, list)) else (index,)
    return any(torch.is_tensor(i) and i.dtype == torch.bool and i.dim() > 0 for i in items)


def syncs_on_cuda(name: str, args: tuple, kwargs: dict) -> bool:
    """Whether the torch call ``name(*args, **kwargs)`` makes the host wait for the device on CUDA."""
    if name in READS or name in SIZED_BY_VALUES:
        return True
    if name == "where":
        return len(args) + len(kwargs) == 1
    if name == "repeat_interleave":
        return "output_size" not in kwargs and (len(args) < 2 or torch.is_tensor(args[1]))
    if name in ("__getitem__", "__setitem__", "index_put_", "index_put"):
        return len(args) > 1 and _bool_index(args[1])
    return False


class HostSyncs(TorchFunctionMode):
    """The host syncs counted while active, by (operation, ``file:line`` of the innermost frame outside
    torch that made it)."""

    def __init__(self) -> None:
        super().__init__()
        self.places: Counter[tuple[str, str]] = Counter()

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        name = getattr(func, "__name__", "")
        if syncs_on_cuda(name, args, kwargs):
            self.places[(name, _caller())] += 1
        return func(*args, **kwargs)

    def total(self) -> int:
        """Every sync counted."""
        return sum(self.places.values())

    def by_place(self) -> dict[tuple[str, str], int]:
        """(operation, ``file:line``) -> count, most frequent first."""
        return dict(self.places.most_common())

    def report(self, per: int = 1) -> str:
        """One line per place, ``count/per  operation  file:line`` (``per``: divide by, e.g. the steps)."""
        return "\n".join(f"{n / per:6.2f}  {op:12s} {place}" for (op, place), n in self.places.most_common())


def _caller() -> str:
    for frame in reversed(traceback.extract_stack()):
        if frame.filename != __file__ and not frame.filename.startswith(_TORCH):
            return f"{os.path.basename(frame.filename)}:{frame.lineno}"
    return "?"


@contextmanager
def count_host_syncs() -> Iterator[HostSyncs]:
    """Count the host syncs of the enclosed code (see the module); yields the :class:`HostSyncs`."""
    mode = HostSyncs()
    with mode:
        yield mode
