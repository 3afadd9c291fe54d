"""Registration: what plugins declare, by entry-point group, and loading what they name.

One path for every kind of part (methods, strategies, start kinds, photo matchers, config
variants), :data:`GROUPS`: an installed package declares its parts as entry points of these
groups (``[project.entry-points."splat_framework.methods"]`` in its pyproject.toml); a module
used without installing declares the same table as a dict ``ENTRY_POINTS = {group: {name:
"module:object"}}`` and is named in ``$SPLAT_PLUGINS`` (comma-separated module names, on
``PYTHONPATH``). :func:`registered` merges both; every reader of a group asks it.

A leaf module (imports nothing of the framework but its errors and environment, never torch): the method registry, the
strategy configs (``StrategyConfig.strategy_class``) and the kinds of strategies and starts load through it.
"""

from __future__ import annotations

import importlib
import os
import warnings
from importlib.metadata import EntryPoint, entry_points
from typing import Any

STRATEGY_ENTRY_POINT_GROUP = "splat_framework.strategies"
"""Entry-point group of strategy kinds: ``KIND = "module:ConfigClass"``, a torch-free
``StrategyConfig`` subclass whose ``kind`` is KIND; every method not narrowing its strategy accepts it."""
INIT_ENTRY_POINT_GROUP = "splat_framework.inits"
"""Entry-point group of initialisation kinds: ``KIND = "module:ConfigClass"``, a torch-free
``InitConfig`` subclass whose ``kind`` is KIND; every model not narrowing its ``init`` accepts it."""
METHOD_ENTRY_POINT_GROUP = "splat_framework.methods"
PHOTO_MATCHER_ENTRY_POINT_GROUP = "splat_framework.photo_matchers"
CONFIG_ENTRY_POINT_GROUP = "splat_framework.configs"

GROUPS: dict[str, str] = {
    METHOD_ENTRY_POINT_GROUP: "a method: NAME = \"module:spec\", a MethodSpec (torch-free module)",
    STRATEGY_ENTRY_POINT_GROUP: "a strategy kind: KIND = \"module:ConfigClass\", a StrategyConfig subclass",
    INIT_ENTRY_POINT_GROUP: "a start kind: KIND = \"module:ConfigClass\", an InitConfig subclass",
    PHOTO_MATCHER_ENTRY_POINT_GROUP: "a photo matcher: NAME = \"module:function\", images -> matches by pair",
    CONFIG_ENTRY_POINT_GROUP: "config variants: NAME = \"package\", a package holding TOML variants",
}
"""Every entry-point group a plugin may declare parts in -> what one entry names."""
PLUGINS_VARIABLE = "SPLAT_PLUGINS"


def registered(group: str) -> list[EntryPoint]:
    """The entry points of ``group``: the installed packages' (in ``importlib.metadata``'s order),
    then those declared by each module of ``$SPLAT_PLUGINS`` (its ``ENTRY_POINTS``), in the
    variable's order. A module that does not import, or whose table is malformed, is a one-line
    DataError naming the variable (the user set it: it is not a plugin to skip)."""
    from .environment import plugin_modules

    found = list(entry_points(group=group))
    for module in plugin_modules(os.environ.get(PLUGINS_VARIABLE)):
        declared = declared_entry_points(module)
        found += [EntryPoint(name, value, group) for name, value in declared.get(group, {}).items()]
    return found


def declared_entry_points(module: str) -> dict[str, dict[str, str]]:
    """The ``ENTRY_POINTS`` table of ``module`` (one named in ``$SPLAT_PLUGINS``), checked."""
    from .environment import plugin_entry_error

    try:
        table = getattr(importlib.import_module(module), "ENTRY_POINTS")
    except AttributeError:
        raise plugin_entry_error(module, "has no ENTRY_POINTS = {group: {name: 'module:object'}}") from None
    except Exception as e:  # the user's module: whatever it raises is reported in one line
        first = next(iter(str(e).splitlines()), "") or type(e).__name__
        raise plugin_entry_error(module, f"cannot be imported ({first})") from None
    if not isinstance(table, dict):
        raise plugin_entry_error(module, f"ENTRY_POINTS is a {type(table).__name__}, not a dict of groups")
    for group, entries in table.items():
        if group not in GROUPS:
            raise plugin_entry_error(module, f"ENTRY_POINTS names group {group!r}; the groups are {', '.join(GROUPS)}")
        if not isinstance(entries, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in entries.items()):
            raise plugin_entry_error(module, f"ENTRY_POINTS[{group!r}] is not a dict of name -> 'module:object' strings")
    return table


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
    for ep in registered(group):
        if ep.name in loaded:
            warnings.warn(f"{what} '{ep.name}' registered twice; keeping the first", stacklevel=2)
            continue
        try:
            loaded[ep.name] = ep.load()
        except Exception as e:
            warnings.warn(f"{what} plugin '{ep.name}' ({ep.value}) failed to import: {e}", stacklevel=2)
    return loaded
