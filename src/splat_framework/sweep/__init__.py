"""Sweeps: a grid of methods x scenes x view counts x seeds, resumable, local or on Ray.

A sweep expands a :class:`Grid` into one :class:`RunSpec` per (scene, views,
method, seed); each run trains in its own folder::

    <out>/runs/<scene-slug>/<method>/v<views>-s<seed>/   config.json, checkpoints/,
                                                        metrics.json, sweep.json, sweep.log

A run whose ``metrics.json`` exists is not trained again, so a killed sweep
re-run does only the missing runs (an interrupted run continues from its last
checkpoint). After every finished run the results table is rewritten as
``<out>/results.{md,csv,json}``: per method, scene and view count, the mean and
sample standard deviation over seeds of PSNR, SSIM, LPIPS, AVG, the wall time
per phase, peak memory, final Gaussian count and render FPS.

Backends:

* ``local`` (default): each run in a fresh Python subprocess (so that its peak
  RSS, ``ru_maxrss``, is its own), at most ``workers`` at a time, each with
  ``threads`` torch threads. A run that raises or whose process dies is
  recorded as failed with a one-line error; the sweep goes on.
* ``ray``: one Ray task per run (``num_cpus=threads``, ``max_calls=1`` so each
  runs in a fresh worker process) on a local instance or a cluster
  (``address="auto"`` or ``"ray://host:10001"``). Run folders are written by
  the workers (use a shared file system on a cluster); the metrics also travel
  back with the task result and are written under ``<out>`` on the driver when
  missing there.
* ``serial``: in this process, one after another (debugging; the peak memory
  reported is this process's).

Modules: ``grid`` (Grid, RunSpec, grid files), ``worker`` (one run), ``backends``
(serial, local, Ray), ``results`` (records, aggregation, tables, figures),
``live`` (the progress table); this package runs the sweep (:func:`run_sweep`).

Importing this package never imports torch or ray.
"""

from __future__ import annotations

import json
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Iterator

from ..files.output_paths import SWEEP_FOLDER, check_output, data_inputs, mark_output
from ..runtime.resources import available_cores
from .backends import import_ray, run_local, run_ray, run_serial, spec_dict
from .grid import (
    BACKENDS,
    DEFAULT_MEM_PER_RUN_GB,
    GRID_KEYS,
    METRICS,
    NUMERIC_FIELDS,
    PHASES,
    RAY_HINT,
    Grid,
    RunSpec,
    SweepError,
    group_key,
    load_grid_file,
    normalise_settings,
    parse_override,
    parse_views,
    run_dir,
    scene_slug,
    unique,
)
from .live import Reporter
from .results import (
    COLUMNS,
    aggregate,
    csv_table,
    fmt_value,
    load_finished,
    markdown_table,
    record_for,
    row_cells,
    row_status,
    run_state,
    table_headers,
    write_figures,
    write_tables,
)
from .worker import build_config, default_workers, execute_run, one_line, peak_rss_mb, threads_per_worker, worker_main


@dataclass
class SweepResult:
    out: Path
    records: list[dict]
    rows: list[dict]
    ran: int
    skipped: int
    failed: int


def run_sweep(
    grid: Grid,
    out: Path,
    *,
    backend: str = "local",
    workers: int | None = None,
    threads: int | None = None,
    address: str | None = None,
    mem_per_run_gb: float = DEFAULT_MEM_PER_RUN_GB,
    live: bool | None = None,
    console=None,
    dry_run: bool = False,
) -> SweepResult:
    """Run every missing run of ``grid`` into ``out`` and write the results tables.

    ``out`` is new, empty or a sweep folder (see :mod:`splat_framework.files.output_paths`),
    else a :class:`~splat_framework.errors.DataError` before anything runs.
    Runs whose metrics.json exists are skipped. Unknown methods raise
    :class:`SweepError` before anything runs; any other problem of a single
    run (bad override, missing dataset, a crash, a conflicting old run) is
    recorded as that run's failure.
    """
    from ..registry import discover_methods

    if backend not in BACKENDS:
        raise SweepError(f"backend: '{backend}' is not one of {', '.join(BACKENDS)}")
    if backend == "ray":
        import_ray()  # fail before anything runs
    out = Path(out)
    check_output(out, SWEEP_FOLDER, keep=True, inputs=[p for d in grid.data for p in data_inputs(d)])
    runs = grid.runs(out)
    known = discover_methods()
    unknown = [m for m in unique(grid.methods) if m not in known]
    if unknown:
        raise SweepError(f"unknown method(s) {', '.join(unknown)} (registered: {', '.join(sorted(known))})")
    with ExitStack() as held:
        if not dry_run:  # one sweep writes into a folder at a time: the second is refused before it plans
            out.mkdir(parents=True, exist_ok=True)
            mark_output(out, SWEEP_FOLDER)
            held.enter_context(_own_sweep_folder(out))
        workers = workers or default_workers(mem_per_run_gb)
        settings = {
            "grid": asdict(grid), "out": str(out), "backend": backend, "workers": workers,
            "threads": threads, "address": address,
        }

        records: dict[RunSpec, dict] = {}
        todo: list[RunSpec] = []
        data_ok: dict[str, str | None] = {}
        for run in runs:
            state, msg = run_state(run)
            if state == "done":
                try:
                    records[run] = load_finished(run) | {"skipped": True}
                    continue
                except (OSError, json.JSONDecodeError):
                    state = "partial"
            if state == "conflict":
                records[run] = record_for(run, "failed", {"error": msg})
                continue
            try:
                build_config(spec_dict(run))
            except Exception as e:
                records[run] = record_for(run, "failed", {"error": one_line(e)})
                continue
            if backend != "ray":  # on a cluster the data may live on the workers only
                if run.data not in data_ok:
                    data_ok[run.data] = _check_data(run.data)
                if data_ok[run.data]:
                    records[run] = record_for(run, "failed", {"error": data_ok[run.data]})
                    continue
            records[run] = record_for(run, "pending")
            todo.append(run)

        ordered = lambda: [records[r] for r in runs]  # noqa: E731
        skipped = sum(1 for r in records.values() if r.get("skipped"))
        reporter = Reporter(console, live=live, total=len(runs))
        reporter.counts["skipped"] = skipped
        reporter.counts["failed"] = sum(1 for r in records.values() if r["status"] == "failed")
        if dry_run:
            for run in runs:
                rec = records[run]
                what = "to run" if rec["status"] == "pending" else ("done" if rec["status"] == "ok" else rec["status"])
                reporter.console.print(f"{what:>7}  {run.run_dir}" + (f"  ({rec['error']})" if rec.get("error") else ""),
                                       markup=False, highlight=False, soft_wrap=True)
            return SweepResult(out, ordered(), aggregate(ordered()), 0, skipped, 0)

        write_tables(out, ordered(), settings)
        workers = max(1, min(workers, len(todo) or 1))
        if backend != "serial":  # serial runs in this process: leave its thread count alone unless asked
            threads = threads or threads_per_worker(workers)
        settings.update(workers=workers, threads=threads)
        if not reporter.use_live:
            reporter.console.print(
                f"sweep: {len(runs)} runs, {skipped} already done, {len(todo)} to run "
                f"({backend}, {workers} worker(s) x {threads or 'default'} thread(s)) -> {out}",
                markup=False, highlight=False, soft_wrap=True,
            )

        def on_start(run: RunSpec) -> None:
            records[run] = record_for(run, "running")
            reporter.counts["running"] += 1
            reporter.update(ordered())

        def on_result(run: RunSpec, result: dict) -> None:
            status = result.get("status", "failed")
            rec = record_for(run, status, result, result.get("metrics") if status == "ok" else None)
            records[run] = rec
            reporter.counts["running"] = max(0, reporter.counts["running"] - 1)
            reporter.run_finished(rec)
            write_tables(out, ordered(), settings)
            reporter.update(ordered())

        reporter.start(ordered())
        try:
            if todo:
                if backend == "serial":
                    run_serial(todo, threads, on_start, on_result)
                elif backend == "local":
                    run_local(todo, workers, threads, on_start, on_result)
                else:
                    run_ray(todo, threads, address, on_start, on_result, local_cpus=available_cores())
        finally:
            for run in runs:  # interrupted: what never finished is pending again
                if records[run]["status"] == "running":
                    records[run] = record_for(run, "pending")
            reporter.stop(ordered())
            rows = write_tables(out, ordered(), settings)
        recs = ordered()
        figures = write_figures(out, recs)
        failed = sum(1 for r in recs if r["status"] in ("failed", "interrupted"))
        if not reporter.use_live:
            reporter.console.print(markdown_table(rows), markup=False, highlight=False, soft_wrap=True)
        reporter.console.print(
            f"sweep: {len(todo)} run(s) trained, {skipped} skipped (already done), {failed} failed; "
            f"tables in {out}/results.{{md,csv,json}}" + (f", {len(figures)} comparison figure(s)" if figures else ""),
            markup=False, highlight=False, soft_wrap=True,
        )
        return SweepResult(out, recs, rows, len(todo), skipped, failed)


@contextmanager
def _own_sweep_folder(out: Path) -> Iterator[None]:
    """Hold the sweep folder ``out``'s lock (:mod:`splat_framework.files.run_lock`) for the block; another
    sweep holding it is one DataError line naming it (its runs are its own: never recorded as failed here)."""
    from ..errors import DataError
    from ..files import run_lock

    try:
        lock = run_lock.acquire(out)
    except run_lock.RunFolderBusy:
        who = run_lock.holder(out) or "identity not written yet"
        raise DataError(f"{out}: another sweep is running into this folder ({who}); wait for it to finish or "
                        "stop it") from None
    try:
        yield
    finally:
        lock.release()


def _check_data(data: str) -> str | None:
    """None when the dataset is there (generating a synthetic scene once, here; photos are posed by the
    first run that reads them, with its own pose options); else the error."""
    try:
        from ..data.resolve import locate_data

        locate_data(data)
    except Exception as e:
        return one_line(e)
    return None


__all__ = [
    "BACKENDS",
    "COLUMNS",
    "DEFAULT_MEM_PER_RUN_GB",
    "GRID_KEYS",
    "METRICS",
    "NUMERIC_FIELDS",
    "PHASES",
    "RAY_HINT",
    "aggregate",
    "build_config",
    "csv_table",
    "default_workers",
    "execute_run",
    "fmt_value",
    "Grid",
    "group_key",
    "import_ray",
    "load_finished",
    "load_grid_file",
    "markdown_table",
    "normalise_settings",
    "one_line",
    "parse_override",
    "parse_views",
    "peak_rss_mb",
    "record_for",
    "Reporter",
    "row_cells",
    "row_status",
    "run_dir",
    "run_local",
    "run_ray",
    "run_serial",
    "run_state",
    "run_sweep",
    "RunSpec",
    "scene_slug",
    "spec_dict",
    "SweepError",
    "SweepResult",
    "table_headers",
    "threads_per_worker",
    "unique",
    "worker_main",
    "write_figures",
    "write_tables",
]
