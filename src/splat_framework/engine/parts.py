"""Every plugin part a run uses, imported and checked once the run is configured and before any
data loads (:func:`resolve_parts`): a broken one is one line naming the plugin, the entry and the
problem (:class:`~splat_framework.errors.PluginError`, exit 2), never a traceback after the data
loaded and the model was built."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable

from ..config.init import InitConfig
from ..config.strategy import StrategyConfig
from ..data.dataparsers import dataparsers
from ..entry_points import INIT_ENTRY_POINT_GROUP, STRATEGY_BASE, STRATEGY_ENTRY_POINT_GROUP, Ref, registered
from ..errors import DataError, did_you_mean
from ..model.strategy import Strategy
from ..registry import MethodSpec

FAMILIES = ((StrategyConfig, STRATEGY_ENTRY_POINT_GROUP, "strategy_class", STRATEGY_BASE),
            (InitConfig, INIT_ENTRY_POINT_GROUP, "points_fn", ""))
"""The kind configs naming a part: (config base, the entry-point group of its kinds, the field naming
the part, the base class the part subclasses; "" a function)."""


@dataclass(frozen=True)
class RunParts:
    """The plugin parts a run uses, imported and checked by :func:`resolve_parts`."""

    model: type
    """The model class (a GaussianModel subclass)."""
    pipeline: type
    """The pipeline class (a Pipeline subclass)."""
    by_field: dict[str, Any]
    """Config field (``strategy``, ``model.init``, ``model.init.fallback``) -> the strategy class or
    points function its config names."""
    photo_matcher: Callable | None
    """The function of the photo matcher ``--photos.matcher`` names, when ``--data`` is photos or a
    video (None: not photos, or the framework's choice, ``auto`` or ``sift``)."""


def resolve_parts(spec: MethodSpec, config) -> RunParts:
    """Import and check every ``"module:Name"`` the run of ``config`` (a ``spec`` method's) will use:
    its model and pipeline, the ``strategy_class`` or ``points_fn`` of every strategy and init config
    in ``config`` (:class:`~splat_framework.entry_points.Ref`), and the photo matcher when ``--data``
    is photos or a video. The first that does not import or is not of its kind is a one-line
    PluginError (DataError, for a photo matcher) naming who declared it (the kind's entry point, else
    the method's), the entry and the problem. Cheap once imported: the CLI calls it before any data
    loads, the Trainer again for a run started in-process."""
    _check_format(config.format)
    model, pipeline = spec.model_class(), spec.pipeline_class()
    by_field = {}
    for where, part in _configs_in(config, tuple(f[0] for f in FAMILIES)):
        _, group, name, base = next(f for f in FAMILIES if isinstance(part, f[0]))
        ref = Ref(str(getattr(part, name, "")), base, f"method '{spec.name}': {where}.{name} of {type(part).__name__}",
                  spec.source)
        obj, problem = ref.resolve()
        if problem:  # named by the plugin that registered the kind, when one did
            raise replace(ref, source=_declared_by(group, type(part)) or ref.source).error(problem)
        by_field[where] = obj
    return RunParts(model, pipeline, by_field, _photo_matcher(config))


def _configs_in(config, kinds: tuple[type, ...], where: str = ""):
    """(field path, config) of every config of ``kinds`` in ``config``'s tree, outside in."""
    from pydantic import BaseModel

    for name in type(config).model_fields:
        value = getattr(config, name)
        path = f"{where}.{name}" if where else name
        if isinstance(value, kinds):
            yield path, value
        if isinstance(value, BaseModel):
            yield from _configs_in(value, kinds, path)


def _declared_by(group: str, cls: type) -> str | None:
    """Who declared ``cls`` as a kind in entry-point ``group`` (``package my-plugin (my_plugin:Config)``), or None."""
    path = f"{cls.__module__}:{cls.__qualname__}"
    return next((str(e) for e in registered(group) if e.value == path), None)


def _photo_matcher(config) -> Callable | None:
    """The photo matcher ``config.photos.matcher`` names, loaded and checked, when ``config.data`` is
    photos or a video; None otherwise, and for ``auto`` and ``sift``: the framework's own, which only
    a run that finds no poses in the cache loads."""
    from ..data.builtin_scenes import builtin_scene_name
    from ..data.photos import photo_source
    from ..data.resolve import locate_data
    from ..sfm.photo_matchers import AUTO_MATCHER, choose_matcher, load_matcher, photo_matchers

    if config.photos.matcher in (AUTO_MATCHER, "sift") or config.data is None:
        return None
    # a built-in scene is rendered, never posed: not located here (that would render it)
    if builtin_scene_name(config.data) is not None or photo_source(locate_data(config.data)) is None:
        return None
    plugins = photo_matchers()
    name = choose_matcher(config.photos.matcher, plugins, flag="--photos.matcher")
    return load_matcher(name, plugins[name])


def build_strategy(config: StrategyConfig) -> Strategy:
    """The strategy ``config`` describes (``config.setup()``; its class checked before the data
    loaded); TypeError when a config's own ``setup`` returns something else."""
    strategy = config.setup()
    if not isinstance(strategy, Strategy):
        raise TypeError(f"{type(config).__name__}.setup() returned {type(strategy).__name__}, not a Strategy")
    return strategy


def _check_format(name: str) -> None:
    """``--format`` names ``auto`` or a registered dataparser (a one-line DataError, exit 2, with the
    closest name, before anything loads)."""
    names = ["auto", *dataparsers()]
    if name not in names:
        raise DataError(f"--format: {name!r} is not one of {', '.join(names)}{did_you_mean(name, names)}")
