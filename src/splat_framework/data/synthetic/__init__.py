"""Built-in synthetic scenes, rendered by an analytic ray caster and written as real datasets.

Two scenes, deterministic from a seed, need no download:

* ``"forward"``: an LLFF-like forward-facing scene (textured back wall, floor,
  cards, boxes, spheres and cylinders between z ~ 2 and ~ 10; 60 degree
  horizontal FoV; cameras on a spiral of radius 0.4). Default 504x378, 20 views.
* ``"object"``: a Blender-like 360 degree scene (a composed textured object,
  cameras on the upper hemisphere at radius 4, RGBA with transparent
  background). Default 400x400, 100 train + 40 test frames.

Images are rendered with :mod:`.raycast` (exact ray/primitive intersections,
texture coordinates attached to each surface, mip-mapped procedural textures,
Lambertian + ambient shading, no view-dependent effects).

On-disk layout
--------------
forward (LLFF)::

    poses_bounds.npy      float64 [N, 17]: per image the 3x5 matrix [R | t | hwf]
                          flattened row-major, then near, far. R's columns are the
                          camera's LLFF axes (down, right, back) in world
                          coordinates, i.e. OpenCV c2w columns [y, x, -z]; so
                          OpenCV c2w rotation = [col1, col0, -col2]. t = camera
                          centre, hwf = [H, W, focal]. near/far = min/max of the
                          view's depth map.
    images/image000.png   RGB, sorted by name in pose order
    depths/image000.npy   depth map (below)

object (Blender)::

    transforms_train.json camera_angle_x + frames {file_path "./train/r_0",
    transforms_test.json  transform_matrix}: 4x4 camera-to-world in OpenGL axes
                          (x right, y up, looking down -z); OpenCV c2w =
                          transform_matrix @ diag(1, -1, -1, 1)
    train/r_0.png ...     RGBA, alpha 0 on the background (RGB 0 there)
    test/r_0.png ...
    depths/train/r_0.npy  depth maps (below)

both::

    cameras.json          exact cameras: {"format", "convention", "views": [{"name",
                          "image" (path relative to the dataset), "split"
                          (Blender: "train"/"test"; LLFF: null), "width",
                          "height", "K" (OpenCV 3x3, principal point in
                          continuous pixel coordinates, pixel centres at
                          +0.5), "world_to_cam" (4x4, OpenCV axes), "near",
                          "far", "depth" (path of the depth map)}]}
    scene.json            generator name/version, kind, seed, size, view counts
                          and the primitive/light description.

Depth maps: ``depths/<image path relative to the image folder, with .npy>``
(LLFF ``depths/image000.npy``; Blender ``depths/train/r_0.npy``), float32
[H, W], the camera-space z (not the ray length) of the surface seen through
the pixel centre (u + 0.5, v + 0.5), exact up to float32 rounding; 0 where the
ray hits nothing (Blender background).

API: :func:`generate_scene` writes a dataset; :func:`ensure_scene` returns a
cached, atomically generated named scene ("forward", "object",
"forward-tiny", "object-tiny").
"""

from .generate import (
    GENERATOR_VERSION,
    NAMED_SCENES,
    build_scene,
    default_cache_dir,
    ensure_scene,
    generate_scene,
    render_view,
)
from .raycast import Hits, Scene, cast_rays

__all__ = [
    "GENERATOR_VERSION",
    "NAMED_SCENES",
    "Hits",
    "Scene",
    "build_scene",
    "cast_rays",
    "default_cache_dir",
    "ensure_scene",
    "generate_scene",
    "render_view",
]
