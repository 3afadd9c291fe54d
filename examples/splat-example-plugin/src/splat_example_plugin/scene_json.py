"""A dataset format of the plugin's own, ``scene-json``: a folder holding ``scene.json`` beside its images.

::

    {"near": 0.5, "far": 20.0,
     "frames": [{"image": "images/000.png", "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
                 "world_to_camera": [[...], [...], [...], [0, 0, 0, 1]], "split": "test"}, ...]}

Cameras in the framework's convention (OpenCV axes, pixel centres at +0.5: ``cx = W / 2`` for a
centred principal point); ``near`` and ``far`` bound the scene's depth from every camera; a frame
with ``"split": "test"`` is held out, the others train (``--views N``: the first N of them).
The module imports no torch until a folder loads: ``--format auto`` runs :func:`recognises` for
every ``--data``.
"""

from __future__ import annotations

import json
from pathlib import Path

from splat_framework.plugin import DataparserSpec

SCENE = "scene.json"


def recognises(folder: Path) -> bool:
    """Whether ``folder`` holds a ``scene.json``."""
    return (Path(folder) / SCENE).is_file()


def load_scene_json(root: Path, *, views="all", downscale: float | None = None):
    """The :class:`SceneData` of the ``scene.json`` folder ``root`` (see the module docstring); a
    one-line DataError naming the file for anything missing or malformed."""
    import torch

    from splat_framework.plugin import Camera, DataError, build_scene, read_image_size

    path = Path(root) / SCENE
    try:
        meta = json.loads(path.read_text())
        near, far, frames = float(meta["near"]), float(meta["far"]), list(meta["frames"])
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise DataError(f"{path}: not a scene.json with near, far and frames ({type(e).__name__}: {e})") from None
    if not frames or not 0 < near < far:
        raise DataError(f"{path}: needs frames and 0 < near < far (got {len(frames)} frames, {near:g}, {far:g})")
    scale = 1.0 / float(downscale or 1.0)
    cameras, images, train, test = [], [], [], []
    for i, frame in enumerate(frames):
        try:
            image = Path(root) / frame["image"]
            K = torch.tensor(frame["K"], dtype=torch.float32)
            w2c = torch.tensor(frame["world_to_camera"], dtype=torch.float32)
        except (KeyError, TypeError, ValueError) as e:
            raise DataError(f"{path}: frame {i} needs image, K [3, 3] and world_to_camera [4, 4] ({e})") from None
        if K.shape != (3, 3) or w2c.shape != (4, 4):
            raise DataError(f"{path}: frame {i}: K must be 3x3 and world_to_camera 4x4")
        width, height = read_image_size(image)
        cameras.append(Camera(K, w2c, width, height, near, far, name=image.stem).scaled(scale))
        images.append(image)
        (test if frame.get("split") == "test" else train).append(i)
    if views != "all":
        if views > len(train):
            raise DataError(f"{path}: views={views} asks for more than the {len(train)} training frames")
        train = train[:views]
    return build_scene(Path(root), "scene-json", cameras, images, train, test, image_scale=scale)


dataparser = DataparserSpec(
    marker=SCENE,
    recognises=recognises,
    load="splat_example_plugin.scene_json:load_scene_json",
)
"""The entry point ``scene-json`` of the group ``splat_framework.dataparsers``."""
