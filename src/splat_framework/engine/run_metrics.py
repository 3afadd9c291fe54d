"""``metrics.json``: what a finished run reports (test metrics, timing, counters), written atomically."""

from __future__ import annotations

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
    }
    metrics["init_stats"] = dict(trainer.model.init_stats)
    report = trainer.model.report(trainer.datamanager)
    if report is not None:
        metrics["model_report"] = report
    if trainer.camera_refiner is not None:  # how far each training camera moved
        metrics["camera_refine"] = trainer.camera_refiner.report(trainer.datamanager.train_cameras)
    atomic_write_json(trainer.run_dir / "metrics.json", metrics)  # OSError (disk full): one line in the CLI
    return metrics
