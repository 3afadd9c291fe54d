"""What a finished run writes: ``metrics.json`` (:func:`run_metrics`: test metrics, timing, counters),
and what a run folder holds in the 3DGS reference's layout, beside config.json and checkpoints:

- ``train.log``: the plain lines of the run as a log gets them (:func:`splat_framework.console.add_log`),
  whatever the terminal shows; each process that writes the run (a start, each ``--resume``) appends
  its lines after a first one naming itself, so nothing is written twice (:class:`RunLog`);
- ``cameras.json``: the held-out, then the training cameras, as the reference's ``camera_to_JSON``
  writes them (id, img_name, width, height, position, rotation, fy, fx; OpenCV axes);
- ``point_cloud/iteration_N/point_cloud.ply``: the trained Gaussians in the 3DGS PLY layout, N the
  last step.

cameras.json and the PLY are written when training ends, before the final evaluation (the
reference writes cameras.json at the start; here it holds the training cameras' poses as trained,
refined where ``--camera-refine.mode`` turns that on; focal lengths too).

SIBR, SuperSplat and the reference's scripts open these directly.
"""

from __future__ import annotations

import json
import os
import shlex
import statistics
import sys
import threading
from datetime import datetime
from pathlib import Path
from typing import Sequence

from ..console import add_log, remove_log
from ..errors import CheckpointError, DataError
from ..export.ply import export_ply
from ..runtime.io import atomic_write_json, atomic_write_text
from ..runtime.threads import threads_record
from .checkpoint import remove_stale_temporaries

__all__ = ["CAMERAS_NAME", "LOG_NAME", "RunLog", "camera_entries", "point_cloud_path", "run_metrics", "step_times",
           "write_cameras", "write_point_cloud", "write_run_outputs"]

LOG_NAME = "train.log"
CAMERAS_NAME = "cameras.json"


def point_cloud_path(run_dir: Path, step: int) -> Path:
    """``RUN/point_cloud/iteration_{step}/point_cloud.ply``, the reference's place for the Gaussians of ``step``."""
    return Path(run_dir) / "point_cloud" / f"iteration_{step}" / "point_cloud.ply"


def write_point_cloud(run_dir: Path, model, step: int) -> Path:
    """Write ``model``'s Gaussians at :func:`point_cloud_path` (atomically); the path."""
    path = point_cloud_path(run_dir, step)
    remove_stale_temporaries(path.parent)  # a write that a killed process left half done
    return export_ply(model, path)


def camera_entries(scene, cameras=None) -> list[dict]:
    """The entries of ``cameras.json`` for ``scene`` (a SceneData; ``cameras``: its cameras as
    trained, default ``scene.cameras``): its held-out cameras, then its training ones, ids counted
    from 0, as the 3DGS reference lists its test then train cameras.
    ``position`` is the camera centre, ``rotation`` the camera-to-world rotation (rows), in the
    OpenCV axes (x right, y down, z forward); width, height and focal lengths at the trained size."""
    entries = []
    cameras = scene.cameras if cameras is None else cameras
    for i in (*scene.test_indices, *scene.train_indices):
        cam = cameras[i]
        cam_to_world = cam.cam_to_world.double().cpu()
        entries.append({
            "id": len(entries),
            "img_name": Path(scene.image_paths[i]).stem,
            "width": int(cam.width),
            "height": int(cam.height),
            "position": cam_to_world[:3, 3].tolist(),
            "rotation": cam_to_world[:3, :3].tolist(),
            "fy": float(cam.K[1, 1]),
            "fx": float(cam.K[0, 0]),
        })
    return entries


def write_cameras(run_dir: Path, scene, cameras=None) -> Path:
    """Write ``RUN/cameras.json`` (:func:`camera_entries`; ``cameras``: the scene's with the poses
    trained, where they were refined), atomically; the path."""
    path = Path(run_dir) / CAMERAS_NAME
    atomic_write_text(path, json.dumps(camera_entries(scene, cameras)) + "\n")
    return path


def write_run_outputs(run_dir: Path, datamanager, model, step: int) -> None:
    """When training ends at ``step``: ``cameras.json`` (the cameras as trained) and
    ``point_cloud/iteration_{step}/point_cloud.ply``."""
    write_cameras(run_dir, datamanager.scene, datamanager.cameras)
    write_point_cloud(run_dir, model, step)


class RunLog:
    """``RUN/train.log`` while a process writes the run: created once the run folder is this
    process's, closed by :meth:`close` (with the line the command ends on, when it ends on an error
    or a stop).

    The lines wait in memory until the run writes its ``config.json`` (a new run after its set-up, a
    resumed one once its checkpoint is checked), so that a start that fails or is refused leaves the
    folder as it was. Then lines are appended whole, the file opened for each and closed again (no
    handle is held: a run built in-process and never closed leaves no open file); a line that a killed
    process left unfinished is ended first."""

    def __init__(self, run_dir: Path, command: Sequence[str] | None, resume: bool):
        self.path = Path(run_dir) / LOG_NAME
        self._config = Path(run_dir) / "config.json"
        self._config_before = _identity(self._config)
        self._lock = threading.Lock()
        self._closed = False
        args = shlex.join(["splat-train", *command]) if command is not None else "(in-process)"
        self._waiting: list[str] | None = [f"{'resumed' if resume else 'started'} {datetime.now():%Y-%m-%d %H:%M:%S}: {args}"]
        add_log(self.write)

    def write(self, line: str) -> None:
        """Append one line (a newline added); kept in memory until the run writes its config."""
        with self._lock:
            if self._closed:
                return
            if self._waiting is not None:
                self._waiting.append(line)
                if _identity(self._config) == self._config_before:
                    return
                line, self._waiting = "\n".join(self._waiting), None
                if self.path.is_file() and self.path.stat().st_size and not _ends_with_newline(self.path):
                    line = "\n" + line
            with open(self.path, "a", encoding="utf-8") as f:
                f.write(line + "\n")

    def close(self) -> None:
        """Stop logging. Called while an exception propagates (a ``finally``), it logs the line the
        command will end on."""
        if self._closed:
            return
        remove_log(self.write)
        error = sys.exc_info()[1]
        if error is not None:
            self.write(_final_line(error))
        with self._lock:
            self._closed = True


def _identity(path: Path) -> tuple[int, int, int] | None:
    """(inode, mtime in ns, size) of ``path``, None when it does not exist: an atomic rewrite changes it."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


def _ends_with_newline(path: Path) -> bool:
    with open(path, "rb") as f:
        f.seek(-1, os.SEEK_END)
        return f.read(1) == b"\n"


def _final_line(error: BaseException) -> str:
    """The line a command prints as ``error`` ends it (splat_framework.cli.common's forms; the
    exception's type where the command shows a traceback)."""
    if isinstance(error, KeyboardInterrupt):
        return "interrupted"
    if isinstance(error, (DataError, CheckpointError)) or getattr(type(error), "cli_exit_code", None) is not None:
        return f"{getattr(type(error), 'cli_prefix', 'error')}: {error}"
    return f"error: {type(error).__name__}: {error}"


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
