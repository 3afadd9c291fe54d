"""The plugin's tests drive the ``splat-*`` commands with :mod:`splat_framework.testing`, on a built-in
tiny scene in a cache of their own. They need the plugin installed (``pip install -e .``): the
commands find its method, strategy and start through its entry points."""

from importlib.metadata import entry_points

import pytest

from splat_framework.testing import cli_env, tiny_scene


@pytest.fixture(scope="session")
def splat(tmp_path_factory):
    """(the commands' environment: a private ``SPLAT_CACHE`` holding forward-tiny, eager kernels; the ``--data`` of forward-tiny)."""
    if "flat-3dgs" not in {ep.name for ep in entry_points(group="splat_framework.methods")}:
        pytest.fail("splat-example-plugin is not installed (its entry points are not registered): pip install -e .")
    cache = tmp_path_factory.mktemp("splatcache")
    return cli_env(SPLAT_CACHE=cache, SPLAT_COMPILE="0"), tiny_scene(cache)
