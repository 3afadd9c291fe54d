"""``metrics.json``: what a finished run reports (test metrics, timing, counters), written atomically."""

from __future__ import annotations

import statistics

from ..runtime.io import atomic_write_json
from ..runtime.threads import threads_record


def run_metrics(trainer, results: dict) -> dict:
    """The metrics record of a finished ``trainer`` (a Trainer) whose held-out ``results`` are those of
    :func:`splat_framework.evaluation.held_out.evaluate`."""
    cfg = trainer.config
    metrics = {
        "method": cfg.method,
        "data": cfg.data,
        "steps": cfg.total_steps,
        "eval_split": cfg.eval_split,
        "mean": results["mean"],
        "per_view": results["per_view"],
        "timing": trainer.timing,
        "num_gaussians": trainer.model.num_gaussians,
        "strategy": f"{type(trainer.strategy).__module__}.{type(trainer.strategy).__qualname__}",
        "render_fps": results["fps"],
        "skipped_steps": trainer.skipped_steps,
        "densify_skipped_steps": trainer.densify_skipped,
        "densified": dict(trainer.densified),
        "restores": trainer.restores,
        "lpips_note": results["lpips_note"],
        "test_pose_steps": cfg.test_pose_steps,
        "threads": threads_record(),
        "rasterizer": trainer.rasterizer,
        "step_times": step_times(trainer.step_seconds),
    }
    if trainer.device.type == "cuda":  # the whole process's peak, training and evaluation
        import torch

        metrics["peak_gpu_memory_mib"] = torch.cuda.max_memory_allocated(trainer.device) / 2**20
    metrics["init_stats"] = dict(trainer.model.init_stats)
    report = trainer.model.report(trainer.datamanager)
    if report is not None:
        metrics["model_report"] = report
    if trainer.camera_refiner is not None:  # how far each training camera moved
        metrics["camera_refine"] = trainer.camera_refiner.report(trainer.datamanager.train_cameras)
    atomic_write_json(trainer.run_dir / "metrics.json", metrics)  # OSError (disk full): one line in the CLI
    return metrics


def step_times(seconds: list[tuple[int, float]]) -> dict | None:
    """The spread of the wall time of this process's training steps, ``seconds`` [(step, s)]
    in the order run, the first left out (it builds what later steps reuse): the median, the
    slowest and its step, and slowest / median; None with fewer than two steps."""
    later = seconds[1:]
    if not later:
        return None
    median = statistics.median(s for _, s in later)
    step, slowest = max(later, key=lambda t: t[1])
    return {"median_s": median, "max_s": slowest, "slowest_step": step,
            "max_over_median": slowest / median if median > 0 else None}
