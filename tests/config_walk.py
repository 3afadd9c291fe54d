"""Walk the configs of every registered method: the fields a test sets to hostile values (issue 40)."""

from __future__ import annotations

import typing

from splat_framework import registry
from splat_framework.config import SplatConfig


def members(annotation) -> tuple:
    """The plain types an annotation admits (Annotated and unions unwrapped)."""
    args = typing.get_args(annotation)
    if typing.get_origin(annotation) is typing.Annotated:
        return members(args[0])
    if typing.get_origin(annotation) is typing.Literal:
        return ()
    return tuple(a for m in args for a in members(m)) if args else (annotation,)


def leaf_fields(config: SplatConfig, prefix: tuple = ()) -> list[tuple[tuple, type[SplatConfig], str, tuple]]:
    """(path, owning class, field name, admitted types) of every non-config field of ``config``, nested."""
    out = []
    for name, info in type(config).model_fields.items():
        value = getattr(config, name)
        if isinstance(value, SplatConfig):
            out += leaf_fields(value, prefix + (name,))
        else:
            out.append((prefix + (name,), type(config), name, members(info.annotation)))
    return out


def sub_configs(config: SplatConfig, kind: type[SplatConfig]) -> list[SplatConfig]:
    """Every sub-config of ``config`` (itself included) of type ``kind``."""
    if isinstance(config, kind):
        return [config]
    if not isinstance(config, SplatConfig):
        return []
    return [c for name in type(config).model_fields for c in sub_configs(getattr(config, name), kind)]


def overrides_in_every(config: SplatConfig, kind: type[SplatConfig], values: dict) -> dict:
    """Overrides (nested, as apply_overrides takes them) that set ``values`` in every sub-config of
    ``config`` of type ``kind``, wherever the method keeps it (e.g. a MatchConfig under
    ``model.matching`` or ``model.init.matching``)."""
    if isinstance(config, kind):
        return dict(values)
    if not isinstance(config, SplatConfig):
        return {}
    return {name: sub for name in type(config).model_fields
            if (sub := overrides_in_every(getattr(config, name), kind, values))}


def nested(path: tuple, value) -> dict:
    out = value
    for key in reversed(path):
        out = {key: out}
    return out


METHODS = registry.discover_methods()
DEFAULTS = {name: spec.default_config() for name, spec in METHODS.items()}
FIELDS = [(m, path, types) for m, cfg in DEFAULTS.items() for path, _, _, types in leaf_fields(cfg)]
