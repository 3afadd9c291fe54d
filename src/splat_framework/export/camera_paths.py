"""Novel-view camera paths: a spiral for forward-facing scenes, an orbit for object scenes."""

from __future__ import annotations

import math

import torch

from ..cameras import Camera, look_at


def _axes(cameras: list[Camera]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Mean camera centre, mean forward (+z) and mean up (-y) world directions."""
    R = torch.stack([c.world_to_cam[:3, :3].double() for c in cameras])
    centers = torch.stack([c.center.double() for c in cameras])
    fwd = R[:, 2].mean(0)
    up = -R[:, 1].mean(0)
    return centers.mean(0), fwd / fwd.norm(), up / up.norm()


def spiral_path(cameras: list[Camera], frames: int = 120, rotations: int = 2) -> list[Camera]:
    """LLFF-style spiral around the mean training pose, looking at the mean focus depth."""
    center, fwd, up = _axes(cameras)
    right = torch.linalg.cross(fwd, up)
    centers = torch.stack([c.center.double() for c in cameras])
    offs = centers - center
    rad = torch.stack([(offs @ right).abs().quantile(0.9), (offs @ up).abs().quantile(0.9)])
    rad = torch.clamp(rad, min=0.05 * float(cameras[0].near))
    focus_depth = 1.0 / (0.25 / cameras[0].near + 0.75 / cameras[0].far)
    focus = center + fwd * focus_depth
    ref = cameras[0]
    path = []
    for i in range(frames):
        t = 2 * math.pi * rotations * i / frames
        eye = center + right * rad[0] * math.cos(t) + up * rad[1] * math.sin(t) + fwd * 0.1 * rad.mean() * math.sin(t / 2)
        w2c = look_at(eye, focus, up).to(ref.world_to_cam)
        path.append(Camera(ref.K, w2c, ref.width, ref.height, ref.near, ref.far, name=f"path{i:04d}"))
    return path


def orbit_path(cameras: list[Camera], center, frames: int = 120, elevation_deg: float = 30.0) -> list[Camera]:
    """Circle around ``center`` at the training cameras' mean distance, ``elevation_deg`` above its equator."""
    _, _, up = _axes(cameras)
    center = torch.as_tensor(center, dtype=torch.float64)
    dist = torch.stack([(c.center.double() - center).norm() for c in cameras]).mean()
    a = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    if abs(float(a @ up)) > 0.9:
        a = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    e1 = a - (a @ up) * up
    e1 = e1 / e1.norm()
    e2 = torch.linalg.cross(up, e1)
    el = math.radians(elevation_deg)
    ref = cameras[0]
    path = []
    for i in range(frames):
        t = 2 * math.pi * i / frames
        d = math.cos(el) * (math.cos(t) * e1 + math.sin(t) * e2) + math.sin(el) * up
        w2c = look_at(center + dist * d, center, up).to(ref.world_to_cam)
        path.append(Camera(ref.K, w2c, ref.width, ref.height, ref.near, ref.far, name=f"path{i:04d}"))
    return path
