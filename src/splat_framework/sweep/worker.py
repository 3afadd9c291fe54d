"""One run of a sweep: its config, its training in this process or a subprocess (``python -m splat_framework.sweep SPEC THREADS``), and how many run at once."""

from __future__ import annotations

import json
import os
import sys
import time
import traceback
from contextlib import redirect_stderr, redirect_stdout
from datetime import datetime
from pathlib import Path
from typing import Any

from ..errors import DataError
from ..runtime.io import atomic_write_text
from ..runtime.resources import available_cores, available_memory_bytes
from .grid import DEFAULT_MEM_PER_RUN_GB, SweepError


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
    from ..config import apply_overrides, deep_merge
    from ..registry import get_method

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


def load_average() -> float | None:
    """The machine's 1-minute load average, None where the system does not report one."""
    try:
        return os.getloadavg()[0]
    except (OSError, AttributeError):
        return None


def execute_run(spec: dict, threads: int | None = None) -> dict:
    """Train one run (in the calling process) and return its result.

    The result: status ("ok", "failed" or "interrupted"), error (one line or
    None), started (ISO time) and load_average (the machine's 1-minute load average, None where the
    system has none) at its start, wall_s, peak_rss_mb (this process's max RSS), peak_gpu_mb (CUDA only),
    metrics (the metrics.json dict when ok). Also written as ``sweep.json`` in
    the run folder; stdout/stderr of the run go to ``sweep.log`` there. Never
    raises for a failing run.
    """
    import resource

    t0 = time.perf_counter()
    rdir = Path(spec["run_dir"])
    rdir.mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {"status": "ok", "error": None, "attempt": spec.get("attempt"),
                              "started": datetime.now().isoformat(timespec="seconds"), "load_average": load_average()}
    metrics = None
    cuda = False
    with open(rdir / "sweep.log", "a", encoding="utf-8") as log, redirect_stdout(log), redirect_stderr(log):
        print(f"=== sweep run {spec.get('attempt')} started {result['started']}", flush=True)
        try:
            import torch

            if threads:
                torch.set_num_threads(int(threads))
                # a table's numbers must not depend on the load: the run keeps this count (a user's
                # own SPLAT_THREADS wins), recorded in its metrics.json
                os.environ.setdefault("SPLAT_THREADS", str(int(threads)))
            config = build_config(spec)
            cuda = str(config.device).startswith("cuda")
            from ..engine.trainer import TrainingInterrupted, train

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
