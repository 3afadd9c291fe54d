"""What a checkpoint holds of a :class:`~splat_framework.engine.trainer.Trainer`, and loading it back.

A checkpoint holds everything the next step depends on: parameters, Adam states, densification
state, model extra state, all RNG states, the learning-rate factor, the fault counters and the
time spent so far, with the experiment record that ``--resume`` checks
(:mod:`splat_framework.engine.resume_check`).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import torch

from ..config import config_payload, save_config
from ..console import say
from ..model.strategy import unplain_state
from ..runtime.rng import restore_rng_state, rng_state
from .checkpoint import (
    CheckpointError,
    check_structure,
    list_checkpoints,
    load_checkpoint,
    load_latest,
    save_checkpoint,
)
from .resume_check import check_checkpoint_record, check_saved_config, experiment_record


class TrainState:
    """The checkpoint side of the Trainer (a base class of it): what a checkpoint saves and
    restores, declared below (the Trainer sets each in its set-up)."""

    config: Any
    """The run's resolved TrainConfig (its experiment record goes into every checkpoint)."""
    spec: Any
    """The method's registration (MethodSpec), to check a checkpoint's record against."""
    run_dir: Path
    device: torch.device
    model: Any
    """The GaussianModel: its rows, networks and extra state."""
    optimizers: dict[str, torch.optim.Optimizer]
    strategy: Any
    strategy_state: dict[str, Any]
    """The strategy's own state; only the strategy edits it, the checkpoint saves and loads it."""
    camera_refiner: Any
    """The training cameras' pose corrections (a CameraRefiner), or None."""
    generator: torch.Generator
    timing: dict[str, float]
    """Seconds per phase (data_s, matching_s, ..., train_s) for metrics.json."""
    start_step: int
    """The step the loop starts at (0, or a loaded checkpoint's)."""
    lr_factor: float
    """The learning rates' fault factor (halved at each restore after non-finite steps)."""
    skipped_steps: int
    densify_skipped: int
    densified: dict[str, int]
    """The strategy's counts (n_clone, n_split, n_prune, ...) summed over the run."""
    restores: int
    _config_verified: bool
    """Whether config.json vouches for the checkpoints (``--resume`` without an edited config)."""
    _train_prior_s: float
    _train_t0: float | None
    """perf_counter at the start of this process's training, None outside the loop."""

    saving: bool
    """A checkpoint is being written (a second stop signal waits for it)."""

    @property
    def checkpoint_dir(self) -> Path:
        return self.run_dir / "checkpoints"

    def config_payload(self) -> dict:
        return config_payload(self.config)

    def write_config(self) -> None:
        """``config.json``: the resolved config with its schema version and a checksum (atomic)."""
        save_config(self.config, self.run_dir / "config.json")

    def check_saved_config(self) -> bool:
        """Before ``--resume`` loads anything: the run's config.json agrees with this run's config
        (:func:`~splat_framework.engine.resume_check.check_saved_config`); whether it vouches for the
        checkpoints."""
        return check_saved_config(self.config, self.spec, self.run_dir)

    def save(self, step: int) -> Path:
        """Write the checkpoint of ``step`` (CheckpointError, one line, on failure).

        A stop signal that arrives meanwhile waits for the write to finish."""
        self.saving = True
        try:
            return save_checkpoint(self.checkpoint_dir, step, self.state_payload(step))
        finally:
            self.saving = False

    def _train_seconds(self) -> float:
        extra = time.perf_counter() - self._train_t0 if self._train_t0 is not None else 0.0
        return self._train_prior_s + extra

    def experiment_record(self) -> dict:
        """The experiment fields of this run's resolved config (what a resume may not change), as
        JSON values; every checkpoint carries it, covered by the checkpoint's checksum."""
        return experiment_record(self.config)

    def state_payload(self, step: int) -> dict:
        odd = unplain_state(self.strategy_state)
        if odd is not None:
            raise TypeError(f"{type(self.strategy).__name__}'s state {odd}: a checkpoint holds tensors and plain "
                            "values only (it is loaded with weights_only=True)")
        timing = dict(self.timing)
        timing["train_s"] = self._train_seconds()
        return {
            "step": step,
            "method": self.config.method,
            "experiment": self.experiment_record(),
            "total_steps": self.config.total_steps,
            "params": {k: v.detach().cpu() for k, v in self.model.params.items()},
            "networks": {k: v.detach().cpu() for k, v in self.model.networks.state_dict().items()},
            "optimizers": {k: o.state_dict() for k, o in self.optimizers.items()},
            "strategy_state": {
                k: (v.detach().cpu() if torch.is_tensor(v) else v) for k, v in self.strategy_state.items()
            },
            "model_state": self.model.extra_state(),
            "camera_refine": self.camera_refiner.state_dict() if self.camera_refiner is not None else None,
            **rng_state(self.generator, self.device),
            "lr_factor": self.lr_factor,
            "skipped_steps": self.skipped_steps,
            "densify_skipped_steps": self.densify_skipped,
            "densified": dict(self.densified),
            "restores": self.restores,
            "timing": timing,
        }

    def _load_state(self, path: Path, ck: dict) -> None:
        dev = self.device
        self.model.restore(ck, dev)
        self.optimizers = self.model.make_optimizers()
        for k, o in self.optimizers.items():
            o.load_state_dict(ck["optimizers"][k])
        self.strategy_state = {
            k: (v.to(dev) if torch.is_tensor(v) else v) for k, v in ck["strategy_state"].items()
        }
        if self.camera_refiner is not None and ck.get("camera_refine"):
            self.camera_refiner.load_state_dict(ck["camera_refine"])
        restore_rng_state(ck, self.generator, dev)
        self.lr_factor = float(ck.get("lr_factor", 1.0))
        self.densified = {str(k): int(v) for k, v in ck.get("densified", {}).items()}  # as at that step
        self.start_step = int(ck["step"])
        if self.start_step > 0:  # the per-step state (SH degree, open levels) of the step the checkpoint ends
            self.model.on_step_start(self.start_step - 1)  # so a finished run evaluates as it did

    def load(self, path: Path) -> int:
        """Load the training state of one checkpoint file (CheckpointError if it does not verify); its step."""
        self._restore_from(Path(path), load_checkpoint(path))
        return self.start_step

    def restore(self) -> bool:
        """Load the newest good checkpoint (``--resume``); False when there is none.

        A corrupt or truncated newer checkpoint is reported in one line and
        the previous one is used; CheckpointError when checkpoint files exist
        but none verifies.
        """
        found = self._load_latest_state()
        if found is None:
            if list_checkpoints(self.checkpoint_dir):
                raise CheckpointError(
                    f"{self.checkpoint_dir}: no valid checkpoint to resume from (all corrupt); use --overwrite to start again"
                )
            return False
        path, ck = found
        self.skipped_steps = int(ck.get("skipped_steps", 0))
        self.densify_skipped = int(ck.get("densify_skipped_steps", 0))
        self.restores = int(ck.get("restores", 0))
        timing = dict(ck.get("timing", {}))
        self._train_prior_s = float(timing.pop("train_s", 0.0))
        self.timing.update(timing)
        say(f"resumed from {path} (step {self.start_step})", "cyan")
        return True

    def _load_latest_state(self) -> tuple[Path, dict] | None:
        """Load the newest checkpoint that verifies and restores (see :meth:`_restore_from`);
        a bad newer one is reported and the previous one tried."""
        return load_latest(
            self.checkpoint_dir, report=lambda msg: say(f"warning: {msg}", "yellow"), accept=self._restore_from
        )

    def _restore_from(self, path: Path, ck: dict) -> dict:
        """Load a verified payload into the trainer after checking its structure against the model
        (parameter names and per-row shapes, float32, optimizer moments); CheckpointError otherwise,
        and DataError for a checkpoint of another experiment (:func:`check_checkpoint_record`)."""
        check_checkpoint_record(self.config, self.spec, path, ck, self._config_verified)
        check_structure(path, ck, self.model.params, max_step=self.config.total_steps)
        try:
            self._load_state(path, ck)
        except (KeyError, ValueError, TypeError, IndexError, RuntimeError) as e:  # e.g. a crafted model_state
            first = (str(e).splitlines() or [""])[0]
            raise CheckpointError(f"{path}: cannot restore ({type(e).__name__}: {first})") from None
        return ck
