"""``config.json``: the resolved config saved beside every run (schema version, checksum), and read
back without executing code (upgraded to today's layout by :mod:`.versions`). Torch-free."""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

from .train import TrainConfig
from .versions import SCHEMA_VERSION, UNVERSIONED, version_problem


def config_payload(config: TrainConfig) -> dict:
    """What ``config.json`` holds: the schema version and the resolved config."""
    return {"schema_version": SCHEMA_VERSION, "config": json.loads(config.model_dump_json())}


def save_config(config: TrainConfig, path: Path) -> None:
    """Write the resolved config as JSON with a schema version and a checksum (atomic)."""
    from ..runtime.io import atomic_write_json

    atomic_write_json(path, config_payload(config))


class SavedConfig(NamedTuple):
    """A run's ``config.json`` as written: its method, its config dict and that dict's schema version
    (``upgrade_saved_config(config, version, method_defaults)`` gives today's layout)."""

    method: str
    config: dict
    version: int


def read_config_json(path: Path, trust_edits: bool = False) -> SavedConfig:
    """The method, config dict and schema version of a saved run; never executes code.

    The checksum written with the config must be present and match, unless
    ``trust_edits`` (the CLIs' ``--trust-edited-config``): a config edited by hand,
    or stripped of its checksum, is refused by default. A file naming no schema version is
    version 1; one of a newer version than this build writes (or no version splat wrote) is a
    DataError naming the file."""
    from ..errors import DataError
    from ..runtime.io import CHECKSUM_KEY, json_checksum, read_json

    payload = read_json(path, verify=False)
    signed = payload.get(CHECKSUM_KEY)
    if not trust_edits and signed is not None and signed != json_checksum(payload):
        raise DataError(
            f"{path}: checksum mismatch (truncated, corrupt or edited file); pass --trust-edited-config to use it anyway"
        )
    version = payload.get("schema_version", UNVERSIONED)
    problem = version_problem(version)
    if problem:
        raise DataError(f"{path}: {problem}")
    if not trust_edits and signed is None:
        raise DataError(f"{path}: no checksum (edited by hand?); pass --trust-edited-config to use it anyway")
    cfg = payload.get("config")
    if not isinstance(cfg, dict) or "method" not in cfg:
        raise DataError(f"{path}: no method in the saved config")
    return SavedConfig(cfg["method"], cfg, version)
