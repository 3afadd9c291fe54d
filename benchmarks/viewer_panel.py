"""How long the viewer's "Render with splat" takes: a model of ``--gaussians`` Gaussians on a real
scene, its first training camera rendered into the panel (RGB | depth | |error|), at the camera's
full size and at the panel's size (:func:`splat_framework.viewer.scene_viewer.panel_camera`).

The model is the method's start (``model.init.kind random``, ``--gaussians`` points in the scene's
box, the start's nearest-neighbour scales), not trained: the time depends on the Gaussians' count
and footprint and on the pixels. One untimed render first, then ``--repeats`` timed ones; prints
the median and the load average before and after (the machine is shared: read the numbers with it).

Usage:
    SPLAT_DATA=../shared/data SPLAT_COMPILE=0 python benchmarks/viewer_panel.py [--data llff/fern]
        [--gaussians 50000] [--threads 2] [--repeats 3] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path


def _median_s(fn, repeats: int) -> tuple[float, float]:
    """Median wall-clock and CPU seconds (all threads of this process) of ``fn()``: on a shared
    machine the CPU time is the one that does not depend on what else runs."""
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


def main(argv: list[str] | None = None) -> dict:
    import torch

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--method", default="3dgs")
    p.add_argument("--data", default="llff/fern")
    p.add_argument("--gaussians", type=int, default=50_000)
    p.add_argument("--threads", type=int, default=2, help="torch threads")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    from splat_framework.engine.trainer import Trainer
    from splat_framework.registry import get_method
    from splat_framework.viewer.scene_viewer import Viewer, panel_camera

    cfg = get_method(args.method).default_config()
    init = cfg.model.init.model_copy(update=dict(kind="random", num_points=args.gaussians))
    scratch = tempfile.TemporaryDirectory()
    cfg = cfg.model_copy(update=dict(data=args.data, progress=False, output=Path(scratch.name) / "run",
                                     model=cfg.model.model_copy(update=dict(init=init))))
    trainer = Trainer(cfg)
    viewer = Viewer(port=0)
    try:
        viewer.set_model(trainer.model, trainer.background)
        viewer.set_dataset(trainer.datamanager)
        label = viewer._start_label
        camera, _ = viewer._cameras[label]
        small = panel_camera(camera)
        load_before = os.getloadavg()
        full_s = _median_s(lambda: trainer.model.get_outputs(camera, trainer.background), args.repeats)
        panel_s = _median_s(lambda: viewer.render_panel(label), args.repeats)
        load_after = os.getloadavg()
    finally:
        viewer.close()
        scratch.cleanup()
    result = {"data": args.data, "num_gaussians": trainer.model.num_gaussians, "threads": args.threads,
              "full_size": [camera.width, camera.height], "full_render_s": full_s[0], "full_render_cpu_s": full_s[1],
              "panel_size": [small.width, small.height], "panel_s": panel_s[0], "panel_cpu_s": panel_s[1],
              "loadavg_before": load_before, "loadavg_after": load_after, "cpus": os.cpu_count()}
    print(f"{args.data}, {result['num_gaussians']:,} Gaussians, {args.threads} threads, median of {args.repeats}: "
          f"full {camera.width}x{camera.height} RGB render {full_s[0]:.2f} s ({full_s[1]:.2f} s CPU); "
          f"panel {small.width}x{small.height} RGB | depth | |error| {panel_s[0]:.2f} s ({panel_s[1]:.2f} s CPU); "
          f"load average {load_before[0]:.1f} -> {load_after[0]:.1f} on {os.cpu_count()} CPUs")
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=1))
    return result


if __name__ == "__main__":
    main()
