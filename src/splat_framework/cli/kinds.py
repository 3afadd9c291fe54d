"""``--PATH.kind K`` on the command line: switch a kind-tagged field of a config to kind ``K``
before the argument parser is built, so that tyro shows and parses that kind's own flags
(``splat-train 3dgs --model.init.kind ply --model.init.path x.ply``, ``splat-train 3dgs
--strategy.kind mcmc``). The one kind switch of every command. Torch-free."""

from __future__ import annotations

import typing

from pydantic import BaseModel


def union_kinds(annotation) -> dict[str, type[BaseModel]]:
    """{kind: config class} of a field annotated as a union of configs tagged by ``kind``
    (:func:`~splat_framework.config.init.init_field`, :func:`~splat_framework.config.strategy_field`),
    as one such config, or as a base whose ``registered_kinds()`` lists them (the registered
    strategies); else {}."""
    while typing.get_origin(annotation) is typing.Annotated:
        annotation = typing.get_args(annotation)[0]
    if typing.get_origin(annotation) is typing.Union:
        members = typing.get_args(annotation)
    elif isinstance(annotation, type) and "registered_kinds" in vars(annotation):  # the base itself, not a narrowed kind
        return dict(annotation.registered_kinds())
    else:
        members = (annotation,)
    kinds = {}
    for m in members:
        field = getattr(m, "model_fields", {}).get("kind")
        tags = typing.get_args(unannotated(field.annotation)) if field is not None else ()
        for tag in tags:
            kinds[tag] = m
    return kinds


def unannotated(annotation):
    """``annotation`` without its ``Annotated`` layers."""
    while typing.get_origin(annotation) is typing.Annotated:
        annotation = typing.get_args(annotation)[0]
    return annotation


def suppressed(info) -> bool:
    """Whether a pydantic field (its ``FieldInfo``) is hidden from the command line (``tyro.conf.Suppress``)."""
    import tyro

    marker = typing.get_args(tyro.conf.Suppress[int])[1]
    return any(m is marker for m in info.metadata)


def flag_value(argv: list[str], flag: str) -> str | None:
    """The last value given to ``flag`` in ``argv`` (``--a.b-c V`` or ``--a.b-c=V``; ``_`` and ``-``
    alike), or None."""
    found = None
    norm = flag.replace("_", "-")
    for i, arg in enumerate(argv):
        name, eq, value = arg.partition("=")
        if name.replace("_", "-") != norm:
            continue
        if eq:
            found = value
        elif i + 1 < len(argv):
            found = argv[i + 1]
    return found


def switched_kind(value: BaseModel | None, cls: type[BaseModel]) -> BaseModel:
    """``value`` switched to the config class ``cls`` (another kind): the kind's defaults, except the
    fields both kinds have, which keep what ``value`` set (a variant's values or a saved run's).
    ``splat-train scgaussian-paper --model.matching.kind auto`` keeps the recipe's 2,000 matches a
    pair and its MAGSAC settings, and changes the matcher alone; the kind's own fields start from
    its defaults (the kinds declare no shared field with different defaults)."""
    kept = {}
    if isinstance(value, BaseModel):
        shared = (set(type(value).model_fields) & set(cls.model_fields)) - {"kind"}
        kept = {name: getattr(value, name) for name in shared & value.model_fields_set}
    return cls.model_construct(**kept)


def choose_kinds(config: BaseModel, argv: list[str], prefix: str = "") -> BaseModel:
    """``config`` with every tagged-union field named by a ``--PATH.kind K`` flag of ``argv`` holding
    kind ``K``: its current value when already of that kind, else :func:`switched_kind` (a field
    without a default stays unset, so the parser asks for it). An unknown kind raises
    :class:`~splat_framework.cli.common.ArgumentsError` (one line naming the choices)."""
    from .common import ArgumentsError, did_you_mean

    updates = {}
    for name, info in type(config).model_fields.items():
        value = getattr(config, name, None)
        kinds = union_kinds(info.annotation)
        chosen = flag_value(argv, f"--{prefix}{name}.kind") if kinds else None
        if chosen is not None and getattr(value, "kind", None) != chosen:
            if chosen not in kinds:
                raise ArgumentsError(
                    f"--{prefix}{name}.kind: {chosen!r} is not one of {', '.join(kinds)}"
                    f"{did_you_mean(chosen, kinds)}"
                )
            value = switched_kind(value, kinds[chosen])
        if isinstance(value, BaseModel):
            value = choose_kinds(value, argv, f"{prefix}{name}.")
        if value is not getattr(config, name, None):
            updates[name] = value
    return config.model_copy(update=updates) if updates else config
