"""``splat-export RUN_DIR --ply out.ply``: write a run's Gaussians as a 3DGS-layout PLY for splat viewers."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from tyro.conf import Positional, arg


@dataclass
class ExportArgs:
    run_dir: Annotated[Positional[Path], arg(metavar="RUN_DIR")]
    """Run folder written by splat-train."""
    ply: Path | None = None
    """Output PLY file (default RUN_DIR/point_cloud.ply)."""
    device: str = "cpu"
    """Torch device used to load the checkpoint."""
    trust_edited_config: bool = False
    """Use the run's config.json even when its checksum is missing or does not match (edited by hand)."""


def main(args: ExportArgs) -> Path:
    from ..errors import DataError
    from ..export import export_ply
    from ..run import load_trained_model
    from ..run_lock import owned, writes_inside

    out = args.ply if args.ply is not None else Path(args.run_dir) / "point_cloud.ply"
    if out.is_dir():
        raise DataError(f"{out}: is a folder; --ply names the file to write (e.g. {out / 'point_cloud.ply'})")
    with owned(args.run_dir, writes=writes_inside(args.run_dir, out)):  # a PLY elsewhere only reads the run
        _, model = load_trained_model(args.run_dir, args.device, trust_edits=args.trust_edited_config)
        export_ply(model, out)
    print(f"wrote {model.num_gaussians} Gaussians to {out}")
    return out


def entrypoint() -> None:
    import tyro

    from .common import run_cli

    args = tyro.cli(
        ExportArgs, args=sys.argv[1:], prog="splat-export",
        description="Export a trained run as a 3DGS-layout PLY (opens in common Gaussian-splat viewers).",
    )
    run_cli(lambda: main(args))


if __name__ == "__main__":
    entrypoint()
