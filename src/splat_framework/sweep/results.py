"""Results of a sweep: each run's state and record, the mean and std over seeds, the tables and figures."""

from __future__ import annotations

import csv
import io
import json
import math
import statistics
import warnings
from datetime import datetime
from pathlib import Path
from typing import Any

from ..errors import DataError
from ..runtime.io import atomic_write_text
from .grid import METRICS, NUMERIC_FIELDS, PHASES, RunSpec, group_key


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
        "matches_digest": None,
    }
    for k in NUMERIC_FIELDS:
        rec[k] = None
    if result:
        rec["peak_rss_mb"] = result.get("peak_rss_mb")
        rec["peak_gpu_mb"] = result.get("peak_gpu_mb")
        rec["load_average"] = _num(result.get("load_average"))
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
        digest = (metrics.get("init_stats") or {}).get("matches_digest")
        rec["matches_digest"] = digest if isinstance(digest, str) else None
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


def aggregate(records: list[dict]) -> list[dict]:
    """One row per (method, data, views), in order of first appearance.

    Each numeric field gets ``<field>_mean`` and ``<field>_std`` over the seeds
    that finished (sample standard deviation; None with fewer than two values,
    both None when no seed has a value, e.g. LPIPS without the lpips package).
    ``matches_digests`` lists the distinct ``MatchSet.digest`` values the
    finished seeds trained from, in seed order (empty for a method without
    matches): two rows compare on the same matches only where these agree.
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
            "matches_digests": list(dict.fromkeys(r["matches_digest"] for r in ok if r.get("matches_digest"))),
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
    ("LPIPS (Alex) ↓", "lpips_alex", ".3f"),
    ("AVG ↓", "avg", ".3f"),
    ("ST-LPIPS ↓", "st_lpips", ".3f"),
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


def has_gpu(rows: list[dict]) -> bool:
    return any(r.get("peak_gpu_mb_mean") is not None for r in rows)


def markdown_table(rows: list[dict]) -> str:
    """The results as a Markdown table; failed runs listed below it."""
    gpu = has_gpu(rows)
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
    cols += ["matches_digests", "errors"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for row in rows:
        out = []
        for c in cols:
            v = row.get(c)
            if c in ("seeds", "matches_digests"):
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
    from ..evaluation.figures import comparison_figure

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
