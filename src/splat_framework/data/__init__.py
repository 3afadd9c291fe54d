"""Datasets: parsers, few-shot splits, image decoding and the data manager."""

from .datamanager import DataManager
from .images import load_alpha, load_image, read_image_size
from .parsers import detect_format, load_scene
from .resolve import resolve_data_path
from .scene import DataError, SceneData
from .splits import blender_split, dtu_split, llff_split

__all__ = [
    "DataError",
    "DataManager",
    "SceneData",
    "blender_split",
    "detect_format",
    "dtu_split",
    "llff_split",
    "load_alpha",
    "load_image",
    "load_scene",
    "read_image_size",
    "resolve_data_path",
]
