"""Fixtures the model tests share."""

from __future__ import annotations

import pytest

from splat_framework.data import DataManager, load_scene
from splat_framework.data.synthetic import generate_scene


@pytest.fixture(scope="module")
def dm(tmp_path_factory):
    """A tiny forward-facing built-in scene (48x36, 3 of 4 views as training views) on the CPU."""
    root = generate_scene("forward", tmp_path_factory.mktemp("scene") / "scene", width=48, height=36, n_views=4, seed=2)
    return DataManager(load_scene(root, views=3), device="cpu", seed=0)
