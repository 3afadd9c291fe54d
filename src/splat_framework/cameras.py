"""Pinhole cameras in the OpenCV convention.

Camera space: x right, y down, z forward (the camera looks down +z). A pixel
(u, v) has its centre at (u + 0.5, v + 0.5) in continuous image coordinates,
so the projection of a camera-space point (x, y, z) is
``u = fx * x / z + cx``, ``v = fy * y / z + cy`` with the principal point
(cx, cy) given in those continuous coordinates (``cx = W / 2`` for a centred
principal point).

Parsers convert their datasets' conventions (LLFF's "down, right, back",
Blender's OpenGL axes) into this one once, at load time.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch
from torch import Tensor


def scaled_size(width: int, height: int, scale: float) -> tuple[int, int]:
    """(width, height) of an image of ``width`` x ``height`` resized by ``scale``.

    The single rounding rule shared by cameras, parsers (camera sizes) and decoders.
    """
    if scale == 1.0:
        return int(width), int(height)
    return max(1, int(round(width * scale))), max(1, int(round(height * scale)))


@dataclass(frozen=True)
class Camera:
    """One posed pinhole camera.

    Attributes:
        K: [3, 3] intrinsics (fx, fy, cx, cy; zero skew).
        world_to_cam: [4, 4] rigid transform from world to camera space.
        width: image width in pixels.
        height: image height in pixels.
        near: nearest scene depth seen by this camera (camera z, > 0).
        far: farthest scene depth seen by this camera.
        name: image name (for logs and file names).
    """

    K: Tensor
    world_to_cam: Tensor
    width: int
    height: int
    near: float = 0.01
    far: float = 100.0
    name: str = ""

    # ------------------------------------------------------------------ basics
    @property
    def device(self) -> torch.device:
        return self.K.device

    def to(self, device: torch.device | str) -> "Camera":
        return replace(self, K=self.K.to(device), world_to_cam=self.world_to_cam.to(device))

    @property
    def cam_to_world(self) -> Tensor:
        """[4, 4] inverse of ``world_to_cam``."""
        return torch.linalg.inv(self.world_to_cam)

    @property
    def center(self) -> Tensor:
        """[3] camera centre in world space."""
        R = self.world_to_cam[:3, :3]
        t = self.world_to_cam[:3, 3]
        return -R.T @ t

    def scaled(self, factor: float) -> "Camera":
        """The same camera for an image resized by ``factor`` (0.5 halves it; the size from
        :func:`scaled_size`, the one rounding rule): :meth:`resized`."""
        return self.resized(*scaled_size(self.width, self.height, factor))

    def resized(self, width: int, height: int) -> "Camera":
        """The same camera for its image resampled to ``width`` x ``height``: each axis of the
        intrinsics scaled by its own ratio (new size / old size), so that every pixel's footprint
        maps exactly (an area-averaged image of any size lines up with it)."""
        K = self.K.clone()
        K[0] *= width / self.width
        K[1] *= height / self.height
        return replace(self, K=K, width=int(width), height=int(height))

    def with_focal_factor(self, factor: "float | Tensor") -> "Camera":
        """The same camera with its focal lengths (fx, fy) times ``factor`` (a float, or a 0-d tensor
        that gradients flow through); the principal point and the image size are kept."""
        factor = torch.as_tensor(factor).to(self.K)
        focal_entries = torch.diag(torch.tensor([1.0, 1.0, 0.0], dtype=self.K.dtype, device=self.K.device))
        return replace(self, K=self.K * (1.0 + (factor - 1.0) * focal_entries))

    def shifted_sideways(self, shift: float) -> "Camera":
        """The camera moved by ``shift`` (world units) along its own x axis (image right): a stereo
        partner, in which a point at camera depth z appears ``K[0, 0] * shift / z`` pixels further left."""
        w2c = self.world_to_cam.clone()
        w2c[0, 3] -= shift
        return replace(self, world_to_cam=w2c)

    def between(self, other: "Camera", t: float) -> "Camera":
        """A camera on the way from this one (``t`` = 0) to ``other`` (1): the centre moved linearly,
        the rotation the nearest one to the blend ``(1 - t) R + t R_other`` (for the small angles
        between neighbouring views, within a hair of the geodesic); this camera's intrinsics and size."""
        R0, R1 = self.world_to_cam[:3, :3], other.world_to_cam[:3, :3].to(self.world_to_cam)
        U, _, Vh = torch.linalg.svd((1 - t) * R0 + t * R1)
        one = U.new_ones(())  # a reflection (rotations about 180 degrees apart) turned back, without a host read
        R = (U * torch.stack([one, one, torch.linalg.det(U @ Vh).sign()])) @ Vh
        centre = (1 - t) * self.center + t * other.center.to(self.world_to_cam)
        w2c = torch.eye(4, dtype=self.world_to_cam.dtype, device=self.world_to_cam.device)
        w2c[:3, :3] = R
        w2c[:3, 3] = -R @ centre
        return replace(self, world_to_cam=w2c)

    # ------------------------------------------------------------- geometry
    def world_to_camera_points(self, points: Tensor) -> Tensor:
        """[..., 3] world points -> [..., 3] camera-space points."""
        R = self.world_to_cam[:3, :3].to(points.dtype)
        t = self.world_to_cam[:3, 3].to(points.dtype)
        return points @ R.T + t

    def project(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """Project world points.

        Args:
            points: [..., 3] world-space points.

        Returns:
            uv: [..., 2] continuous pixel coordinates (pixel centres at +0.5).
            z: [...] camera-space depth (may be <= 0 for points behind).
        """
        pc = self.world_to_camera_points(points)
        z = pc[..., 2]
        K = self.K.to(points.dtype)
        zs = torch.where(z.abs() < 1e-12, torch.full_like(z, 1e-12), z)
        u = K[0, 0] * pc[..., 0] / zs + K[0, 2]
        v = K[1, 1] * pc[..., 1] / zs + K[1, 2]
        return torch.stack([u, v], dim=-1), z

    def pixel_rays(self, uv: Tensor) -> tuple[Tensor, Tensor]:
        """Rays through continuous pixel coordinates.

        Args:
            uv: [..., 2] pixel coordinates (use ``+ 0.5`` for pixel centres).

        Returns:
            origins: [..., 3] the camera centre, broadcast.
            directions: [..., 3] unit directions in world space.
        """
        K = self.K.to(uv.dtype)
        x = (uv[..., 0] - K[0, 2]) / K[0, 0]
        y = (uv[..., 1] - K[1, 2]) / K[1, 1]
        d_cam = torch.stack([x, y, torch.ones_like(x)], dim=-1)
        R = self.world_to_cam[:3, :3].to(uv.dtype)
        d = d_cam @ R  # R^T d_cam, row-vector form
        d = d / d.norm(dim=-1, keepdim=True)
        o = self.center.to(uv.dtype).expand_as(d)
        return o, d

    def unproject_depth(self, uv: Tensor, z: Tensor) -> Tensor:
        """World points at camera depth ``z`` (camera z, not ray length) on pixels ``uv``.

        Args:
            uv: [..., 2] pixel coordinates.
            z: [...] camera-space depth.

        Returns:
            [..., 3] world points.
        """
        K = self.K.to(uv.dtype)
        x = (uv[..., 0] - K[0, 2]) / K[0, 0] * z
        y = (uv[..., 1] - K[1, 2]) / K[1, 1] * z
        pc = torch.stack([x, y, z], dim=-1)
        R = self.world_to_cam[:3, :3].to(uv.dtype)
        t = self.world_to_cam[:3, 3].to(uv.dtype)
        return (pc - t) @ R


def look_at(eye: Tensor, target: Tensor, up: Tensor) -> Tensor:
    """[4, 4] world-to-camera matrix (OpenCV axes) for a camera at ``eye`` looking at ``target``.

    ``up`` is the world direction that should appear upwards in the image.
    """
    eye, target, up = (torch.as_tensor(a, dtype=torch.float64) for a in (eye, target, up))
    z = target - eye
    z = z / z.norm()
    x = torch.linalg.cross(z, up)
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    R = torch.stack([x, y, z], dim=0)  # rows: camera axes in world space
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ eye
    return w2c


def intrinsics(fx: float, fy: float, cx: float, cy: float) -> Tensor:
    """[3, 3] float32 intrinsics matrix."""
    return torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=torch.float32)


def camera_centers(w2c: np.ndarray) -> np.ndarray:
    """[M, 3] camera centres -R^T t of world-to-camera matrices [M, 3 or 4, 4]."""
    return -np.einsum("nji,nj->ni", w2c[:, :3, :3], w2c[:, :3, 3])


def pose_differences(a_w2c: np.ndarray, b_w2c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rotation angles in degrees [M], camera-centre distances [M]) between two sets of
    world-to-camera matrices [M, 3 or 4, 4]."""
    rel = b_w2c[:, :3, :3] @ np.transpose(a_w2c[:, :3, :3], (0, 2, 1))
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(cos)), np.linalg.norm(camera_centers(a_w2c) - camera_centers(b_w2c), axis=1)


def view_angle(cam_a: Camera, cam_b: Camera) -> float:
    """Angle in degrees between the optical axes of two cameras."""
    za = cam_a.world_to_cam[2, :3].detach().cpu().double().numpy()
    zb = cam_b.world_to_cam[2, :3].detach().cpu().double().numpy()
    cos = float(za @ zb / max(np.linalg.norm(za) * np.linalg.norm(zb), 1e-12))
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
