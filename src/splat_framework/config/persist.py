"""``config.json``: the resolved config saved beside every run (schema version, checksum), read
back without executing code, and upgraded from the layouts older versions wrote. Torch-free."""

from __future__ import annotations

import json
from pathlib import Path

from pydantic import ValidationError

from .init import upgrade_init_layout
from .merge import deep_merge
from .model import GaussianModelConfig, ModelConfig, OptimConfig, upgrade_reg_layout
from .train import TrainConfig

SCHEMA_VERSION = 1
"""Version of the saved ``config.json`` layout; bump on incompatible change."""


def config_payload(config: TrainConfig) -> dict:
    """What ``config.json`` holds: the schema version and the resolved config."""
    return {"schema_version": SCHEMA_VERSION, "config": json.loads(config.model_dump_json())}


def save_config(config: TrainConfig, path: Path) -> None:
    """Write the resolved config as JSON with a schema version and a checksum (atomic)."""
    from ..runtime.io import atomic_write_json

    atomic_write_json(path, config_payload(config))


#: Fields that config.json files of this schema may still hold but the configs no longer have
#: (dotted paths). SCGaussian's never-prune flag and child rule moved from DensifyConfig into its
#: own strategy class (their values were fixed by the method, never a user's choice);
#: ``steps_per_view`` (scgaussian: max(1000, 250 x views) iterations) became ``schedule_views``
#: (1000 x views / 4 beyond 4 views), which gives the same count for every view count it was used with.
MOVED_FIELDS = ("strategy.never_prune_key", "strategy.child_defaults", "steps_per_view")

#: Fields every method's ``model`` and ``optim`` held before the model config was split into what
#: every model reads and what the 3DGS model reads (issue 41): a method whose config no longer has
#: one never read it (Scaffold-GS, Octree-GS), so an old run's value of it is dropped.
OLD_SHARED_FIELDS = {
    "model": tuple(n for n in GaussianModelConfig.model_fields if n not in ModelConfig.model_fields),
    "optim": tuple(OptimConfig.model_fields),
}


_DENSE = ("dense_preset", "dense_upscale", "fb_threshold", "dense_oversample", "min_texture")
_LIGHTGLUE = ("min_confidence", "weights", "device", "max_keypoints", "learned_resize")
#: The matcher-specific fields of the flat ``matching`` block that config.json files held before each
#: matcher had a config of its own (tagged by ``kind``, then named ``matcher``), by the matcher that
#: read them: a record of that layout, whatever today's matcher configs become.
FLAT_MATCHER_FIELDS = {
    "dense": _DENSE, "sift": ("sift_features", "ratio", "sift_upscale"), "loftr": ("min_confidence", "weights", "device"),
    "aliked-lightglue": _LIGHTGLUE, "disk-lightglue": _LIGHTGLUE,
    "auto": ("auto_flow_max_angle", "auto_min_matches", "auto_guided_flow_max_views", *_DENSE, *_LIGHTGLUE),
}


def upgrade_match_layout(block):
    """A saved ``matching`` block (dict) written before the matchers' configs were tagged, in today's
    layout: its ``matcher`` is its ``kind``, and the other matchers' fields (:data:`FLAT_MATCHER_FIELDS`,
    which its matcher never read) are dropped. Any other value is returned as it is."""
    if not isinstance(block, dict) or "matcher" not in block or "kind" in block:
        return block
    out = dict(block)
    kind = out.pop("matcher")
    if kind not in FLAT_MATCHER_FIELDS:
        return {"kind": kind, **out}  # validation names it
    others = {f for fields in FLAT_MATCHER_FIELDS.values() for f in fields} - set(FLAT_MATCHER_FIELDS[kind])
    return {"kind": kind, **{k: v for k, v in out.items() if k not in others}}


def _upgrade_matching(model: dict) -> dict:
    """``model`` (a saved model config dict) with its matching blocks (the prior's, the triangulated
    start's) in today's layout (:func:`upgrade_match_layout`)."""
    out = dict(model)
    if "matching" in out:
        out["matching"] = upgrade_match_layout(out["matching"])
    if isinstance(out.get("init"), dict) and "matching" in out["init"]:
        out["init"] = {**out["init"], "matching": upgrade_match_layout(out["init"]["matching"])}
    return out


def regroup_fields(cfg: dict, defaults: dict) -> dict:
    """A copy of a saved config dict whose ``model`` and ``optim`` fields sit where the method's
    ``defaults`` (its default config, as a dict) keep them: a field the other group has now moves
    there (Scaffold-GS's learning rates, once model fields, are its ``optim``), one of the
    :data:`OLD_SHARED_FIELDS` the method no longer has is dropped; any other stays, for validation
    to report."""
    out = dict(cfg)
    for group, other in (("model", "optim"), ("optim", "model")):
        section, known, there = out.get(group), defaults.get(group), defaults.get(other)
        if not (isinstance(section, dict) and isinstance(known, dict) and isinstance(there, dict)):
            continue
        section = out[group] = dict(section)
        for name in [k for k in section if k not in known]:
            target = out.get(other)
            if name in there and isinstance(target, dict) and name not in target:
                out[other] = {**target, name: section.pop(name)}
            elif name in OLD_SHARED_FIELDS[group]:
                section.pop(name)
    return out


def upgrade_saved_config(cfg: dict, defaults: TrainConfig | None = None) -> dict:
    """A copy of a saved config dict without the :data:`MOVED_FIELDS` (runs written before they moved),
    its ``model.init``, ``model.reg`` and matching blocks in today's layout
    (:func:`~splat_framework.config.init.upgrade_init_layout`, :func:`~splat_framework.config.model.upgrade_reg_layout`,
    :func:`upgrade_match_layout`).

    With ``defaults`` (the method's default config), its model and learning-rate fields are
    regrouped as the method keeps them (:func:`regroup_fields`) and fields added since the file
    was written take the method's default value (as ``config.json`` would hold them now); a dict
    that does not validate is returned as it is, for the caller to report."""
    out = dict(cfg)
    for path in MOVED_FIELDS:
        *parents, name = path.split(".")
        section = out
        for p in parents:
            if not isinstance(section.get(p), dict):
                break
            section[p] = section = dict(section[p])
        else:
            section.pop(name, None)
    if isinstance(out.get("model"), dict):
        out["model"] = _upgrade_matching(upgrade_reg_layout(upgrade_init_layout(out["model"])))
    if defaults is not None:
        default_dict = json.loads(defaults.model_dump_json())
        filled = deep_merge(default_dict, regroup_fields(out, default_dict))
        try:
            out = json.loads(type(defaults).model_validate(filled).model_dump_json())
        except ValidationError:
            pass
    return out


def read_config_json(path: Path, trust_edits: bool = False) -> tuple[str, dict]:
    """(method name, raw config dict) of a saved run; never executes code.

    The checksum written with the config must be present and match, unless
    ``trust_edits`` (the CLIs' ``--trust-edited-config``): a config edited by hand,
    or stripped of its checksum, is refused by default."""
    from ..errors import DataError
    from ..runtime.io import CHECKSUM_KEY, json_checksum, read_json

    payload = read_json(path, verify=False)
    signed = payload.get(CHECKSUM_KEY)
    if not trust_edits and signed is not None and signed != json_checksum(payload):
        raise DataError(
            f"{path}: checksum mismatch (truncated, corrupt or edited file); pass --trust-edited-config to use it anyway"
        )
    if payload.get("schema_version") != SCHEMA_VERSION:
        raise DataError(
            f"{path}: config schema version {payload.get('schema_version')} is not {SCHEMA_VERSION}"
        )
    if not trust_edits and signed is None:
        raise DataError(f"{path}: no checksum (edited by hand?); pass --trust-edited-config to use it anyway")
    cfg = payload.get("config")
    if not isinstance(cfg, dict) or "method" not in cfg:
        raise DataError(f"{path}: no method in the saved config")
    return cfg["method"], upgrade_saved_config(cfg)
