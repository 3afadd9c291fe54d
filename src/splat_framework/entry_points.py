"""Registration: what plugins declare, by entry-point group, and loading what they name.

One path for every kind of part (methods, strategies, init kinds, photo matchers, config
variants, dataparsers), :data:`GROUPS`: an installed package declares its parts as entry points of these
groups (``[project.entry-points."splat_framework.methods"]`` in its pyproject.toml); a module
used without installing declares the same table as a dict ``ENTRY_POINTS = {group: {name:
"module:object"}}`` and is named in ``$SPLAT_PLUGINS`` (comma-separated module names, on
``PYTHONPATH``). :func:`registered` merges both; every reader of a group asks it.

Every kind follows one rule (:class:`Parts`): names follow :data:`PART_NAME`, and a taken name
keeps its first registration (the framework's own first, then installed packages, then
``$SPLAT_PLUGINS``): a second is left out with one warning naming both sources.

A part that is named as ``"module:Name"`` (a method's model and pipeline, a strategy's class, a start's
points function) is a :class:`Ref`: a string until :meth:`Ref.load` imports it and checks its kind.

A leaf module (imports nothing of the framework but its errors and environment, never torch): the method registry, the
strategy configs (``StrategyConfig.strategy_class``) and the kinds of strategies and starts load through it.
"""

from __future__ import annotations

import importlib
import os
import re
import warnings
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from typing import Any, Callable, Generic, TypeVar

STRATEGY_ENTRY_POINT_GROUP = "splat_framework.strategies"
"""Entry-point group of strategy kinds: ``KIND = "module:ConfigClass"``, a torch-free
``StrategyConfig`` subclass whose ``kind`` is KIND; every method not narrowing its strategy accepts it."""
INIT_ENTRY_POINT_GROUP = "splat_framework.inits"
"""Entry-point group of initialisation kinds: ``KIND = "module:ConfigClass"``, a torch-free
``InitConfig`` subclass whose ``kind`` is KIND; every model not narrowing its ``init`` accepts it."""
METHOD_ENTRY_POINT_GROUP = "splat_framework.methods"
PHOTO_MATCHER_ENTRY_POINT_GROUP = "splat_framework.photo_matchers"
CONFIG_ENTRY_POINT_GROUP = "splat_framework.configs"
DATAPARSER_ENTRY_POINT_GROUP = "splat_framework.dataparsers"

GROUPS: dict[str, str] = {
    METHOD_ENTRY_POINT_GROUP: "a method: NAME = \"module:spec\", a MethodSpec (torch-free module)",
    STRATEGY_ENTRY_POINT_GROUP: "a strategy kind: KIND = \"module:ConfigClass\", a StrategyConfig subclass",
    INIT_ENTRY_POINT_GROUP: "an init kind: KIND = \"module:ConfigClass\", an InitConfig subclass",
    PHOTO_MATCHER_ENTRY_POINT_GROUP: "a photo matcher: NAME = \"module:function\", images -> matches by pair",
    CONFIG_ENTRY_POINT_GROUP: "config variants: NAME = \"package\", a package holding TOML variants",
    DATAPARSER_ENTRY_POINT_GROUP: "a dataset format: NAME = \"module:spec\", a DataparserSpec (torch-free module)",
}
"""Every entry-point group a plugin may declare parts in -> what one entry names."""
PLUGINS_VARIABLE = "SPLAT_PLUGINS"
INSTALLED_VARIABLE = "SPLAT_INSTALLED_PLUGINS"


FRAMEWORK_DISTRIBUTION = "splat-framework"
"""The distribution of the framework itself (its pyproject's name): its entry points are the built-in
parts (3dgs, scgaussian, the learned photo matchers, the shipped variants) and register first."""

PART_NAME = re.compile(r"[a-z0-9]+(?:-[a-z0-9]+)*")
"""A part's name (a method, a variant, a strategy or init kind, a matcher): lower-case letters and
digits, in words joined by hyphens (``3dgs``, ``scgaussian-hybrid``, ``ray-gaussian``)."""
MAX_NAME_LENGTH = 64


def name_problem(name: object) -> str | None:
    """Why ``name`` cannot name a part (one phrase), or None: every kind's names follow :data:`PART_NAME`."""
    if isinstance(name, str) and len(name) <= MAX_NAME_LENGTH and PART_NAME.fullmatch(name):
        return None
    return (f"{name!r} is not a name (lower-case letters and digits in words joined by '-', at most "
            f"{MAX_NAME_LENGTH} characters: my-method)")


@dataclass(frozen=True)
class Entry:
    """One declared part: ``name = "module:object"`` in entry-point ``group``, and who declared it
    (``source``: ``package splat-example-plugin``, ``SPLAT_PLUGINS module 'my_plugin'``)."""

    name: str
    value: str
    group: str
    source: str

    def load(self) -> Any:
        """The object ``value`` names, importing its module."""
        return EntryPoint(self.name, self.value, self.group).load()

    def __str__(self) -> str:
        return f"{self.source} ({self.value})"


def _installed(group: str) -> list[Entry]:
    """The installed packages' entry points of ``group``: the framework's own first, then the others
    in ``importlib.metadata``'s order (none with ``SPLAT_INSTALLED_PLUGINS=off``; an entry point of no
    distribution, a test's, is kept)."""
    from .environment import installed_plugins_setting

    eps = list(entry_points(group=group))
    if not installed_plugins_setting(os.environ.get(INSTALLED_VARIABLE)):
        eps = [ep for ep in eps if _distribution(ep) in (None, FRAMEWORK_DISTRIBUTION)]
    found = []
    for ep in sorted(eps, key=lambda ep: _distribution(ep) != FRAMEWORK_DISTRIBUTION):
        dist = _distribution(ep)
        found.append(Entry(ep.name, ep.value, group, f"package {dist}" if dist else "an installed package"))
    return found


def _distribution(ep: EntryPoint) -> str | None:
    dist = getattr(ep, "dist", None)
    return dist.name if dist is not None else None


def registered(group: str) -> list[Entry]:
    """The entry points of ``group``, in the order they register: the framework's own, the other
    installed packages' (in ``importlib.metadata``'s order), then those declared by each module of
    ``$SPLAT_PLUGINS`` (its ``ENTRY_POINTS``), in the variable's order. A module that does not import
    (whatever it raises, ``SystemExit`` included), or whose table is malformed, is a one-line
    DataError naming the variable and the module (the user set it: it is not a plugin to skip)."""
    from .environment import plugin_modules

    found = _installed(group)
    for module in plugin_modules(os.environ.get(PLUGINS_VARIABLE)):
        declared = declared_entry_points(module)
        found += [Entry(name, value, group, f"SPLAT_PLUGINS module '{module}'")
                  for name, value in declared.get(group, {}).items()]
    return found


def raised(e: BaseException) -> str:
    """What an import raised, in a few words: ``RuntimeError: plugin broke``, ``SystemExit(0)``."""
    if isinstance(e, SystemExit):
        return f"SystemExit({e.code!r}): it called sys.exit"
    first = next(iter(str(e).strip().splitlines()), "")
    return f"{type(e).__name__}: {first}" if first else type(e).__name__


IMPORT_FAILURES = (Exception, SystemExit, KeyboardInterrupt)
"""What importing a plugin's module may raise that is reported (in one line naming it), never passed
on: a plugin's ``sys.exit`` or ``KeyboardInterrupt`` must not end a command silently."""

_OBJECT_PATH = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")
_MODULE_PATH = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")


def declared_entry_points(module: str) -> dict[str, dict[str, str]]:
    """The ``ENTRY_POINTS`` table of ``module`` (one named in ``$SPLAT_PLUGINS``), checked: a module
    that raises anything while importing, has no table, names another group, a part by other than a
    :data:`PART_NAME` or an object by other than ``"module:object"`` (a package, for variants) is
    one DataError line naming the module."""
    from .environment import plugin_entry_error

    try:
        imported = importlib.import_module(module)
    except IMPORT_FAILURES as e:  # the user's module: whatever it raises is reported in one line
        raise plugin_entry_error(module, f"cannot be imported ({raised(e)})") from None
    table = getattr(imported, "ENTRY_POINTS", None)
    if table is None:
        raise plugin_entry_error(module, "has no ENTRY_POINTS = {group: {name: 'module:object'}}")
    if not isinstance(table, dict):
        raise plugin_entry_error(module, f"ENTRY_POINTS is a {type(table).__name__}, not a dict of groups")
    for group, entries in table.items():
        if group not in GROUPS:
            raise plugin_entry_error(module, f"ENTRY_POINTS names group {group!r}; the groups are {', '.join(GROUPS)}")
        if not isinstance(entries, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in entries.items()):
            raise plugin_entry_error(module, f"ENTRY_POINTS[{group!r}] is not a dict of name -> 'module:object' strings")
        for name, value in entries.items():
            problem = _entry_problem(group, name, value)
            if problem:
                raise plugin_entry_error(module, f"ENTRY_POINTS[{group!r}][{name!r}]: {problem}")
    return table


def _entry_problem(group: str, name: str, value: str) -> str | None:
    """Why ``name = value`` cannot be an entry of ``group``, or None."""
    if group == CONFIG_ENTRY_POINT_GROUP:  # a package of variants, named for its own sake: the variants are the parts
        return None if _MODULE_PATH.fullmatch(value) else f"{value!r} is not a package name (my_plugin.configs)"
    problem = name_problem(name)
    if problem:
        return problem
    return None if _OBJECT_PATH.fullmatch(value) else f"{value!r} is not a 'module:object' path (my_plugin:spec)"


def load_object(path: str) -> Any:
    """The object a ``"module:Name"`` path names (``"pkg.mod:Class"``), importing its module (unchecked:
    a plugin's part loads through :class:`Ref`)."""
    module, sep, name = path.partition(":")
    if not sep or not module or not name:
        raise ValueError(f"{path!r} is not a 'module:Name' path")
    return getattr(importlib.import_module(module), name)


MODEL_BASE = "splat_framework.model.gaussians:GaussianModel"
PIPELINE_BASE = "splat_framework.pipeline:Pipeline"
STRATEGY_BASE = "splat_framework.model.strategy:Strategy"


@dataclass(frozen=True)
class Ref:
    """A plugin part named as ``"module:Name"``: ``MethodSpec.model`` (a :data:`MODEL_BASE` subclass),
    ``MethodSpec.pipeline`` (a :data:`PIPELINE_BASE` subclass), ``StrategyConfig.strategy_class`` (a
    :data:`STRATEGY_BASE` subclass), ``InitConfig.points_fn`` (a function). A string (torch-free, read
    for ``--help``) until :meth:`load` imports it and checks its kind.

    ``base``: ``"module:Class"`` of the class it must subclass, "" for a function (any callable);
    ``entry``: the field that holds it, in messages (``method 'my-3dgs': model``); ``source``: who
    declared it (:attr:`Entry.source`: ``package my-plugin``, ``SPLAT_PLUGINS module 'my_plugin'``)."""

    path: str
    base: str
    entry: str
    source: str = ""

    def resolve(self) -> tuple[Any, str | None]:
        """(the object, None), or (None, a phrase saying why it is unusable: does not import, not the kind)."""
        try:
            obj = load_object(self.path)
        except IMPORT_FAILURES as e:  # the plugin's module: whatever it raises is one line
            return None, f"does not import ({raised(e)})"
        if not self.base:
            return (obj, None) if callable(obj) else (None, f"is not a function (it is a {type(obj).__name__})")
        base = load_object(self.base)
        if isinstance(obj, type) and issubclass(obj, base):
            return obj, None
        what = f"the class {obj.__name__}" if isinstance(obj, type) else f"a {type(obj).__name__}"
        return None, f"is not a {base.__name__} subclass (it is {what})"

    def load(self) -> Any:
        """The object ``path`` names, of its kind; a :class:`~splat_framework.errors.PluginError`
        (one line naming the source, the entry and the problem) when it is not."""
        obj, problem = self.resolve()
        if problem:
            raise self.error(problem)
        return obj

    def error(self, problem: str):
        """The one-line PluginError saying ``problem`` of this reference."""
        from .errors import PluginError

        where = f"{self.source}: " if self.source else ""
        return PluginError(printable(f"{where}{self.entry} {self.path!r} {problem}"))


def printable(text: str) -> str:
    """``text`` with every character that does not print as itself (a newline, a zero-width space)
    escaped as Python writes it (``\\n``, ``\\u200b``): a message naming a file stays one visible line."""
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)


class RegistrationWarning(UserWarning):
    """A part was left out of its registry (a taken name, a name that is not one, an entry that does
    not import or is not what its group holds): always one line naming the part and who declared it."""


T = TypeVar("T")


class Parts(Generic[T]):
    """The registered parts of one kind, by name: the one rule every kind follows (methods, variants,
    strategies, inits, photo matchers, prior matchers).

    - Names follow :data:`PART_NAME`.
    - A taken name keeps its first registration (built-ins register first): a second is left out
      with one warning naming both sources, and nothing else moves.
    - A part that fails (does not import, is not what its group holds) is left out with one warning,
      and :attr:`refused` keeps why, so that a command asking for it by name can say so in one line.

    ``what`` names the kind in messages (``"method"``, ``"photo matcher"``); ``category`` is the
    warnings' class."""

    def __init__(self, what: str, category: type[Warning] = RegistrationWarning) -> None:
        self.what, self.category = what, category
        self.parts: dict[str, T] = {}
        self.sources: dict[str, str] = {}
        self.refused: dict[str, str] = {}

    def claim(self, name: str, source: str) -> bool:
        """Whether ``name`` is a free, valid name, now ``source``'s; else one warning naming why
        (and, for a taken name, both sources) and False."""
        problem = name_problem(name)
        if problem:
            self.refuse(name, f"{self.what} of {source}: {problem}")
            return False
        if name in self.sources:
            self.warn(f"{self.what} '{name}' of {source} is already registered by {self.sources[name]}, "
                      "which keeps it")
            return False
        self.sources[name] = source
        return True

    def add(self, name: str, part: T, source: str) -> bool:
        """Register ``part`` as ``name`` (declared by ``source``) when :meth:`claim` allows it."""
        if not self.claim(name, source):
            return False
        self.parts[name] = part
        return True

    def refuse(self, name: str, reason: str) -> None:
        """Leave ``name`` out with one warning (``reason; ignored``), and remember the first reason."""
        self.refused.setdefault(name, printable(reason))
        self.warn(reason)

    def warn(self, reason: str) -> None:
        """One warning line: ``reason; ignored`` (a file name's newline or invisible character escaped)."""
        warnings.warn(printable(f"{reason}; ignored"), self.category, stacklevel=4)

    def load(self, group: str, check: Callable[[str, Any], str | None] | None = None, load: bool = True) -> "Parts":
        """Register the entries of ``group`` (:func:`registered`), each loaded (``load``; else the
        :class:`Entry` itself is the part, loaded when used) and passed by ``check(name, object)``
        (a phrase saying what is wrong, or None). A taken or invalid name is never imported."""
        for entry in registered(group):
            if not self.claim(entry.name, str(entry)):
                continue
            if not load:
                self.parts[entry.name] = entry
                continue
            try:
                part = entry.load()
            except IMPORT_FAILURES as e:  # a broken plugin must not kill the CLI (nor end it)
                self._release(entry.name, f"{self.what} '{entry.name}' of {entry} failed to import ({raised(e)})")
                continue
            problem = check(entry.name, part) if check else None
            if problem:
                self._release(entry.name, f"{self.what} '{entry.name}' of {entry}: {problem}")
                continue
            self.parts[entry.name] = part
        return self

    def _release(self, name: str, reason: str) -> None:
        del self.sources[name]  # a later registration of the name may take it
        self.refuse(name, reason)

    def __contains__(self, name: object) -> bool:
        return name in self.parts

    def __getitem__(self, name: str) -> T:
        return self.parts[name]


def load_entry_points(group: str, what: str) -> dict[str, Any]:
    """Entry-point name -> loaded object of ``group`` under :class:`Parts`' rule (the first of a
    name keeps it; one that fails to import is left out with one warning naming it: a broken plugin
    must not kill the CLI)."""
    return Parts(what).load(group).parts
