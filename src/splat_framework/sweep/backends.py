"""Where the runs of a sweep execute: serially in this process, in local subprocesses, or as Ray tasks."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import uuid
from collections import deque
from pathlib import Path
from typing import Callable

from ..runtime.io import atomic_write_json, atomic_write_text
from .grid import RAY_HINT, RunSpec, SweepError
from .worker import execute_run, one_line, peak_rss_mb

ResultCallback = Callable[[RunSpec, dict], None]


def spec_dict(run: RunSpec) -> dict:
    d = run.to_json()
    d["attempt"] = uuid.uuid4().hex[:12]
    return d


def run_serial(runs: list[RunSpec], threads: int | None, on_start, on_result: ResultCallback) -> None:
    for run in runs:
        on_start(run)
        on_result(run, execute_run(spec_dict(run), threads))


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
                spec = spec_dict(run)
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


def _ray_task(spec: dict, threads: int) -> dict:
    return execute_run(spec, threads)


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
            spec = spec_dict(run)
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
