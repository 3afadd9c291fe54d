"""``splat-scene``: generate a built-in synthetic dataset (no download needed).

Examples::

    splat-scene forward --out data/forward --width 504 --height 378 --views 20 --seed 0
    splat-scene object --out data/object            # Blender format, 100 train + 40 test
    splat-scene forward                             # into the cache, as `--data synthetic/forward` would

Heavy imports (numpy, cv2, torch) happen only after argument parsing, so
``--help`` stays fast.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import tyro
from pydantic import Field

from ..config import SplatConfig

MAX_SIDE = 8192
"""Largest image width or height (pixels) of a synthetic scene."""
MAX_VIEWS = 1000
"""Largest number of views (``--views``) of a synthetic scene."""
ImageSide = Annotated[int, Field(ge=4, le=MAX_SIDE)]


class SceneArgs(SplatConfig):
    """Render a synthetic scene with the analytic ray caster and write it as a dataset."""

    kind: tyro.conf.Positional[Literal["forward", "object"]]
    """forward: LLFF-like forward-facing scene (LLFF format); object: Blender-like 360 degree object (RGBA, Blender format)."""
    out: Path | None = None
    """Output folder. Default: the synthetic-scene cache ($SPLAT_CACHE/synthetic or ~/.cache/splat/synthetic), reused if already generated."""
    width: ImageSide | None = None
    """Image width in pixels, 4 to 8192 (default: forward 504, object 400)."""
    height: ImageSide | None = None
    """Image height in pixels, 4 to 8192 (default: forward 378, object 400)."""
    views: Annotated[int, Field(ge=1, le=MAX_VIEWS)] | None = None
    """forward: number of images (default 20); object: number of training frames (default 100), plus 40% as many test frames; 1 to 1000."""
    seed: int = Field(0, ge=0, lt=2**32)
    """Seed for the layout, textures and cameras; the same seed gives byte-identical files."""
    overwrite: bool = False
    """Replace --out when it is a scene folder that splat-scene wrote (only its own files are removed)."""


def main(args: SceneArgs) -> Path:
    import time

    from rich.console import Console
    from rich.table import Table

    from ..data.synthetic.generate import DEFAULTS, ensure_generated, generate_scene
    from ..files.output_paths import SCENE_FOLDER, check_output, install_output
    from ..files.work_folder import building

    console = Console()
    dflt = DEFAULTS[args.kind]
    params = dict(
        kind=args.kind,
        width=dflt["width"] if args.width is None else args.width,
        height=dflt["height"] if args.height is None else args.height,
        n_views=dflt["n_views"] if args.views is None else args.views,
        seed=args.seed,
    )
    if args.out is not None:
        check_output(args.out, SCENE_FOLDER, overwrite=args.overwrite)  # every refusal before any work
    t0 = time.perf_counter()
    with console.status(f"rendering the {args.kind} scene ({params['width']}x{params['height']})..."):
        if args.out is None:
            out = ensure_generated(args.kind, params)
        else:  # built beside --out and moved into place at the end: Ctrl-C leaves nothing half-written
            p = dict(params)
            with building(args.out, lambda staged, out: install_output(staged, out, SCENE_FOLDER)) as work:
                generate_scene(p.pop("kind"), work, **p)
            out = args.out
    dt = time.perf_counter() - t0

    table = Table(title=f"synthetic {args.kind} scene (seed {args.seed}) in {out}")
    table.add_column("what")
    table.add_column("where")
    if args.kind == "forward":
        n_img = len(list((out / "images").glob("*.png")))
        table.add_row(f"{n_img} RGB images {params['width']}x{params['height']}", "images/*.png")
        table.add_row("LLFF poses + bounds [N, 17]", "poses_bounds.npy")
        table.add_row("depth maps (float32 camera z, 0 = none)", "depths/*.npy")
    else:
        n_train = len(list((out / "train").glob("*.png")))
        n_test = len(list((out / "test").glob("*.png")))
        table.add_row(f"{n_train} train + {n_test} test RGBA images {params['width']}x{params['height']}",
                      "train/*.png, test/*.png")
        table.add_row("Blender cameras (OpenGL c2w)", "transforms_train.json, transforms_test.json")
        table.add_row("depth maps (float32 camera z, 0 = none)", "depths/train/*.npy, depths/test/*.npy")
    table.add_row("exact cameras (OpenCV K, world_to_cam)", "cameras.json")
    table.add_row("generator parameters", "scene.json")
    console.print(table)
    console.print(f"done in {dt:.1f} s: [bold]{out}[/bold]")
    return out


def entrypoint() -> None:
    from .common import parse_cli, run_cli

    run_cli(lambda: main(parse_cli(SceneArgs, prog="splat-scene", field_prefix="")))


if __name__ == "__main__":
    entrypoint()
