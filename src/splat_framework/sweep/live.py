"""The live progress table of a running sweep (rich)."""

from __future__ import annotations

from .results import aggregate, has_gpu, row_cells, table_headers


class Reporter:
    """A rich live table on a terminal; one plain line per finished run otherwise."""

    def __init__(self, console=None, live: bool | None = None, total: int = 0):
        from rich.console import Console

        self.console = console or Console()
        self.use_live = self.console.is_terminal if live is None else (live and self.console.is_terminal)
        self.total = total
        self.live = None
        self.counts = {"done": 0, "skipped": 0, "failed": 0, "running": 0}

    def _renderable(self, records: list[dict]):
        from rich.table import Table

        rows = aggregate(records)
        gpu = has_gpu(rows)
        c = self.counts
        table = Table(
            title="sweep",
            caption=(
                f"{c['done'] + c['skipped']}/{self.total} finished ({c['skipped']} already done) · "
                f"{c['running']} running · {c['failed']} failed"
            ),
        )
        for i, h in enumerate(table_headers(gpu)):
            table.add_column(h, justify="left" if i < 2 else "right", no_wrap=i >= 2)
        for row in rows:
            style = "red" if row["n_failed"] else ("dim" if row["n_ok"] == 0 else None)
            table.add_row(*row_cells(row, gpu), style=style)
        return table

    def start(self, records: list[dict]) -> None:
        if self.use_live:
            from rich.live import Live

            self.live = Live(self._renderable(records), console=self.console, refresh_per_second=2)
            self.live.start()

    def update(self, records: list[dict]) -> None:
        if self.live is not None:
            self.live.update(self._renderable(records))

    def run_finished(self, rec: dict) -> None:
        if rec["status"] == "ok":
            self.counts["done"] += 1
        else:
            self.counts["failed"] += 1
        if self.live is None:
            n = self.counts["done"] + self.counts["failed"] + self.counts["skipped"]
            what = f"{rec['method']} {rec['data']} v{rec['views']} s{rec['seed']}"
            if rec["status"] == "ok":
                psnr = "n/a" if rec["psnr"] is None else f"{rec['psnr']:.2f}"
                wall = rec.get("wall_s")
                tail = f"PSNR {psnr}" + (f", {wall:.1f} s" if wall is not None else "")
            else:
                tail = f"{rec['status']}: {rec['error']}"
            self.console.print(f"[{n}/{self.total}] {rec['status']:>6} {what}: {tail}", markup=False, highlight=False, soft_wrap=True)

    def stop(self, records: list[dict]) -> None:
        if self.live is not None:
            self.live.update(self._renderable(records))
            self.live.stop()
            self.live = None
