"""The pipeline: what one training step feeds the model and what it is scored by, and the evaluation.

nerfstudio's ``VanillaPipeline`` is the anchor: the pipeline owns the data manager and the model;
the trainer (:class:`splat_framework.engine.trainer.Trainer`) drives only the loop, the
optimizers, the strategy, the checkpoints and resume. A method that needs more than one view a
step (a binocular or multi-view consistency loss) subclasses :class:`Pipeline` and names it in its
``MethodSpec(pipeline="my_plugin.pipeline:MyPipeline")``; every other method runs through this one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from .cameras import Camera
from .console import say
from .evaluation.held_out import evaluate
from .render import RenderOutput
from .runtime.profiling import section
from .runtime.rng import keyed_generator


class Pipeline:
    """The data manager and the model, and one step's batch, render and loss terms.

    Args:
        config: the run's resolved TrainConfig.
        datamanager: the run's :class:`~splat_framework.data.DataManager` (views, batches, sampler).
        model: the run's model (a :class:`~splat_framework.model.gaussians.GaussianModel` or any
            model with its hooks).
        background: [3] the background colour renders composite over.
        camera_refiner: the per-view pose corrections being learned (``--camera-refine.mode``), or None.
    """

    def __init__(self, config, datamanager, model, background: Tensor, camera_refiner=None) -> None:
        self.config = config
        self.datamanager = datamanager
        self.model = model
        self.background = background
        self.camera_refiner = camera_refiner

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
