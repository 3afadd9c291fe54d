"""The terminal: one-line messages, the training progress bar and the end-of-run summary table (rich).

Messages and the bar go to stderr (``console``); the summary table to stdout.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table
from rich.text import Text

console = Console(stderr=True)


def say(message: str, style: str | None = None) -> None:
    """One line on stderr, never wrapped, never parsed as markup."""
    console.print(Text(message, style=style or ""), soft_wrap=True)


@contextmanager
def training_progress(enabled: bool):
    """The live bar of a training run: step, loss, train PSNR, Gaussian count, it/s, elapsed and remaining time."""
    progress = Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TextColumn("[cyan]loss {task.fields[loss]:.4f}"),
        TextColumn("[green]PSNR {task.fields[psnr]:.2f}"),
        TextColumn("[magenta]{task.fields[n]} gaussians"),
        _SpeedColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        disable=not enabled,
    )
    with progress:
        yield progress


class _SpeedColumn(TextColumn):
    def __init__(self):
        super().__init__("")

    def render(self, task):
        speed = task.finished_speed or task.speed
        return Text(f"{speed:.2f} it/s" if speed else "-- it/s")


def print_summary(metrics: dict, run_dir: Path) -> None:
    """The final rich table: test metrics, Gaussian count and time per phase."""
    table = Table(title=f"{metrics['method']} on {metrics['data']}")
    table.add_column("metric")
    table.add_column("value", justify="right")
    split = next((v.get("split", "test") for v in metrics.get("per_view") or []), "test")
    for k, v in metrics["mean"].items():
        table.add_row(f"{split} {k}", "n/a" if v is None else f"{v:.4f}")
    table.add_row("gaussians", str(metrics["num_gaussians"]))
    table.add_row("steps", str(metrics["steps"]))
    if metrics.get("skipped_steps"):
        table.add_row("skipped steps", str(metrics["skipped_steps"]))
    if metrics.get("render_fps"):
        table.add_row("render fps", f"{metrics['render_fps']:.1f}")
    for k, v in metrics["timing"].items():
        table.add_row(k, f"{v:.1f}")
    table.add_row("run folder", str(run_dir))
    Console().print(table)
    if split == "train":
        say("Training-view metrics: the scene has no held-out test view (every photo is a training view); "
            "splat-render RUN --path auto renders a video of novel views", "yellow")
    if metrics.get("lpips_note"):
        say(f"LPIPS not computed: {metrics['lpips_note']}", "yellow")
