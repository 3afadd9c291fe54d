"""Estimated cameras against true ones: the Sim(3) alignment of their centres and the pose errors after it."""

from __future__ import annotations

import itertools

import numpy as np

from ..cameras import camera_centers, pose_differences
from ..errors import DataError
from .colmap import load_pycolmap


def align_sim3(est_w2c: np.ndarray, true_w2c: np.ndarray) -> np.ndarray:
    """World-to-camera matrices [M, 4, 4] of the estimated cameras moved into the true cameras'
    frame by the similarity that best maps their centres onto the true ones (Umeyama,
    ``pycolmap.estimate_sim3d``); the true frame's units."""
    pycolmap = load_pycolmap()
    sim = pycolmap.estimate_sim3d(camera_centers(est_w2c), camera_centers(true_w2c))
    if sim is None:
        raise DataError("the estimated camera centres are degenerate; no similarity aligns them")
    m = np.asarray(sim.matrix())  # [3, 4] = [s R | t]: x_true = s R x_est + t
    out = np.tile(np.eye(4), (len(est_w2c), 1, 1))
    out[:, :3, :3] = est_w2c[:, :3, :3] @ (m[:, :3] / float(sim.scale)).T
    out[:, :3, 3] = -np.einsum("nij,nj->ni", out[:, :3, :3], camera_centers(est_w2c) @ m[:, :3].T + m[:, 3])
    return out


def sim3_errors(est_w2c: np.ndarray, true_w2c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pose errors after :func:`align_sim3`: (rotation errors in degrees [M], camera-centre
    errors [M] in the true frame's units) of world-to-camera matrices [M, 3 or 4, 4]."""
    return pose_differences(align_sim3(est_w2c, true_w2c), true_w2c)


def pose_errors(est_w2c: np.ndarray, true_w2c: np.ndarray) -> dict:
    """Errors of estimated world-to-camera matrices [M, 4, 4] against the true ones (lists of
    floats): ``rotation_deg`` and ``center_error_rel_spread`` (centre error over the extent of
    the true centres) after :func:`align_sim3`, and ``translation_direction_deg``, the angle
    between estimated and true direction from camera i to camera j, seen from camera i, over
    every ordered pair (scale- and frame-free)."""
    rot, center = sim3_errors(est_w2c, true_w2c)

    def directions(w2c: np.ndarray) -> list[np.ndarray]:
        c = camera_centers(w2c)
        t = [w2c[i, :3, :3] @ (c[j] - c[i]) for i, j in itertools.permutations(range(len(w2c)), 2)]
        return [v / np.linalg.norm(v) for v in t]

    dirs = [float(np.degrees(np.arccos(np.clip(a @ b, -1, 1)))) for a, b in zip(directions(est_w2c), directions(true_w2c))]
    true_c = camera_centers(true_w2c)
    spread = np.linalg.norm(true_c.max(0) - true_c.min(0))
    return {"rotation_deg": rot.tolist(), "translation_direction_deg": dirs,
            "center_error_rel_spread": (center / spread).tolist()}
