"""Every plugin part a run uses is imported and checked when the run is configured, before any data
loads (``registry.resolve_parts``): a broken one is one line naming the plugin, the entry and the problem."""

from __future__ import annotations

import sys
import time
from typing import ClassVar, Literal

import pytest

from splat_framework.config import DensifyConfig, Kind
from splat_framework.entry_points import MODEL_BASE, Ref
from splat_framework.errors import PluginError

BAD_PARTS = '''"""A plugin whose every method names one broken part."""

from typing import ClassVar, Literal

from pydantic import Field

from splat_framework.plugin import (
    DensifyConfig, GaussianModelConfig, InitConfig, Kind, MethodSpec, TrainConfig, init_field, strategy_field,
)


class TypoStrategyConfig(DensifyConfig):
    """3DGS's densification, its class mistyped."""

    kind: Kind[Literal["typo-densify"]] = "typo-densify"
    """The strategy's tag."""
    strategy_class: ClassVar[str] = "bad_parts:NoSuchStrategy"


class TypoInitConfig(InitConfig):
    """A start whose function is mistyped."""

    kind: Kind[Literal["typo-grid"]] = "typo-grid"
    """The start's kind."""
    points_fn: ClassVar[str] = "bad_parts:no_such_points"


class TypoModelConfig(GaussianModelConfig):
    """3DGS's model options, with the mistyped start."""

    init: init_field(TypoInitConfig) = Field(default_factory=TypoInitConfig)
    """Initial points."""


class TypoStrategyTrainConfig(TrainConfig):
    """3DGS's options, with the mistyped strategy."""

    strategy: strategy_field(TypoStrategyConfig) = Field(default_factory=TypoStrategyConfig)
    """Densification options."""


class TypoInitTrainConfig(TrainConfig):
    """3DGS's options, with the mistyped start."""

    model: TypoModelConfig = Field(default_factory=TypoModelConfig)
    """Model options."""


class NotAPipeline:
    """Feeds nothing."""


def method(name, config=TrainConfig, **parts):
    return MethodSpec(name=name, description=f"broken: {name}", config_factory=lambda: config(method=name),
                      **{"model": "splat_framework.plugin:GaussianModel", **parts})


typo_model = method("typo-model", model="nosuch:M")
typo_pipeline = method("typo-pipeline", pipeline="bad_parts:Nope")
typo_strategy = method("typo-strategy", TypoStrategyTrainConfig)
typo_points = method("typo-points", TypoInitTrainConfig)
not_a_pipeline = method("not-a-pipeline", pipeline="bad_parts:NotAPipeline")
not_a_model = method("not-a-model", model="bad_parts:TypoModelConfig")

ENTRY_POINTS = {"splat_framework.methods": {
    spec.name: f"bad_parts:{attr}" for attr, spec in dict(globals()).items() if isinstance(spec, MethodSpec)
}, "splat_framework.photo_matchers": {"typo-matcher": "bad_parts:no_such_match"}}
'''

class BrokenConfig(DensifyConfig):
    """3DGS's densification, its class missing (a kind another plugin registers)."""

    kind: Kind[Literal["broken"]] = "broken"
    """The strategy's tag."""
    strategy_class: ClassVar[str] = "splat_framework.model.strategy:NoSuchStrategy"


PHOTO_MATCHER = ("photo matcher 'typo-matcher' of SPLAT_PLUGINS module 'bad_parts' (bad_parts:no_such_match) cannot be "
                 "imported (AttributeError: module 'bad_parts' has no attribute 'no_such_match')")
CASES = {  # method -> (the entry, the problem)
    "typo-model": ("method 'typo-model': model 'nosuch:M'",
                   "does not import (ModuleNotFoundError: No module named 'nosuch')"),
    "typo-pipeline": ("method 'typo-pipeline': pipeline 'bad_parts:Nope'",
                      "does not import (AttributeError: module 'bad_parts' has no attribute 'Nope')"),
    "typo-strategy": ("method 'typo-strategy': strategy.strategy_class of TypoStrategyConfig 'bad_parts:NoSuchStrategy'",
                      "does not import (AttributeError: module 'bad_parts' has no attribute 'NoSuchStrategy')"),
    "typo-points": ("method 'typo-points': model.init.points_fn of TypoInitConfig 'bad_parts:no_such_points'",
                    "does not import (AttributeError: module 'bad_parts' has no attribute 'no_such_points')"),
    "not-a-pipeline": ("method 'not-a-pipeline': pipeline 'bad_parts:NotAPipeline'",
                       "is not a Pipeline subclass (it is the class NotAPipeline)"),
    "not-a-model": ("method 'not-a-model': model 'bad_parts:TypoModelConfig'",
                    "is not a GaussianModel subclass (it is the class TypoModelConfig)"),
}


@pytest.fixture
def bad_parts(tmp_path, monkeypatch):
    """``SPLAT_PLUGINS=bad_parts``: a module on the path declaring the methods of :data:`CASES`."""
    (tmp_path / "bad_parts.py").write_text(BAD_PARTS)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("SPLAT_PLUGINS", "bad_parts")
    monkeypatch.delitem(sys.modules, "bad_parts", raising=False)
    import torch._dynamo  # noqa: F401  (PyTorch and its compiler loaded in the set-up: `starting`'s 3-6 s)

    import splat_framework.engine.trainer  # noqa: F401

    yield
    sys.modules.pop("bad_parts", None)


@pytest.mark.parametrize("method", sorted(CASES))
@pytest.mark.bad_input("a plugin's `model`, `pipeline`, `strategy_class` or init `points_fn` mistyped, a pipeline that "
                       "is not a Pipeline subclass, a model that is not a GaussianModel",
                       "exit 2, one line naming the plugin and the entry, before any data loads")
def test_a_broken_plugin_part_is_one_line_before_the_data_loads(method, bad_parts, capsys):
    """``splat-train METHOD``: the part is imported and checked once the command line is parsed; its
    failure names the plugin (the SPLAT_PLUGINS module and its entry), the field and the problem,
    before "loading data", within 5 s."""
    from splat_framework.cli.train import main

    entry, problem = CASES[method]
    t0 = time.perf_counter()
    with pytest.raises(PluginError) as e:
        main([method, "--data", "synthetic/forward-tiny", "--steps", "10", "--no-progress"])
    seconds = time.perf_counter() - t0
    assert str(e.value) == f"SPLAT_PLUGINS module 'bad_parts' (bad_parts:{method.replace('-', '_')}): {entry} {problem}"
    assert PluginError.cli_exit_code == 2  # cli.common.run_cli prints "error: " and the line, and exits 2
    assert "loading data" not in "".join(capsys.readouterr())
    assert seconds < 5


@pytest.mark.bad_input("`--photos.matcher` naming a plugin's photo matcher that does not import (`--data` a folder of photos)",
                       "exit 2, one line naming the matcher and its plugin, before the photos are posed")
def test_a_broken_photo_matcher_is_one_line_before_the_photos_are_posed(bad_parts, tmp_path, capsys):
    """``--data`` a folder of photos posed with a plugin's matcher (``--photos.matcher``) that does not
    import: one line naming it and its plugin, before the photos are posed."""
    import numpy as np
    from PIL import Image

    from splat_framework.cli.train import main
    from splat_framework.errors import DataError

    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(2):
        Image.fromarray(np.full((16, 16, 3), 40 * i, np.uint8)).save(photos / f"{i}.png")
    with pytest.raises(DataError) as e:
        main(["3dgs", "--data", str(photos), "--photos.matcher", "typo-matcher", "--no-progress"])
    assert str(e.value) == PHOTO_MATCHER
    assert "poses" not in "".join(capsys.readouterr())  # neither estimated nor read from the cache


def test_an_unknown_photo_matcher_names_the_flag_it_was_given_by(tmp_path):
    """splat-train's photo matcher is ``--photos.matcher`` (splat-process's is ``--matcher``): an
    unknown name is one line naming that flag and the choices."""
    import numpy as np
    from PIL import Image

    from splat_framework.cli.train import main
    from splat_framework.errors import DataError

    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(2):
        Image.fromarray(np.full((16, 16, 3), 40 * i, np.uint8)).save(photos / f"{i}.png")
    with pytest.raises(DataError, match=r"^--photos\.matcher must be one of auto, sift, .*got 'nope'$"):
        main(["3dgs", "--data", str(photos), "--photos.matcher", "nope", "--no-progress"])


def test_a_part_is_checked_for_its_kind():
    """``Ref.load``: a class of the base named, or any callable for a function; else one line."""
    from splat_framework.model.gaussians import GaussianModel

    assert Ref("splat_framework.model.gaussians:GaussianModel", MODEL_BASE, "model").load() is GaussianModel
    assert Ref("splat_framework.model.init:box_points", "", "points_fn").load().__name__ == "box_points"
    for path, problem in (("splat_framework.matching.prior:MIN_TRIANGULATED", "is not a function (it is a int)"),
                          ("splat_framework.model.init:box_points", "is not a GaussianModel subclass (it is a function)"),
                          ("no-colon", "does not import (ValueError: 'no-colon' is not a 'module:Name' path)")):
        base = "" if "MIN" in path else MODEL_BASE
        with pytest.raises(PluginError, match=r"^package p: x ") as e:
            Ref(path, base, "x", "package p").load()
        assert str(e.value).endswith(problem) and "\n" not in str(e.value)


def test_a_kind_registered_by_a_plugin_is_named_by_that_plugin(monkeypatch):
    """A strategy kind another plugin registered (``--strategy.kind``) with a broken ``strategy_class``:
    the line names the plugin that registered the kind, not the method's."""
    import re

    from splat_framework import registry
    from splat_framework.engine import parts as run_parts
    from splat_framework.entry_points import STRATEGY_ENTRY_POINT_GROUP, Entry

    spec = registry.get_method("3dgs")
    config = spec.default_config()
    config = config.model_copy(update={"strategy": BrokenConfig()})
    declared = Entry("broken", f"{__name__}:BrokenConfig", STRATEGY_ENTRY_POINT_GROUP, "package broken-kinds")
    monkeypatch.setattr(run_parts, "registered", lambda group: [declared] if group == STRATEGY_ENTRY_POINT_GROUP else [])
    with pytest.raises(PluginError, match=rf"^package broken-kinds \({re.escape(__name__)}:BrokenConfig\): method '3dgs': "
                       r"strategy\.strategy_class of BrokenConfig 'splat_framework\.model\.strategy:NoSuchStrategy' "
                       r"does not import \(AttributeError: "):
        run_parts.resolve_parts(spec, config)
    parts = run_parts.resolve_parts(spec, spec.default_config())  # the method's own parts, loaded
    assert parts.model.__name__ == "GaussianModel" and parts.pipeline.__name__ == "Pipeline"
    assert parts.by_field["strategy"].__name__ == "DefaultStrategy" and parts.by_field["model.init"].__name__ == "box_points"


def test_the_command_exits_2_with_the_line(tmp_path):
    """Through a new process: exit 2, the one line, nothing of the data."""
    import os

    from cli_harness import cli_env, run_cli

    (tmp_path / "bad_parts.py").write_text(BAD_PARTS)
    path = os.pathsep.join(p for p in (str(tmp_path), os.environ.get("PYTHONPATH")) if p)
    result = run_cli("train", "typo-strategy", "--data", "synthetic/forward-tiny", "--output", tmp_path / "run",
                     code=2, env=cli_env(PYTHONPATH=path, SPLAT_PLUGINS="bad_parts"),
                     match=("error: SPLAT_PLUGINS module 'bad_parts' (bad_parts:typo_strategy): " + " ".join(CASES["typo-strategy"]),))
    assert "loading data" not in result.stdout + result.stderr and not (tmp_path / "run").exists()
