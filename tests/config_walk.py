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


def nested(path: tuple, value) -> dict:
    out = value
    for key in reversed(path):
        out = {key: out}
    return out


METHODS = registry.discover_methods()
DEFAULTS = {name: spec.default_config() for name, spec in METHODS.items()}
FIELDS = [(m, path, types) for m, cfg in DEFAULTS.items() for path, _, _, types in leaf_fields(cfg)]
