"""Modules that moved into wings keep their old import paths for one release, with a warning."""

import importlib
import sys

import pytest

from splat_framework._moved import MOVED


@pytest.mark.parametrize("old", sorted(MOVED))
def test_old_module_path_is_the_moved_module_and_warns(old, monkeypatch):
    new = importlib.import_module(f"splat_framework.{MOVED[old]}")
    monkeypatch.delitem(sys.modules, f"splat_framework.{old}", raising=False)
    with pytest.warns(DeprecationWarning, match=f"splat_framework.{old} moved to splat_framework.{MOVED[old]};"):
        moved = importlib.import_module(f"splat_framework.{old}")
    assert moved is new
    assert new.__spec__.name == new.__name__  # the module keeps its own identity


@pytest.mark.parametrize("wing, module, name", [
    ("evaluation", "held_out", "evaluate"), ("evaluation", "pictures", "write_png"), ("evaluation", "metrics", "depth_metrics"),
    ("export", "ply", "write_ply"), ("viewer", "scene_viewer", "Viewer")])
def test_old_names_of_a_module_that_became_a_wing(wing, module, name):
    package = importlib.import_module(f"splat_framework.{wing}")
    with pytest.warns(DeprecationWarning, match=f"moved to splat_framework.{wing}.{module}.{name}"):
        value = getattr(package, name)
    assert value is getattr(importlib.import_module(f"splat_framework.{wing}.{module}"), name)
    with pytest.raises(AttributeError):
        package.no_such_name
