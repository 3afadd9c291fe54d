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

from .address import LOOPBACK, Port
from .base import FOLDED, MAX_STEPS, MAX_VIEWS, RUN_OPTION, Device, Interval, Positive, SplatConfig, StartSteps, Steps
from .data import PhotoPosesConfig, ResolvedData
from .model import GaussianModelConfig, OptimConfig
from .strategy import DensifyConfig, RegisteredStrategies


class CameraRefineConfig(SplatConfig):
    """Joint refinement of the training cameras' poses while the scene trains (nerfstudio's camera
    optimizer, BARF's pose corrections): each training view but the first gets a rotation and a
    translation correction of its own, optimised with the scene by Adam."""

    mode: Literal["auto", "on", "off"] = "off"
    """off; auto: on where the poses were estimated from the photos; on (see docs/decisions.md)."""
    lr_rotation: Positive = 1e-3
    """Initial step of the rotation corrections (radians; decays to 1 %)."""
    focal: bool = True
    """Also refine one focal-length factor shared by the training views."""


class TrainConfig(SplatConfig):
    """Options every training command accepts (the command-line contract)."""

    method: tyro.conf.Suppress[str] = "3dgs"
    """Method name (set by the subcommand)."""
    data: str = "synthetic/forward"
    """Dataset folder, or a folder of photos or a video; else under $SPLAT_DATA."""
    format: str = "auto"
    """Dataset format: auto (detected from the folder's contents) or a dataparser (llff, blender, dtu, transforms, colmap, a plugin's)."""
    views: Annotated[int, Field(ge=1, le=MAX_VIEWS)] | Literal["all"] | None = None
    """Training views, or all (default: 3 on LLFF, Blender, DTU; else all)."""
    downscale: Positive | None = None
    """Image downscale factor (default: the dataset's, 8 on LLFF, 2 on Blender)."""
    eval_split: Literal["test", "val"] = "test"
    """Score the test views, or the validation views (neither trained nor tested: choose defaults on these)."""
    test_every: Annotated[int, Field(ge=2, le=MAX_VIEWS)] | None = None
    """Hold out every K-th image (the first, the K+1-th, ...) as a test view, at any image count (default: every 8th, and none up to 8 photos of one's own; LLFF, COLMAP and transforms.json scenes)."""
    train_poses: Annotated[Path | None, FOLDED] = None
    """Pose file (JSON) replacing the training views' cameras."""
    photos: PhotoPosesConfig = Field(default_factory=PhotoPosesConfig)
    """Pose estimation when --data is a folder of photos or a video."""
    resolved_data: Annotated[tyro.conf.Suppress[ResolvedData | None], RUN_OPTION] = None
    """The dataset as the run resolved it (absolute folder, train and test image names), recorded in config.json so that eval, render, view and export work from any folder and shell."""
    camera_refine: CameraRefineConfig = Field(default_factory=CameraRefineConfig)
    """Refine the training cameras' poses (and focal length) with the scene."""
    test_pose_steps: Annotated[int, FOLDED, Field(ge=0, le=MAX_STEPS)] = 0
    """Fit each test camera's pose by this many steps before scoring (0 = off)."""
    steps: Annotated[int, Field(ge=1, le=MAX_STEPS)] | None = None
    """Total iterations; rescales the method's whole schedule (the iteration counts you set keep your numbers)."""
    default_steps: tyro.conf.Suppress[Annotated[int, Field(ge=1, le=MAX_STEPS)]] = 3000
    """The method's own total iterations, which its schedule fields are written for."""
    schedule_views: tyro.conf.Suppress[Annotated[int, Field(ge=0, le=MAX_VIEWS)]] = 0
    """The number of training views the method's default schedule is written for: without --steps, a run of N > this views (an integer --views) trains default_steps x N / this iterations, its whole schedule rescaled as --steps would (0 = default_steps whatever N)."""
    coarse_steps: Annotated[StartSteps, FOLDED] = 0
    """The first iterations train on the images downscaled by coarse_scale (area average, cameras scaled to match): cheaper steps while the model takes its coarse shape (0 = off)."""
    coarse_scale: Annotated[float, FOLDED, Field(gt=0, lt=1, allow_inf_nan=False)] = 0.5
    """Image scale of the coarse iterations (coarse_steps)."""
    random_background: Annotated[bool, FOLDED] = False
    """Composite each training render over a random colour (new each step, from the seed) where the photos are opaque; white-backdrop scenes and test renders keep the scene's."""
    output: Annotated[Path | None, RUN_OPTION] = None
    """Run folder (default outputs/<scene>/<method>/<timestamp>)."""
    seed: int = Field(0, ge=0, lt=2**32)
    """Random seed for everything (initialisation, view order, matching)."""
    device: Annotated[Device, RUN_OPTION] = "cpu"
    """Torch device: cpu, cuda, cuda:N, mps, ..."""
    resume: Annotated[bool, RUN_OPTION] = False
    """Continue the unfinished run in --output (default: this command's)."""
    overwrite: Annotated[bool, RUN_OPTION] = False
    """Allow writing into an existing non-empty --output folder."""
    trust_edited_config: Annotated[bool, RUN_OPTION, FOLDED] = False
    """With --resume or --load-config: accept a config.json that is missing its checksum or edited by hand."""
    eval_every: Annotated[Steps, RUN_OPTION] = 0
    """Evaluate the test views every this many iterations (0 = at the end)."""
    checkpoint_every: Annotated[Steps, FOLDED] = 1000
    """Write a checkpoint every this many iterations (and at the end)."""
    save_renders: Annotated[bool, RUN_OPTION, FOLDED] = True
    """Write the test views' renders into the run folder."""
    progress: Annotated[bool, RUN_OPTION, FOLDED] = True
    """Show the rich progress bar."""
    viewer: Annotated[bool, RUN_OPTION] = False
    """Show the model in the web viewer while training (open until Ctrl-C)."""
    viewer_port: Annotated[Port, RUN_OPTION, FOLDED] = 8080
    """TCP port of the training viewer (0 = any free port)."""
    viewer_host: Annotated[str, RUN_OPTION, FOLDED] = LOOPBACK
    """Interface the training viewer listens on (other than 127.0.0.1: a warning)."""
    viewer_every: Annotated[Interval, RUN_OPTION, FOLDED] = 100
    """Send the model to the training viewer every this many iterations."""
    compile: Annotated[bool, RUN_OPTION, FOLDED] = True
    """Compile the rasterizer's kernels (native C++ on a CPU, Triton on CUDA, else torch.compile)."""
    rasterizer: Annotated[Literal["auto", "native", "triton", "torch"], RUN_OPTION, FOLDED] = "auto"
    """Which kernels render: auto (native C++ on a CPU, Triton on CUDA, torch elsewhere; SPLAT_RASTERIZER when set), native, triton (CUDA; a CPU under TRITON_INTERPRET=1) or torch."""
    model: GaussianModelConfig = Field(default_factory=GaussianModelConfig)
    """Model options."""
    strategy: RegisteredStrategies = Field(default_factory=DensifyConfig)
    """Densification (--strategy.kind K picks another registered strategy)."""
    optim: OptimConfig = Field(default_factory=OptimConfig)
    """Learning rates."""

    @property
    def total_steps(self) -> int:
        return self.steps if self.steps is not None else self.default_steps


def run_options(config_cls: type[SplatConfig]) -> set[str]:
    """Top-level fields of ``config_cls`` marked :data:`RUN_OPTION`: how a run is carried out (where it
    goes, whether it overwrites or resumes, the viewer and its address, the device, ...). The one list:
    they come only from the command line, never from a TOML variant (refused, naming the key) nor from
    ``--load-config``'s file (the method's defaults instead), and may change on ``--resume``."""
    return {name for name, info in config_cls.model_fields.items() if any(m is RUN_OPTION for m in info.metadata)}


def experiment_fields(config_cls: type[SplatConfig]) -> set[str]:
    """Top-level fields of ``config_cls`` that define the experiment: all but its :func:`run_options`."""
    return set(config_cls.model_fields) - run_options(config_cls)
