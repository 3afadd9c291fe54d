"""No dead options: every flag a method's (or a variant's) ``--help`` shows is read by that method.

Reads are enumerated by instrumenting the configs' attribute access (``SplatConfig.__getattribute__``)
while the method trains a few steps end to end (set-up, steps, densification, checkpoint,
evaluation) on a tiny generated scene. The run switches on every opt-in regulariser and makes its
strategy act within those steps, so that flags read only while a term or an update runs are read.
Registered names whose flags are the same set as another's (a variant that changes only values)
share that name's run. Flags read in other phases than training are listed in
:data:`READ_ELSEWHERE`, each with where it is read.
"""

from __future__ import annotations

import sys
import typing

import pytest

from splat_framework.config import SplatConfig, apply_overrides, resolve_steps
from splat_framework.registry import discover_methods

READ_ELSEWHERE = {
    "viewer": "splat-train's command line: the training viewer (cli/train.py)",
    "viewer_port": "splat-train's command line: the training viewer",
    "viewer_host": "splat-train's command line: the training viewer",
    "viewer_every": "splat-train's command line: the training viewer",
    "trust_edited_config": "--resume only (Trainer._check_saved_config)",
}
"""Top-level flags read outside a fresh training run, and where."""

READ_IN_ANOTHER_MODE = {
    "model.cache_until": "scgaussian's single-stage schedule only (scgaussian-single-stage; the two-stage one "
                         "caches during its warm-up), as its help says",
    "photos.matcher": "--data naming a folder of photos or a video only (sfm/own_photos.py poses them), as its help says",
    "photos.mapper": "--data naming a folder of photos or a video only",
    "photos.frames": "--data naming a video only",
    "photos.pairs": "--data naming a folder of photos or a video only",
    "camera_refine.lr_rotation": "--camera-refine.mode on, or auto with estimated training poses (off by default), "
                                 "as its help says",
    "camera_refine.focal": "--camera-refine.mode on, or auto with estimated training poses",
    "coarse_scale": "--coarse-steps above 0 only (methods that leave it 0 train at full size), as its help says",
}
"""Flags read only in a mode that another value of the method's config picks, and which."""

DEVICE_FIELDS = {"device"}
"""Device fields are read by the device check before anything runs (``devices.device_fields``, a
walker: see :data:`WALKERS`), and by the code that places tensors there."""

WALKERS = {"scale_schedule", "device_fields"}
"""Functions that visit every field of a config (rescaling the schedule, checking device names):
their reads say nothing about the method reading a flag."""

ACTIVE = {
    "reg": {"backdrop_weight": 0.5, "depth_smoothness": 0.1, "stereo_weight": 0.1, "stereo_start": 0.0,
            "anisotropy_weight": 0.1, "drop_rate": 0.1, "multiview_weight": 0.1, "pseudo_view_weight": 0.1},
    "strategy": {
        "default": {"refine_start_iter": 1, "refine_every": 2, "refine_stop_iter": 100, "reset_every": 3,
                    "refine_scale2d_stop_iter": 100, "pause_refine_after_reset": 1},
        "anchor": {"start_stat": 0, "update_from": 1, "update_interval": 2, "update_until": 100},
        "octree": {"start_stat": 0, "update_from": 1, "update_interval": 2, "update_until": 100},
    },
}
"""Values that make every regulariser and the strategy act within the few steps of the run."""
STEPS = 6


def _suppressed(info) -> bool:
    """Whether the field is hidden from the command line (``tyro.conf.Suppress``)."""
    import tyro

    marker = typing.get_args(tyro.conf.Suppress[int])[1]
    return any(m is marker for m in info.metadata)


def shown_flags(config: SplatConfig, prefix: str = ""):
    """(dotted flag, config class, field) of every leaf field of ``config`` (its ``--help`` flags;
    the ``kind`` tags, which pick a config class, and suppressed fields left out)."""
    for name, info in type(config).model_fields.items():
        value = object.__getattribute__(config, "__dict__")[name]
        if isinstance(value, SplatConfig):
            yield from shown_flags(value, f"{prefix}{name}.")
        elif name != "kind" and not _suppressed(info):
            yield prefix + name, type(config), name


def _active(config):
    """``config`` resolved to :data:`STEPS` steps, with the regularisers on and its strategy acting
    within them (set after the schedule is rescaled, so they keep these values)."""
    config = resolve_steps(config.model_copy(update={"steps": STEPS}))
    kind = config.strategy.kind
    init = config.model.init
    few = {"fallback": {"num_points": 300}} if hasattr(init, "fallback") else {"num_points": 300} if hasattr(init, "num_points") else {}
    over = {"model": {"reg": ACTIVE["reg"], "init": few},
            "strategy": ACTIVE["strategy"].get(kind, ACTIVE["strategy"]["default"])}
    return apply_overrides(config, over)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from splat_framework.data.synthetic import generate_scene

    return generate_scene("forward", tmp_path_factory.mktemp("flags") / "scene", width=40, height=30, n_views=5, seed=3)


def _reads_of_a_run(config, spec) -> set[tuple[type, str]]:
    from splat_framework.engine.trainer import train

    reads: set[tuple[type, str]] = set()
    original = SplatConfig.__getattribute__

    def spy(self, name):
        if name in type(self).model_fields and sys._getframe(1).f_code.co_name not in WALKERS:
            reads.add((type(self), name))
        return original(self, name)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(SplatConfig, "__getattribute__", spy)
        train(config, spec=spec)
    return reads


METHODS = discover_methods()


def _groups():
    """{the first name of each distinct flag set: every registered name showing that set}."""
    groups: dict[frozenset, list[str]] = {}
    for name, spec in sorted(METHODS.items()):
        flags = frozenset(flag for flag, _, _ in shown_flags(spec.default_config()))
        groups.setdefault(flags, []).append(name)
    return {names[0]: names for names in groups.values()}


@pytest.mark.slow
@pytest.mark.parametrize("name, names", sorted(_groups().items()))
def test_every_flag_a_method_shows_is_read(name, names, scene, tmp_path):
    spec = METHODS[name]
    config = _active(spec.default_config()).model_copy(update={
        "data": str(scene), "output": tmp_path / "run", "progress": False, "save_renders": False})
    dense = {"matching": {"kind": "dense", "cache": False}}  # no weights, fast on 40x30 images; matched, not cached
    # (its flags are the dense matcher's: each matcher's config holds only what that matcher reads)
    if "matching" in type(config.model).model_fields:
        config = apply_overrides(config, {"model": dense})
    if "matching" in type(config.model.init).model_fields:
        config = apply_overrides(config, {"model": {"init": dense}})
    if "voxel_size" in type(config.model).model_fields:  # few neural Gaussians: a coarse grid, 2 per anchor
        config = apply_overrides(config, {"model": {"voxel_size": 0.5, "n_offsets": 2}})
    reads = _reads_of_a_run(config, spec)
    unread = [flag for flag, cls, field in shown_flags(config)
              if (cls, field) not in reads and flag not in {*READ_ELSEWHERE, *READ_IN_ANOTHER_MODE, *DEVICE_FIELDS}]
    assert not unread, f"{', '.join(names)}: flags shown in --help but never read: {unread}"
