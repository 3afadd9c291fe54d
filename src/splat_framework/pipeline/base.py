"""The pipeline: it builds the run's data and model, and gives each step's render and loss terms.

nerfstudio's ``VanillaPipeline`` is the anchor: from the resolved config, the model class and the
device the pipeline builds what it owns (the scene and its data manager, the model, the background,
the camera refiner) and says which densification the run uses; the trainer
(:class:`splat_framework.engine.trainer.Trainer`) keeps the kernels, the run folder, the loop, the
optimizers, the strategy's calls, the checkpoints and resume. A method changes how its data or
model is built, or what a step feeds the model (a binocular or multi-view loss), by subclassing
:class:`Pipeline` and naming it in its ``MethodSpec(pipeline="my_plugin.pipeline:MyPipeline")``;
every other method runs through this one.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from ..cameras import Camera
from ..config import RunFacts, StrategyConfig, TrainConfig
from ..console import phase, say
from ..data import DataManager, describe_split, record_data
from ..evaluation.held_out import evaluate
from ..evaluation.metrics import psnr_tensor
from ..render import RenderOutput
from ..runtime.profiling import section
from ..runtime.rng import keyed_generator
from .camera_refine import CameraRefiner, refined_cameras
from .memory_plan import image_memory_budget, plan_memory
from .scene import background_for, load_config_scene


class Pipeline:
    """The run's data manager and model, built here, and one step's batch, render and loss terms.

    Built in this order, each a method a subclass may override: :meth:`build_datamanager` (the
    scene, in the phase "loading data"), the background, :meth:`build_model`, the camera refiner.

    Args:
        config: the run's resolved TrainConfig; ``self.config`` is it with the data's folder and
            split recorded (what config.json saves).
        model_class: the method's model class (a :class:`~splat_framework.model.gaussians.GaussianModel`
            subclass).
        device: where the images, the model and the renders live.
        generator: the seeded generator the model's init draws from.

    Attributes:
        datamanager: the :class:`~splat_framework.data.DataManager` (views, batches, sampler).
        model: the model, on ``device``.
        background: [3] the background colour renders composite over.
        camera_refiner: the per-view pose corrections being learned (``--camera-refine.mode``), or None.
        run_facts: what the model reads of the run (:class:`~splat_framework.config.RunFacts`).
        timing: seconds of ``data_s``, ``init_s`` and the model's own set-up phases (metrics.json).
    """

    def __init__(self, config: TrainConfig, model_class: type, device: torch.device,
                 generator: torch.Generator) -> None:
        self.config = config
        self.model_class = model_class
        self.device = device
        self.run_facts = RunFacts.of(config)
        t0 = time.perf_counter()
        with phase("loading data"):
            self.datamanager = self.build_datamanager()
        scene = self.datamanager.scene
        self.config = record_data(self.config, scene)  # config.json names the folder and split: eval from any shell
        split = describe_split(scene, self.config.views, self.config.test_every)
        if split:
            say(split)
        self.timing: dict[str, float] = {"data_s": time.perf_counter() - t0}
        self.background = background_for(scene, device)
        t0 = time.perf_counter()
        self.model = self.build_model(generator).to(device)
        self.timing.update(self.model.init_timing)
        self.timing["init_s"] = time.perf_counter() - t0 - sum(self.model.init_timing.values())
        self.camera_refiner = CameraRefiner.for_run(self.config, self.datamanager.num_train, self.model.scene_scale,
                                                    device)

    def build_datamanager(self) -> DataManager:
        """The scene the config names, read, and its data manager (its image cache sized to the
        machine's memory), making the batch fields the model class asks for."""
        scene = load_config_scene(self.config)
        budget = plan_memory(scene, self.config, image_memory_budget())
        return DataManager(scene, device=self.device, seed=self.config.seed, memory_budget_bytes=budget,
                           fields=self.model_class.batch_fields(self.config.model))

    def build_model(self, generator: torch.Generator):
        """The model, from the data: ``model_class.from_data(config.model, run_facts, datamanager,
        generator)`` (moved to the device by the caller)."""
        return self.model_class.from_data(self.config.model, self.run_facts, self.datamanager, generator)

    def strategy_config(self) -> StrategyConfig:
        """The densification the run trains with: ``config.strategy`` (a subclass may choose
        another once its model is built, e.g. SCGaussian's baseline schedule after a thin prior;
        config.json keeps the run's one config)."""
        return self.config.strategy

    def use_trained_poses(self) -> None:
        """After training, before the evaluation: the training views' cameras at the poses they
        trained at (the camera refiner's corrections applied; nothing without a refiner)."""
        if self.camera_refiner is not None:
            self.datamanager.cameras = refined_cameras(self.datamanager.cameras, self.datamanager.train_indices,
                                                       self.camera_refiner.state_dict())

    def train_psnr(self, outputs: RenderOutput, batch: dict[str, Any]) -> Tensor:
        """The PSNR of a training step's render against its image (0-dim, on the device)."""
        return psnr_tensor(outputs.rgb.detach().clamp(0, 1), batch["image"])

    def next_batch(self, step: int) -> tuple[Camera, dict[str, Any]]:
        """The training view of ``step`` (the data manager's seeded order): its camera (at the
        coarse scale in the first ``coarse_steps`` steps, with its learned pose correction) and its
        batch (``image``, ``index``, ``train_position``, masks)."""
        cfg = self.config
        camera, batch = self.datamanager.next_train(step)
        if step < cfg.coarse_steps:
            camera, batch = self.datamanager.coarse_view(camera, batch, cfg.coarse_scale)
        elif step == cfg.coarse_steps > 0:
            say(f"step {step}: the {step} coarse steps (images at {cfg.coarse_scale:g}x) are done; "
                "the steps from here train at the images' own size and take longer")
        if self.camera_refiner is not None:
            camera = self.camera_refiner.apply(camera, batch["train_position"])
        return camera, batch

    def train_background(self, step: int) -> Tensor:
        """[3] the colour step ``step``'s training render composites over: the scene's, or with
        ``random_background`` on a scene of opaque photos (no white backdrop) a colour drawn from the
        seed and the step alone (a resumed run draws the same). Over a fixed black a Gaussian may stay
        transparent wherever the photo is dark, and a novel view then sees through it; over a colour
        that changes every step only opaque Gaussians reproduce the photo."""
        if not self.config.random_background or self.datamanager.scene.white_background:
            return self.background
        draw = keyed_generator(self.config.seed, step, 2)  # stream 2 (1: the stereo partner, 3: the pseudo view)
        colour = torch.rand(3, generator=draw)  # drawn on the host: the same colours on every device
        if self.background.device.type == "cuda":  # copied without waiting for the GPU (no host sync)
            colour = colour.pin_memory()
        return colour.to(self.background.device, self.background.dtype, non_blocking=True)

    def train_losses(self, step: int) -> tuple[RenderOutput, dict[str, Any], dict[str, Tensor]]:
        """One step's (render of the step's view, its batch, the model's loss terms {name: scalar}).
        The render's ``meta`` is what the strategy sees; the trainer adds the strategy's own terms."""
        camera, batch = self.next_batch(step)
        with section("forward"):
            outputs = self.model.get_outputs(camera, self.train_background(step), step=step)
        with section("loss"):
            losses = self.model.get_loss_dict(outputs, batch, camera, step)
        return outputs, batch, losses

    def evaluate(self, renders_dir: Path | None = None, pose_steps: int = 0) -> dict:
        """Held-out metrics of the model on the evaluation views (:func:`~splat_framework.evaluation.held_out.evaluate`),
        renders written under ``renders_dir`` when given."""
        return evaluate(self.model, self.datamanager, self.background, renders_dir, pose_steps=pose_steps)
