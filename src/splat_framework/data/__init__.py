"""Datasets: parsers, few-shot splits, image decoding and the data manager."""

from .datamanager import DataManager
from .images import load_alpha, load_image, read_image_size
from .parsers import detect_format, load_scene
from .pose_file import apply_pose_file
from .run_data import describe_split, record_data, resolve_views
from .scene import DataError, SceneData
from .splits import blender_split, dtu_split, llff_split


__all__ = [
    "DataError",
    "DataManager",
    "SceneData",
    "apply_pose_file",
    "blender_split",
    "detect_format",
    "describe_split",
    "dtu_split",
    "llff_split",
    "load_alpha",
    "load_image",
    "load_scene",
    "read_image_size",
    "record_data",
    "resolve_views",
]
