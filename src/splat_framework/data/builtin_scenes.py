"""The built-in scenes' names and generator parameters (``--data synthetic/NAME``), in a module
of their own that imports nothing heavy: ``data.resolve`` suggests them for a mistyped ``--data``
before PyTorch, NumPy or OpenCV load; ``data.synthetic`` generates them."""

from __future__ import annotations

SYNTHETIC_PREFIX = "synthetic/"
"""What a ``--data`` naming a built-in scene starts with."""

NAMED_SCENES: dict[str, dict] = {
    "forward": dict(kind="forward", width=504, height=378, n_views=20, seed=0),
    "object": dict(kind="object", width=400, height=400, n_views=100, seed=0),
    "forward-tiny": dict(kind="forward", width=64, height=48, n_views=20, seed=0),
    "object-tiny": dict(kind="object", width=64, height=64, n_views=100, seed=0),
}
"""Scenes that :func:`splat_framework.data.synthetic.ensure_scene` knows by name."""


def builtin_scene_name(spec: object) -> str | None:
    """The NAME of a ``synthetic/NAME`` spec (either slash; "" when the name is missing), or None
    when ``spec`` does not name a built-in scene."""
    posix = str(spec).replace("\\", "/")
    return posix[len(SYNTHETIC_PREFIX):].strip("/") if posix.startswith(SYNTHETIC_PREFIX) else None


def unknown_scene_message(name: str) -> str | None:
    """The one line refusing ``synthetic/NAME`` when NAME is missing or names no built-in scene (with
    the closest name and the known ones), or None when it names one. Torch-free: ``splat-train``
    says it before PyTorch loads, and the generator says the same."""
    from ..errors import did_you_mean

    if not name:
        return f"{SYNTHETIC_PREFIX}: missing synthetic scene name ({SYNTHETIC_PREFIX}<name>)"
    if name in NAMED_SCENES:
        return None
    return (f"{SYNTHETIC_PREFIX}{name}: unknown synthetic scene{did_you_mean(name, NAMED_SCENES)} "
            f"(known: {', '.join(NAMED_SCENES)})")
