"""``--resume`` continues the same experiment: config.json and every checkpoint's own record are
compared with the command line's config, and a difference is refused in one line naming the
fields the user changed (a changed ``--steps`` is named once, not with the schedule it rescales)."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel

from ..config import (
    SCHEMA_VERSION,
    TrainConfig,
    config_payload,
    experiment_fields,
    flag_name,
    follows_schedule,
    read_config_json,
    upgrade_saved_config,
)
from ..config.versions import UNVERSIONED, version_problem
from ..data import DataError
from ..registry import MethodSpec
from .checkpoint import list_checkpoints

SHOWN_FIELDS = 4
"""Changed fields named in a refusal; the rest are counted."""


def experiment_record(config: TrainConfig) -> dict:
    """The experiment fields of a resolved config (what a resume may not change), as JSON values,
    with the config's ``schema_version`` (a record without one is version 1); every checkpoint
    carries it, covered by the checkpoint's checksum."""
    experiment = experiment_fields(type(config))
    fields = {k: v for k, v in config_payload(config)["config"].items() if k in experiment}
    return {"schema_version": SCHEMA_VERSION, **fields}


def check_saved_config(config: TrainConfig, spec: MethodSpec, run_dir: Path) -> bool:
    """``--resume`` continues the run's own experiment; returns whether config.json verified.

    config.json must carry its checksum, unedited, unless ``--trust-edited-config``; its
    experiment fields must equal the command line's. Without config.json a folder holding
    checkpoints is refused (unless trusted: the checkpoints' own records are then checked,
    :func:`check_checkpoint_record`); with nothing to continue the run simply starts."""
    path = run_dir / "config.json"
    trust = config.trust_edited_config
    if not path.is_file():
        if list_checkpoints(run_dir / "checkpoints") and not trust:
            raise DataError(
                f"{path}: missing, so --resume cannot check that the checkpoints are this experiment's; "
                "pass --trust-edited-config to check against the checkpoints' own record"
            )
        return False
    try:
        saved, verified = read_config_json(path), True
    except DataError:
        if not trust:
            raise
        saved, verified = read_config_json(path, trust_edits=True), False
    check_same_experiment(config, spec, path, saved.config, saved.version)
    return verified


def check_checkpoint_record(config: TrainConfig, spec: MethodSpec, path: Path, ck: dict, config_verified: bool) -> None:
    """A checkpoint continues only the experiment it recorded (DataError otherwise, never a
    fallback to an older file). A checkpoint written before checkpoints recorded their
    experiment is accepted only on the word of a verified config.json (``config_verified``)."""
    record = ck.get("experiment")
    if isinstance(record, dict):
        record = dict(record)
        version = record.pop("schema_version", UNVERSIONED)
        problem = version_problem(version)
        if problem:
            raise DataError(f"{path}: its experiment record's {problem}")
        check_same_experiment(config, spec, path, record, version)
    elif not config_verified:
        raise DataError(
            f"{path}: records no experiment (written by an older version) and config.json is missing or "
            "edited, so nothing shows that --resume continues the same experiment"
        )


def check_same_experiment(config: TrainConfig, spec: MethodSpec, path: Path, saved: dict, version: int) -> None:
    """DataError naming the fields (up to :data:`SHOWN_FIELDS`) in which ``saved`` (a config dict of
    schema ``version``) is another experiment than ``config``."""
    old = upgrade_saved_config(saved, version, spec.default_config())
    new = config_payload(config)["config"]
    if old.get("method") not in (None, new["method"]):
        raise DataError(f"{path}: the run was trained with method {old['method']!r}, not {new['method']!r}")
    experiment = experiment_fields(type(config))
    old = {k: v for k, v in old.items() if k in experiment}
    new = {k: v for k, v in new.items() if k in experiment}
    diff = user_changes(old, new, config)
    if diff:  # a resumed run must be the same experiment, or its results mean nothing
        shown = ", ".join(diff[:SHOWN_FIELDS]) + (
            f" and {len(diff) - SHOWN_FIELDS} more" if len(diff) > SHOWN_FIELDS else "")
        raise DataError(
            f"{path}: --resume cannot change the experiment: {shown} "
            f"(resume with the saved settings, or start a new run)"
        )


def user_changes(old: dict, new: dict, config: TrainConfig) -> list[str]:
    """``--flag (old -> new)`` for each experiment field that differs, named as the user types it
    (``--strategy.grow-grad2d``): a changed total of iterations is ``--steps (3000 -> 20)``, and the
    fields that follow from it (the internal ``default_steps`` and every iteration count the total
    rescales) are left out."""
    diff = config_diff(old, new)
    old_total, new_total = _total_steps(old), _total_steps(new)
    if old_total != new_total:
        derived = {"steps", "default_steps"} | steps_fields(config)
        diff = [("steps", old_total, new_total)] + [d for d in diff if d[0] not in derived]
    return [f"{flag_name(name)} ({a} -> {b})" for name, a, b in diff]


def _total_steps(payload: dict):
    steps = payload.get("steps")
    return steps if steps is not None else payload.get("default_steps")


def steps_fields(config: BaseModel, prefix: str = "") -> set[str]:
    """Dotted names of the fields of ``config`` (nested configs included) that ``--steps`` rescales:
    those that count iterations (``Steps`` and its kin) and the per-step factors (``StepFactor``)."""
    out = set()
    for name, info in type(config).model_fields.items():
        value = getattr(config, name)
        if isinstance(value, BaseModel):
            out |= steps_fields(value, f"{prefix}{name}.")
        elif follows_schedule(info):
            out.add(f"{prefix}{name}")
    return out


def config_diff(old: dict, new: dict, prefix: str = "") -> list[tuple[str, object, object]]:
    """``(dotted.field, old, new)`` for every leaf that differs between two config dicts, sorted."""
    out = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k), new.get(k)
        if isinstance(a, dict) and isinstance(b, dict):
            out += config_diff(a, b, f"{prefix}{k}.")
        elif a != b:
            out.append((f"{prefix}{k}", a, b))
    return out
