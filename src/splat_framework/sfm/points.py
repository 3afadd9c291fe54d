"""The init kind "sfm": a model starts from the structure-from-motion points a dataset holds."""

from __future__ import annotations

import torch

from ..data.scene import SceneData
from ..errors import DataError
from ..model.init import StartPoints


def sfm_points(init, datamanager, generator: torch.Generator) -> StartPoints:
    """Init kind "sfm": the dataset's structure-from-motion points and colours (a COLMAP dataset's
    points3D, kept by its parser in ``scene.extras``); DataError when it has none."""
    scene: SceneData = datamanager.scene
    xyz = scene.extras.get("points3d")
    if xyz is None or len(xyz) == 0:
        raise DataError(
            f"{scene.root}: no structure-from-motion points to start from (model.init.kind sfm needs a COLMAP "
            "dataset with sparse/0/points3D); choose another --model.init.kind"
        )
    points = torch.as_tensor(xyz, dtype=torch.float32)
    colors = torch.as_tensor(scene.extras["points3d_rgb"], dtype=torch.float32) / 255.0
    return StartPoints(points, colors)  # initial_points puts them on the training images' device
