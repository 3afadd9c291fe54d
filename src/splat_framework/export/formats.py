"""splat-export's formats -> the function that writes each (``write(path, gaussians) -> path``);
their file extensions and output kinds: :data:`splat_framework.files.output_paths.EXPORT_FILES`."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from .compressed_ply import write_compressed_ply
from .ply import write_ply
from .sog import write_sog
from .splat import write_splat
from .spz import write_spz

__all__ = ["WRITERS"]

WRITERS: dict[str, Callable[[Path, dict], Path]] = {
    "ply": write_ply, "spz": write_spz, "sog": write_sog, "splat": write_splat, "compressed-ply": write_compressed_ply,
}
