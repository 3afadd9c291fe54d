"""``splat-export RUN_DIR --ply out.ply``: write a run's Gaussians as a 3DGS-layout PLY for splat viewers."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from tyro.conf import Positional, arg


@dataclass
class ExportArgs:
    run_dir: Annotated[Positional[Path], arg(metavar="RUN_DIR")]
    """Run folder written by splat-train."""
    ply: Path | None = None
    """Output PLY file (default RUN_DIR/point_cloud.ply). A new file, or one splat-export wrote (with --overwrite)."""
    overwrite: bool = False
    """Replace --ply when it is a PLY that splat-export wrote (RUN_DIR/point_cloud.ply is always replaced)."""
    device: str = "cpu"
    """Torch device used to load the checkpoint."""
    trust_edited_config: bool = False
    """Use the run's config.json even when its checksum is missing or does not match (edited by hand)."""


def main(args: ExportArgs) -> Path:
    from ..files.output_paths import PLY_FILE, check_output, run_inputs

    out = args.ply if args.ply is not None else Path(args.run_dir) / "point_cloud.ply"
    check_output(out, PLY_FILE, overwrite=args.overwrite or args.ply is None, inputs=run_inputs(args.run_dir),
                 flag="--ply")  # before torch loads

    from ..console import starting

    with starting():
        from ..engine.run import load_trained_model
        from ..export.ply import export_ply
        from ..files.run_lock import owned, writes_inside

    with owned(args.run_dir, writes=writes_inside(args.run_dir, out)):  # a PLY elsewhere only reads the run
        _, model = load_trained_model(args.run_dir, args.device, trust_edits=args.trust_edited_config)
        export_ply(model, out)
    print(f"wrote {model.num_gaussians} Gaussians to {out}")
    return out


def entrypoint() -> None:
    from .common import parse_cli, run_cli

    run_cli(lambda: main(parse_cli(
        ExportArgs, prog="splat-export",
        description="Export a trained run as a 3DGS-layout PLY (opens in common Gaussian-splat viewers).",
    )))


if __name__ == "__main__":
    entrypoint()
