"""Datasets: parsers, few-shot splits, image decoding and the data manager."""

from .datamanager import DataManager
from .images import load_alpha, load_image, read_image_size
from .parsers import detect_format, load_scene
from .pose_file import apply_pose_file
from .resolve import resolve_data_path
from .scene import DataError, SceneData
from .splits import blender_split, dtu_split, llff_split



def load_config_scene(config) -> SceneData:
    """The scene a training config names (``data``, ``format``, ``views``, ``downscale``),
    its training cameras replaced from ``train_poses`` when set."""
    scene = load_scene(resolve_data_path(config.data), format=config.format, views=config.views,
                       downscale=config.downscale)
    return apply_pose_file(scene, config.train_poses) if config.train_poses is not None else scene


__all__ = [
    "DataError",
    "DataManager",
    "SceneData",
    "apply_pose_file",
    "blender_split",
    "detect_format",
    "dtu_split",
    "llff_split",
    "load_alpha",
    "load_config_scene",
    "load_image",
    "load_scene",
    "read_image_size",
    "resolve_data_path",
]
