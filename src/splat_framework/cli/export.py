"""``splat-export RUN_DIR --format spz sog``: write a run's Gaussians in the formats splat viewers open."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

from tyro.conf import Positional, arg

Format = Literal["ply", "spz", "sog", "splat", "compressed-ply"]


@dataclass
class ExportArgs:
    run_dir: Annotated[Positional[Path], arg(metavar="RUN_DIR")]
    """Run folder written by splat-train."""
    format: tuple[Format, ...] = ("ply",)
    """One or more formats: ply (the 3DGS layout, exact), spz (Niantic), sog (PlayCanvas), splat (antimatter15), compressed-ply (PlayCanvas); what each keeps: docs/export.md."""
    out: Path | None = None
    """Output path (default RUN_DIR/point_cloud), each format's extension (.ply, .spz, .sog, .splat, .compressed.ply) in place of any it ends in. New files, or ones splat-export wrote (with --overwrite)."""
    overwrite: bool = False
    """Replace the --out files that splat-export wrote (RUN_DIR/point_cloud.* are always replaced)."""
    device: str = "cpu"
    """Torch device used to load the checkpoint."""
    trust_edited_config: bool = False
    """Use the run's config.json even when its checksum is missing or does not match (edited by hand)."""


def output_paths(args: ExportArgs) -> dict[str, Path]:
    """Format -> the file it is written to: ``--out`` (or RUN_DIR/point_cloud) less any export
    extension it ends in, plus the format's; each format once, in the order given."""
    from ..files.output_paths import EXPORT_SUFFIXES

    base = Path(args.out) if args.out is not None else Path(args.run_dir) / "point_cloud"
    name = base.name
    for suffix in sorted(EXPORT_SUFFIXES.values(), key=len, reverse=True):  # .compressed.ply before .ply
        if name.lower().endswith(suffix) and len(name) > len(suffix):
            name = name[: -len(suffix)]
            break
    return {f: base.with_name(name + EXPORT_SUFFIXES[f]) for f in dict.fromkeys(args.format)}


def main(args: ExportArgs) -> list[Path]:
    from ..errors import DataError
    from ..files.output_paths import EXPORT_FILES, check_output, run_inputs

    if not args.format:
        raise DataError("--format: name one or more formats (ply, spz, sog, splat, compressed-ply)")
    if args.out is not None and Path(args.out).is_dir():
        raise DataError(f"{args.out}: is a folder; --out names the files to write (each format adds its extension)")
    outputs = output_paths(args)
    inputs = run_inputs(args.run_dir)
    for fmt, out in outputs.items():  # every target checked before torch loads
        check_output(out, EXPORT_FILES[fmt], overwrite=args.overwrite or args.out is None, inputs=inputs,
                     flag="--out")

    from ..console import phase, starting

    with starting():
        from ..engine.run import load_trained_model
        from ..export.formats import WRITERS
        from ..export.ply import gaussians_for_export
        from ..files.run_lock import owned, writes_inside

    inside = any(writes_inside(args.run_dir, out) for out in outputs.values())
    with owned(args.run_dir, writes=inside):  # files elsewhere only read the run
        _, model = load_trained_model(args.run_dir, args.device, trust_edits=args.trust_edited_config)
        gaussians = gaussians_for_export(model)
        for fmt, out in outputs.items():
            with phase(f"writing {out.name}"):
                WRITERS[fmt](out, gaussians)
            print(f"wrote {model.num_gaussians} Gaussians to {out} ({_size(out.stat().st_size)})")
    return list(outputs.values())


def _size(n: int) -> str:
    """``812 KB``, ``23.4 MB``: a file size in decimal units."""
    if n < 1_000_000:
        return f"{max(1, round(n / 1000))} KB"
    return f"{n / 1e6:.1f} MB"


def entrypoint() -> None:
    from .common import parse_cli, run_cli

    run_cli(lambda: main(parse_cli(
        ExportArgs, prog="splat-export",
        description="Export a trained run as PLY (the 3DGS layout), SPZ, SOG, .splat or compressed PLY, the files "
                    "Gaussian-splat viewers open.",
    )))


if __name__ == "__main__":
    entrypoint()
