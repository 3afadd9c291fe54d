"""The run configuration every training command takes (:class:`TrainConfig`, the command-line
contract) and which of its fields are the experiment (:func:`experiment_fields`). Torch-free.

A method's config is a subclass of :class:`TrainConfig` whose ``model`` field holds the
method-specific part (a :class:`~splat_framework.config.model.ModelConfig`), its ``strategy`` the
densification and its ``optim`` the learning rates the method reads.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import tyro
from pydantic import Field

from .base import MAX_STEPS, MAX_VIEWS, RUN_OPTION, Device, Interval, Positive, SplatConfig, Steps
from .data import PhotoPosesConfig, ResolvedData
from .model import GaussianModelConfig, OptimConfig
from .strategy import DensifyConfig, RegisteredStrategies
from .address import LOOPBACK, Port


class CameraRefineConfig(SplatConfig):
    """Joint refinement of the training cameras' poses while the scene trains (nerfstudio's camera
    optimizer, BARF's pose corrections): each training view but the first gets a rotation and a
    translation correction of its own, optimised with the scene by Adam."""

    mode: Literal["auto", "on", "off"] = "off"
    """off (the default: on fern's estimated poses it gained nothing, see docs/decisions.md); auto: on where the training poses were estimated from the training photos themselves (--train-poses, or --data a folder of photos or a video); on: always."""
    lr_rotation: Positive = 1e-3
    """Adam's initial step of each view's rotation correction (radians); the translation's is this times the scene radius; both decay exponentially to 1 % over the run."""
    focal: bool = True
    """Also refine one focal-length factor shared by the training views (poses estimated from a few photos get the focal length a few per cent wrong: fern's 3 photos, 4 % long); its step is lr_rotation on the factor's logarithm."""


class TrainConfig(SplatConfig):
    """Options every training command accepts (the command-line contract)."""

    method: tyro.conf.Suppress[str] = "3dgs"
    """Method name (set by the subcommand)."""
    data: str = "synthetic/forward"
    """Dataset folder, or a folder of your own photos or a video (posed first, see --photos.*; then every photo trains unless --views says otherwise); a relative path that does not exist is looked up under $SPLAT_DATA; synthetic/forward and synthetic/object are generated on first use."""
    format: Literal["auto", "llff", "blender", "dtu", "transforms", "colmap"] = "auto"
    """Dataset format; auto detects it from the folder's contents (transforms: a nerfstudio or instant-ngp transforms.json)."""
    views: Annotated[int, Field(ge=1, le=MAX_VIEWS)] | Literal["all"] | None = None
    """Number of training views (few-shot split rules of the dataset), or all (every view but the held-out test views). Default: the format's, settled when the run starts and recorded in config.json: 3 on LLFF, Blender and DTU (the papers' few-shot setting), all on COLMAP and transforms.json scenes and your own photos (every 8th held out for testing beyond 8 photos); --resume keeps the run's."""
    downscale: Positive | None = None
    """Image downscale factor (default: the dataset's protocol, e.g. 8 for LLFF, 2 for Blender)."""
    train_poses: Path | None = None
    """Pose file (JSON) whose cameras replace the training views' poses and intrinsics; test views keep the dataset's (the benchmarks' --poses estimated protocol: poses from SfM on the training photos alone, aligned to the dataset's frame; see splat_framework.data.pose_file)."""
    photos: PhotoPosesConfig = Field(default_factory=PhotoPosesConfig)
    """Pose estimation when --data is a folder of photos or a video (cached in $SPLAT_CACHE/photos, keyed by the photos' contents and these options)."""
    resolved_data: Annotated[tyro.conf.Suppress[ResolvedData | None], RUN_OPTION] = None
    """The dataset as the run resolved it (absolute folder, train and test image names), recorded in config.json so that eval, render, view and export work from any folder and shell."""
    camera_refine: CameraRefineConfig = Field(default_factory=CameraRefineConfig)
    """Refine the training cameras' poses (and focal length) with the scene."""
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
    """Continue the run in --output from its last good checkpoint; without --output, the one unfinished run (no metrics.json) of this method on this --data under outputs/ (none, or several: refused, naming them)."""
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
    """Compile the rasterizer's compositing kernels, for training and for rendering this run later: on a CPU the native C++ kernels, elsewhere (or where they cannot be built) torch.compile'd ones (built once per machine and kept under $SPLAT_CACHE; eager fallback on any failure; SPLAT_COMPILE=0/1 overrides)."""
    model: GaussianModelConfig = Field(default_factory=GaussianModelConfig)
    """Model options."""
    strategy: RegisteredStrategies = Field(default_factory=DensifyConfig)
    """Densification options (the strategy's kind is the method's or the variant's; --strategy.kind KIND picks another registered one, with its defaults)."""
    optim: OptimConfig = Field(default_factory=OptimConfig)
    """Learning rates."""

    @property
    def total_steps(self) -> int:
        return self.steps if self.steps is not None else self.default_steps


def experiment_fields(config_cls: type[SplatConfig]) -> set[str]:
    """Top-level fields of ``config_cls`` that define the experiment: all but those marked :data:`RUN_OPTION`."""
    return {name for name, info in config_cls.model_fields.items() if not any(m is RUN_OPTION for m in info.metadata)}
