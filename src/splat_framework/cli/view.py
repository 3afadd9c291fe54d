"""``splat-view RUN_DIR``: look around a trained model in a web browser (viser; works headless)."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from tyro.conf import Positional, arg


@dataclass
class ViewArgs:
    run_dir: Annotated[Positional[Path], arg(metavar="RUN_DIR")]
    """Run folder written by splat-train."""
    port: int = 8080
    """TCP port of the viewer (0 = any free port)."""
    host: str = "0.0.0.0"
    """Interface to listen on (0.0.0.0: reachable from other machines; 127.0.0.1: this one only)."""
    device: str | None = None
    """Torch device of the 'Render with splat' button (default: the run's)."""
    trust_edited_config: bool = False
    """Use the run's config.json even when its checksum is missing or does not match (edited by hand)."""


def main(args: ViewArgs, serve: bool = True):
    from ..viewer import view_run

    viewer = view_run(args.run_dir, args.port, args.host, args.device, args.trust_edited_config)
    print(f"viewer of {args.run_dir} ({viewer.num_splats:,} Gaussians) at {viewer.url}  (Ctrl-C to stop)", flush=True)
    if not serve:
        return viewer
    viewer.serve_until_interrupted()
    return None


def entrypoint() -> None:
    import tyro

    from .common import run_cli

    args = tyro.cli(ViewArgs, args=sys.argv[1:], prog="splat-view",
                    description="Open a trained run in a web viewer: the Gaussians, the cameras, and splat's own renders.")
    run_cli(lambda: main(args))


if __name__ == "__main__":
    entrypoint()
