"""Re-open a finished (or interrupted) run folder: config, data and trained model."""

from __future__ import annotations

from pathlib import Path

import torch

from ..config import RunFacts, read_config_json, upgrade_saved_config
from ..devices import resolve_config_devices
from ..errors import CheckpointError, DataError
from ..registry import get_method
from ..render import RenderSettings, prepare_kernels
from .checkpoint import check_structure, load_latest


def load_trained_model(run_dir: Path, device: str | None = None, scene_scale: float = 1.0,
                       trust_edits: bool = False):
    """(config, model) of ``run_dir`` from its newest good checkpoint, without loading the dataset.

    ``scene_scale`` only scales learning rates, which rendering and exporting do not use;
    ``trust_edits``: accept a config.json without a valid checksum (see ``read_config_json``).
    """
    config, model, _ = _load_checkpointed(run_dir, device, scene_scale, trust_edits)
    return config, model


def _load_checkpointed(run_dir: Path, device: str | None, scene_scale: float, trust_edits: bool):
    """(config, model, the checkpoint's training-camera corrections or None): see ``load_trained_model``."""
    run_dir = Path(run_dir)
    cfg_path = run_dir / "config.json"
    if not run_dir.exists():
        raise DataError(f"{run_dir}: no such run folder")
    if not run_dir.is_dir():
        raise DataError(f"{run_dir}: not a run folder (a file, not a folder)")
    if not cfg_path.is_file():
        raise DataError(f"{cfg_path}: not a run folder (config.json missing)")
    method, raw, version = read_config_json(cfg_path, trust_edits)
    try:
        spec = get_method(method)
    except KeyError as e:
        raise DataError(f"{cfg_path}: {e.args[0]}") from None
    defaults = spec.default_config()
    config = type(defaults).model_validate(upgrade_saved_config(raw, version, defaults))
    if device is not None:
        config = config.model_copy(update={"device": device})
    resolve_config_devices(config, None if device is not None else str(cfg_path))

    def rebuild(path: Path, ck: dict):
        check_structure(path, ck, max_step=config.total_steps)
        try:
            model = spec.model_class().from_checkpoint(config.model, RunFacts.of(config), scene_scale, ck)
            _renders(model)
        except (KeyError, ValueError, TypeError, IndexError, RuntimeError) as e:  # e.g. wrong per-row shapes
            first = (str(e).splitlines() or [""])[0]
            raise CheckpointError(f"{path}: not a {method} model ({type(e).__name__}: {first})") from None
        return model, ck.get("camera_refine")  # the training views' pose corrections, if any

    found = load_latest(run_dir / "checkpoints", accept=rebuild)
    if found is None:
        raise CheckpointError(f"{run_dir / 'checkpoints'}: no valid checkpoint")
    model, camera_refine = found[1]
    model = model.to(config.device)
    model.render_settings = prepare_kernels(torch.device(config.device), RenderSettings.from_config(config))
    return config, model, camera_refine


def _renders(model) -> None:
    """Render a 4x4 image of ``model`` (raises if its parameters do not fit the rasterizer) with a
    camera that every Gaussian at a finite position is behind: the projection checks every row,
    and nothing is composited (a camera inside the scene composited 106k Gaussians for 51 s)."""
    from ..cameras import Camera, intrinsics

    away = torch.eye(4)
    away[2, 3] = -1e30  # camera z of every point: about -1e30, behind the near plane
    cam = Camera(K=intrinsics(4.0, 4.0, 2.0, 2.0), world_to_cam=away, width=4, height=4)
    with torch.no_grad():
        model.get_outputs(cam)


def load_run(run_dir: Path, device: str | None = None, trust_edits: bool = False):
    """(config, datamanager, model) of ``run_dir``, the model holding the newest good checkpoint."""
    from ..console import phase
    from ..data import DataManager
    from ..pipeline.camera_refine import refined_cameras
    from ..pipeline.scene import load_config_scene

    with phase(f"loading {run_dir}: its newest checkpoint"):
        config, model, camera_refine = _load_checkpointed(run_dir, device, 1.0, trust_edits)
    with phase(f"loading {run_dir}: its dataset's cameras ({config.data})"):
        scene = load_config_scene(config)
        model.scene_scale = float(scene.scene_radius)
        datamanager = DataManager(scene, device=config.device, seed=config.seed)
        datamanager.cameras = refined_cameras(datamanager.cameras, datamanager.train_indices, camera_refine)
    return config, datamanager, model
