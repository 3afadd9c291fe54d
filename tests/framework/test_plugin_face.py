"""splat_framework.plugin: the one module plugin authors import from, resolved lazily."""

import subprocess
import sys

import pytest

import splat_framework.plugin as plugin


def test_importing_the_plugin_face_and_its_configs_imports_no_torch():
    code = (
        "import sys; from splat_framework.plugin import MethodSpec, TrainConfig, GaussianModelConfig, Steps; "
        "print('torch' in sys.modules)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"


@pytest.mark.parametrize("name", plugin.__all__)
def test_every_public_name_resolves_to_the_frameworks_object(name):
    from importlib import import_module

    value = getattr(plugin, name)
    if name in plugin._MODULES:
        assert value is import_module(plugin._MODULES[name])
    else:
        assert value is getattr(import_module(plugin._EXPORTS[name]), name)


def test_the_face_names_the_model_contract():
    from splat_framework.model.gaussians import GaussianModel
    from splat_framework.registry import MethodSpec

    assert plugin.GaussianModel is GaussianModel and plugin.MethodSpec is MethodSpec
    assert callable(plugin.ops.remove) and callable(plugin.rasterize)
    with pytest.raises(AttributeError, match="no attribute 'box_points'"):
        plugin.box_points  # internal names are not part of the face


def test_the_public_api_lists_the_contract_then_the_optional_services():
    """Two documented sections, every public name in one of them; the matching prior is a service;
    no helper that served one plugin's internals (the 3dgs baseline's config, the registered
    defaults, flag names, the schedule resolution) is public: ``baseline_schedule`` is the one call."""
    assert set(plugin.CONTRACT).isdisjoint(plugin.SERVICES)
    assert sorted(plugin.CONTRACT | plugin.SERVICES | plugin._MODULES) == plugin.__all__
    assert {"compute_match_set", "match_pairs", "MatchKinds"} <= set(plugin.SERVICES)
    assert {"GaussianModel", "Pipeline", "Strategy", "RunFacts", "rasterize", "baseline_schedule"} <= set(plugin.CONTRACT)
    assert not {"config_3dgs", "registered_defaults", "flag_name", "resolve_steps"} & set(plugin.__all__)
    for section in ("**The contract**", "**Optional services**"):
        assert section in plugin.__doc__
