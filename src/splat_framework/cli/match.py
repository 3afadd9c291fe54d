"""``splat-match``: compute the SCGaussian matching prior for a scene's training views.

Example::

    splat-match --data llff/fern --views 3 --kind dense --out runs/fern_matches

writes ``matches.npz`` (a :class:`splat_framework.matching.MatchSet`) and one picture
``matches_i_j.png`` per pair into ``--out``, and prints the counts per pair.
Heavy imports (torch, cv2, kornia, the data loaders) happen inside functions so
``--help`` is fast.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import tyro
from pydantic import AfterValidator, Field

from ..config import AutoMatchConfig, MatchConfig, MatchKinds, SplatConfig

if TYPE_CHECKING:  # pragma: no cover
    from splat_framework.cameras import Camera

    from ..matching import MatchSet


def _at_least_one_view(views: int | str) -> int | str:
    if views != "all" and views < 1:
        raise ValueError(f"{views} views: at least 1 (or 'all')")
    return views


MAX_LINES = 100_000
"""Upper bound of ``--max-lines`` (a picture with more lines is a solid smear)."""


class MatchArgs(SplatConfig):
    """Compute verified pixel matches between every pair of training views."""

    data: str
    """Dataset folder, or a name such as "llff/fern" resolved under $SPLAT_DATA."""

    out: Path
    """Output folder: matches.npz and one matches_i_j.png per pair."""

    views: Annotated[int | Literal["all"], AfterValidator(_at_least_one_view)] = 3
    """Number of training views (the dataset's few-shot split), or "all"."""

    cache_dir: Path | None = None
    """Match cache folder (default: <out>/cache)."""

    max_lines: int = Field(200, ge=0, le=MAX_LINES)
    """Match lines drawn per picture (0 = the two views only)."""

    overwrite: bool = False
    """Replace the results in --out when splat-match wrote them (matches.npz, matches_*.png; the cache stays)."""

    config: Annotated[MatchKinds, tyro.conf.arg(name="")] = Field(default_factory=AutoMatchConfig)
    """Matching settings (--kind K: the matcher, whose flags --help then shows)."""


def _image_to_numpy(img: Any) -> Any:
    import numpy as np

    if hasattr(img, "detach"):
        img = img.detach().cpu().numpy()
    a = np.asarray(img)
    if a.ndim == 3 and a.shape[0] in (3, 4) and a.shape[-1] not in (3, 4):
        a = a.transpose(1, 2, 0)
    return a


def run_matching(
    images: list[Any],
    cameras: list["Camera"] | None,
    view_ids: list[int],
    config: MatchConfig,
    out_dir: Path,
    cache_dir: Path | None = None,
    max_lines: int = 200,
    console: Any = None,
) -> "MatchSet":
    """Compute matches, write the ``matches_i_j.png`` files, then ``matches.npz``, print a table and
    warn about the pairs left empty and the views without any verified match, by the cameras' names
    (:func:`~splat_framework.matching.report.warn_empty`).

    Every file is written atomically and ``matches.npz`` last, so an interrupted or failed
    run leaves either no match set or a complete one (and only whole pictures)."""
    from rich.console import Console
    from rich.table import Table

    from ..matching import compute_matches, draw_matches
    from ..matching.report import view_names, warn_empty

    console = console or Console()
    out_dir = Path(out_dir)
    images = [_image_to_numpy(im) for im in images]
    n_pairs = len(view_ids) * (len(view_ids) - 1) // 2
    console.print(f"matching {len(view_ids)} views ({n_pairs} pairs) with {config.kind}...", highlight=False)
    t0 = time.perf_counter()
    ms = compute_matches(images, cameras, view_ids, config, cache_dir)
    dt = time.perf_counter() - t0
    by_id = {int(v): im for v, im in zip(view_ids, images)}
    for i, j in ms.pairs():
        pa, pb = ms.get(i, j)
        draw_matches(by_id[i], by_id[j], pa, pb, out_dir / f"matches_{i}_{j}.png", max_lines=max_lines, seed=config.seed)
    ms.save(out_dir / "matches.npz")  # last: its presence means the run finished

    cached = " (cached)" if ms.meta.get("cache_hit") else ""
    used = sorted(set(ms.meta.get("pair_matchers", {}).values()))  # "auto" uses dense, learned or both
    table = Table(title=f"{config.kind} ({', '.join(used) or config.kind}) matches, views {ms.view_ids}{cached}")
    for col in ("pair", "raw", "MAGSAC", "epipolar", "final"):
        table.add_column(col, justify="right")
    for p in ms.pairs():
        s = ms.stats.get(p, {})
        note = f" [yellow]{ms.warnings[p]}[/]" if p in ms.warnings else ""
        table.add_row(f"{p[0]}-{p[1]}", *(str(s.get(k, "-")) for k in ("raw", "magsac", "epipolar")),
                      f"{len(ms.get(*p)[0])}{note}")
    table.add_row("total", "", "", "", str(ms.total()), end_section=True)
    console.print(table)
    console.print(f"{ms.total()} matches in {dt:.2f} s -> {out_dir / 'matches.npz'}")
    warn_empty(ms, view_names(view_ids, cameras))
    return ms


def main(args: MatchArgs) -> "MatchSet":
    """Load the scene's training views and run :func:`run_matching` (bad input: DataError, exit 2)."""
    from rich.console import Console

    from splat_framework.data.datamanager import load_view_image
    from splat_framework.data.parsers import load_scene
    from splat_framework.sfm.own_photos import resolve_data_path

    from ..files.output_paths import MATCH_FOLDER, check_output, claim_output, data_inputs

    root = resolve_data_path(args.data)
    inputs = [root, *data_inputs(args.data)]  # the scene, and the photos it was posed from
    check_output(args.out, MATCH_FOLDER, overwrite=args.overwrite, inputs=inputs)
    scene = load_scene(root, views=args.views)
    ids = [int(i) for i in scene.train_indices]
    images = [load_view_image(scene, i) for i in ids]
    cameras = [scene.cameras[i] for i in ids]
    cache = None if not args.config.cache else (args.cache_dir or Path(args.out) / "cache")
    claim_output(args.out, MATCH_FOLDER, overwrite=args.overwrite, inputs=inputs)
    return run_matching(images, cameras, ids, args.config, Path(args.out), cache, args.max_lines, Console())


def chosen_kind(argv: list[str]) -> MatchArgs:
    """The defaults of :class:`MatchArgs` with the matcher that ``--kind K`` in ``argv`` names (so that
    the parser shows and reads its flags; with ``--help``, as :mod:`.help_screen` shows them, every
    matcher listed); an unknown kind is an ArgumentsError (one line)."""
    from ..config import match_kinds
    from .common import ArgumentsError, did_you_mean
    from .help_screen import ALL, help_group, help_view
    from .kinds import flag_value

    kind, kinds = flag_value(argv, "--kind"), match_kinds()
    if kind is not None and kind not in kinds:
        raise ArgumentsError(f"--kind: {kind!r} is not one of {', '.join(kinds)}{did_you_mean(kind, kinds)}")
    args = MatchArgs.model_construct(config=kinds[kind or AutoMatchConfig().kind]())
    return args if help_group(argv, None)[1] is None else help_view(args, ALL, "splat-match")[0]


def entrypoint() -> None:
    import sys

    from .common import parse_cli, run_cli

    run_cli(lambda: main(parse_cli(MatchArgs, prog="splat-match", field_prefix="", default=chosen_kind(sys.argv[1:]))))


if __name__ == "__main__":
    entrypoint()
