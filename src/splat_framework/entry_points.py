"""Loading what plugins name: ``"module:Class"`` paths and the objects of an entry-point group.

A leaf module (imports nothing of the framework, never torch): the method registry, the
strategy configs (``StrategyConfig.strategy_class``) and the strategy kinds
(:func:`splat_framework.config.strategy_kinds`) load through it.
"""

from __future__ import annotations

import importlib
import warnings
from importlib.metadata import entry_points
from typing import Any

STRATEGY_ENTRY_POINT_GROUP = "splat_framework.strategies"
"""Entry-point group of strategy kinds: ``KIND = "module:ConfigClass"``, a torch-free
``StrategyConfig`` subclass whose ``kind`` is KIND; every method not narrowing its strategy accepts it."""
INIT_ENTRY_POINT_GROUP = "splat_framework.inits"
"""Entry-point group of initialisation kinds: ``KIND = "module:ConfigClass"``, a torch-free
``InitConfig`` subclass whose ``kind`` is KIND; every model not narrowing its ``init`` accepts it."""


def load_object(path: str) -> Any:
    """The object a ``"module:Name"`` path names (``"pkg.mod:Class"``), importing its module."""
    module, sep, name = path.partition(":")
    if not sep or not module or not name:
        raise ValueError(f"{path!r} is not a 'module:Name' path")
    return getattr(importlib.import_module(module), name)


def load_entry_points(group: str, what: str) -> dict[str, Any]:
    """Entry-point name -> loaded object of ``group``; one that fails to import is left out with one
    warning naming it and ``what`` it should be (a broken plugin must not kill the CLI)."""
    loaded: dict[str, Any] = {}
    for ep in entry_points(group=group):
        if ep.name in loaded:
            warnings.warn(f"{what} '{ep.name}' registered twice; keeping the first", stacklevel=2)
            continue
        try:
            loaded[ep.name] = ep.load()
        except Exception as e:
            warnings.warn(f"{what} plugin '{ep.name}' ({ep.value}) failed to import: {e}", stacklevel=2)
    return loaded
