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

Importing this module never imports torch or ray.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import statistics
import subprocess
import sys
import time
import traceback
import uuid
import warnings
from collections import deque
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path, PurePosixPath
from typing import Any, Callable, Iterable

from .errors import DataError
from .io import atomic_write_json, atomic_write_text
from .resources import available_cores, available_memory_bytes

METRICS = ("psnr", "ssim", "lpips", "avg")
"""Test metrics reported per run (``metrics.json`` ``mean``)."""
PHASES = ("matching_s", "warmup_s", "train_s", "eval_s", "total_s")
"""Wall-time phases reported per run (``metrics.json`` ``timing``)."""
NUMERIC_FIELDS = METRICS + PHASES + ("peak_rss_mb", "peak_gpu_mb", "num_gaussians", "render_fps")
"""Every per-run number the table aggregates over seeds."""
BACKENDS = ("local", "ray", "serial")
GRID_KEYS = {
    "methods", "data", "views", "seeds", "steps", "overrides",
    "out", "workers", "threads", "backend", "address", "mem_per_run_gb",
}
"""Keys a grid file (TOML or JSON) may hold."""
DEFAULT_MEM_PER_RUN_GB = 2.0
RAY_HINT = "--backend ray needs Ray, which is not installed: pip install splat[ray]"


class SweepError(DataError):
    """Bad sweep input (grid file, options); one line, CLI exit code 2."""


# ------------------------------------------------------------------ the grid
@dataclass(frozen=True)
class RunSpec:
    """One training run of a sweep."""

    method: str
    data: str
    views: int | str
    seed: int
    steps: int | None
    run_dir: Path
    overrides: dict = field(default_factory=dict, compare=False, hash=False)

    @property
    def group(self) -> tuple:
        """The table row this run belongs to (seeds are aggregated)."""
        return (self.method, self.data, self.views)

    @property
    def label(self) -> str:
        return f"{self.method} {self.data} v{self.views} s{self.seed}"

    def to_json(self) -> dict:
        d = asdict(self)
        d["run_dir"] = str(self.run_dir)
        return d


@dataclass
class Grid:
    """Methods x scenes x view counts x seeds, with shared steps and config overrides."""

    methods: list[str]
    data: list[str]
    views: list[int | str] = field(default_factory=lambda: [3])
    seeds: list[int] = field(default_factory=lambda: [0])
    steps: int | None = None
    overrides: dict = field(default_factory=dict)

    def runs(self, out: Path) -> list[RunSpec]:
        """Every run, ordered scene, views, method, seed (the table's row order)."""
        if not self.methods:
            raise SweepError("sweep: no methods given")
        if not self.data:
            raise SweepError("sweep: no datasets given")
        slugs: dict[str, str] = {}
        for d in self.data:
            s = scene_slug(d)
            if s in slugs and slugs[s] != d:
                raise SweepError(f"sweep: datasets '{slugs[s]}' and '{d}' share the run-folder name '{s}'")
            slugs[s] = d
        out = Path(out)
        return [
            RunSpec(m, d, v, s, self.steps, run_dir(out, d, m, v, s), self.overrides)
            for d in _unique(self.data)
            for v in _unique(self.views)
            for m in _unique(self.methods)
            for s in _unique(self.seeds)
        ]


def _unique(xs: Iterable) -> list:
    seen, out = set(), []
    for x in xs:
        if x not in seen:
            seen.add(x)
            out.append(x)
    return out


def scene_slug(data: str) -> str:
    """Folder name of a dataset spec: ``llff/fern`` -> ``llff-fern``.

    Absolute paths keep their last two components (``/d/nerf_llff/fern`` ->
    ``nerf_llff-fern``); anything but letters, digits and ``._+-`` becomes ``_``.
    """
    text = str(data).replace("\\", "/").strip()
    parts = [p for p in PurePosixPath(text).parts if p not in ("/", ".", "..", "~")]
    if text.startswith(("/", "~")) and len(parts) > 2:
        parts = parts[-2:]
    slug = re.sub(r"[^A-Za-z0-9._+-]+", "_", "-".join(parts)).strip("._-")
    return slug or "scene"


def group_key(data: str, views) -> str:
    """Name of a (scene, view count) group: ``llff-fern-v3`` (its comparison figure's file stem)."""
    return f"{scene_slug(data)}-v{views}"

def run_dir(out: Path, data: str, method: str, views: int | str, seed: int) -> Path:
    """``<out>/runs/<scene-slug>/<method>/v<views>-s<seed>``."""
    return Path(out) / "runs" / scene_slug(data) / method / f"v{views}-s{seed}"


def parse_views(value: Any) -> int | str:
    """``3`` / ``"3"`` -> 3, ``"all"`` -> "all"."""
    if isinstance(value, bool):
        raise SweepError(f"views: {value!r} is not a view count or 'all'")
    if isinstance(value, int):
        if value < 1:
            raise SweepError(f"views: {value} must be at least 1")
        return value
    text = str(value).strip().lower()
    if text == "all":
        return "all"
    try:
        return parse_views(int(text))
    except ValueError:
        raise SweepError(f"views: {value!r} is not a view count or 'all'") from None


def _as_list(key: str, value: Any) -> list:
    if isinstance(value, (list, tuple)):
        return list(value)
    if isinstance(value, (str, int)):
        return [value]
    raise SweepError(f"{key}: expected a value or a list, got {type(value).__name__}")


def _as_int(key: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, str)):
        raise SweepError(f"{key}: {value!r} is not an integer")
    try:
        return int(value)
    except ValueError:
        raise SweepError(f"{key}: {value!r} is not an integer") from None


def load_grid_file(path: Path) -> dict:
    """Settings of a grid file (``.toml`` or ``.json``), validated and normalised.

    Keys: methods, data, views, seeds (a value or a list each), steps, overrides
    (nested config overrides applied to every run, e.g. ``[overrides.model]``),
    out, workers, threads, backend, address, mem_per_run_gb.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise SweepError(f"{path}: cannot read grid file ({e.strerror or e})") from None
    try:
        if path.suffix.lower() == ".json":
            doc = json.loads(text)
        else:
            import tomllib

            doc = tomllib.loads(text)
    except (ValueError, json.JSONDecodeError) as e:  # TOMLDecodeError is a ValueError
        raise SweepError(f"{path}: not valid {'JSON' if path.suffix.lower() == '.json' else 'TOML'} ({e})") from None
    if not isinstance(doc, dict):
        raise SweepError(f"{path}: the grid must be a table/object")
    unknown = sorted(set(doc) - GRID_KEYS)
    if unknown:
        raise SweepError(f"{path}: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(GRID_KEYS))})")
    try:
        return normalise_settings(doc)
    except SweepError as e:
        raise SweepError(f"{path}: {e}") from None


def normalise_settings(doc: dict) -> dict:
    """Type-check and normalise grid settings (values None are left out)."""
    s: dict[str, Any] = {}
    for key, value in doc.items():
        if value is None:
            continue
        if key in ("methods", "data"):
            s[key] = [str(x) for x in _as_list(key, value)]
        elif key == "views":
            s[key] = [parse_views(x) for x in _as_list(key, value)]
        elif key == "seeds":
            s[key] = [_as_int(key, x) for x in _as_list(key, value)]
        elif key in ("steps", "workers", "threads"):
            n = _as_int(key, value)
            if n < 1:
                raise SweepError(f"{key}: {n} must be at least 1")
            s[key] = n
        elif key == "overrides":
            if not isinstance(value, dict):
                raise SweepError("overrides: expected a table of config overrides")
            s[key] = value
        elif key == "backend":
            if value not in BACKENDS:
                raise SweepError(f"backend: '{value}' is not one of {', '.join(BACKENDS)}")
            s[key] = value
        elif key == "mem_per_run_gb":
            s[key] = float(value)
        else:
            s[key] = str(value)
    return s


def parse_override(text: str) -> dict:
    """``model.init_num_points=300`` -> ``{"model": {"init_num_points": 300}}`` (value JSON, else string)."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise SweepError(f"--override {text!r}: expected KEY=VALUE, e.g. model.lambda_rg=0.0")
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw
    out: dict = {}
    node = out
    parts = key.strip().split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
    node[parts[-1]] = value
    return out


# -------------------------------------------------------------- resources
def default_workers(mem_per_run_gb: float = DEFAULT_MEM_PER_RUN_GB) -> int:
    """``max(1, min(cores // 2, available memory / per-run estimate))``."""
    cores = available_cores()
    n = cores // 2
    mem = available_memory_bytes()
    if mem is not None and mem_per_run_gb > 0:
        n = min(n, int(mem / 2**30 // mem_per_run_gb))
    return max(1, n)


def threads_per_worker(workers: int) -> int:
    return max(1, available_cores() // max(1, workers))


def peak_rss_mb(ru_maxrss: int) -> float:
    """``ru_maxrss`` in MiB (kilobytes on Linux, bytes on macOS)."""
    return ru_maxrss / (2**20 if sys.platform == "darwin" else 2**10)


# ------------------------------------------------------------ one run
def one_line(e: BaseException, limit: int = 240) -> str:
    """A one-line description of an exception (pydantic errors listed by field)."""
    try:
        from pydantic import ValidationError

        if isinstance(e, ValidationError):
            msg = "invalid config: " + "; ".join(
                f"{'.'.join(str(p) for p in err['loc']) or 'config'}: {err['msg']}" for err in e.errors()
            )
            return msg[:limit]
    except ImportError:  # pragma: no cover
        pass
    text = " ".join(str(e).split()) if str(e) else ""
    name = type(e).__name__
    msg = f"{name}: {text}" if text else name
    if isinstance(e, DataError) and text:
        msg = text
    return msg if len(msg) <= limit else msg[: limit - 3] + "..."


def build_config(spec: dict):
    """The validated TrainConfig of a run spec (no torch import)."""
    from .config import apply_overrides, deep_merge
    from .registry import get_method

    try:
        base = get_method(spec["method"]).default_config()
    except KeyError as e:
        raise SweepError(e.args[0]) from None
    fixed = {
        "data": spec["data"],
        "views": spec["views"],
        "seed": spec["seed"],
        "output": str(spec["run_dir"]),
        "progress": False,
        "resume": True,  # continue an interrupted run; a fresh folder just starts at step 0
    }
    if spec.get("steps") is not None:
        fixed["steps"] = spec["steps"]
    return apply_overrides(base, deep_merge(spec.get("overrides") or {}, fixed))


def execute_run(spec: dict, threads: int | None = None) -> dict:
    """Train one run (in the calling process) and return its result.

    The result: status ("ok", "failed" or "interrupted"), error (one line or
    None), wall_s, peak_rss_mb (this process's max RSS), peak_gpu_mb (CUDA only),
    metrics (the metrics.json dict when ok). Also written as ``sweep.json`` in
    the run folder; stdout/stderr of the run go to ``sweep.log`` there. Never
    raises for a failing run.
    """
    import resource

    t0 = time.perf_counter()
    rdir = Path(spec["run_dir"])
    rdir.mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {"status": "ok", "error": None, "attempt": spec.get("attempt")}
    metrics = None
    cuda = False
    with open(rdir / "sweep.log", "a", encoding="utf-8") as log, redirect_stdout(log), redirect_stderr(log):
        print(f"=== sweep run {spec.get('attempt')} started {datetime.now().isoformat(timespec='seconds')}", flush=True)
        try:
            import torch

            if threads:
                torch.set_num_threads(int(threads))
            config = build_config(spec)
            cuda = str(config.device).startswith("cuda")
            from .trainer import TrainingInterrupted, train

            try:
                metrics = train(config)
            except TrainingInterrupted as e:
                result.update(status="interrupted", error=one_line(e))
        except Exception as e:
            result.update(status="failed", error=one_line(e))
            traceback.print_exc()
        log.flush()
    result["wall_s"] = time.perf_counter() - t0
    result["peak_rss_mb"] = peak_rss_mb(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
    result["peak_gpu_mb"] = None
    if cuda:
        try:
            import torch

            result["peak_gpu_mb"] = torch.cuda.max_memory_allocated() / 2**20
        except Exception:
            pass
    atomic_write_text(rdir / "sweep.json", json.dumps(result, indent=2))
    result["metrics"] = metrics
    return result


def worker_main(argv: list[str] | None = None) -> None:
    """Subprocess entry of the local backend: ``python -m splat_framework.sweep SPEC.json THREADS``."""
    argv = sys.argv[1:] if argv is None else argv
    spec = json.loads(Path(argv[0]).read_text())
    threads = int(argv[1]) if len(argv) > 1 else None
    result = execute_run(spec, threads)
    sys.exit(0 if result["status"] == "ok" else 3)


def _ray_task(spec: dict, threads: int) -> dict:
    return execute_run(spec, threads)


# ------------------------------------------------------------ run state
def run_state(run: RunSpec) -> tuple[str, str | None]:
    """("done" | "partial" | "new" | "conflict", message) of a run's folder.

    done: metrics.json exists (the run is skipped). partial: a config.json
    exists (resume from its last checkpoint). conflict: the folder holds a run
    with another number of steps (never overwritten; recorded as failed).
    """
    m = run.run_dir / "metrics.json"
    if m.is_file():
        try:
            metrics = json.loads(m.read_text())
        except (OSError, json.JSONDecodeError):
            return "partial", None
        if run.steps is not None and metrics.get("steps") not in (None, run.steps):
            return "conflict", (
                f"{m}: holds a {metrics.get('steps')}-step run, the sweep asks for {run.steps} "
                "(use another --out or delete the folder)"
            )
        return "done", None
    c = run.run_dir / "config.json"
    if c.is_file():
        try:
            saved = json.loads(c.read_text()).get("config", {})
        except (OSError, json.JSONDecodeError, AttributeError):
            saved = {}
        steps = saved.get("steps") or saved.get("default_steps")
        if run.steps is not None and steps not in (None, run.steps):
            return "conflict", (
                f"{c}: holds a {steps}-step run, the sweep asks for {run.steps} "
                "(use another --out or delete the folder)"
            )
        return "partial", None
    return "new", None


def record_for(run: RunSpec, status: str, result: dict | None = None, metrics: dict | None = None) -> dict:
    """The flat per-run record of the results table."""
    rec: dict[str, Any] = {
        "method": run.method,
        "data": run.data,
        "views": run.views,
        "seed": run.seed,
        "steps": run.steps,
        "run_dir": str(run.run_dir),
        "status": status,
        "error": (result or {}).get("error"),
        "wall_s": (result or {}).get("wall_s"),
    }
    for k in NUMERIC_FIELDS:
        rec[k] = None
    if result:
        rec["peak_rss_mb"] = result.get("peak_rss_mb")
        rec["peak_gpu_mb"] = result.get("peak_gpu_mb")
    if metrics:
        mean = metrics.get("mean") or {}
        for k in METRICS:
            rec[k] = _num(mean.get(k))
        timing = metrics.get("timing") or {}
        for k in PHASES:
            rec[k] = _num(timing.get(k))
        rec["num_gaussians"] = _num(metrics.get("num_gaussians"))
        rec["render_fps"] = _num(metrics.get("render_fps"))
        if metrics.get("steps") is not None:
            rec["steps"] = metrics["steps"]
        if metrics.get("lpips_note"):
            rec["lpips_note"] = metrics["lpips_note"]
    return rec


def _num(v) -> float | None:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    return float(v) if math.isfinite(v) else None


def load_finished(run: RunSpec) -> dict:
    """Record of a run whose metrics.json exists (plus its sweep.json, if any)."""
    metrics = json.loads((run.run_dir / "metrics.json").read_text())
    result = None
    sj = run.run_dir / "sweep.json"
    if sj.is_file():
        try:
            result = json.loads(sj.read_text())
            result["error"] = None
        except (OSError, json.JSONDecodeError):
            result = None
    return record_for(run, "ok", result, metrics)


# ------------------------------------------------------------ aggregation
def aggregate(records: list[dict]) -> list[dict]:
    """One row per (method, data, views), in order of first appearance.

    Each numeric field gets ``<field>_mean`` and ``<field>_std`` over the seeds
    that finished (sample standard deviation; None with fewer than two values,
    both None when no seed has a value, e.g. LPIPS without the lpips package).
    """
    groups: dict[tuple, list[dict]] = {}
    for r in records:
        groups.setdefault((r["method"], r["data"], r["views"]), []).append(r)
    rows = []
    for (method, data, views), rs in groups.items():
        ok = [r for r in rs if r["status"] == "ok"]
        row: dict[str, Any] = {
            "method": method,
            "data": data,
            "views": views,
            "seeds": [r["seed"] for r in rs],
            "n_runs": len(rs),
            "n_ok": len(ok),
            "n_failed": sum(r["status"] in ("failed", "interrupted") for r in rs),
            "n_pending": sum(r["status"] in ("pending", "running") for r in rs),
            "errors": [f"seed {r['seed']}: {r['error']}" for r in rs if r["status"] in ("failed", "interrupted")],
        }
        for f in NUMERIC_FIELDS:
            vals = [r[f] for r in ok if r.get(f) is not None]
            row[f"{f}_mean"] = statistics.fmean(vals) if vals else None
            row[f"{f}_std"] = statistics.stdev(vals) if len(vals) >= 2 else None
        rows.append(row)
    return rows


# -------------------------------------------------------------- tables
COLUMNS: list[tuple[str, str | None, str]] = [
    # (header, field (None: special), format)
    ("Method", None, "method"),
    ("Data", None, "data"),
    ("Views", None, "views"),
    ("Seeds", None, "seeds"),
    ("PSNR ↑", "psnr", ".2f"),
    ("SSIM ↑", "ssim", ".3f"),
    ("LPIPS ↓", "lpips", ".3f"),
    ("AVG ↓", "avg", ".3f"),
    ("Matching (s)", "matching_s", ".1f"),
    ("Warm-up (s)", "warmup_s", ".1f"),
    ("Training (s)", "train_s", ".1f"),
    ("Evaluation (s)", "eval_s", ".1f"),
    ("Peak mem (MB)", "peak_rss_mb", ".0f"),
    ("Gaussians", "num_gaussians", ",.0f"),
    ("FPS", "render_fps", ".1f"),
    ("Status", None, "status"),
]


def fmt_value(mean: float | None, std: float | None, fmt: str) -> str:
    """``12.34 ± 0.56``; ``n/a`` when there is no value."""
    if mean is None:
        return "n/a"
    text = format(mean, fmt)
    if std is not None:
        text += f" ± {format(std, fmt)}"
    return text


def row_status(row: dict) -> str:
    parts = [f"{row['n_ok']}/{row['n_runs']} ok"]
    if row["n_failed"]:
        parts.append(f"{row['n_failed']} failed")
    if row["n_pending"]:
        parts.append(f"{row['n_pending']} pending")
    return ", ".join(parts)


def row_cells(row: dict, gpu: bool = False) -> list[str]:
    cells = []
    for header, f, fmt in COLUMNS:
        if f is None:
            if fmt == "seeds":
                cells.append(str(len(row["seeds"])))
            elif fmt == "status":
                cells.append(row_status(row))
            else:
                cells.append(str(row[fmt]))
        else:
            cells.append(fmt_value(row[f"{f}_mean"], row[f"{f}_std"], fmt))
        if gpu and f == "peak_rss_mb":
            cells.append(fmt_value(row["peak_gpu_mb_mean"], row["peak_gpu_mb_std"], ".0f"))
    return cells


def table_headers(gpu: bool = False) -> list[str]:
    heads = []
    for header, f, _ in COLUMNS:
        heads.append(header)
        if gpu and f == "peak_rss_mb":
            heads.append("Peak GPU (MB)")
    return heads


def _has_gpu(rows: list[dict]) -> bool:
    return any(r.get("peak_gpu_mb_mean") is not None for r in rows)


def markdown_table(rows: list[dict]) -> str:
    """The results as a Markdown table; failed runs listed below it."""
    gpu = _has_gpu(rows)
    heads = table_headers(gpu)
    lines = ["| " + " | ".join(heads) + " |", "|" + "|".join("---" if i < 2 else "--:" for i in range(len(heads))) + "|"]
    for row in rows:
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in row_cells(row, gpu)) + " |")
    notes = [
        f"- {r['method']} on {r['data']} ({r['views']} views), {e}" for r in rows for e in r["errors"]
    ]
    text = "\n".join(lines) + "\n"
    text += (
        "\nMean ± sample standard deviation over seeds; times are wall seconds per phase, "
        "peak memory is the run process's max RSS; n/a: not measured or not part of the method.\n"
    )
    if notes:
        text += "\nFailed runs:\n\n" + "\n".join(notes) + "\n"
    return text


def csv_table(rows: list[dict]) -> str:
    """One line per row: keys, counts, then ``<field>_mean`` and ``<field>_std`` (empty when n/a)."""
    cols = ["method", "data", "views", "seeds", "n_runs", "n_ok", "n_failed", "n_pending"]
    for f in NUMERIC_FIELDS:
        cols += [f"{f}_mean", f"{f}_std"]
    cols.append("errors")
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for row in rows:
        out = []
        for c in cols:
            v = row.get(c)
            if c == "seeds":
                v = " ".join(str(s) for s in v)
            elif c == "errors":
                v = " | ".join(v)
            out.append("" if v is None else v)
        w.writerow(out)
    return buf.getvalue()


def write_tables(out: Path, records: list[dict], settings: dict | None = None) -> list[dict]:
    """Write ``results.md``, ``results.csv`` and ``results.json`` into ``out`` (atomically); return the rows."""
    out = Path(out)
    rows = aggregate(records)
    atomic_write_text(out / "results.md", markdown_table(rows))
    atomic_write_text(out / "results.csv", csv_table(rows))
    payload = {
        "generated": datetime.now().isoformat(timespec="seconds"),
        "sweep": settings or {},
        "rows": rows,
        "runs": records,
    }
    atomic_write_text(out / "results.json", json.dumps(payload, indent=2, default=str))
    return rows


def write_figures(out: Path, records: list[dict]) -> list[Path]:
    """One qualitative comparison per scene and view count (the paper's figure):
    ground truth on top, a row per method (its lowest-seed finished run).

    Written to ``<out>/figures/<scene>-v<views>.png``; runs without renders are left out.
    """
    from .figures import comparison_figure

    groups: dict[tuple, dict[str, dict]] = {}
    for r in records:
        if r["status"] != "ok" or not (Path(r["run_dir"]) / "renders").is_dir():
            continue
        methods = groups.setdefault((r["data"], r["views"]), {})
        if r["method"] not in methods or r["seed"] < methods[r["method"]]["seed"]:
            methods[r["method"]] = r
    written = []
    for (data, views), methods in groups.items():
        target = Path(out) / "figures" / f"{group_key(data, views)}.png"
        rows = [(m, Path(r["run_dir"])) for m, r in methods.items()]
        try:
            written.append(comparison_figure(rows, target))
        except DataError as e:  # a run without usable renders: the tables still stand
            warnings.warn(f"{target}: comparison figure skipped ({e})", stacklevel=2)
    return written


# ------------------------------------------------------------ reporting
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
        gpu = _has_gpu(rows)
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


# ------------------------------------------------------------ backends
ResultCallback = Callable[[RunSpec, dict], None]


def _spec_dict(run: RunSpec) -> dict:
    d = run.to_json()
    d["attempt"] = uuid.uuid4().hex[:12]
    return d


def run_serial(runs: list[RunSpec], threads: int | None, on_start, on_result: ResultCallback) -> None:
    for run in runs:
        on_start(run)
        on_result(run, execute_run(_spec_dict(run), threads))


def run_local(
    runs: list[RunSpec], workers: int, threads: int, on_start, on_result: ResultCallback, poll_s: float = 0.2
) -> None:
    """Each run in a fresh ``python -m splat_framework.sweep`` subprocess, ``workers`` at a time."""
    queue = deque(runs)
    running: dict[int, tuple] = {}
    env = dict(os.environ)
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        env[var] = str(threads)
    try:
        while queue or running:
            while queue and len(running) < workers:
                run = queue.popleft()
                spec = _spec_dict(run)
                run.run_dir.mkdir(parents=True, exist_ok=True)
                spec_path = run.run_dir / "sweep-spec.json"
                atomic_write_text(spec_path, json.dumps(spec, indent=2))
                log = open(run.run_dir / "sweep.log", "ab")
                proc = subprocess.Popen(
                    [sys.executable, "-m", "splat_framework.sweep", str(spec_path), str(threads)],
                    stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env,
                )
                log.close()
                running[proc.pid] = (proc, run, spec["attempt"])
                on_start(run)
            finished = []
            for pid, (proc, run, attempt) in running.items():
                rusage = None
                if hasattr(os, "wait4"):
                    wpid, status, rusage = os.wait4(pid, os.WNOHANG)
                    if wpid == 0:
                        continue
                    proc.returncode = os.waitstatus_to_exitcode(status)
                elif proc.poll() is None:
                    continue
                finished.append(pid)
                on_result(run, _child_result(run, attempt, proc.returncode, rusage))
            for pid in finished:
                del running[pid]
            if not finished:
                time.sleep(poll_s)
    finally:
        _stop_children([p for p, _, _ in running.values()])


def _child_result(run: RunSpec, attempt: str, returncode: int, rusage) -> dict:
    result = None
    try:
        result = json.loads((run.run_dir / "sweep.json").read_text())
        if result.get("attempt") != attempt:
            result = None
    except (OSError, json.JSONDecodeError):
        pass
    if result is None:
        how = f"killed by signal {-returncode}" if returncode < 0 else f"exited with code {returncode}"
        if returncode in (-9, 137):
            how += " (out of memory?)"
        last = _last_line(run.run_dir / "sweep.log")
        result = {"status": "failed", "error": f"worker process {how}" + (f": {last}" if last else "")}
    if rusage is not None:
        result["peak_rss_mb"] = peak_rss_mb(rusage.ru_maxrss)
    if result["status"] == "ok":
        try:
            result["metrics"] = json.loads((run.run_dir / "metrics.json").read_text())
        except (OSError, json.JSONDecodeError) as e:
            result.update(status="failed", error=f"metrics.json unreadable after the run ({e})")
    return result


def _last_line(path: Path) -> str:
    try:
        lines = [ln.strip() for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1][:200] if lines else ""


def _stop_children(procs: list, grace_s: float = 60.0) -> None:
    """SIGTERM (the trainer writes a checkpoint), then SIGKILL after ``grace_s``."""
    import signal

    for p in procs:
        if p.returncode is None:
            try:
                p.send_signal(signal.SIGTERM)
            except OSError:
                pass
    deadline = time.monotonic() + grace_s
    for p in procs:
        try:
            p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
        except ChildProcessError:
            pass


def import_ray():
    try:
        import ray
    except ImportError:
        raise SweepError(RAY_HINT) from None
    return ray


def run_ray(
    runs: list[RunSpec], threads: int, address: str | None, on_start, on_result: ResultCallback,
    local_cpus: int | None = None,
) -> None:
    """One Ray task per run; results gathered as they finish."""
    ray = import_ray()
    started = False
    if not ray.is_initialized():
        if address in (None, "", "local"):
            ray.init(num_cpus=local_cpus, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
        started = True
    try:
        node_cpus = [n.get("Resources", {}).get("CPU", 0) for n in ray.nodes() if n.get("Alive")]
        if node_cpus and max(node_cpus) >= 1 and threads > max(node_cpus):
            threads = int(max(node_cpus))  # a task asking for more CPUs than any node has would never start
        task = ray.remote(num_cpus=threads, max_calls=1)(_ray_task)
        refs = {}
        for run in runs:
            spec = _spec_dict(run)
            spec["run_dir"] = str(Path(spec["run_dir"]).resolve())
            refs[task.remote(spec, threads)] = run
            on_start(run)
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1, timeout=1.0)
            for ref in done:
                run = refs[ref]
                try:
                    result = ray.get(ref)
                except Exception as e:  # the task's process died, or the cluster lost it
                    result = {"status": "failed", "error": f"ray task failed: {one_line(e)}"}
                _mirror_result(run, result)
                on_result(run, result)
    except BaseException:
        for ref in refs:
            try:
                ray.cancel(ref)
            except Exception:
                pass
        raise
    finally:
        if started:
            ray.shutdown()


def _mirror_result(run: RunSpec, result: dict) -> None:
    """Write metrics.json/sweep.json under the driver's <out> when the worker's file system is another one."""
    if result.get("status") == "ok" and result.get("metrics") and not (run.run_dir / "metrics.json").is_file():
        atomic_write_json(run.run_dir / "metrics.json", result["metrics"])
        atomic_write_text(
            run.run_dir / "sweep.json", json.dumps({k: v for k, v in result.items() if k != "metrics"}, indent=2)
        )


# ------------------------------------------------------------ the sweep
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

    Runs whose metrics.json exists are skipped. Unknown methods raise
    :class:`SweepError` before anything runs; any other problem of a single
    run (bad override, missing dataset, a crash, a conflicting old run) is
    recorded as that run's failure.
    """
    from .registry import discover_methods

    if backend not in BACKENDS:
        raise SweepError(f"backend: '{backend}' is not one of {', '.join(BACKENDS)}")
    if backend == "ray":
        import_ray()  # fail before anything runs
    out = Path(out)
    runs = grid.runs(out)
    known = discover_methods()
    unknown = [m for m in _unique(grid.methods) if m not in known]
    if unknown:
        raise SweepError(f"unknown method(s) {', '.join(unknown)} (registered: {', '.join(sorted(known))})")
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
            build_config(_spec_dict(run))
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

    out.mkdir(parents=True, exist_ok=True)
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


def _check_data(data: str) -> str | None:
    """None when the dataset resolves (generating a synthetic scene once, here); else the error."""
    try:
        from .data.resolve import resolve_data_path

        resolve_data_path(data)
    except Exception as e:
        return one_line(e)
    return None


if __name__ == "__main__":
    worker_main()
