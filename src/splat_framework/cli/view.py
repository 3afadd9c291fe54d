"""``splat-view RUN_DIR``: look around a trained model in a web browser (viser; works headless)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from tyro.conf import Positional, arg

from ..config.address import LOOPBACK, Port


@dataclass
class ViewArgs:
    run_dir: Annotated[Positional[Path], arg(metavar="RUN_DIR")]
    """Run folder written by splat-train."""
    port: Port = 8080
    """TCP port of the viewer, 0..65535 (0 = any free port; a port in use: the next free one, said in one line)."""
    host: str = LOOPBACK
    """Interface to listen on: 127.0.0.1, this machine only (default); any other address, e.g. 0.0.0.0 for every interface, lets other machines see the model, the photos' thumbnails and "Render with splat" (a warning says so)."""
    device: str | None = None
    """Torch device of the 'Render with splat' button (default: the run's)."""
    trust_edited_config: bool = False
    """Use the run's config.json even when its checksum is missing or does not match (edited by hand)."""


def main(args: ViewArgs, serve: bool = True):
    from ..viewer.scene_viewer import view_run

    print(f"{args.run_dir}: loading the newest checkpoint and the cameras, then serving the viewer", flush=True)
    viewer = view_run(args.run_dir, args.port, args.host, args.device, args.trust_edited_config)
    print(f"viewer of {args.run_dir} ({viewer.num_splats:,} Gaussians) at {viewer.url}  (Ctrl-C to stop)", flush=True)
    if not serve:
        return viewer
    viewer.serve_until_interrupted()
    return None


def entrypoint() -> None:
    from .common import parse_cli, run_cli

    run_cli(lambda: main(parse_cli(  # parsing inside run_cli: an invalid port is one line and exit 2
        ViewArgs, prog="splat-view",
        description="Open a trained run in a web viewer: the Gaussians, the cameras, and splat's own renders.",
    )))


if __name__ == "__main__":
    entrypoint()
