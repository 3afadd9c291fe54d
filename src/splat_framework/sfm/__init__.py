"""Poses from photos: structure from motion with pycolmap, and the tools around it.

- :mod:`.reconstruct`: ``estimate_scene(images, out)``, photos to a posed COLMAP scene folder;
- :mod:`.own_photos`: one's own photos (or a video) as ``--data``: posed once, cached (:func:`resolve_data_path`);
- :mod:`.photos`: a folder's photos in natural order, decoded, checked and staged;
- :mod:`.photo_matchers`: the correspondences COLMAP maps from (SIFT or a registered matcher);
- :mod:`.colmap`: pycolmap itself, its database of matches and verified pair counts;
- :mod:`.video`: frames of a video, spread along it and sharp;
- :mod:`.alignment`: the Sim(3) alignment of estimated cameras to true ones, and pose errors;
- :mod:`.training_poses`: the benchmarks' estimated-poses protocol (a dataset's training views
  posed from their own photos alone);
- :mod:`.points`: the init kind "sfm", a model started from a dataset's structure-from-motion points.

pycolmap (PyPI; it ships COLMAP, runs on the CPU, downloads nothing) is an optional
dependency: ``pip install "splat-framework[process]"``.
"""

from ..cameras import camera_centers
from .alignment import align_sim3, pose_errors, sim3_errors
from .own_photos import resolve_data_path
from .photo_matchers import AUTO_MATCHER, AUTO_PREFERRED, PHOTO_MATCHER_GROUP, photo_matchers
from .photos import IMAGE_SUFFIXES, list_images
from .reconstruct import MAPPERS, SfmSummary, estimate_scene
from .training_poses import estimate_training_poses
from .video import pick_video_frames

__all__ = ["AUTO_MATCHER", "AUTO_PREFERRED", "IMAGE_SUFFIXES", "MAPPERS", "PHOTO_MATCHER_GROUP", "SfmSummary",
           "align_sim3", "camera_centers", "estimate_scene", "estimate_training_poses", "list_images",
           "photo_matchers", "pick_video_frames", "pose_errors", "resolve_data_path", "sim3_errors"]
