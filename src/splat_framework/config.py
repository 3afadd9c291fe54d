"""Typed run configuration shared by every method.

Importing this module must stay cheap (no torch, no cv2): the CLIs build
their ``--help`` from these classes. Every field carries a docstring right
below it; tyro shows it as the flag's help.

A method's config is a subclass of :class:`TrainConfig` whose ``model`` field
holds the method-specific part. Variants (paper ablation rows) are a base
config plus a few overrides, see :func:`apply_overrides`. Fields whose value is
an iteration count are annotated with :data:`Steps`, so that ``--steps N``
can rescale the whole schedule proportionally.
"""

from __future__ import annotations

import json
import warnings
from functools import cache
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal, Union

import tyro
from pydantic import BeforeValidator, Field, SerializeAsAny, ValidationError

from .config_base import (  # noqa: F401  (re-exported: the config machinery's home is config_base)
    DEVICE_MARKER,
    MAX_GAUSSIANS,
    MAX_MATCHES,
    MAX_SCHEDULE,
    MAX_STEPS,
    MAX_VIEWS,
    RUN_OPTION,
    SHORTEN_ONLY,
    STEPS_MARKER,
    Device,
    Finite,
    Fraction,
    Interval,
    InvalidArguments,
    LearningRate,
    Marker,
    NonNegative,
    OptionalPeriod,
    Period,
    Positive,
    RampPeriod,
    SplatConfig,
    StartSteps,
    Steps,
    cli_parsing,
)
from .data_config import PhotoPosesConfig, ResolvedData
from .init_config import InitKinds, RandomInitConfig, upgrade_init_layout
from .viewer.serving import LOOPBACK, Port

SCHEMA_VERSION = 1
"""Version of the saved ``config.json`` layout; bump on incompatible change."""



class StrategyConfig(SplatConfig):
    """Base of the densification strategies' configs, each tagged by its ``kind``.

    Each subclass names its ``kind`` (a one-value Literal: the tag by which a saved
    config, a TOML variant, a sweep or ``--strategy.kind`` picks it) and its strategy
    class as ``"module:Class"`` in :attr:`strategy_class` (imported, with torch, only
    by :meth:`setup`). A kind registered in the entry-point group
    ``splat_framework.strategies`` (see :mod:`splat_framework.entry_points`) is accepted by
    every method whose config keeps :data:`RegisteredStrategies`; a method that
    accepts fewer kinds lists them with :func:`strategy_field`."""

    strategy_class: ClassVar[str] = ""
    """``"module:Class"`` of the :class:`~splat_framework.model.strategy.Strategy` built from this config."""
    kind: str
    """The strategy's tag."""
    enabled: bool = True
    """Run densification at all (False keeps the initial Gaussians only)."""

    def setup(self):
        """The :class:`~splat_framework.model.strategy.Strategy` this config describes: ``strategy_class(self)``."""
        if not self.strategy_class:
            raise NotImplementedError(f"{type(self).__name__}.strategy_class is not set")
        from .entry_points import load_object

        return load_object(self.strategy_class)(self)


def strategy_field(*configs: type[StrategyConfig]):
    """The annotation of a ``strategy`` field accepting only these :class:`StrategyConfig` kinds.

    A method whose strategy must not be swapped for any registered one (SCGaussian keeps the
    Gaussians of its matches) narrows its field, e.g.
    ``strategy: strategy_field(MyStrategyConfig, DensifyConfig) = Field(default_factory=MyStrategyConfig)``.
    The CLI shows the flags of the default's kind (no subcommand to type)."""
    if len(configs) == 1:
        return Annotated[configs[0], tyro.conf.AvoidSubcommands]
    return Annotated[Union[configs], Field(discriminator="kind"), tyro.conf.AvoidSubcommands]


@cache
def strategy_kinds() -> dict[str, type[StrategyConfig]]:
    """Every strategy kind a method accepts unless it narrows its field: ``default``
    (:class:`DensifyConfig`), then the ``splat_framework.strategies`` entry points (an entry that is
    not a :class:`StrategyConfig` of its own name's kind is left out with one warning)."""
    from .entry_points import STRATEGY_ENTRY_POINT_GROUP, load_entry_points

    kinds: dict[str, type[StrategyConfig]] = {"default": DensifyConfig}
    for name, cls in load_entry_points(STRATEGY_ENTRY_POINT_GROUP, "strategy").items():
        if not (isinstance(cls, type) and issubclass(cls, StrategyConfig)) or cls.model_fields["kind"].default != name:
            warnings.warn(f"strategy plugin '{name}' is not a StrategyConfig of kind '{name}'; ignored", stacklevel=2)
        elif name in kinds:
            warnings.warn(f"strategy kind '{name}' registered twice; keeping the first", stacklevel=2)
        else:
            kinds[name] = cls
    return kinds


def _registered_strategy(value: Any) -> Any:
    """``value`` (a dict or a config) as the :class:`StrategyConfig` of its registered kind."""
    kinds = strategy_kinds()
    kind = value.get("kind", "default") if isinstance(value, dict) else getattr(value, "kind", None)
    if kind not in kinds:
        raise ValueError(f"unknown strategy kind {kind!r} (registered: {', '.join(repr(k) for k in kinds)})")
    cls = kinds[kind]
    return value if type(value) is cls else cls.model_validate(value if isinstance(value, dict) else value.model_dump())


class DensifyConfig(StrategyConfig):
    """Adaptive density control of 3DGS (clone, split, prune, opacity reset)."""

    kind: tyro.conf.Suppress[Literal["default"]] = "default"
    """The strategy's tag."""
    prune_opa: Annotated[float, Field(ge=0, lt=1, allow_inf_nan=False)] = 0.005
    """Prune Gaussians whose opacity falls below this."""
    grow_grad2d: NonNegative = 0.0002
    """Grow Gaussians whose mean screen-space gradient (NDC units) exceeds this."""
    grow_scale3d: Positive = 0.01
    """Clone below / split above this largest scale, relative to the scene scale."""
    grow_scale2d: Positive = 0.05
    """Also split Gaussians whose screen radius / image size exceeds this (only before refine_scale2d_stop_iter)."""
    prune_scale3d: Positive = 0.1
    """After the first opacity reset, prune Gaussians larger than this (relative to the scene scale)."""
    prune_scale2d: Positive = 0.15
    """Prune Gaussians whose screen radius exceeds this fraction of the image size (until refine_scale2d_stop_iter)."""
    refine_scale2d_stop_iter: Steps = 0
    """Stop the 2D-size pruning after this iteration (0 = never use it)."""
    refine_start_iter: StartSteps = 500
    """First iteration at which densification runs (a longer schedule keeps it: see StartSteps)."""
    refine_stop_iter: Steps = 2500
    """Last iteration at which densification runs."""
    reset_every: OptionalPeriod = 3000
    """Reset opacities to 2*prune_opa every this many iterations (None: never; the 3D-size pruning, which starts after the first reset, then never runs either)."""
    opacity_decay: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] = 1.0
    """Multiply every opacity by this after each step from refine_start_iter on (Binocular3DGS, Han et al. NeurIPS 2024: 0.995, with no reset), so only Gaussians the views keep asking for stay opaque (1 = off)."""
    refine_every: Interval = 100
    """Densify every this many iterations (not rescaled by --steps, so short runs do not densify more often)."""
    pause_refine_after_reset: Steps = 0
    """Skip densification for this many iterations after an opacity reset."""
    absgrad: bool = False
    """Use the absolute-gradient criterion (AbsGS); raise grow_grad2d accordingly."""
    revised_opacity: bool = False
    """Use the revised opacity for cloned/split Gaussians (Rota Bulo et al. 2024)."""

    strategy_class: ClassVar[str] = "splat_framework.model.strategy:DefaultStrategy"


RegisteredStrategies = Annotated[
    SerializeAsAny[StrategyConfig], BeforeValidator(_registered_strategy), tyro.conf.AvoidSubcommands
]
"""The strategy kinds every method accepts unless it narrows them with :func:`strategy_field`:
``default`` (:class:`DensifyConfig`) and every kind of the ``splat_framework.strategies`` entry points."""


class OptimConfig(SplatConfig):
    """Learning rates of the Gaussian parameters (Adam, one optimizer per group)."""

    means_lr: LearningRate = 1.6e-4
    """Initial position learning rate, multiplied by the scene scale."""
    means_lr_final: LearningRate = 1.6e-6
    """Final position learning rate (exponential decay over the run), times the scene scale."""
    scales_lr: LearningRate = 5e-3
    """Log-scale learning rate."""
    quats_lr: LearningRate = 1e-3
    """Rotation learning rate."""
    opacities_lr: LearningRate = 5e-2
    """Opacity-logit learning rate."""
    sh0_lr: LearningRate = 2.5e-3
    """Base colour (SH degree 0) learning rate."""
    shN_lr: LearningRate = 2.5e-3 / 20
    """Higher SH coefficients learning rate."""


class GaussianModelConfig(SplatConfig):
    """The 3DGS Gaussian model."""

    init: InitKinds = Field(default_factory=RandomInitConfig)
    """Where the initial points come from (--model.init.kind: random, frustum, triangulated, sfm, ply)."""
    init_opacity: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] = 0.1
    """Initial opacity of every Gaussian."""
    init_scale: Positive = 1.0
    """Multiplier of the initial scale (mean distance to the 3 nearest neighbours)."""
    sh_degree: int = Field(3, ge=0, le=3)
    """Highest spherical-harmonics degree."""
    sh_degree_interval: RampPeriod = 500
    """Raise the active SH degree by one every this many iterations (a longer run keeps the interval, as the 3DGS reference raises it every 1000 iterations whatever the length; a shorter one compresses it)."""
    lambda_dssim: Fraction = 0.2
    """Weight of the D-SSIM term in the photometric loss."""
    backdrop_weight: NonNegative = 0.0
    """On scenes with an unlit backdrop (DTU's black studio background; see data.images.dark_backdrop_mask): weight of the mean rendered alpha over the backdrop, whose target colour is also set to black, so that it stays empty space, as the public SCGaussian and DNGaussian code do on DTU with weight 1 (0 = off, the default: on DTU scan37, 3 views, 1000 iterations, seed 0, weight 1 moved masked PSNR from 15.37 to 14.96 for scgaussian and from 9.37 to 9.52 for 3dgs)."""
    depth_smoothness: NonNegative = 0.0
    """Weight of the edge-aware smoothness of each training view's rendered depth (losses.depth_smoothness: |depth difference| of neighbouring covered pixels, relative to the mean depth, weighted by exp(-gamma * colour difference)); 0 = off."""
    depth_smoothness_gamma: NonNegative = 10.0
    """Edge sensitivity of depth_smoothness: a neighbour pair's weight is exp(-gamma * mean |colour difference|), colours in [0, 1]."""
    depth_mode: Literal["accumulated", "expected"] = "expected"
    """Depth reported in outputs and renders."""
    stereo_weight: NonNegative = 0.0
    """Weight of the binocular consistency (Binocular3DGS, Han et al. NeurIPS 2024; losses.stereo_consistency): the training view is rendered again from a camera shifted sideways, and that render, warped back with the disparity of the view's rendered depth, must match the photo (L1 over covered pixels); one more render per step while it is on; 0 = off (scgaussian with weight 1 on DTU scan37, 3 views, seed 0: 16.19 -> 16.03 masked PSNR, so not on by default)."""
    stereo_disparity: Positive = 0.05
    """Largest disparity of the stereo partner at the view's mean rendered depth, as a fraction of the image width (the shift is drawn uniformly up to it, either side), a rule in pixels so that it holds at any scene scale."""
    stereo_start: Fraction = 2 / 3
    """Fraction of the run after which the binocular consistency applies (Binocular3DGS: 20000 of 30000 iterations), once the depth is worth warping with."""
    anisotropy_weight: NonNegative = 0.0
    """Weight of the anisotropy regulariser (PhysGaussian; losses.scale_anisotropy: the mean excess of each Gaussian's largest-to-smallest scale ratio over max_anisotropy); 0 = off (scgaussian on DTU scan37, 3 views, seed 0, weight 1 at ratio 10: 16.19 -> 15.88 masked PSNR, so not on by default)."""
    max_anisotropy: Annotated[float, Field(ge=1, allow_inf_nan=False)] = 10.0
    """The scale ratio above which anisotropy_weight penalises a Gaussian."""
    drop_rate: Annotated[float, Field(ge=0, lt=1, allow_inf_nan=False)] = 0.0
    """DropGaussian (Park et al., CVPR 2025): each training step renders with every Gaussian dropped with this probability times the fraction of the run done (a ramp from 0), the kept ones' opacity divided by (1 - probability); evaluation renders all Gaussians; 0 = off."""

    def memory_per_point(self, bytes_per_gaussian: int) -> int:
        """Training memory of one initial point, in bytes (the memory plan's estimate, see
        ``memory_plan.plan_memory``): one Gaussian here; a model that decodes several Gaussians per
        point (anchors) says so."""
        return bytes_per_gaussian


class TrainConfig(SplatConfig):
    """Options every training command accepts (the command-line contract)."""

    method: tyro.conf.Suppress[str] = "3dgs"
    """Method name (set by the subcommand)."""
    data: str = "synthetic/forward"
    """Dataset folder, or a folder of your own photos or a video (posed first, see --photos.*; then every photo trains unless --views says otherwise); a relative path that does not exist is looked up under $SPLAT_DATA; synthetic/forward and synthetic/object are generated on first use."""
    format: Literal["auto", "llff", "blender", "dtu", "colmap"] = "auto"
    """Dataset format; auto detects it from the folder's contents."""
    views: Annotated[int, Field(ge=1, le=MAX_VIEWS)] | Literal["all"] = 3
    """Number of training views (few-shot split rules of the dataset), or all."""
    downscale: Positive | None = None
    """Image downscale factor (default: the dataset's protocol, e.g. 8 for LLFF, 2 for Blender)."""
    train_poses: Path | None = None
    """Pose file (JSON) whose cameras replace the training views' poses and intrinsics; test views keep the dataset's (the benchmarks' --poses estimated protocol: poses from SfM on the training photos alone, aligned to the dataset's frame; see splat_framework.data.pose_file)."""
    photos: PhotoPosesConfig = Field(default_factory=PhotoPosesConfig)
    """Pose estimation when --data is a folder of photos or a video (cached in $SPLAT_CACHE/photos, keyed by the photos' contents and these options)."""
    resolved_data: Annotated[tyro.conf.Suppress[ResolvedData | None], RUN_OPTION] = None
    """The dataset as the run resolved it (absolute folder, train and test image names), recorded in config.json so that eval, render, view and export work from any folder and shell."""
    test_pose_steps: int = Field(0, ge=0, le=MAX_STEPS)
    """Fit each test camera's pose to its photo by this many Adam steps, the model frozen, before the final scores (pose-free methods' protocol, as splat-eval --test-pose-steps); 0 = score the test poses as given."""
    steps: Annotated[int, Field(ge=1, le=MAX_STEPS)] | None = None
    """Total optimisation iterations; rescales the method's whole schedule proportionally (default: the method's)."""
    default_steps: tyro.conf.Suppress[Annotated[int, Field(ge=1, le=MAX_STEPS)]] = 3000
    """The method's own total iterations, which its schedule fields are written for."""
    schedule_views: tyro.conf.Suppress[Annotated[int, Field(ge=0, le=MAX_VIEWS)]] = 0
    """The number of training views the method's default schedule is written for: without --steps, a run of N > this views (an integer --views) trains default_steps x N / this iterations, its whole schedule rescaled as --steps would (0 = default_steps whatever N)."""
    output: Annotated[Path | None, RUN_OPTION] = None
    """Run folder (default outputs/<scene>/<method>/<timestamp>)."""
    seed: int = Field(0, ge=0, lt=2**32)
    """Random seed for everything (initialisation, view order, matching)."""
    device: Annotated[Device, RUN_OPTION] = "cpu"
    """Torch device: cpu, cuda, cuda:N, mps, ... (checked against what torch has before a run starts)."""
    resume: Annotated[bool, RUN_OPTION] = False
    """Continue the run in --output from its last good checkpoint."""
    overwrite: Annotated[bool, RUN_OPTION] = False
    """Allow writing into an existing non-empty --output folder."""
    trust_edited_config: Annotated[bool, RUN_OPTION] = False
    """With --resume: continue even though the run's config.json is missing, unsigned or edited by hand; the experiment recorded in the checkpoints themselves (covered by their checksum) must then match the command line."""
    eval_every: Annotated[Steps, RUN_OPTION] = 0
    """Evaluate the test views every this many iterations (0 = only at the end)."""
    checkpoint_every: Steps = 1000
    """Write a checkpoint every this many iterations (and always at the end)."""
    save_renders: Annotated[bool, RUN_OPTION] = True
    """Write test-view renders (render, ground truth, depth) into the run folder."""
    progress: Annotated[bool, RUN_OPTION] = True
    """Show the rich progress bar."""
    viewer: Annotated[bool, RUN_OPTION] = False
    """Open the web viewer (splat-view) while training, showing the model every viewer_every iterations; it stays open after training until Ctrl-C."""
    viewer_port: Annotated[Port, RUN_OPTION] = 8080
    """TCP port of the training viewer, 0..65535 (0 = any free port; a port in use: the next free one, said in one line)."""
    viewer_host: Annotated[str, RUN_OPTION] = LOOPBACK
    """Interface the training viewer listens on: 127.0.0.1, this machine only (default); any other address, e.g. 0.0.0.0 for every interface, lets other machines see the model, the photos' thumbnails and "Render with splat" (a warning says so)."""
    viewer_every: Annotated[Interval, RUN_OPTION] = 100
    """Send the model to the training viewer every this many iterations."""
    compile: Annotated[bool, RUN_OPTION] = True
    """Fuse the rasterizer's compositing kernels with torch.compile, for training and for rendering this run later (eager fallback on any failure; compiled kernels cached under $SPLAT_CACHE/inductor: about 40 s the first time on a 2-core CPU, seconds after; SPLAT_COMPILE=0/1 overrides). On real fern training steps on a 2-core CPU: 1.85-3.0x faster than eager (benchmarks/train_step.py)."""
    model: GaussianModelConfig = Field(default_factory=GaussianModelConfig)
    """Model options."""
    strategy: RegisteredStrategies = Field(default_factory=DensifyConfig)
    """Densification options (the strategy's kind is the method's or the variant's; --strategy.kind KIND picks another registered one, with its defaults)."""
    optim: OptimConfig = Field(default_factory=OptimConfig)
    """Learning rates."""

    @property
    def total_steps(self) -> int:
        return self.steps if self.steps is not None else self.default_steps


# ----------------------------------------------------------------- helpers
def _has_marker(info, marker: Marker) -> bool:
    return any(m is marker for m in info.metadata)


def experiment_fields(config_cls: type[SplatConfig]) -> set[str]:
    """Top-level fields of ``config_cls`` that define the experiment: all but those marked :data:`RUN_OPTION`."""
    return {name for name, info in config_cls.model_fields.items() if not any(m is RUN_OPTION for m in info.metadata)}


def scale_schedule(config: SplatConfig, factor: float) -> SplatConfig:
    """A copy of ``config`` with every :data:`Steps` field multiplied by ``factor`` (recursively),
    except that a :data:`StartSteps` or :data:`RampPeriod` field is only ever shortened (times
    ``min(factor, 1)``).

    The rule for starts follows the public 3DGS and SCGaussian code, which begin densification
    at iteration 500 whatever the run's length; measured on lego (8 views, 2000 iterations,
    seed 0) scgaussian's densification from 500 scored 23.53 against 23.18 from 1000 (its
    4-view schedule stretched in proportion). The same for the SH degree's interval, which
    the public code keeps at 1000 (stretched to 2000, lego never left degree 0): seeds 0-2,
    23.58 ± 0.08 -> 23.65 ± 0.08.
    """
    updates: dict[str, Any] = {}
    for name, info in type(config).model_fields.items():
        value = getattr(config, name)
        if isinstance(value, SplatConfig):
            updates[name] = scale_schedule(value, factor)
        elif _has_marker(info, STEPS_MARKER) and isinstance(value, int) and value > 0:
            f = min(factor, 1.0) if _has_marker(info, SHORTEN_ONLY) else factor
            updates[name] = max(1, int(round(value * f)))
    return config.model_copy(update=updates)


def resolve_steps(config: TrainConfig) -> TrainConfig:
    """The config with its total iterations settled and the schedule rescaled to fit them.

    The total is ``--steps`` when given, else ``default_steps``, scaled by
    views / ``schedule_views`` when the run has more training views than the
    method's schedule is written for (each view is then seen as often); a
    resolved config resolves to itself (so a resumed run sees the same schedule).
    """
    steps = config.steps
    if steps is None and config.schedule_views > 0 and isinstance(config.views, int) and config.views > config.schedule_views:
        steps = int(round(config.default_steps * config.views / config.schedule_views))
    if steps is None or steps == config.default_steps:
        return config
    scaled = scale_schedule(config, steps / config.default_steps)
    return scaled.model_copy(update={"default_steps": steps, "steps": steps})


def apply_overrides(config: SplatConfig, overrides: dict[str, Any]) -> SplatConfig:
    """A validated copy of ``config`` with nested ``overrides`` applied.

    ``overrides`` mirrors the config's nesting, e.g. ``{"model": {"use_rg": False}}``.
    Unknown keys raise ``pydantic.ValidationError`` naming the field.
    """
    return type(config).model_validate(deep_merge(config.model_dump(), overrides))


def deep_merge(a: dict, b: dict) -> dict:
    """``b`` merged into a copy of ``a``: nested dicts are merged key by key (unless ``b``'s names
    another ``kind``, see :func:`_same_kind`), any other value of ``b`` replaces ``a``'s. The one
    merge rule of configs, variants and sweeps."""
    out = {k: (deep_merge(v, {}) if isinstance(v, dict) else v) for k, v in a.items()}
    for k, v in b.items():
        out[k] = deep_merge(out[k], v) if isinstance(v, dict) and _same_kind(out.get(k), v) else v
    return out


def _same_kind(a, b: dict) -> bool:
    """Whether dict ``b`` edits dict ``a``; a ``b`` that names another ``kind`` (a discriminated
    union member, e.g. another strategy) replaces ``a`` instead, taking its own defaults."""
    return isinstance(a, dict) and b.get("kind", a.get("kind")) == a.get("kind")


def config_payload(config: TrainConfig) -> dict:
    """What ``config.json`` holds: the schema version and the resolved config."""
    return {"schema_version": SCHEMA_VERSION, "config": json.loads(config.model_dump_json())}


def save_config(config: TrainConfig, path: Path) -> None:
    """Write the resolved config as JSON with a schema version and a checksum (atomic)."""
    from .files.io import atomic_write_json

    atomic_write_json(path, config_payload(config))


#: Fields that config.json files of this schema may still hold but the configs no longer have
#: (dotted paths). SCGaussian's never-prune flag and child rule moved from DensifyConfig into its
#: own strategy class (their values were fixed by the method, never a user's choice);
#: ``steps_per_view`` (scgaussian: max(1000, 250 x views) iterations) became ``schedule_views``
#: (1000 x views / 4 beyond 4 views), which gives the same count for every view count it was used with.
MOVED_FIELDS = ("strategy.never_prune_key", "strategy.child_defaults", "steps_per_view")


def upgrade_saved_config(cfg: dict, defaults: TrainConfig | None = None) -> dict:
    """A copy of a saved config dict without the :data:`MOVED_FIELDS` (runs written before they moved),
    its ``model.init`` in today's layout (:func:`~splat_framework.init_config.upgrade_init_layout`).

    With ``defaults`` (the method's default config), fields added since the file
    was written take the method's default value (as ``config.json`` would hold
    them now); a dict that does not validate is returned as it is, for the
    caller to report."""
    out = dict(cfg)
    for path in MOVED_FIELDS:
        *parents, name = path.split(".")
        section = out
        for p in parents:
            if not isinstance(section.get(p), dict):
                break
            section[p] = section = dict(section[p])
        else:
            section.pop(name, None)
    if isinstance(out.get("model"), dict):
        out["model"] = upgrade_init_layout(out["model"])
    if defaults is not None:
        filled = deep_merge(json.loads(defaults.model_dump_json()), out)
        try:
            out = json.loads(type(defaults).model_validate(filled).model_dump_json())
        except ValidationError:
            pass
    return out


def read_config_json(path: Path, trust_edits: bool = False) -> tuple[str, dict]:
    """(method name, raw config dict) of a saved run; never executes code.

    The checksum written with the config must be present and match, unless
    ``trust_edits`` (the CLIs' ``--trust-edited-config``): a config edited by hand,
    or stripped of its checksum, is refused by default."""
    from .errors import DataError
    from .files.io import CHECKSUM_KEY, json_checksum, read_json

    payload = read_json(path, verify=False)
    signed = payload.get(CHECKSUM_KEY)
    if not trust_edits and signed is not None and signed != json_checksum(payload):
        raise DataError(
            f"{path}: checksum mismatch (truncated, corrupt or edited file); pass --trust-edited-config to use it anyway"
        )
    if payload.get("schema_version") != SCHEMA_VERSION:
        raise DataError(
            f"{path}: config schema version {payload.get('schema_version')} is not {SCHEMA_VERSION}"
        )
    if not trust_edits and signed is None:
        raise DataError(f"{path}: no checksum (edited by hand?); pass --trust-edited-config to use it anyway")
    cfg = payload.get("config")
    if not isinstance(cfg, dict) or "method" not in cfg:
        raise DataError(f"{path}: no method in the saved config")
    return cfg["method"], upgrade_saved_config(cfg)
