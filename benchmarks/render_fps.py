"""Steady rendering speed of a trained model: the test views of a real run, rendered again and again.

Loads a snapshot of ``benchmarks/train_step.py``'s reference run (trained there when
missing) into a trainer, renders every test view twice untimed (compile, allocator),
then ``--repeats`` times timed, and prints ms per frame and FPS (best and median
pass). No gradients, the run's own kernels (compiled by default). Compare two
versions of the code by running it alternately in one session
(``PYTHONPATH=/path/to/other/src python benchmarks/render_fps.py``).

Usage:
    SPLAT_DATA=../shared/data python benchmarks/render_fps.py [--method scgaussian] [--at 1000]
        [--data llff/fern --views 3] [--repeats 5] [--threads 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> dict:
    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import train_step

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--method", default="scgaussian")
    p.add_argument("--at", type=int, default=1000, help="snapshot iteration of the reference run")
    p.add_argument("--data", default="llff/fern")
    p.add_argument("--views", type=int, default=3)
    p.add_argument("--train-steps", type=int, default=1000, help="length of the reference run")
    p.add_argument("--repeats", type=int, default=5, help="timed passes over the test views")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    p.add_argument("--work", type=Path, default=None, help="snapshot folder (train_step.py's)")
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    from splat_framework.engine.trainer import Trainer

    snap_args = argparse.Namespace(data=args.data, views=args.views, at=[args.at], train_steps=args.train_steps,
                                   work=args.work)
    snap = train_step.snapshots(args.method, snap_args)[args.at]
    config = train_step.method_config(args.method, args.data, args.views, args.train_steps,
                                      train_step.work_dir(args.work) / "scratch").model_copy(update={"progress": False})
    trainer = Trainer(config)
    train_step.load_snapshot(trainer, snap)
    views = [camera for camera, _ in trainer.datamanager.eval_views()]

    def render_all() -> None:
        with torch.no_grad():
            for camera in views:
                trainer.model.get_outputs(camera, trainer.background)

    render_all()
    render_all()
    ms = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        render_all()
        ms.append((time.perf_counter() - t0) / len(views) * 1e3)
    result = {"method": args.method, "at": args.at, "data": args.data, "views": len(views),
              "num_gaussians": trainer.model.num_gaussians, "ms_per_frame": ms,
              "fps_best": 1e3 / min(ms), "fps_median": 1e3 / statistics.median(ms)}
    print(f"{args.method} @ {args.at} ({result['num_gaussians']:,} G), {len(views)} test views of {args.data}: "
          f"{statistics.median(ms):.1f} ms per frame (median of {args.repeats}), "
          f"{result['fps_median']:.1f} FPS (best {result['fps_best']:.1f})")
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=1))
    return result


if __name__ == "__main__":
    main()
