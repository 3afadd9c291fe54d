"""The one merge rule of configs, TOML variants and sweeps: nested overrides applied to a config
(:func:`apply_overrides`, :func:`deep_merge`). Torch-free."""

from __future__ import annotations

from typing import Any

from .base import SplatConfig


def apply_overrides(config: SplatConfig, overrides: dict[str, Any]) -> SplatConfig:
    """A validated copy of ``config`` with nested ``overrides`` applied.

    ``overrides`` mirrors the config's nesting, e.g. ``{"model": {"use_rg": False}}``.
    Unknown keys raise ``pydantic.ValidationError`` naming the field.
    """
    return type(config).model_validate(deep_merge(config.model_dump(), overrides))


def deep_merge(a: dict, b: dict) -> dict:
    """``b`` merged into a copy of ``a``: nested dicts are merged key by key (unless ``b``'s names
    another ``kind``, see :func:`_same_kind`), any other value of ``b`` replaces ``a``'s. The one
    merge rule of configs, variants and sweeps."""
    out = {k: (deep_merge(v, {}) if isinstance(v, dict) else v) for k, v in a.items()}
    for k, v in b.items():
        out[k] = deep_merge(out[k], v) if isinstance(v, dict) and _same_kind(out.get(k), v) else v
    return out


def _same_kind(a, b: dict) -> bool:
    """Whether dict ``b`` edits dict ``a``; a ``b`` that names another ``kind`` (a discriminated
    union member, e.g. another strategy) replaces ``a`` instead, taking its own defaults."""
    return isinstance(a, dict) and b.get("kind", a.get("kind")) == a.get("kind")

