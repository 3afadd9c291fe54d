"""A run folder like the 3DGS reference's: point_cloud/iteration_N/point_cloud.ply, cameras.json and
the run's log, train.log (engine/run_outputs.py)."""

import json
import re

import pytest
import torch

from splat_framework.config import apply_overrides
from splat_framework.engine.run import load_trained_model
from splat_framework.engine.run_outputs import RunLog, point_cloud_path
from splat_framework.engine.trainer import Trainer, TrainingInterrupted
from splat_framework.export.ply import gaussians_for_export, load_ply
from splat_framework.registry import get_method


def test_a_finished_run_folder_holds_the_references_files(run_dir):
    from splat_framework.pipeline.scene import load_config_scene

    metrics = json.loads((run_dir / "metrics.json").read_text())
    steps = metrics["steps"]
    ply = point_cloud_path(run_dir, steps)
    assert ply == run_dir / "point_cloud" / f"iteration_{steps}" / "point_cloud.ply"
    config, model = load_trained_model(run_dir, "cpu")
    back, ref = load_ply(ply), gaussians_for_export(model)
    assert back["means"].shape[0] == metrics["num_gaussians"]
    assert all(torch.equal(back[k], ref[k]) for k in ref)

    # cameras.json: the reference's camera_to_JSON fields, its held-out then its training cameras
    scene = load_config_scene(config)
    cams = json.loads((run_dir / "cameras.json").read_text())
    order = [*scene.test_indices, *scene.train_indices]
    assert [c["id"] for c in cams] == list(range(len(order))) and len(order) == len(scene.test_indices) + 3
    for entry, i in zip(cams, order):
        assert set(entry) == {"id", "img_name", "width", "height", "position", "rotation", "fy", "fx"}
        cam = scene.cameras[i]
        assert entry["img_name"] == scene.image_paths[i].stem
        assert (entry["width"], entry["height"], entry["fx"], entry["fy"]) == (
            cam.width, cam.height, pytest.approx(float(cam.K[0, 0])), pytest.approx(float(cam.K[1, 1])))
        rotation, position = torch.tensor(entry["rotation"]), torch.tensor(entry["position"])
        # camera-to-world: the camera centre, and the rotation taking camera axes (OpenCV) to the world's
        assert torch.allclose(position, cam.center.float(), atol=1e-5)
        assert torch.allclose(rotation, cam.world_to_cam[:3, :3].float().T, atol=1e-5)

    # train.log: the plain lines of the run (this one trained with --progress off: the log has them still)
    lines = (run_dir / "train.log").read_text().splitlines()
    assert lines[0].startswith("started ")
    assert any(line.startswith(f"training: {steps}/{steps} steps, done in ") for line in lines)
    assert any("test psnr" in line and f"{metrics['mean']['psnr']:.4f}" in line for line in lines)  # the summary table


def _headers(lines):
    """The first line of each process that wrote the log."""
    return [line for line in lines if re.match(r"(started|resumed) \d{4}-\d\d-\d\d ", line)]


def _config(output, **over):
    cfg = get_method("3dgs").default_config()
    base = {"data": "synthetic/forward-tiny", "output": str(output), "default_steps": 6, "checkpoint_every": 3,
            "progress": False, "save_renders": False, "model": {"init": {"num_points": 300}}}
    return apply_overrides(apply_overrides(cfg, base), over)


def test_a_stopped_then_resumed_run_logs_each_line_once(tmp_path):
    run = tmp_path / "run"

    def stop_at_3(trainer, step):
        if step == 3:
            trainer.request_stop("test stop")

    with pytest.raises(TrainingInterrupted):
        Trainer(_config(run), [stop_at_3], command=["3dgs", "--output", str(run)]).train()
    first = (run / "train.log").read_text()
    assert first.splitlines()[0].endswith(f"splat-train 3dgs --output {run}")
    assert first.splitlines()[-1].startswith("stopped: test stop at step 3/6: checkpoint written to ")
    assert not (run / "point_cloud").exists() and not (run / "cameras.json").exists()  # written when training ends

    Trainer(_config(run, resume=True), command=["3dgs", "--output", str(run), "--resume"]).train()
    log = (run / "train.log").read_text()
    assert log.startswith(first)  # appended, nothing of the first process's rewritten
    rest = log[len(first):].splitlines()
    assert _headers(rest) == [rest[0]] and rest[0].startswith("resumed ")
    assert any(line.startswith("training: 6/6 steps, done in ") for line in rest)
    assert [p.name for p in (run / "point_cloud").iterdir()] == ["iteration_6"]

    # --overwrite: what the previous run wrote goes, this run's log starts afresh
    Trainer(_config(run, overwrite=True, default_steps=4)).train()
    lines = (run / "train.log").read_text().splitlines()
    assert len(_headers(lines)) == 1 and not any(line.startswith("stopped: ") for line in lines)
    assert [p.name for p in (run / "point_cloud").iterdir()] == ["iteration_4"]


def test_the_log_waits_for_the_run_to_write_and_ends_a_line_left_unfinished(tmp_path):
    from splat_framework.runtime.io import atomic_write_text

    (tmp_path / "config.json").write_text("{}")
    before = "started 2026-01-01 00:00:00: splat-train 3dgs\ntraining: 3/6 st"  # a process killed mid-line
    (tmp_path / "train.log").write_text(before)
    log = RunLog(tmp_path, ["3dgs", "--resume"], resume=True)
    log.write("loading data")
    assert (tmp_path / "train.log").read_text() == before  # a refused or failed resume changes nothing
    atomic_write_text(tmp_path / "config.json", "{ }")  # the run writes its config: the log follows
    log.write("a line")
    log.close()
    lines = (tmp_path / "train.log").read_text().splitlines()
    assert lines[1:] == ["training: 3/6 st", lines[2], "loading data", "a line"] and lines[2].startswith("resumed ")
    (tmp_path / "new").mkdir()
    log = RunLog(tmp_path / "new", None, resume=False)
    log.write("loading data")
    log.close()
    assert list((tmp_path / "new").iterdir()) == []  # a failed start of a new run leaves its folder empty
