"""The rules docs/extending.md states for plugin authors, each checked by the framework where it is
cheap: one line naming the class or entry that breaks it, not a failure far from the cause."""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from splat_framework.config import DensifyConfig, RunFacts, TrainConfig
from splat_framework.engine.train_state import TrainState
from splat_framework.model.gaussians import GaussianModel
from splat_framework.model.strategy import DefaultStrategy, unplain_state


@pytest.mark.parametrize("declaration", [
    'Literal["x"] = "x"', 'Annotated[Literal["x"], KIND] = "x"', 'tyro.conf.Suppress[Literal["x"]] = "x"',
    'Kind[Literal["x"]] = "y"', 'Kind[Literal["x", "y"]] = "x"', 'Kind[Literal["Big_Tag"]] = "Big_Tag"',
])
def test_a_kind_tag_is_declared_one_way(declaration):
    """Every kind-tagged config (init kinds, strategies) declares ``kind: Kind[Literal["tag"]] = "tag"``,
    a lower-case hyphenated tag; any other way is a TypeError naming the class when it is defined."""
    from typing import Annotated, Literal

    import tyro

    from splat_framework.config import InitConfig, Kind, StrategyConfig

    names = {"Annotated": Annotated, "Literal": Literal, "tyro": tyro, "Kind": Kind, "KIND": tyro.conf.arg(metavar="KIND")}

    def define(source: str, base: type) -> None:  # annotations evaluated at once, as in a module without the future import
        exec(compile(source, "<plugin>", "exec", dont_inherit=True), {**names, base.__name__: base})

    for base in (StrategyConfig, InitConfig):
        define(f"class Fine({base.__name__}):\n    kind: Kind[Literal['my-kind']] = 'my-kind'", base)
        with pytest.raises(TypeError, match=r"Odd\.kind: declare the tag as kind: Kind\[Literal\["):
            define(f"class Odd({base.__name__}):\n    kind: {declaration}", base)


def test_a_models_init_takes_rows():
    """``from_checkpoint`` builds every model with ``rows=``: an ``__init__`` without it is refused
    when the class is defined."""
    class Fine(GaussianModel):
        def __init__(self, config, run, scene_scale, points, colors, *, rows=None):
            super().__init__(config, run, scene_scale, points, colors, rows=rows)

    with pytest.raises(TypeError, match=r"NoRows\.__init__ takes no rows="):
        class NoRows(GaussianModel):
            def __init__(self, config, scene_scale, points, colors):
                super().__init__(config, scene_scale, points, colors)


def test_what_init_params_reads_is_set_before_super_init():
    class Late(GaussianModel):
        def __init__(self, config, run, scene_scale, points, colors, *, rows=None):
            super().__init__(config, run, scene_scale, points, colors, rows=rows)
            self.opacity = 0.5  # too late: init_params has run

        def init_params(self, points, colors):
            return super().init_params(points, colors) | {"extra": torch.nn.Parameter(points[:, :1] * self.opacity)}

    with pytest.raises(AttributeError, match=r"'opacity'.*set every attribute init_params and build_networks read "
                                             r"before calling super\(\).__init__\(\)"):
        config = TrainConfig(method="3dgs")
        Late(config.model, RunFacts.of(config), 1.0, torch.rand(8, 3), torch.rand(8, 3))


@pytest.mark.parametrize("value,named", [
    (np.float64(0.5), "'bad' (float64)"), ({"nested": [1, object()]}, "'bad' (object)"), (torch.float32, "'bad' (dtype)"),
])
def test_a_strategy_state_holds_tensors_and_plain_values_only(value, named):
    """Checkpoints are loaded with ``weights_only=True``: a strategy state value that could not be loaded
    back is refused when the checkpoint is written, naming the strategy and the key."""
    strategy = DefaultStrategy(DensifyConfig())
    state = strategy.initialize_state(2.0) | {"counts": [torch.zeros(3), 1, "a", None, {"k": 2.5}]}
    assert unplain_state(state) is None
    trainer = SimpleNamespace(strategy=strategy, strategy_state=state | {"bad": value})
    with pytest.raises(TypeError, match=re.escape(f"DefaultStrategy's state {named}: a checkpoint holds tensors and plain values")):
        TrainState.state_payload(trainer, 0)
