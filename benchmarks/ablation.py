"""Reproduce the paper-style ablation table of SCGaussian on a scene.

Runs every ablation row (a registered method or config variant) through the
sweep machinery (:mod:`splat_framework.sweep`: resumable, parallel, optionally
on Ray) and writes the Markdown table that goes into the README:
``<out>/ablation.md`` (and the sweep's full ``results.{md,csv,json}``).

Rows (paper order): 3DGS with random initialisation, 3DGS initialised from the
triangulated matches, the hybrid representation alone, + rendering-geometry
loss, + dual optimisation, the full SCGaussian (public-code two-stage schedule),
the paper text's single-stage schedule, and the two representation ablations
(only ray-based Gaussians, only non-structure Gaussians), all on the default
``scgaussian`` (``--table default-ablation`` gives their table its own title and README
markers); ``--table paper`` runs the same rows on the official code's recipe
(``scgaussian-paper`` and its ``scgaussian-paper-*`` rows).

Usage:
    python benchmarks/ablation.py --data llff/fern --views 3 --seeds 0 1 2 \\
        --out runs/ablation-fern [--steps N] [--workers W] \\
        [--methods 3dgs scgaussian ...] [--backend local|ray --address auto] \\
        [--override model.key=value] [--md PATH] [--readme README.md]

``--md PATH`` also copies each scene's comparison figure next to PATH and embeds
it; ``--readme README.md`` replaces the block between the markers
``<!-- ablation:SCENE-vVIEWS -->`` and ``<!-- /ablation:SCENE-vVIEWS -->`` (``-NAME`` appended
for ``--table NAME``, a named table such as ``comp-tria``) with the
table of that scene (so the README's Results section is generated, not typed).

A killed run of this script, started again with the same options, trains only
the missing runs; ``--no-train`` writes the tables from the runs finished so far.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
from datetime import date
from pathlib import Path

ROWS: dict[str, str] = {
    "3dgs": "3DGS (reference random init)",
    "3dgs-frustum": "3DGS, frustum init with pixel colours",
    "3dgs-triang": "3DGS + triangulated-match init",
    "scgaussian-hybrid": "Hybrid representation",
    "scgaussian-hybrid-rg": "+ rendering-geometry loss",
    "scgaussian-hybrid-rg-dual": "+ dual optimisation (z warm-up)",
    "scgaussian-ray-bound": "SCGaussian (full: + cache and filter, public-code schedule; ray-bound all run)",
    "scgaussian-single-stage": "SCGaussian, single-stage schedule (paper text)",
    "scgaussian-only-ray": "Only ray-based Gaussians",
    "scgaussian": "Only non-structure Gaussians after the warm-up: the default `scgaussian`",
}
"""Ablation rows in table order: method/variant name -> row label. The paper's "only non-structure" row
on the default is the default itself (``scgaussian-only-nonstructure`` names the same config)."""

MATCHER_ROWS: dict[str, str] = {
    "scgaussian-dense": "SCGaussian, dense DIS-flow matches",
    "scgaussian-sift": "SCGaussian, SIFT matches",
    "scgaussian-disk-lightglue": "SCGaussian, DISK + LightGlue matches",
    "scgaussian-aliked-lightglue": "SCGaussian, ALIKED + LightGlue matches (the default)",
}
"""The paper's robustness-to-matching-models rows (``--methods scgaussian-dense ...``); not run by default."""

ANCHOR_ROWS: dict[str, str] = {
    "scaffold-gs": "Scaffold-GS (random init)",
    "scaffold-gs-triang": "Triang. init + Scaffold-GS",
    "octree-gs": "Octree-GS (random init)",
    "octree-gs-triang": "Triang. init + Octree-GS",
}
"""The anchor-based plugin's rows (``anchor_gs``); not run by default."""

PAPER_ROWS: dict[str, str] = {
    "scgaussian-paper-hybrid": "Hybrid representation (official recipe)",
    "scgaussian-paper-hybrid-rg": "+ rendering-geometry loss (official recipe)",
    "scgaussian-paper-hybrid-rg-dual": "+ dual optimisation (official recipe)",
    "scgaussian-paper": "SCGaussian, the official code's recipe (scgaussian-paper)",
    "scgaussian-paper-single-stage": "Single-stage schedule (paper text), official recipe",
    "scgaussian-paper-only-ray": "Only ray-based Gaussians (official recipe)",
    "scgaussian-paper-only-nonstructure": "Only non-structure Gaussians (official recipe)",
}
"""The ablation rows on the official code's recipe (``--table paper``); the rows of :data:`ROWS` are on the default."""

LABELS = {**ROWS, **PAPER_ROWS, **MATCHER_ROWS, **ANCHOR_ROWS}

TABLES: dict[str, tuple[str, list[str]]] = {
    "paper": ("The paper's ablation on the official code's recipe (scgaussian-paper; docs/methods.md)",
              ["3dgs", "3dgs-triang", *PAPER_ROWS]),
    "paper-recipe": ("The official code's recipe (scgaussian-paper; docs/methods.md)", ["scgaussian-paper"]),
    "default": ("The default `scgaussian`", ["scgaussian"]),
    "default-ablation": ("The paper's ablation on the default `scgaussian` (its additions kept)",
                         ["3dgs", "3dgs-triang", *(m for m in ROWS if m.startswith("scgaussian"))]),
    "comp-tria": ("Triangulated initialisation across representations (the paper's Tab. comp_tria)",
                  ["3dgs", "3dgs-triang", "scaffold-gs-triang", "octree-gs-triang", "scgaussian"]),
}
"""Named tables (``--table NAME``): title and rows (the default ``--methods``, in table order); the README
markers are ``<!-- ablation:SCENE-vVIEWS-NAME -->``."""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", nargs="+", default=["llff/fern"], help="scene(s) (as for splat-train --data)")
    p.add_argument("--views", nargs="+", default=["3"], help="training view count(s) or 'all'")
    p.add_argument("--steps", type=int, default=None, help="total iterations per run (default: each method's own)")
    p.add_argument("--seeds", nargs="+", type=int, default=[0], help="seeds; the table shows mean ± std over them")
    p.add_argument("--out", type=Path, default=None, help="sweep folder (default runs/ablation-<scene>)")
    p.add_argument("--workers", type=int, default=None, help="parallel runs (default: by cores and memory)")
    p.add_argument("--threads", type=int, default=None, help="torch threads per run (default cores // workers)")
    p.add_argument("--methods", nargs="+", default=None, metavar="METHOD",
                   help="rows to run (default: the --table's rows, else every ablation row)")
    p.add_argument("--table", choices=sorted(TABLES), default=None,
                   help="a named table: its title, rows and README markers ablation:SCENE-vVIEWS-NAME")
    p.add_argument("--backend", choices=["local", "ray", "serial"], default="local")
    p.add_argument("--address", default=None, help="Ray address (auto, ray://HOST:10001); default a local instance")
    p.add_argument("--override", action="append", default=[], metavar="KEY=VALUE", help="config override for every run")
    p.add_argument("--md", type=Path, default=None, help="where to write the table (default <out>/ablation.md)")
    p.add_argument("--readme", type=Path, default=None, help="splice each scene's table into this file's ablation markers")
    p.add_argument("--no-live", action="store_true", help="plain progress lines instead of the live table")
    p.add_argument("--poses", choices=["dataset", "estimated"], default="dataset",
                   help="estimated: also train every row on the training views' poses estimated from those photos "
                        "alone (splat_framework.sfm.estimate_training_poses, Sim(3)-aligned to the dataset), "
                        "next to the dataset's poses, both scored after a test-time pose fit; one comparison table")
    p.add_argument("--test-pose-steps", type=int, default=200,
                   help="with --poses estimated: test-pose fitting steps of every run (TrainConfig.test_pose_steps)")
    p.add_argument("--sfm-matcher", default="auto", help="with --poses estimated: correspondences of the SfM "
                   "(splat-process --matcher: auto, sift, aliked-lightglue, disk-lightglue)")
    p.add_argument("--no-train", action="store_true",
                   help="train nothing: tables from the runs already finished (rows say how many seeds they hold)")
    args = p.parse_args(argv)
    if args.methods is None:
        args.methods = list(TABLES[args.table][1]) if args.table else list(ROWS)
    return args


def table_key(args: argparse.Namespace, data: str, views) -> str:
    """The README marker key of a (scene, views) table: ``sweep.group_key``, plus ``-NAME`` for ``--table NAME``."""
    from splat_framework.sweep import group_key

    return group_key(data, views) + (f"-{args.table}" if args.table else "")


def splice_block(text: str, key: str, block: str, source: str = "README", prefix: str = "ablation") -> str:
    """``text`` with the lines between ``<!-- PREFIX:KEY -->`` and ``<!-- /PREFIX:KEY -->`` replaced by ``block``."""
    from splat_framework.errors import DataError

    start, end = f"<!-- {prefix}:{key} -->", f"<!-- /{prefix}:{key} -->"
    i, j = text.find(start), text.find(end)
    if i < 0 or j < i:
        raise DataError(f"{source}: no '{start}' ... '{end}' markers to put the {key} table between")
    return text[: i + len(start)] + "\n" + block.strip("\n") + "\n" + text[j:]


def footer(command: str, threads: int | None = None, run_loads: list[float | None] | None = None) -> list[str]:
    """The Markdown lines under a benchmark table: machine, torch threads, load average, date, command.

    ``run_loads``: the load average each row's runs started under (``load_average_mean`` of a sweep
    row; None where its runs predate that record); given, the line states those instead of the load
    while the table is written, which for a table regenerated from finished runs says nothing."""
    if run_loads is not None:
        known = [v for v in run_loads if v is not None]
        load = ", load average when the runs started "
        load += f"{statistics.fmean(known):.2f} ({min(known):.2f}-{max(known):.2f} by row)" if known else "not recorded"
        if known and len(known) < len(run_loads):
            load += f", not recorded for {len(run_loads) - len(known)} of {len(run_loads)} rows"
    else:
        from splat_framework.sweep.worker import load_average

        now = load_average()
        load = f", load average {now:.2f}" if now is not None else ""
    torch_threads = f", {threads} torch threads" if threads else ""
    return [
        "",
        f"Machine: {platform.platform()}, Python {platform.python_version()}, {os.cpu_count()} CPU cores"
        f"{torch_threads}{load}; {date.today()}.",
        f"Reproduce: `{command}`",
        "",
    ]


def publish(json_path: Path, payload, table: str, readme: Path | None, key: str, prefix: str = "ablation") -> None:
    """Write a benchmark's JSON and Markdown (``json_path`` with ``.md``), splice the table into ``readme``
    between its ``<!-- PREFIX:KEY -->`` markers when given, and print the table."""
    import json

    from splat_framework.runtime.io import atomic_write_text

    atomic_write_text(json_path, json.dumps(payload, indent=1))
    atomic_write_text(json_path.with_suffix(".md"), table)
    if readme is not None:
        atomic_write_text(readme, splice_block(readme.read_text(encoding="utf-8"), key, table, str(readme), prefix))
    print(table)


def ablation_markdown(
    rows: list[dict], args: argparse.Namespace, command: str, figures: dict[str, Path] | None = None,
    base: Path = Path("."),
) -> dict[str, str]:
    """The README tables: one Markdown section per (scene, views) keyed by ``sweep.group_key``,
    one line per ablation row, the comparison figure ``figures[key]`` below (linked relative to
    the folder ``base`` of the Markdown file)."""
    from splat_framework.sweep import fmt_value, group_key

    title, table_rows = TABLES[args.table] if args.table else ("Ablation", [])
    order = {m: i for i, m in enumerate(dict.fromkeys([*table_rows, *LABELS]))}
    sections: dict[tuple, list[dict]] = {}
    for r in rows:
        sections.setdefault((r["data"], r["views"]), []).append(r)
    steps = f"{args.steps} iterations" if args.steps else "each method's default iterations"
    seeds = ", ".join(str(s) for s in args.seeds)
    out: dict[str, str] = {}
    for (data, views), rs in sections.items():
        rs = sorted(rs, key=lambda r: order.get(r["method"], len(order)))
        tail = footer(command, run_loads=[r.get("load_average_mean") for r in rs])[1:]
        lines = [
            f"### {title} on `{data}`, {views} training views",
            "",
            f"{steps}; mean ± std over seeds {seeds}.",
            "",
            "| Row | Config | PSNR ↑ | SSIM ↑ | LPIPS ↓ | AVG ↓ | ST-LPIPS ↓ | Gaussians | Warm-up (s) | Train (s) | Total (s) | Peak mem (MB) |",
            "|---|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|",
        ]
        for r in rs:
            def v(f, fmt):
                return fmt_value(r[f"{f}_mean"], r[f"{f}_std"], fmt)

            label = LABELS.get(r["method"], r["method"])
            if r["n_ok"] == 0:
                cells = ["failed" if r["n_failed"] else "not run"] + ["n/a"] * 9
            else:
                cells = [v("psnr", ".2f"), v("ssim", ".3f"), v("lpips", ".3f"), v("avg", ".3f"), v("st_lpips", ".3f"),
                         v("num_gaussians", ",.0f"), v("warmup_s", ".1f"), v("train_s", ".1f"),
                         v("total_s", ".1f"), v("peak_rss_mb", ".0f")]
                if r["n_failed"]:
                    label += f" ({r['n_failed']} of {r['n_runs']} seeds failed)"
                elif r["n_ok"] < r["n_runs"]:
                    label += f" ({r['n_ok']} of {r['n_runs']} seeds run)"
            lines.append(f"| {label} | `{r['method']}` | " + " | ".join(cells) + " |")
        lines.append("")
        errors = [f"- `{r['method']}`, {e}" for r in rs for e in r["errors"]]
        if errors:
            lines += ["Failed runs:", "", *errors, ""]
        if all(r["lpips_mean"] is None for r in rs):
            lines += ["LPIPS and AVG are n/a: the `lpips` package or its weights were not available."
                      + (" ST-LPIPS (shift-tolerant LPIPS, AlexNet, weights of the `stlpips-pytorch` wheel) stands in;"
                         " its values are not comparable with papers' LPIPS."
                         if any(r["st_lpips_mean"] is not None for r in rs) else ""), ""]
        key = group_key(data, views)
        if figures and key in figures:
            link = Path(os.path.relpath(figures[key].resolve(), base.resolve())).as_posix()
            lines += [f"![Test views of `{data}`: ground truth, then one row per config]({link})", ""]
        out[table_key(args, data, views)] = "\n".join(lines + tail)
    return out


def main(argv: list[str] | None = None) -> Path:
    from splat_framework.config import deep_merge
    from splat_framework.runtime.io import atomic_write_text
    from splat_framework.sweep import Grid, parse_override, parse_views, scene_slug

    args = parse_args(argv)
    out = args.out or Path("runs") / f"ablation-{scene_slug(args.data[0])}"
    overrides: dict = {}
    for text in args.override:
        overrides = deep_merge(overrides, parse_override(text))
    grid = Grid(
        methods=list(args.methods), data=list(args.data), views=[parse_views(v) for v in args.views],
        seeds=list(args.seeds), steps=args.steps, overrides=overrides,
    )
    command = "python benchmarks/ablation.py " + " ".join(sys.argv[1:] if argv is None else argv)
    if args.poses == "estimated":
        return estimated_poses_tables(args, grid, out, command)
    result = sweep(args, grid, out)
    md_path = args.md or out / "ablation.md"
    figures = publish_figures(out, md_path, [(r["data"], r["views"]) for r in result.rows])
    sections = ablation_markdown(result.rows, args, command, figures, md_path.parent)
    atomic_write_text(md_path, "\n".join(sections.values()))
    print(f"ablation table: {md_path}")
    if args.readme is not None:
        sections = ablation_markdown(result.rows, args, command, figures, args.readme.parent)
        splice_sections(args.readme, sections)
    return md_path


def sweep(args: argparse.Namespace, grid, out: Path):
    """Train the missing runs of ``grid`` into ``out`` with the options' backend (nothing with
    --no-train, whose comparison figures are redrawn from the runs finished so far, as its tables are)."""
    from splat_framework.sweep import run_sweep, write_figures

    result = run_sweep(grid, out, backend=args.backend, workers=args.workers, threads=args.threads,
                       address=args.address, live=False if args.no_live else None, dry_run=args.no_train)
    if args.no_train:
        write_figures(out, result.records)
    return result


def splice_sections(readme: Path, sections: dict[str, str]) -> None:
    """Replace each ``{key: table}`` between its ablation markers in ``readme``."""
    from splat_framework.runtime.io import atomic_write_text

    text = readme.read_text(encoding="utf-8")
    for key, block in sections.items():
        text = splice_block(text, key, block, str(readme))
    atomic_write_text(readme, text)
    print(f"README tables updated: {readme} ({', '.join(sections)})")


def estimated_poses_tables(args: argparse.Namespace, grid, out: Path, command: str) -> Path:
    """``--poses estimated``: per (scene, views), the training views' pose file from their photos
    alone (``<out>/poses/<key>.json``, made once), every row trained on the dataset's poses
    (``<out>/dataset-poses``) and on the estimated ones (``<out>/estimated-poses``), both with
    ``test_pose_steps``; one table per group, keyed ``<key>-estimated-poses`` in the README."""
    import dataclasses
    import json

    from splat_framework.runtime.io import atomic_write_json, atomic_write_text
    from splat_framework.sfm import estimate_training_poses
    from splat_framework.sweep import group_key

    sections: dict[str, str] = {}
    for data in grid.data:
        for views in grid.views:
            key = group_key(data, views)
            pose_file = (out / "poses" / f"{key}.json").resolve()
            if not pose_file.is_file():
                print(f"{key}: posing the training views from their photos ({args.sfm_matcher} matches) ...", flush=True)
                atomic_write_json(pose_file, estimate_training_poses(data, views=views, matcher=args.sfm_matcher))
            info = json.loads(pose_file.read_text())["info"]
            rows = {}
            for poses, extra in (("dataset", {}), ("estimated", {"train_poses": str(pose_file)})):
                g = dataclasses.replace(grid, data=[data], views=[views],
                                        overrides={**grid.overrides, **extra, "test_pose_steps": args.test_pose_steps})
                rows[poses] = sweep(args, g, out / f"{poses}-poses").rows
            sections[f"{key}-estimated-poses"] = estimated_poses_markdown(data, views, rows, info, args, command)
    md_path = args.md or out / "estimated-poses.md"
    atomic_write_text(md_path, "\n".join(sections.values()))
    print(f"estimated-poses table: {md_path}")
    if args.readme is not None:
        splice_sections(args.readme, sections)
    return md_path


def estimated_poses_markdown(data: str, views, rows: dict[str, list[dict]], info: dict,
                             args: argparse.Namespace, command: str) -> str:
    """The dataset-vs-estimated-poses table of one (scene, views) group, with the pose errors."""
    from splat_framework.sweep import fmt_value

    def spread(xs: list[float]) -> str:
        return f"{statistics.fmean(xs):.2f} (max {max(xs):.2f})"

    steps = f"{args.steps} iterations" if args.steps else "each method's default iterations"
    focal = [e / d - 1 for e, d in zip(info["focal_estimated"], info["focal_dataset"])]
    lines = [
        f"### Dataset poses vs poses from the {views} training photos: `{data}`",
        "",
        f"{info['registered']} of {info['views']} training views registered from their photos alone "
        f"({info['matcher']} matches at {info['sfm_size'][0]}x{info['sfm_size'][1]}, "
        f"{info.get('mapper', 'incremental')} mapper, {info['points']:,} points, "
        f"reprojection error {info['reprojection_px']:.2f} px). Errors after Sim(3) alignment to the dataset's "
        f"training cameras: rotation {spread(info['rotation_deg'])} deg, camera centre "
        f"{spread([100 * c for c in info['center_error_rel_spread']])} % of their spread, translation direction "
        f"{spread(info['translation_direction_deg'])} deg, focal length {100 * statistics.fmean(focal):+.1f} %.",
        "",
        f"{steps}; mean ± std over seeds {', '.join(str(s) for s in args.seeds)}; every test camera's pose fitted to "
        f"its photo by {args.test_pose_steps} steps with the model frozen before scoring (BARF / CF-3DGS protocol); "
        "\"as given\": the dataset's test pose, unfitted.",
        "",
        "| Method | Training poses | PSNR ↑ | PSNR, test pose as given ↑ | SSIM ↑ | ST-LPIPS ↓ | Gaussians |",
        "|---|---|--:|--:|--:|--:|--:|",
    ]
    for method in grid_methods(rows):
        for poses, rs in rows.items():
            for r in rs:
                if r["method"] != method:
                    continue
                if r["n_ok"] == 0:
                    cells = ["failed" if r["n_failed"] else "not run"] + ["n/a"] * 4
                else:
                    cells = [fmt_value(r[f"{f}_mean"], r[f"{f}_std"], fmt) for f, fmt in (
                        ("psnr", ".2f"), ("psnr_before_pose_fit", ".2f"), ("ssim", ".3f"), ("st_lpips", ".3f"),
                        ("num_gaussians", ",.0f"))]
                label = "dataset (COLMAP, all views)" if poses == "dataset" else f"from the {views} training photos"
                lines.append(f"| `{method}` | {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines + footer(command, run_loads=[r.get("load_average_mean") for rs in rows.values() for r in rs]))


def grid_methods(rows: dict[str, list[dict]]) -> list[str]:
    """The methods of the tables' rows, in order of first appearance."""
    return list(dict.fromkeys(r["method"] for rs in rows.values() for r in rs))


def publish_figures(out: Path, md_path: Path, groups: list[tuple], max_width: int = 1200) -> dict[str, Path]:
    """Copy each (scene, views) comparison figure of the sweep next to ``md_path``, as a JPEG
    at most ``max_width`` pixels wide (the full-size PNG stays in ``out/figures``).

    Returns ``{section key: JPEG path}`` for the figures the sweep wrote.
    """
    import cv2

    from splat_framework.runtime.io import atomic_write_bytes
    from splat_framework.sweep import group_key

    written: dict[str, Path] = {}
    for data, views in dict.fromkeys(groups):
        key = group_key(data, views)
        img = cv2.imread(str(Path(out) / "figures" / f"{key}.png"), cv2.IMREAD_COLOR)
        if img is None:
            continue
        if img.shape[1] > max_width:
            h = round(img.shape[0] * max_width / img.shape[1])
            img = cv2.resize(img, (max_width, h), interpolation=cv2.INTER_AREA)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 88])
        if ok:
            written[key] = md_path.parent / f"{md_path.stem}-{key}.jpg"
            atomic_write_bytes(written[key], buf.tobytes())
    return written


if __name__ == "__main__":
    from splat_framework.cli.common import run_cli

    run_cli(main)
