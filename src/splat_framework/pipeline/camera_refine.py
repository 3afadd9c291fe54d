"""Joint refinement of the training cameras' poses while the scene trains.

Poses estimated from the few training photos themselves are off by a fraction of a degree (fern's
3 photos: 0.3-0.4 degrees after alignment), which moves the image by a few pixels: the scene then
fits three slightly inconsistent views. As nerfstudio's camera optimizer and BARF do, every
training view but the first (which fixes the frame the test cameras were aligned to) gets an SE(3)
correction of its own, ``exp([w, v]) @ world_to_cam`` (rotation vector ``w``, translation ``v`` in
scene units, the correction of :mod:`splat_framework.evaluation.pose_refine`), zero at the start
and optimised with the scene by Adam, its step decaying exponentially to 1 % over the run.
One focal-length factor shared by the training views is refined with them (``focal``).
``TrainConfig.camera_refine`` switches it: off by default, because on fern's poses estimated from
its 3 photos it gained nothing (docs/decisions.md); auto: on where the training poses were
estimated.

The corrections are saved in every checkpoint (``camera_refine``) and applied to the training
cameras wherever a run is loaded (:func:`refined_cameras`), so a training view is scored at the
pose it was trained at.
"""

from __future__ import annotations

import dataclasses
import math

import torch
from torch import Tensor

from ..cameras import Camera
from ..evaluation.pose_refine import rigid_correction
from ..model.optim import adam


def poses_estimated(config) -> bool:
    """Whether ``config``'s training poses were estimated from its training photos: a pose file
    (``--train-poses``), or ``--data`` a folder of photos or a video that splat posed."""
    from ..data.photos import photo_source
    from ..data.resolve import locate_data
    from ..data.scene import DataError

    record = config.resolved_data
    if config.train_poses is not None or (record is not None and record.train_poses is not None):
        return True
    try:
        return photo_source(locate_data(config.data)) is not None
    except DataError:
        return False


def refine_enabled(config) -> bool:
    mode = config.camera_refine.mode
    return mode == "on" or (mode == "auto" and poses_estimated(config))


class CameraRefiner:
    """The training views' pose corrections and their optimizer.

    Args:
        views: number of training views (corrections are indexed by ``train_position``; the first
            stays the identity).
        lr_rotation: initial Adam step of the rotation vectors (radians).
        lr_translation: initial Adam step of the translations (scene units).
        total_steps: the run's length, over which both steps decay to 1 %.
    """

    def __init__(self, views: int, lr_rotation: float, lr_translation: float, total_steps: int,
                 device: torch.device | str = "cpu", focal: bool = False):
        self.rotation = torch.zeros(views, 3, device=device, requires_grad=True)
        self.translation = torch.zeros(views, 3, device=device, requires_grad=True)
        self.log_focal = torch.zeros(1, device=device, requires_grad=focal)
        self.total_steps = max(int(total_steps), 1)
        groups = [("rotation", self.rotation, lr_rotation), ("translation", self.translation, lr_translation)]
        if focal:
            groups.append(("log_focal", self.log_focal, lr_rotation))
        self._trained = {f"camera_refine.{name}": tensor for name, tensor, _ in groups}
        self.base_lr = [lr for _, _, lr in groups]
        self.optimizer = adam([{"params": [tensor], "lr": lr} for _, tensor, lr in groups], lr=lr_rotation)

    @classmethod
    def for_run(cls, config, views: int, scene_scale: float, device) -> "CameraRefiner | None":
        """The refiner ``config.camera_refine`` asks for (None when off, or with a single training
        view: the first view fixes the frame, so there is nothing to refine it against)."""
        if not refine_enabled(config) or views < 2:
            return None
        lr = config.camera_refine.lr_rotation
        return cls(views, lr, lr * float(scene_scale), config.total_steps, device, focal=config.camera_refine.focal)

    def tensors(self) -> dict[str, Tensor]:
        """The refined tensors by name (the focal factor only when it is refined)."""
        return dict(self._trained)

    def set_learning_rates(self, step: int, factor: float = 1.0) -> None:
        """Both steps at ``step`` (a pure function of it): exponential decay to 1 % over the run."""
        decay = math.exp(math.log(0.01) * min(max(step / self.total_steps, 0.0), 1.0))
        for group, lr in zip(self.optimizer.param_groups, self.base_lr):
            group["lr"] = lr * decay * factor

    def apply(self, camera: Camera, position: int) -> Camera:
        """``camera`` (training view ``position``) with its correction; differentiable in it."""
        if position == 0:  # the first view fixes the frame: its focal length alone is refined
            return corrected(camera, self.rotation.new_zeros(3), self.translation.new_zeros(3), self.log_focal)
        return corrected(camera, self.rotation[position], self.translation[position], self.log_focal)

    def step(self) -> None:
        self.optimizer.step()
        self.zero_grad()

    def zero_grad(self) -> None:
        self.optimizer.zero_grad(set_to_none=True)

    def state_dict(self) -> dict:
        return {"rotation": self.rotation.detach().cpu(), "translation": self.translation.detach().cpu(),
                "log_focal": self.log_focal.detach().cpu(), "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        with torch.no_grad():
            self.rotation.copy_(state["rotation"])
            self.translation.copy_(state["translation"])
            self.log_focal.copy_(state["log_focal"])
        self.optimizer.load_state_dict(state["optimizer"])

    def report(self, cameras: list[Camera]) -> list[dict]:
        """Per training view: its name, the correction's rotation (degrees), translation (scene units)
        and focal-length factor."""
        focal = math.exp(float(self.log_focal.detach()))
        return [{"view": cam.name, "rotation_deg": math.degrees(float(w.norm())), "translation": float(v.norm()),
                 "focal_factor": focal} for cam, w, v in zip(cameras, self.rotation.detach(), self.translation.detach())]


def corrected(camera: Camera, rotation: Tensor, translation: Tensor, log_focal: Tensor) -> Camera:
    """``camera`` moved by the correction of rotation vector ``rotation`` [3] and translation [3],
    its focal lengths scaled by exp(``log_focal``) [1]."""
    correction = rigid_correction(rotation.float(), translation.float()).to(camera.world_to_cam)
    camera = camera.with_focal_factor(log_focal.exp().reshape(()))
    return dataclasses.replace(camera, world_to_cam=correction @ camera.world_to_cam)


def refined_cameras(cameras: list[Camera], train_indices: list[int], state: dict | None) -> list[Camera]:
    """``cameras`` with the saved corrections ``state`` (a checkpoint's ``camera_refine``) applied
    to the training views; unchanged without one."""
    if not state:
        return cameras
    cameras = list(cameras)
    with torch.no_grad():
        for position, index in enumerate(train_indices):
            cameras[index] = corrected(cameras[index], state["rotation"][position], state["translation"][position],
                                       state.get("log_focal", torch.zeros(1)))
    return cameras
