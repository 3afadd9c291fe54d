"""``config.json`` carries its schema version; old versions are upgraded by one ordered list of steps
(``config.versions.UPGRADES``), a newer one is refused in one line naming the file (issue 62, item 3)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cli_harness import run_cli
from splat_framework.config import (
    SCHEMA_VERSION,
    UPGRADES,
    config_payload,
    read_config_json,
    save_config,
    upgrade_saved_config,
)
from splat_framework.errors import DataError
from splat_framework.registry import get_method
from splat_framework.runtime.io import atomic_write_json

OLD = Path(__file__).parent / "old_init_configs"


def test_every_version_below_the_current_one_has_one_step():
    assert list(UPGRADES) == list(range(1, SCHEMA_VERSION))


def written_at(version: int, tmp_path: Path) -> list[Path]:
    """config.json files of schema ``version``: version 1's layouts before issue 41 (``old_init_configs``),
    and one holding version 2's layout, as every run wrote it until version 2 (also without a version
    at all); version 2's: a run's record of its dataset, resolved before ``eval_split`` existed;
    version 3's: an SCGaussian run whose matching prior had no total budget; version 4's: an SCGaussian
    run from before coarse steps; version 5's: a run's record of its dataset, resolved before
    ``test_every`` existed."""
    assert version in (1, 2, 3, 4, 5), "a new version needs its sample files here"
    if version == 5:
        payload = json.loads(json.dumps(config_payload(get_method("3dgs").default_config())))
        cfg = payload["config"]
        del cfg["test_every"]
        source = {k: cfg[k] for k in ("data", "format", "views", "downscale", "eval_split", "train_poses", "photos")}
        cfg["resolved_data"] = {"path": str(tmp_path), "train": ["a"], "test": ["b"], "train_poses": None, "source": source}
        atomic_write_json(tmp_path / "v5.json", {**payload, "schema_version": 5})
        return [tmp_path / "v5.json"]
    if version == 4:
        cfg = json.loads(json.dumps(config_payload(get_method("scgaussian").default_config())))
        del cfg["config"]["coarse_steps"]
        atomic_write_json(tmp_path / "v4.json", {**cfg, "schema_version": 4})
        return [tmp_path / "v4.json"]
    if version == 3:
        cfg = json.loads(json.dumps(config_payload(get_method("scgaussian").default_config())))
        del cfg["config"]["model"]["matching"]["max_total_matches"]
        atomic_write_json(tmp_path / "v3.json", {**cfg, "schema_version": 3})
        return [tmp_path / "v3.json"]
    today = json.loads(json.dumps(config_payload(get_method("scaffold-gs").default_config())))
    today["config"].pop("eval_split")
    if version == 2:
        cfg = today["config"]
        source = {k: cfg[k] for k in ("data", "format", "views", "downscale", "train_poses", "photos")}
        cfg["resolved_data"] = {"path": str(tmp_path), "train": ["a"], "test": ["b"], "train_poses": None, "source": source}
        atomic_write_json(tmp_path / "v2.json", {**today, "schema_version": 2})
        return [tmp_path / "v2.json"]
    files = sorted(OLD.glob("*.json"))
    for name, payload in (("today.json", {**today, "schema_version": 1}), ("unversioned.json", today["config"])):
        atomic_write_json(tmp_path / name, payload if name == "today.json" else {"config": payload})
        files.append(tmp_path / name)
    return files


@pytest.mark.parametrize("version", range(1, SCHEMA_VERSION))
def test_a_file_of_each_old_version_upgrades_to_the_current_config(version, tmp_path):
    """Upgraded, a file of an old version is a valid config of today's schema: written again (current
    version), it reads back as the same config, through no step."""
    for path in written_at(version, tmp_path):
        method, raw, found = read_config_json(path)
        assert found == version, path
        defaults = get_method(method).default_config()
        config = type(defaults).model_validate(upgrade_saved_config(raw, found, defaults))
        save_config(config, tmp_path / "again.json")
        _, again, now = read_config_json(tmp_path / "again.json")
        assert now == SCHEMA_VERSION and type(defaults).model_validate(again) == config, path
        if path.name == "today.json":  # a file already in version 2's layout: upgraded to itself
            assert config == type(defaults).model_validate(json.loads(path.read_text())["config"])
        if path.name == "v4.json":  # every iteration at the images' own size, as it was trained
            assert config.coarse_steps == 0 and get_method(method).default_config().coarse_steps == 500
        if path.name == "v3.json":  # its prior keeps every pair's matches, as it was trained
            assert config.model.matching.max_total_matches == 0 and config.model.matching.max_matches == 12000
        if config.resolved_data is not None:  # the record still names the run's data
            assert config.resolved_data.resolves(config) and config.eval_split == "test", path
            assert config.test_every is None, path


@pytest.mark.bad_input("a run's `config.json` written by a newer splat (a higher schema version)",
                       "exit 2, one line naming the file and its version; nothing written")
def test_a_file_of_a_newer_version_is_refused_naming_it(tmp_path):
    payload = config_payload(get_method("3dgs").default_config().model_copy(update={"steps": 2}))
    path = tmp_path / "config.json"
    atomic_write_json(path, {**payload, "schema_version": SCHEMA_VERSION + 1})  # signed: only the version is wrong
    with pytest.raises(DataError, match="newer") as refused:
        read_config_json(path)
    assert str(path) in str(refused.value) and "\n" not in str(refused.value)
    run_cli("train", "--load-config", path, code=2, match=(str(path), f"version {SCHEMA_VERSION + 1}", "newer"),
            watch=[tmp_path])
