"""Training cameras from a pose file: a scene trained on poses estimated from its training photos.

The benchmarks' ``--poses estimated`` protocol (pose-free few-shot methods: the training
views' poses and focal lengths come from SfM on the training photos alone, moved into the
dataset's frame by the similarity that best aligns them to the dataset's training cameras;
the test views keep the dataset's poses and are scored after a test-time pose fit) needs
the scene with its training cameras replaced and nothing else changed, but one thing: where the
file gives every training view the same focal length relative to the dataset's (one camera,
calibrated once, as SfM on the few photos does), the test views, photos of that same camera,
take that focal length too. Scored at the dataset's focal length instead, a model trained at the
estimated one is rendered zoomed against its test photos, an error of the calibration that the
test-time pose fit cannot remove (fern, 4 % long: 0.9 dB; 0.1 dB with the shared focal length).
A pose file says which cameras; ``TrainConfig.train_poses`` applies it to any dataset format.

File (JSON)::

    {"views": [{"index": 3, "name": "IMG_4026", "width": 1008, "height": 756,
                "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "world_to_cam": [[...4x4...]]}, ...],
     "info": {...how the poses were made, their errors...}}

``index`` is the camera's index in the scene (as parsed, all views); ``K`` is in pixels of
``width`` x ``height`` and is rescaled to the size the scene is loaded at.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import torch

from ..cameras import Camera
from ..errors import DataError
from .scene import SceneData


def pose_file_payload(cameras: dict[int, Camera], info: dict) -> dict:
    """The JSON payload of a pose file holding ``cameras`` ({scene index: camera})."""
    views = [{"index": int(i), "name": c.name, "width": int(c.width), "height": int(c.height),
              "K": c.K.double().tolist(), "world_to_cam": c.world_to_cam.double().tolist()}
             for i, c in sorted(cameras.items())]
    return {"views": views, "info": info}


def _view(entry: dict) -> str:
    """``view 3 (IMG_4026)``: a pose file's entry by its index and, where it has one, its image's name."""
    name = entry.get("name")
    return f"view {entry.get('index')}" + (f" ({name})" if name else "")


def _matrix(path: Path, entry: dict, key: str, shape: tuple[int, int]) -> torch.Tensor:
    """The entry's matrix ``key`` of ``shape`` (float64); a one-line DataError naming the view when it is not one."""
    try:
        m = torch.tensor(entry[key], dtype=torch.float64)
    except (KeyError, TypeError, ValueError):
        raise DataError(f"{path}: {_view(entry)}: '{key}' missing or not a {shape[0]}x{shape[1]} "
                        "matrix of numbers") from None
    if tuple(m.shape) != shape or not bool(torch.isfinite(m).all()):
        raise DataError(f"{path}: {_view(entry)}: '{key}' is not a finite {shape[0]}x{shape[1]} matrix")
    return m


def apply_pose_file(scene: SceneData, path: Path | str) -> SceneData:
    """``scene`` with each training camera replaced by the pose file's camera of the same index
    (intrinsics rescaled to the scene's image size; near/far and name kept). Where every training
    camera's focal lengths changed by the same factor (one camera), the test cameras' focal lengths
    are scaled by it too; their poses, the images, masks and the scene bounds are untouched.

    Raises DataError (one line naming the file) when the file is unreadable, malformed, lacks
    a training view, or was written for images of another name or aspect ratio."""
    path = Path(path)
    try:
        payload = json.loads(path.read_text(encoding="utf-8"))
        entries = {int(e["index"]): e for e in payload["views"]}
    except OSError as e:
        raise DataError(f"{path}: cannot read the pose file ({e.strerror or e})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DataError(f"{path}: not a JSON pose file ({e})") from None
    except (KeyError, TypeError, ValueError):
        raise DataError(f"{path}: not a pose file (expected {{\"views\": [{{\"index\": ..., ...}}]}})") from None
    cameras = list(scene.cameras)
    for i in scene.train_indices:
        if i not in entries:
            raise DataError(f"{path}: no camera for training view {i} ({cameras[i].name or 'unnamed'}); "
                            "the file was written for another scene or view count")
        entry, old = entries[i], cameras[i]
        if entry.get("name") and old.name and entry["name"] != old.name:
            raise DataError(f"{path}: view {i} is '{entry['name']}' in the file but '{old.name}' in the scene")
        try:
            width, height = int(entry["width"]), int(entry["height"])
        except (KeyError, TypeError, ValueError):
            width = height = 0
        if width <= 0 or height <= 0 or not math.isclose(width / height, old.width / old.height, rel_tol=0.02):
            raise DataError(f"{path}: {_view(entry)}: size {entry.get('width')}x{entry.get('height')} does not "
                            f"have the scene's aspect ratio ({old.width}x{old.height})")
        K = _matrix(path, entry, "K", (3, 3)).to(old.K.dtype)
        w2c = _matrix(path, entry, "world_to_cam", (4, 4)).to(old.world_to_cam.dtype)
        new = Camera(K=K, world_to_cam=w2c, width=width, height=height).scaled(old.width / width)
        cameras[i] = replace(old, K=new.K, world_to_cam=new.world_to_cam)
    factor = shared_focal_factor([scene.cameras[i] for i in scene.train_indices], [cameras[i] for i in scene.train_indices])
    if factor is not None:
        for i in scene.test_indices:
            cameras[i] = cameras[i].with_focal_factor(factor)
    return replace(scene, cameras=cameras, extras={**scene.extras, "train_poses": str(path)})


def shared_focal_factor(before: list[Camera], after: list[Camera], tolerance: float = 1e-3) -> float | None:
    """The factor by which every camera's focal lengths (fx and fy) went from ``before`` to
    ``after``, when it is one factor within ``tolerance`` (relative), else None."""
    factors = [float(b.K[axis, axis] / a.K[axis, axis]) for a, b in zip(before, after) for axis in (0, 1)]
    if not factors or max(factors) > min(factors) * (1 + tolerance):
        return None
    return sum(factors) / len(factors)


__all__ = ["apply_pose_file", "pose_file_payload"]
