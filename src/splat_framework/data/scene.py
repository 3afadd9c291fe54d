"""What every dataset parser returns: cameras, image files and the split."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..cameras import Camera
from ..errors import DataError  # noqa: F401  (re-exported)
from .undistort import Undistortion


@dataclass
class SceneData:
    """A parsed dataset, before any image is decoded.

    Attributes:
        root: the dataset folder.
        format: the dataparser's name ("llff", "blender", "dtu", "transforms", "colmap", a plugin's).
        cameras: one Camera per image, already matching the size at which the
            images will be decoded (after ``image_scale`` and ``undistort``).
        image_paths: one image file per camera.
        train_indices: indices into ``cameras`` used for training.
        test_indices: indices into ``cameras`` held out for evaluation (the views scored).
        val_indices: the validation views, neither trained on nor tested, on which defaults are
            chosen (``--eval-split val`` scores them instead of the test views); None: every
            view that is neither (:attr:`validation_indices`).
        held_out: which views ``test_indices`` holds: "test" (the protocol's), or "val" when the
            run scores the validation views (:func:`~splat_framework.data.run_data.held_out_views`).
        image_scale: resize factor applied when decoding (1.0 = as stored).
        white_background: composite RGBA images on white (Blender) instead of black.
        mask_paths: optional per-image foreground masks (DTU); None where absent.
        depth_paths: optional per-image ground-truth depth maps (``.npy``,
            float32 [H, W] camera z at stored resolution; 0 = no surface).
        undistort: per camera, how its decoded image (and mask, depth map) loses the lens
            distortion its dataset states (:mod:`~splat_framework.data.undistort`), None for a
            pinhole camera; None when every camera is one. ``cameras`` are the undistorted ones.
        scene_center: [3] centre of the region of interest (world).
        scene_radius: radius of that region (used for random init and lr scaling).
        masked_metrics: compute PSNR/SSIM on mask pixels only (DTU protocol).
        dark_backdrop: the photos have an unlit backdrop that is empty space
            (DTU's black studio background): training batches carry its mask
            (:func:`~splat_framework.data.images.dark_backdrop_mask`).
        content_box: (min corner, max corner) of an axis-aligned world box
            around the scene content where the dataset defines one (Blender:
            the reference code's [-1.3, 1.3]^3; DTU: the unit sphere's cube);
            None = derived from the training frusta (random initialisation).
    """

    root: Path
    format: str
    cameras: list[Camera]
    image_paths: list[Path]
    train_indices: list[int]
    test_indices: list[int]
    val_indices: list[int] | None = None
    held_out: str = "test"
    image_scale: float = 1.0
    white_background: bool = False
    mask_paths: list[Path] | None = None
    depth_paths: list[Path] | None = None
    undistort: list[Undistortion | None] | None = None
    scene_center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scene_radius: float = 1.0
    masked_metrics: bool = False
    dark_backdrop: bool = False
    content_box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    extras: dict = field(default_factory=dict)

    @property
    def validation_indices(self) -> list[int]:
        """The validation views: ``val_indices`` where the parser chose them (Blender's ``val``
        split), else every view that is neither a training nor a test view, in order."""
        if self.val_indices is not None:
            return list(self.val_indices)
        used = {*self.train_indices, *self.test_indices}
        return [i for i in range(len(self.cameras)) if i not in used]

    @property
    def train_cameras(self) -> list[Camera]:
        return [self.cameras[i] for i in self.train_indices]

    @property
    def test_cameras(self) -> list[Camera]:
        return [self.cameras[i] for i in self.test_indices]
