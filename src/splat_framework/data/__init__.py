"""Datasets: parsers, few-shot splits, image decoding and the data manager."""

from .datamanager import DataManager
from .images import load_alpha, load_image, read_image_size
from .parsers import detect_format, load_scene
from .pose_file import apply_pose_file
from .resolve import resolve_data_path
from .run_data import describe_split, load_config_scene, record_data, resolve_views
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
    "load_config_scene",
    "load_image",
    "load_scene",
    "read_image_size",
    "record_data",
    "resolve_data_path",
    "resolve_views",
]
