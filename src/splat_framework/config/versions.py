"""``config.json``'s schema versions and the one ordered list of steps that upgrades a saved
config from each version to the next (torch-free; never executes code from the file).

A change of the saved layout (a field renamed, moved or regrouped) bumps :data:`SCHEMA_VERSION`
and adds one step to :data:`UPGRADES`, keyed by the version it upgrades from: step N takes a
config dict of version N to version N + 1, reading only the fields of version N. A field added
with a default needs no step (a saved config without it takes the method's default), unless that
default changes what an old run did: then the step writes the value the old runs had (version 3).

Versions:

1. Every layout written before the layout was versioned (every ``config.json`` until schema 2 says
   ``"schema_version": 1``), and a file that names no version. Version 1 covers several layouts,
   so its one step checks for the old fields each repair replaces: SCGaussian's ray rule in
   ``strategy`` and ``steps_per_view`` (:data:`MOVED_FIELDS`), ``model.init`` as a string
   (:func:`init_layout`), flat regularisers in ``model`` (:func:`reg_layout`), the fields of the
   model/optim split (:func:`regroup_fields`), one flat ``matching`` block whose ``matcher`` named
   the matcher, holding every matcher's options (:func:`match_layout`).
2. The layout before validation views: ``resolved_data.source`` (the fields a run's recorded
   dataset was resolved from) has no ``eval_split``; every such run scored its test views
   (:func:`from_version_2`).
3. The layout before the total match budget: a ``matching`` block has no ``max_total_matches``, and
   every pair kept up to ``max_matches`` whatever the number of pairs (:func:`from_version_3`).
4. The layout before coarse steps: there is no ``coarse_steps``, and every run trained every
   iteration at the images' own size (:func:`from_version_4`).
5. The layout before ``--test-every``: ``resolved_data.source`` has no ``test_every``; every such
   run held out its format's test views (:func:`from_version_5`).
6. Today's layout.
"""

from __future__ import annotations

import json
from typing import Callable

from pydantic import ValidationError

from .init import FALLBACK_POINTS
from .merge import deep_merge
from .model import GaussianModelConfig, ModelConfig, OptimConfig, RegularisersConfig
from .train import TrainConfig

SCHEMA_VERSION = 6
"""Version of the ``config.json`` layout this build writes (see the module docstring)."""

UNVERSIONED = 1
"""The version of a saved config that names none."""

#: Fields that version 1 may hold but the configs no longer have (dotted paths). SCGaussian's
#: never-prune flag and child rule moved from DensifyConfig into its own strategy class (their values
#: were fixed by the method, never a user's choice); ``steps_per_view`` (scgaussian: max(1000, 250 x
#: views) iterations) became ``schedule_views`` (1000 x views / 4 beyond 4 views), which gives the same
#: count for every view count it was used with.
MOVED_FIELDS = ("strategy.never_prune_key", "strategy.child_defaults", "steps_per_view")

#: Fields every method's ``model`` and ``optim`` held before the model config was split into what
#: every model reads and what the 3DGS model reads (issue 41): a method whose config no longer has
#: one never read it (Scaffold-GS, Octree-GS), so an old run's value of it is dropped.
OLD_SHARED_FIELDS = {
    "model": tuple(n for n in GaussianModelConfig.model_fields if n not in ModelConfig.model_fields),
    "optim": tuple(OptimConfig.model_fields),
}

REGULARISER_FIELDS = tuple(RegularisersConfig.model_fields)
"""The regularisers' field names (version 1 may hold them flat in ``model``)."""


def drop_moved_fields(cfg: dict) -> dict:
    """A copy of ``cfg`` without the :data:`MOVED_FIELDS`."""
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
    return out


def init_layout(model: dict) -> dict:
    """A model config (dict) written before ``model.init`` was a tagged union, in the union's layout.

    Then ``init`` was "random" or "frustum" and ``init_num_points`` its count; a ``-triang`` method
    (``max_reprojection_px`` and ``matching`` beside them, and for Scaffold/Octree-GS
    ``start_from = "triangulated"``) started from triangulated matches and fell back to
    ``max(init_num_points, FALLBACK_POINTS)`` points placed by ``init``. A model config without
    a string ``init`` is returned as it is."""
    if not isinstance(model.get("init"), str):
        return model
    out = dict(model)
    placed = {"kind": out.pop("init")}
    if "init_num_points" in out:
        placed["num_points"] = out.pop("init_num_points")
    start = out.pop("start_from", "triangulated")  # Scaffold/Octree-GS named their start; 3dgs-triang had none
    if "max_reprojection_px" in out:  # the triangulation's fields (Scaffold/Octree-GS carried them whatever their start)
        prior = {"matching": out.pop("matching", {}), "max_reprojection_px": out.pop("max_reprojection_px")}
        if start == "triangulated":
            count = max(int(placed.get("num_points", FALLBACK_POINTS)), FALLBACK_POINTS)
            placed = {"kind": "triangulated", **prior, "fallback": placed | {"num_points": count}}
    out["init"] = placed
    return out


def reg_layout(model: dict) -> dict:
    """A model config (dict) written before the regularisers were a group, with its flat regulariser
    fields (:data:`REGULARISER_FIELDS`) moved into ``reg``. A model config that has a ``reg``
    already, or none of those fields, is returned as it is."""
    flat = {k: model[k] for k in REGULARISER_FIELDS if k in model}
    if "reg" in model or not flat:
        return model
    return {k: v for k, v in model.items() if k not in flat} | {"reg": flat}


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


def match_layout(model: dict) -> dict:
    """``model`` (a saved model config dict) with its matching blocks (the prior's, the triangulated
    start's) in today's layout (:func:`upgrade_match_layout`)."""
    out = dict(model)
    if "matching" in out:
        out["matching"] = upgrade_match_layout(out["matching"])
    if isinstance(out.get("init"), dict) and "matching" in out["init"]:
        out["init"] = {**out["init"], "matching": upgrade_match_layout(out["init"]["matching"])}
    return out


def from_version_1(cfg: dict, defaults: dict) -> dict:
    """Version 1 -> 2: the repairs of the layouts version 1 covers, each a no-op on a config that
    has none of the old fields it replaces (see the module docstring)."""
    out = drop_moved_fields(cfg)
    if isinstance(out.get("model"), dict):
        out["model"] = match_layout(reg_layout(init_layout(out["model"])))
    return regroup_fields(out, defaults)


def from_version_2(cfg: dict, defaults: dict) -> dict:
    """Version 2 to 3: a recorded dataset's source gains ``eval_split`` "test" (what every run of
    version 2 scored), so the record still resolves the run's config."""
    record = cfg.get("resolved_data")
    if isinstance(record, dict) and isinstance(record.get("source"), dict):
        source = {**record["source"], "eval_split": record["source"].get("eval_split", "test")}
        cfg = {**cfg, "resolved_data": {**record, "source": source}}
    return cfg


def without_match_budget(value):
    """``value`` (part of a saved config) with ``max_total_matches`` 0 in every matching block (a dict
    holding ``max_matches``) that names none."""
    if isinstance(value, list):
        return [without_match_budget(v) for v in value]
    if not isinstance(value, dict):
        return value
    out = {k: without_match_budget(v) for k, v in value.items()}
    if "max_matches" in out and "max_total_matches" not in out:
        out["max_total_matches"] = 0
    return out


def from_version_3(cfg: dict, defaults: dict) -> dict:
    """Version 3 to 4: every matching block gains ``max_total_matches`` 0 (no total budget: what
    every run of version 3 had), so an old run's prior is rebuilt as it was trained."""
    return without_match_budget(cfg)


def from_version_4(cfg: dict, defaults: dict) -> dict:
    """Version 4 to 5: the config gains ``coarse_steps`` 0 (every iteration at the images' own size:
    what every run of version 4 did; SCGaussian's default is 500 since), so an old run resumes as it
    was trained."""
    return {**cfg, "coarse_steps": cfg.get("coarse_steps", 0)}


def from_version_5(cfg: dict, defaults: dict) -> dict:
    """Version 5 to 6: a recorded dataset's source gains ``test_every`` None (the format's own test
    views: what every run of version 5 held out), so the record still resolves the run's config."""
    record = cfg.get("resolved_data")
    if isinstance(record, dict) and isinstance(record.get("source"), dict):
        source = {**record["source"], "test_every": record["source"].get("test_every")}
        cfg = {**cfg, "resolved_data": {**record, "source": source}}
    return cfg


UPGRADES: dict[int, Callable[[dict, dict], dict]] = {
    1: from_version_1,
    2: from_version_2,
    3: from_version_3,
    4: from_version_4,
    5: from_version_5,
}
"""Version N -> the step taking a config dict of version N to N + 1, given the method's default
config (as a dict); ordered, one per version below :data:`SCHEMA_VERSION`."""


def version_problem(version) -> str | None:
    """Why a saved config of ``version`` cannot be read (one phrase), or None when it can."""
    if isinstance(version, int) and not isinstance(version, bool) and UNVERSIONED <= version <= SCHEMA_VERSION:
        return None
    if isinstance(version, int) and not isinstance(version, bool) and version > SCHEMA_VERSION:
        return (f"config schema version {version} is newer than this version of splat reads "
                f"({SCHEMA_VERSION}); use a newer splat")
    return f"config schema version {version!r} is not one splat wrote (1 to {SCHEMA_VERSION})"


def upgrade_saved_config(cfg: dict, version: int, defaults: TrainConfig) -> dict:
    """A saved config dict of schema ``version`` in today's layout: the :data:`UPGRADES` from
    ``version`` on, then the fields it lacks take the method's value in ``defaults`` (its default
    config, as ``config.json`` would hold them now). A dict that does not validate is returned as
    it is, for the caller to report; ``version`` must be readable (:func:`version_problem`)."""
    default_dict = json.loads(defaults.model_dump_json())
    out = dict(cfg)
    for step in range(version, SCHEMA_VERSION):
        out = UPGRADES[step](out, default_dict)
    try:
        return json.loads(type(defaults).model_validate(deep_merge(default_dict, out)).model_dump_json())
    except ValidationError:
        return out
