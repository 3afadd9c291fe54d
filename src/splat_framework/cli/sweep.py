"""``splat-sweep [GRID.toml|GRID.json] [--methods ...] [--data ...] ...``: run a grid of runs.

Methods x datasets x view counts x seeds, each run in
``<out>/runs/<scene-slug>/<method>/v<views>-s<seed>/``; runs whose metrics.json
exists are skipped (a killed sweep re-run does only the missing runs). The
results table (mean ± std over seeds) is written to ``<out>/results.{md,csv,json}``.
Command-line values override those of the grid file.

Examples::

    splat-sweep --methods 3dgs scgaussian --data synthetic/forward llff/fern \\
        --views 3 --seeds 0 1 --steps 500 --out sweeps/x
    splat-sweep grid.toml --workers 2
    splat-sweep grid.toml --backend ray --address auto --threads 4

A grid file (TOML; JSON with the same keys works too)::

    methods = ["3dgs", "scgaussian"]
    data = ["synthetic/forward", "llff/fern"]
    views = [3, 6]
    seeds = [0, 1, 2]
    steps = 500
    out = "sweeps/x"
    [overrides.model.init]       # applied to every run
    num_points = 5000
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


class RunsFailed(Exception):
    """Some runs of a sweep failed: exit 1 with one line naming them (their logs: ``sweep.log``)."""

    cli_exit_code = 1


def build_parser() -> argparse.ArgumentParser:
    from .common import OneLineArgumentParser

    p = OneLineArgumentParser(
        prog="splat-sweep",
        description="Run a grid of methods x datasets x view counts x seeds (resumable) and tabulate the results.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=(
            "examples:\n"
            "  splat-sweep --methods 3dgs scgaussian --data synthetic/forward llff/fern --views 3 --seeds 0 1 --steps 500 --out sweeps/x\n"
            "  splat-sweep grid.toml --workers 2\n"
            "  splat-sweep grid.toml --backend ray --address auto --threads 4"
        ),
    )
    p.add_argument("grid", nargs="?", type=Path, help="grid file (.toml or .json); command-line values override it")
    p.add_argument("--methods", nargs="+", metavar="METHOD", help="registered methods or config variants")
    p.add_argument("--data", nargs="+", metavar="PATH", help="dataset folders (as for splat-train --data)")
    p.add_argument("--views", nargs="+", metavar="K", help="training view counts (or 'all'); default 3")
    p.add_argument("--seeds", nargs="+", metavar="S", help="random seeds; default 0")
    p.add_argument("--steps", metavar="N", help="total iterations of every run (default: each method's own)")
    p.add_argument("--out", metavar="DIR", help="sweep folder (runs/ and results.{md,csv,json})")
    p.add_argument(
        "--override", action="append", default=[], metavar="KEY=VALUE",
        help="config override for every run, e.g. model.init.num_points=5000 (value parsed as JSON); repeatable",
    )
    p.add_argument("--backend", choices=["local", "ray", "serial"], help="local worker processes (default), a Ray cluster, or in-process one by one")
    p.add_argument("--address", help="Ray address: auto (a running cluster), ray://HOST:10001, or omit for a local instance")
    p.add_argument("--workers", metavar="N", help="parallel runs (local); default max(1, min(cores // 2, available memory / --mem-per-run-gb))")
    p.add_argument("--threads", metavar="T", help="torch threads per run (and Ray num_cpus per task); default cores // workers")
    p.add_argument("--mem-per-run-gb", type=float, metavar="GB", help="memory estimate of one run, bounds the default --workers (default 2)")
    p.add_argument("--no-live", action="store_true", help="plain progress lines instead of the live table")
    p.add_argument("--dry-run", action="store_true", help="list the runs and which are already done; run nothing")
    return p


def settings_from_args(args: argparse.Namespace) -> dict:
    """Grid-file settings overridden by the command line, normalised."""
    from ..config import deep_merge
    from ..sweep import SweepError, load_grid_file, normalise_settings, parse_override

    settings = load_grid_file(args.grid) if args.grid is not None else {}
    cli = normalise_settings(
        {
            "methods": args.methods, "data": args.data, "views": args.views, "seeds": args.seeds,
            "steps": args.steps, "out": args.out, "backend": args.backend, "address": args.address,
            "workers": args.workers, "threads": args.threads, "mem_per_run_gb": args.mem_per_run_gb,
        }
    )
    settings.update(cli)
    overrides = settings.get("overrides", {})
    for text in args.override:
        overrides = deep_merge(overrides, parse_override(text))
    settings["overrides"] = overrides
    for key in ("methods", "data"):
        if not settings.get(key):
            raise SweepError(f"sweep: no {key} given (--{key} or '{key}' in the grid file)")
    if not settings.get("out"):
        raise SweepError("sweep: no output folder given (--out or 'out' in the grid file)")
    return settings


def main(argv: list[str] | None = None):
    from ..sweep import DEFAULT_MEM_PER_RUN_GB, Grid, run_sweep

    args = build_parser().parse_args(argv)
    s = settings_from_args(args)
    grid = Grid(
        methods=s["methods"], data=s["data"], views=s.get("views", [3]), seeds=s.get("seeds", [0]),
        steps=s.get("steps"), overrides=s.get("overrides", {}),
    )
    result = run_sweep(
        grid, Path(s["out"]), backend=s.get("backend", "local"), workers=s.get("workers"),
        threads=s.get("threads"), address=s.get("address"),
        mem_per_run_gb=s.get("mem_per_run_gb", DEFAULT_MEM_PER_RUN_GB),
        live=False if args.no_live else None, dry_run=args.dry_run,
    )
    if not args.dry_run:
        check_all_succeeded(result)
    return result


def check_all_succeeded(result, shown: int = 3) -> None:
    """Raise :class:`RunsFailed` (exit 1) naming the failed runs, each with its log
    (``<run>/sweep.log``) or, for a run that never started, its error."""
    failed = [r for r in result.records if r["status"] in ("failed", "interrupted")]
    if not failed:
        return
    def where(rec: dict) -> str:
        log = Path(rec["run_dir"]) / "sweep.log"
        return f"{rec['run_dir']} ({f'log: {log}' if log.is_file() else rec.get('error') or rec['status']})"
    more = f"; and {len(failed) - shown} more" if len(failed) > shown else ""
    raise RunsFailed(
        f"{len(failed)} of {len(result.records)} run(s) failed: {'; '.join(map(where, failed[:shown]))}{more} "
        f"(all in {result.out / 'results.md'})"
    )


def entrypoint() -> None:
    from .common import run_cli

    run_cli(lambda: main(sys.argv[1:]))


if __name__ == "__main__":
    entrypoint()
