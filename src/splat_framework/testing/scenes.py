"""The built-in tiny scenes, for a test's commands: generated once into the test's own cache."""

from __future__ import annotations

from pathlib import Path

TINY_SCENES = ("forward-tiny", "object-tiny")
"""The built-in scenes small enough for a test: ``forward-tiny`` (64x48, 20 forward-facing views) and
``object-tiny`` (64x64, 100 training and 40 test views around an object)."""


def tiny_scene(cache: Path, name: str = "forward-tiny") -> str:
    """Generate the built-in scene ``name`` (one of :data:`TINY_SCENES`) into ``cache``, the folder
    that ``SPLAT_CACHE`` names for the test's commands (``cli_env(SPLAT_CACHE=cache)``), unless it is
    there; returns ``"synthetic/<name>"``, the ``--data`` that names it. Generated before a command
    runs, the scene adds no "generating" line to what the command prints."""
    if name not in TINY_SCENES:
        raise ValueError(f"{name!r} is not a tiny scene; choose one of {', '.join(TINY_SCENES)}")
    from ..data.synthetic.generate import ensure_scene

    ensure_scene(name, Path(cache) / "synthetic")
    return f"synthetic/{name}"
