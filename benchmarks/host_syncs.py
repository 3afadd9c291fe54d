"""How often a training step makes the host wait for the device: host syncs per step, by place.

Trains ``--method`` on ``--data`` for ``--warmup`` steps (the first steps make one-time choices),
then counts the next ``--steps`` steps' host syncs two ways: what the code asks for
(:mod:`splat_framework.testing.host_syncs`, any device, by ``file:line``) and, on CUDA, what torch
itself reports (``torch.cuda.set_sync_debug_mode``: one warning per synchronizing call). It also
times the counted steps (on CUDA with a synchronize at both ends). The counter needs this
checkout's ``splat_framework``; torch's count works with any version of the code, so the GPU check
(benchmarks/cuda.py) runs it on the code before as well.

Usage::

    python benchmarks/host_syncs.py [--method scgaussian] [--data llff/fern] [--device cuda]
        [--warmup 30] [--steps 20] [--json host-syncs.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
import warnings
from datetime import datetime, timezone
from pathlib import Path


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--method", default="scgaussian")
    p.add_argument("--data", default="synthetic/forward-tiny", help="a --data of splat-train")
    p.add_argument("--device", default="cpu")
    p.add_argument("--warmup", type=int, default=30, help="steps before counting (one-time choices)")
    p.add_argument("--steps", type=int, default=20, help="steps counted")
    p.add_argument("--output", type=Path, default=Path("/tmp/splat-host-syncs-run"), help="the run folder (replaced)")
    p.add_argument("--json", type=Path, default=None, help="write the counts here")
    return p.parse_args(argv)


def cuda_syncs(trainer, steps: range, torch) -> tuple[int, list[str]]:
    """Synchronizing CUDA calls torch reports over ``steps`` (sync debug mode "warn"), and a few of
    its messages' places."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        torch.cuda.set_sync_debug_mode("warn")
        try:
            for step in steps:
                trainer.train_step(step)
        finally:
            torch.cuda.set_sync_debug_mode("default")
    found = [w for w in caught if "synchroniz" in str(w.message)]
    return len(found), sorted({f"{Path(w.filename).name}:{w.lineno}" for w in found})[:40]


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    import torch

    from splat_framework.config import apply_overrides
    from splat_framework.engine.trainer import Trainer
    from splat_framework.registry import get_method
    from splat_framework.runtime.profiling import synchronize

    try:
        from splat_framework.testing.host_syncs import count_host_syncs
    except ImportError:  # the code before the counter: torch's own count only
        count_host_syncs = None
    device = torch.device(args.device)
    cfg = apply_overrides(get_method(args.method).default_config(), {
        "data": args.data, "device": args.device, "output": str(args.output), "overwrite": True, "progress": False,
        "save_renders": False})
    trainer = Trainer(cfg)
    total = trainer.config.total_steps
    if args.warmup + 2 * args.steps > total:
        raise SystemExit(f"--warmup {args.warmup} + 2 x --steps {args.steps} exceeds the run's {total} steps")
    print(f"{args.method} on {args.data} ({device}): {args.warmup} steps before counting", flush=True)
    for step in range(args.warmup):
        trainer.train_step(step)
    first = range(args.warmup, args.warmup + args.steps)
    record: dict = {
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"), "method": args.method, "data": args.data,
        "device": str(device), "machine": platform.node(), "torch": torch.__version__, "cpus": os.cpu_count(),
        "loadavg": os.getloadavg()[0], "steps": args.steps, "first_step": args.warmup,
        "gaussians": trainer.model.num_gaussians,
    }
    if device.type == "cuda":
        record["gpu"] = torch.cuda.get_device_name(device)
    synchronize(device)
    t0 = time.perf_counter()
    if count_host_syncs is not None:
        with count_host_syncs() as syncs:
            for step in first:
                trainer.train_step(step)
        record["counted_per_step"] = syncs.total() / args.steps
        record["counted_places"] = {f"{op} {place}": n / args.steps for (op, place), n in syncs.by_place().items()}
    else:
        for step in first:
            trainer.train_step(step)
    synchronize(device)
    record["step_ms_while_counting"] = 1e3 * (time.perf_counter() - t0) / args.steps
    second = range(first.stop, first.stop + args.steps)
    t0 = time.perf_counter()
    if device.type == "cuda":
        n, places = cuda_syncs(trainer, second, torch)
        synchronize(device)
        record["cuda_syncs_per_step"], record["cuda_sync_places"] = n / args.steps, places
    else:
        for step in second:
            trainer.train_step(step)
    record["step_ms"] = 1e3 * (time.perf_counter() - t0) / args.steps
    trainer.release()
    for key in ("counted_per_step", "cuda_syncs_per_step", "step_ms"):
        if key in record:
            print(f"{key}: {record[key]:.2f}")
    for place, n in record.get("counted_places", {}).items():
        print(f"  {n:6.2f}  {place}")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(record, indent=1) + "\n")
    return record


if __name__ == "__main__":
    main()
