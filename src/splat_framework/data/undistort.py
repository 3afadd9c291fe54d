"""Lens distortion removed as each image is decoded, with OpenCV: every camera the framework sees is
a pinhole one.

A dataset that states distortion (transforms.json's ``k1`` ... ``p2`` or ``OPENCV_FISHEYE``,
COLMAP's SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV and fisheye models) gives its camera a
:class:`Lens` at the size its images are decoded; :func:`undistortion` turns it into the pinhole
camera the image becomes (:class:`Undistortion`: its intrinsics, size and the remap that makes it).
The new intrinsics follow gsplat's and nerfstudio's loaders:

- perspective (OpenCV's Brown-Conrady model: k1, k2, p1, p2, k3 and the rational k4, k5, k6):
  ``cv2.getOptimalNewCameraMatrix`` with alpha 0 (every pixel kept sees the photo), the image
  cropped to the rectangle it returns and the principal point moved by the crop;
- fisheye (OpenCV's Kannala-Brandt model: k1 ... k4): ``cv2.fisheye.estimateNewCameraMatrixForUndistortRectify``
  with balance 0, at the photo's size.

OpenCV puts pixel centres at integers, the framework at +0.5 (:mod:`splat_framework.cameras`):
the principal point is moved by half a pixel into OpenCV's convention and back. Pixels that map
a fraction of a pixel outside the photo take its edge's value (``BORDER_REPLICATE``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np

from ..errors import DataError

LensModel = Literal["perspective", "fisheye"]
ROUND_TRIP_PX = 0.5
"""Largest distance (pixels) between an undistorted pixel and the same pixel distorted and undistorted
again by OpenCV: beyond it the coefficients fold the image over (no one-to-one undistortion)."""


@dataclass(frozen=True)
class Lens:
    """A camera's lens as its dataset states it, for images decoded at ``size``.

    Attributes:
        model: "perspective" or "fisheye".
        fx, fy, cx, cy: intrinsics in decoded pixels (principal point with +0.5 pixel centres).
        coeffs: OpenCV's distortion coefficients: perspective (k1, k2, p1, p2, k3) or
            (k1, k2, p1, p2, k3, k4, k5, k6); fisheye (k1, k2, k3, k4).
        size: (width, height) of the decoded image.
    """

    model: LensModel
    fx: float
    fy: float
    cx: float
    cy: float
    coeffs: tuple[float, ...]
    size: tuple[int, int]

    def opencv_K(self) -> np.ndarray:
        """[3, 3] float64 intrinsics in OpenCV's convention (pixel centres at integers)."""
        return np.array([[self.fx, 0.0, self.cx - 0.5], [0.0, self.fy, self.cy - 0.5], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Undistortion:
    """How one decoded image of a :class:`Lens` becomes a pinhole image.

    Attributes:
        lens: the distorted camera.
        fx, fy, cx, cy: the pinhole intrinsics of the output (+0.5 pixel centres).
        crop: (x, y, width, height) of the output in the remapped image of the lens's size.
    """

    lens: Lens
    fx: float
    fy: float
    cx: float
    cy: float
    crop: tuple[int, int, int, int]

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the output."""
        return self.crop[2], self.crop[3]

    def apply(self, image: np.ndarray, *, nearest: bool = False) -> np.ndarray:
        """[H, W] or [H, W, C] float32 decoded at the lens's size -> the same at :attr:`size`,
        resampled bilinearly (``nearest``: nearest neighbour, for depth maps)."""
        import cv2

        if image.shape[:2] != self.lens.size[::-1]:
            raise ValueError(f"image is {image.shape[1]}x{image.shape[0]}, the lens {self.lens.size[0]}x{self.lens.size[1]}")
        map_x, map_y = _maps(self.lens, _new_K(self))
        out = cv2.remap(np.ascontiguousarray(image), map_x, map_y, cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
        x, y, w, h = self.crop
        return np.ascontiguousarray(out[y : y + h, x : x + w])


def _new_K(u: Undistortion) -> tuple[float, float, float, float]:
    """The output's intrinsics before the crop, in OpenCV's convention."""
    return u.fx, u.fy, u.cx - 0.5 + u.crop[0], u.cy - 0.5 + u.crop[1]


@lru_cache(maxsize=4)
def _maps(lens: Lens, new: tuple[float, float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's remap tables [H, W] float32 (the lens's size) from pinhole pixels of intrinsics
    ``new`` to the distorted photo; kept for the last few lenses (a scene's cameras usually share one)."""
    import cv2

    fx, fy, cx, cy = new
    P = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    D = np.array(lens.coeffs, dtype=np.float64)
    if lens.model == "fisheye":
        return cv2.fisheye.initUndistortRectifyMap(lens.opencv_K(), D, np.eye(3), P, lens.size, cv2.CV_32FC1)
    return cv2.initUndistortRectifyMap(lens.opencv_K(), D, None, P, lens.size, cv2.CV_32FC1)


def undistortion(lens: Lens, where: str) -> Undistortion:
    """The pinhole camera ``lens``'s images become (the rule in the module docstring); a DataError
    naming ``where`` when its coefficients are not finite or give no one-to-one pinhole image."""
    n = {"perspective": (5, 8), "fisheye": (4,)}[lens.model]
    if len(lens.coeffs) not in n:
        raise ValueError(f"a {lens.model} lens has {' or '.join(map(str, n))} coefficients, got {len(lens.coeffs)}")
    if not np.isfinite(lens.coeffs).all():
        raise DataError(f"{where}: non-finite distortion coefficients {_listed(lens.coeffs)}")
    out = _undistortion(lens)
    if out is None:
        raise DataError(f"{where}: the {lens.model} lens's distortion coefficients {_listed(lens.coeffs)} give no "
                        "one-to-one pinhole image (they fold the image over, or the lens sees 180 degrees or more)")
    return out


@lru_cache(maxsize=64)
def _undistortion(lens: Lens) -> Undistortion | None:
    """:func:`undistortion` of finite coefficients, None where they give no pinhole image; computed
    once per lens (the frames of a scene often share one)."""
    import cv2

    K, D = lens.opencv_K(), np.array(lens.coeffs, dtype=np.float64)
    w, h = lens.size
    if lens.model == "fisheye":
        P = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(K, D, lens.size, np.eye(3), balance=0.0)
        crop = (0, 0, w, h)
    else:
        P, roi = cv2.getOptimalNewCameraMatrix(K, D, lens.size, 0.0)
        crop = tuple(int(v) for v in roi)
    fx, fy, cx, cy = float(P[0, 0]), float(P[1, 1]), float(P[0, 2]), float(P[1, 2])
    out = Undistortion(lens, fx, fy, cx + 0.5 - crop[0], cy + 0.5 - crop[1], crop)
    ok = np.isfinite([fx, fy, cx, cy]).all() and fx > 0 and fy > 0 and crop[2] >= 1 and crop[3] >= 1
    with np.errstate(all="ignore"):  # absurd coefficients overflow: refused below, not warned about
        return out if ok and _round_trip_error(out) <= ROUND_TRIP_PX else None


def _round_trip_error(u: Undistortion, samples: int = 17) -> float:
    """Largest distance (pixels) between a grid of output pixels (of the remapped image, before the
    crop) and the same pixels distorted by the lens and undistorted again by OpenCV's iterative
    inverse; infinite where a pixel's distorted position is more than a pixel outside the photo."""
    import cv2

    fx, fy, cx, cy = _new_K(u)
    x0, y0, w, h = u.crop
    gx, gy = np.meshgrid(np.linspace(x0, x0 + w - 1, samples), np.linspace(y0, y0 + h - 1, samples))
    grid = np.stack([gx, gy], -1).reshape(-1, 2)
    rays = np.column_stack([(grid[:, 0] - cx) / fx, (grid[:, 1] - cy) / fy, np.ones(len(grid))]).reshape(-1, 1, 3)
    K, D = u.lens.opencv_K(), np.array(u.lens.coeffs, dtype=np.float64)
    P = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    zero = np.zeros(3)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    if u.lens.model == "fisheye":
        distorted, _ = cv2.fisheye.projectPoints(rays, zero, zero, K, D)
        back = cv2.fisheye.undistortPoints(distorted, K, D, R=np.eye(3), P=P, criteria=criteria)
    else:
        distorted, _ = cv2.projectPoints(rays, zero, zero, K, D)
        if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4 (OpenCV 5 folds the criteria into undistortPoints)
            back = cv2.undistortPointsIter(distorted, K, D, np.eye(3), P, criteria)
        else:
            back = cv2.undistortPoints(distorted, K, D, R=np.eye(3), P=P, criteria=criteria)
    distorted = distorted.reshape(-1, 2)
    (W, H), margin = u.lens.size, 1.0
    inside = ((distorted >= -0.5 - margin) & (distorted <= np.array([W, H]) - 0.5 + margin)).all(1)
    err = np.where(inside, np.linalg.norm(back.reshape(-1, 2) - grid, axis=1), np.inf)
    return float(np.nan_to_num(err, nan=np.inf).max())


def _listed(coeffs: tuple[float, ...]) -> str:
    return "(" + ", ".join(f"{c:g}" for c in coeffs) + ")"
