"""Decoded images on the device, and the order in which training sees them.

``DataManager`` decodes every image used by the split (train and test only)
once, into float32 tensors on the device, undistorted where the scene's lens is distorted
(``scene.undistort``: the image, its mask and depth map alike; :func:`load_view_image`):

- ``image`` [H, W, 3] in [0, 1] (RGBA composited per ``scene.white_background``),
- ``mask`` [H, W, 1] in {0, 1} when the scene has masks,
- ``depth`` [H, W, 1] camera z (0 = no surface) when the scene has depth maps,
- ``backdrop`` [H, W, 1] in {0, 1} (1 = unlit backdrop): training views of a
  ``scene.dark_backdrop`` scene, when the DataManager is asked for it (``fields``; the
  trainer asks for what the model's ``batch_fields`` names).

A batch also carries ``index`` (the camera's index in the scene) and, for a training view
(``next_train``, ``train_views``), ``train_position``: its position in ``train_indices``
(what a model keeps per training view, e.g. SCGaussian's matches, is indexed by it).

Training order: shuffled epochs over the training views. The permutation of
epoch ``e`` is drawn from a ``torch.Generator`` seeded from ``(seed, e)``
only, so ``next_train(step)`` is a pure function of ``(seed, step)`` and a
run resumed at step ``s`` sees exactly the views it would have seen.

Memory: when ``memory_budget_bytes`` is given and the decoded tensors would
exceed it, only the views that fit in the budget are cached (training views
first, then test views); every other request decodes its file again (slower
but bounded memory). Image sizes are still checked up front from headers.
:func:`estimate_image_bytes` gives the decoded size of a scene before any
decoding (the trainer uses it to check a run fits in memory).

Batches share the cached tensors: treat them as read-only.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import numpy as np
import torch
from torch import Tensor

from ..cameras import Camera
from ..console import track
from ..runtime.rng import keyed_generator
from .images import dark_backdrop_mask, load_alpha, load_depth, load_image, load_mask, read_image_size, scaled_size
from .scene import DataError, SceneData

Batch = dict

OPTIONAL_FIELDS = ("backdrop",)
"""Batch fields made only when asked for (``DataManager(fields=...)``); the others always are."""


def decoded_size(scene: SceneData, i: int) -> tuple[int, int]:
    """(width, height) of camera ``i``'s image as decoded, before any undistortion."""
    u = scene.undistort[i] if scene.undistort is not None else None
    cam = scene.cameras[i]
    return u.lens.size if u is not None else (cam.width, cam.height)


def undistorted(scene: SceneData, i: int, a: np.ndarray, *, nearest: bool = False) -> np.ndarray:
    """``a`` ([H, W] or [H, W, C] at :func:`decoded_size`) as camera ``i`` sees it: undistorted where
    its lens is distorted (``nearest``: nearest-neighbour resampling, for depth), else itself."""
    u = scene.undistort[i] if scene.undistort is not None else None
    return a if u is None else u.apply(a, nearest=nearest)


def load_view_image(scene: SceneData, i: int) -> np.ndarray:
    """[H, W, 3] float32 in [0, 1]: camera ``i``'s image as training sees it, decoded at
    ``scene.image_scale``, composited per ``scene.white_background`` and undistorted; a DataError
    naming the file when it decodes to another size than its camera's."""
    path = Path(scene.image_paths[i])
    img = load_image(path, scale=scene.image_scale, white_background=scene.white_background)
    w, h = decoded_size(scene, i)
    if img.shape[:2] != (h, w):
        cam = scene.cameras[i]
        raise DataError(f"{path}: image is {img.shape[1]}x{img.shape[0]} but its camera is {cam.width}x{cam.height}"
                        + (f" (undistorted from {w}x{h})" if (w, h) != (cam.width, cam.height) else ""))
    return undistorted(scene, i, img)


def area_resized(x: Tensor, width: int, height: int) -> Tensor:
    """[H, W, C] -> [height, width, C] float: each output pixel the mean of the input area it covers
    (``x`` itself when it has that size)."""
    if x.shape[:2] == (height, width):
        return x
    y = torch.nn.functional.interpolate(x.permute(2, 0, 1)[None].float(), size=(height, width), mode="area")
    return y[0].permute(1, 2, 0).contiguous()


def view_bytes(scene: SceneData, i: int) -> int:
    """Bytes of the decoded float32 tensors (image, mask, depth, backdrop) of camera ``i``
    (an upper bound: the backdrop mask is counted for training views, whether or not it is asked for)."""
    cam = scene.cameras[i]
    backdrop = scene.dark_backdrop and i in scene.train_indices
    per_pixel = 3 + (scene.mask_paths is not None) + (scene.depth_paths is not None) + backdrop
    return cam.width * cam.height * per_pixel * 4


def estimate_image_bytes(scene: SceneData) -> int:
    """Bytes the decoded views of the split (train and test) take when all are cached."""
    used = set(scene.train_indices) | set(scene.test_indices)
    n = len(scene.cameras)
    return sum(view_bytes(scene, i) for i in used if 0 <= i < n)


class DataManager:
    """Cached training / evaluation views of a :class:`SceneData`.

    Args:
        scene: parsed dataset.
        device: where images, masks, depths and cameras live.
        seed: seed of the training-view order.
        memory_budget_bytes: optional cap on decoded tensor memory; above it
            images are decoded on demand instead of cached.
        fields: the optional batch fields to make (:data:`OPTIONAL_FIELDS`): ``backdrop``, the
            mask of training views of scenes with a dark backdrop (only a loss that uses it needs it).
    """

    def __init__(
        self,
        scene: SceneData,
        device: str | torch.device = "cpu",
        seed: int = 0,
        memory_budget_bytes: int | None = None,
        fields: Iterable[str] = (),
    ):
        fields = frozenset(fields)
        unknown = sorted(fields - set(OPTIONAL_FIELDS))
        if unknown:
            raise ValueError(f"DataManager makes no batch field {unknown} (optional fields: {list(OPTIONAL_FIELDS)})")
        self.scene = scene
        self.backdrop = "backdrop" in fields and scene.dark_backdrop
        self.device = torch.device(device)
        self.seed = int(seed)
        n = len(scene.cameras)
        if len(scene.image_paths) != n:
            raise DataError(f"{scene.root}: {n} cameras but {len(scene.image_paths)} image paths")
        for name, extra in (("mask_paths", scene.mask_paths), ("depth_paths", scene.depth_paths)):
            if extra is not None and len(extra) != n:
                raise DataError(f"{scene.root}: {n} cameras but {len(extra)} {name}")
        for idx in (*scene.train_indices, *scene.test_indices):
            if not 0 <= idx < n:
                raise DataError(f"{scene.root}: split index {idx} out of range for {n} cameras")
        if not scene.train_indices:
            raise DataError(f"{scene.root}: no training views")
        self.train_indices = list(scene.train_indices)
        self.test_indices = list(scene.test_indices)
        self.cameras: list[Camera] = [c.to(self.device) for c in scene.cameras]

        used = sorted(set(self.train_indices) | set(self.test_indices))
        for i in used:
            self._check_size(i)
        nbytes = estimate_image_bytes(scene)
        self.estimated_bytes = nbytes
        self.memory_budget_bytes = memory_budget_bytes
        self.lazy = memory_budget_bytes is not None and nbytes > memory_budget_bytes
        self._cache: dict[int, Batch] = {}
        if not self.lazy:
            for i in track(used, "decoding images", unit="images"):
                self._cache[i] = self._decode(i)
        else:
            # cache what fits, training views first; the rest is decoded on demand
            room = int(memory_budget_bytes)
            order = list(dict.fromkeys([*self.train_indices, *self.test_indices]))
            for i in order:
                size = view_bytes(scene, i)
                if size <= room:
                    self._cache[i] = self._decode(i)
                    room -= size
        self._perm_epoch = -1
        self._perm: list[int] = []
        self._coarse: dict[tuple[int, float], Batch] = {}  # (camera index, scale) -> its downscaled fields

    # ------------------------------------------------------------ decoding
    def _check_size(self, i: int) -> None:
        path = Path(self.scene.image_paths[i])
        w, h = read_image_size(path)
        size = scaled_size(w, h, self.scene.image_scale)
        expected = decoded_size(self.scene, i)
        if size != expected:
            raise DataError(
                f"{path}: image decodes to {size[0]}x{size[1]} but its camera is "
                f"{expected[0]}x{expected[1]} (mixed image sizes?)"
            )

    def _decode(self, i: int) -> Batch:
        scene = self.scene
        img = load_view_image(scene, i)
        batch: Batch = {"image": self._tensor(img), "index": i}
        size = decoded_size(scene, i)
        if scene.mask_paths is not None:
            batch["mask"] = self._tensor(undistorted(scene, i, load_mask(scene.mask_paths[i], size))[:, :, None])
        if scene.depth_paths is not None:
            depth = undistorted(scene, i, load_depth(scene.depth_paths[i], size), nearest=True)
            batch["depth"] = self._tensor(depth[:, :, None])
        if self.backdrop and i in self.train_indices:
            batch["backdrop"] = self._tensor(dark_backdrop_mask(img)[:, :, None])
        return batch

    def alpha(self, index: int) -> np.ndarray | None:
        """[H, W] float32 alpha channel of camera ``index``'s own image file (0 = background), or None without one.

        Only images that carry alpha (RGBA renders such as Blender's) have it;
        evaluation masks (``mask_paths``, DTU) are not alpha and never appear here.
        """
        alpha = load_alpha(Path(self.scene.image_paths[index]), scale=self.scene.image_scale)
        return None if alpha is None else undistorted(self.scene, index, alpha)

    def _tensor(self, a: np.ndarray) -> Tensor:
        return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)).to(self.device)

    def batch(self, index: int) -> Batch:
        """The batch of camera ``index`` (a fresh dict; tensors are shared)."""
        if index in self._cache:
            return dict(self._cache[index])
        if not self.lazy:
            raise KeyError(f"camera {index} is in neither the training nor the test split")
        return self._decode(index)

    # ------------------------------------------------------------ training
    def epoch_permutation(self, epoch: int) -> list[int]:
        """Order of the training views (positions into ``train_indices``) in ``epoch``."""
        g = keyed_generator(self.seed, epoch)
        return torch.randperm(len(self.train_indices), generator=g).tolist()

    def next_train(self, step: int) -> tuple[Camera, Batch]:
        """The training view for ``step`` (0-based): shuffled epochs, seeded."""
        if step < 0:
            raise ValueError(f"step must be >= 0, got {step}")
        n = len(self.train_indices)
        epoch, pos = divmod(int(step), n)
        if epoch != self._perm_epoch:
            self._perm = self.epoch_permutation(epoch)
            self._perm_epoch = epoch
        return self.train_view(self._perm[pos])

    def train_view(self, position: int) -> tuple[Camera, Batch]:
        """The training view at ``position`` in ``train_indices``, its batch carrying ``train_position``."""
        idx = self.train_indices[position]
        return self.cameras[idx], self.batch(idx) | {"train_position": position}

    def coarse_view(self, camera: Camera, batch: Batch, scale: float) -> tuple[Camera, Batch]:
        """``camera`` and ``batch`` for the image downscaled by ``scale`` (0 < scale < 1): every
        [H, W, C] field (image, masks, depth) area-averaged to round(W scale) x round(H scale), the
        camera resized to match (:meth:`Camera.resized`). Made once per view and scale, then kept."""
        width, height = scaled_size(camera.width, camera.height, scale)
        key = (batch["index"], scale)
        if key not in self._coarse:
            self._coarse[key] = {
                k: area_resized(v, width, height) for k, v in batch.items()
                if isinstance(v, Tensor) and v.dim() == 3 and v.shape[:2] == (camera.height, camera.width)
            }
        return camera.resized(width, height), batch | self._coarse[key]

    def train_views(self) -> list[tuple[Camera, Batch]]:
        """All training views, in split order."""
        return [self.train_view(p) for p in range(len(self.train_indices))]

    def eval_views(self) -> list[tuple[Camera, Batch]]:
        """All held-out views, in split order."""
        return [(self.cameras[i], self.batch(i)) for i in self.test_indices]

    @property
    def train_cameras(self) -> list[Camera]:
        return [self.cameras[i] for i in self.train_indices]

    @property
    def eval_cameras(self) -> list[Camera]:
        return [self.cameras[i] for i in self.test_indices]

    @property
    def num_train(self) -> int:
        return len(self.train_indices)

    @property
    def num_eval(self) -> int:
        return len(self.test_indices)
