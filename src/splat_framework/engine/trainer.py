"""The training loop: seeded, checkpointed, resumable, with a live progress bar.

One step reads top to bottom in :meth:`Trainer.train_step`::

    camera, batch = datamanager.next_train(step)
    outputs = model.get_outputs(camera, background)
    losses = model.get_loss_dict(outputs, batch, camera, step)
    sum(losses).backward(); optimizers step; strategy densifies

Reliability contract:

- **Run folders** are never overwritten silently: without ``--output`` a new
  timestamped folder is made; an existing non-empty ``--output`` needs
  ``--resume`` (continue it) or ``--overwrite`` (start again; its old
  checkpoints and metrics are removed first).
- **One owner**: the run folder is locked by this process before the data
  is loaded (:mod:`splat_framework.engine.run_lock`); a second ``splat-train`` on the
  same ``--output``, fresh or ``--resume``, or a ``splat-eval`` of it, is
  refused in one line naming the holder; the lock is released when
  :meth:`Trainer.train` ends, however it ends.
- **Provenance**: ``--resume`` needs the run's own config.json (present,
  checksum intact) unless ``--trust-edited-config``, and refuses any change of
  an experiment field (all but the ``RUN_OPTION`` ones) against config.json
  and against the experiment every checkpoint records under its own checksum;
  config.json is rewritten only after that check, with this run's config.
- **Checkpoints** hold everything the next step depends on (parameters, Adam
  states, densification state, model extra state, all RNG states, the
  learning-rate factor); the view order is a pure function of (seed, step).
  So a run stopped at step s and resumed gives the same parameters as an
  uninterrupted run. Checkpoints, ``config.json`` and ``metrics.json`` are
  written atomically with a checksum; ``--resume`` skips a corrupt checkpoint
  (one-line warning) and uses the previous good one.
- **Signals**: SIGINT/SIGTERM finish the current step, write a checkpoint and
  raise :class:`TrainingInterrupted` (the CLI exits with code 130).
- **Numerics**: a step whose loss or gradients are not finite is skipped and
  counted; after :data:`MAX_NONFINITE` consecutive skips (or parameters that
  became non-finite) the last checkpoint is restored with halved learning
  rates, at most :data:`MAX_RESTORES` times, then :class:`TrainingDiverged`.
  Non-finite parameters are never written to disk.
- **Memory**: ``$SPLAT_IMAGE_MEMORY_BUDGET`` (bytes, ``"2G"`` style accepted)
  caps the decoded-image cache (the rest is decoded on demand); a run whose
  estimated memory exceeds the machine is reported before training starts.
"""

from __future__ import annotations

import math
import signal
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Sequence

import torch
from torch import Tensor

from . import run_lock
from .checkpoint import CheckpointError, check_structure, list_checkpoints, load_checkpoint, load_latest, save_checkpoint
from ..config import (
    TrainConfig, config_payload, experiment_fields, read_config_json, resolve_steps, save_config, upgrade_saved_config,
)
from ..console import console, print_summary, say, training_progress
from ..data import DataError, DataManager, load_config_scene
from ..data.cache_dir import user_cache_dir
from ..devices import resolve_config_devices
from ..evaluation.held_out import evaluate
from ..files.io import atomic_write_json
from .memory_plan import image_memory_budget, plan_memory
from ..evaluation.metrics import psnr
from ..model.strategy import Strategy
from .profiling import section
from ..render import set_compile
from ..render import apply_process_threads
from ..registry import MethodSpec, get_method
from .rng import restore_rng_state, rng_state, seed_everything
from .run_folder import prepare_run_dir
from .run_lock import is_empty_run_dir

MAX_NONFINITE = 20
"""Consecutive non-finite steps tolerated before restoring the last checkpoint."""
MAX_RESTORES = 2
"""Checkpoint restores (each halving the learning rates) before giving up."""


class TrainingInterrupted(Exception):
    """SIGINT/SIGTERM arrived; the message says what was saved (a checkpoint, or nothing during
    setup). The CLIs exit with code 130."""

    cli_exit_code = 130
    cli_prefix = "stopped"


class TrainingDiverged(RuntimeError):
    """Non-finite losses/gradients persisted through checkpoint restores (one-line message)."""

    cli_exit_code = 1
    cli_prefix = "error"


class _Restart(Exception):
    """Internal: a checkpoint was restored; continue the loop from ``Trainer.start_step``."""


# -------------------------------------------------------------------- misc
def _config_diff(old: dict, new: dict, prefix: str = "") -> list[str]:
    out = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k), new.get(k)
        if isinstance(a, dict) and isinstance(b, dict):
            out += _config_diff(a, b, f"{prefix}{k}.")
        elif a != b:
            out.append(f"{prefix}{k} ({a} -> {b})")
    return out


@contextmanager
def _stop_signals(trainer: "Trainer"):
    """Turn SIGINT/SIGTERM into a stop request the loop checks between steps.

    A second signal while stopping raises KeyboardInterrupt at once, except while a
    checkpoint is being written: that write finishes first (the stop then ends the run).
    """

    def handler(signum, frame):
        if trainer.stop_reason is None:
            trainer.request_stop(signal.Signals(signum).name)
        elif not getattr(trainer, "_saving", False):  # a checkpoint being written is never cut short
            raise KeyboardInterrupt

    sigs = (signal.SIGINT, signal.SIGTERM)
    old = {}
    try:
        for s in sigs:
            old[s] = signal.signal(s, handler)
    except ValueError:  # not in the main thread: no handlers
        pass
    try:
        yield
    finally:
        for s, h in old.items():
            try:
                signal.signal(s, h)
            except ValueError:
                pass


def _first_nonfinite(tensors: dict[str, Tensor | None]) -> str | None:
    """Name of the first tensor holding a NaN or inf (None when all are finite), with one host sync."""
    names = [k for k, t in tensors.items() if t is not None]
    if not names:
        return None
    ok = torch.stack([torch.isfinite(tensors[k]).all() for k in names]).tolist()
    return next((k for k, good in zip(names, ok) if not good), None)


def trainable_tensors(model) -> list[tuple[str, Tensor]]:
    """(name, tensor) of every per-row parameter and every network weight of ``model``."""
    return list(model.params.items()) + [(f"networks.{k}", p) for k, p in model.networks.named_parameters()]


def optimized_tensors(optimizers: dict) -> list[tuple[str, Tensor]]:
    """(optimizer name[.index], tensor) of every tensor an optimizer updates."""
    out = []
    for name, opt in optimizers.items():
        ps = [p for g in opt.param_groups for p in g["params"]]
        out += [(name if len(ps) == 1 else f"{name}.{i}", p) for i, p in enumerate(ps)]
    return out


# ---------------------------------------------------------------- trainer
class Trainer:
    """Owns the data, the model, its optimizers and the densification strategy.

    Args:
        config: the run config.
        callbacks: ``callback(trainer, step)`` called after every completed
            step (after its periodic checkpoint); a callback may call
            :meth:`request_stop` to stop the run like SIGINT would.
        spec: the registered method ``config.method`` names, when the caller already looked it
            up (the CLI); else it is looked up here, once.
    """

    def __init__(
        self, config: TrainConfig, callbacks: Sequence[Callable[["Trainer", int], None]] = (),
        spec: MethodSpec | None = None,
    ):
        self.spec = get_method(config.method) if spec is None else spec
        self.config = resolve_steps(config)
        self.callbacks = list(callbacks)
        self.device = resolve_config_devices(self.config)["device"]  # every device field, before anything is written
        out = self.config.output
        fresh = out is None or not Path(out).exists() or (Path(out).is_dir() and is_empty_run_dir(Path(out)))
        self.run_dir = prepare_run_dir(self.config)  # owned by this process from here on (run_lock)
        try:
            # before any data or model work; whether config.json vouches for the checkpoints
            self._config_verified = self._check_saved_config() if self.config.resume else True
            try:
                self._setup()
            except KeyboardInterrupt:
                raise TrainingInterrupted(self._setup_interrupted(fresh)) from None
        except BaseException:
            self.release()
            raise

    def _setup(self) -> None:
        """Data, model (SCGaussian: matching, warm-up), optimizers and strategy."""
        set_compile(self.config.compile, user_cache_dir() / "inductor")
        self.timing: dict[str, float] = {}
        self.generator = seed_everything(self.config.seed)
        t0 = time.perf_counter()
        scene = load_config_scene(self.config)
        apply_process_threads()
        budget = plan_memory(scene, self.config, image_memory_budget())
        self.datamanager = DataManager(
            scene, device=self.device, seed=self.config.seed, memory_budget_bytes=budget,
            backdrop=self.config.model.reg.backdrop_weight > 0,
        )
        self.timing["data_s"] = time.perf_counter() - t0
        bg = 1.0 if scene.white_background else 0.0
        self.background = torch.full((3,), bg, device=self.device)
        t0 = time.perf_counter()
        self.model = self.spec.model_class().from_data(self.config, self.datamanager, self.generator).to(self.device)
        self.timing.update(self.model.init_timing)
        self.timing["init_s"] = time.perf_counter() - t0 - sum(self.model.init_timing.values())
        self.optimizers = self.model.make_optimizers()
        strategy_config = self.model.strategy_config()
        self.strategy = strategy_config.setup()
        if not isinstance(self.strategy, Strategy):
            raise TypeError(
                f"{type(strategy_config).__name__}.setup() returned {type(self.strategy).__name__}, not a Strategy"
            )
        self.strategy.check_sanity(self.model.params, self.optimizers)  # a model breaking the ops conventions fails here
        self.strategy_state = self.strategy.initialize_state(scene_scale=self.model.scene_scale)
        self.start_step = 0
        self.nonfinite_streak = 0
        self.skipped_steps = 0
        self.densify_skipped = 0  # steps whose model hook resized the model, so the strategy did not run
        self.restores = 0
        self.lr_factor = 1.0
        self.stop_reason: str | None = None
        self._train_prior_s = 0.0
        self._train_t0: float | None = None
        if not self.config.resume:  # a resumed run's is written once its checkpoint's record is checked
            self.write_config()

    def _setup_interrupted(self, fresh: bool) -> str:
        """The one-line message of a stop during setup; a run folder this run created (still empty) is removed."""
        what = "interrupted during setup (data, matching, warm-up), before any training step"
        self.release()  # deletes the lock file: an empty folder is then truly empty
        if fresh and self.run_dir.is_dir() and not any(self.run_dir.iterdir()):
            self.run_dir.rmdir()
            return f"{what}: nothing was trained, {self.run_dir} removed (start the run again)"
        return f"{what}: {self.run_dir} is unchanged" + (" (continue with --resume)" if self.config.resume else "")

    # ------------------------------------------------------------- config
    def config_payload(self) -> dict:
        return config_payload(self.config)

    def write_config(self) -> None:
        """``config.json``: the resolved config with its schema version and a checksum (atomic)."""
        save_config(self.config, self.run_dir / "config.json")

    def release(self) -> None:
        """Give up the run folder (its lock; see :mod:`splat_framework.engine.run_lock`): done writing."""
        run_lock.release(self.run_dir)

    def experiment_record(self) -> dict:
        """The experiment fields of this run's resolved config (what a resume may not change), as
        JSON values; every checkpoint carries it, covered by the checkpoint's checksum."""
        experiment = experiment_fields(type(self.config))
        return {k: v for k, v in self.config_payload()["config"].items() if k in experiment}

    def _check_saved_config(self) -> bool:
        """``--resume`` continues the run's own experiment; returns whether config.json verified.

        config.json must carry its checksum, unedited, unless ``--trust-edited-config``; its
        experiment fields must equal the command line's. Without config.json a folder holding
        checkpoints is refused (unless trusted: the checkpoints' own records are then checked,
        :meth:`_check_checkpoint_record`); with nothing to continue the run simply starts."""
        path = self.run_dir / "config.json"
        trust = self.config.trust_edited_config
        if not path.is_file():
            if list_checkpoints(self.checkpoint_dir) and not trust:
                raise DataError(
                    f"{path}: missing, so --resume cannot check that the checkpoints are this experiment's; "
                    "pass --trust-edited-config to check against the checkpoints' own record"
                )
            return False
        try:
            saved, verified = read_config_json(path)[1], True
        except DataError:
            if not trust:
                raise
            saved, verified = read_config_json(path, trust_edits=True)[1], False
        self._check_same_experiment(path, saved)
        return verified

    def _check_checkpoint_record(self, path: Path, ck: dict) -> None:
        """A checkpoint continues only the experiment it recorded (DataError otherwise, never a
        fallback to an older file). A checkpoint written before checkpoints recorded their
        experiment is accepted only on the word of a verified config.json."""
        record = ck.get("experiment")
        if isinstance(record, dict):
            self._check_same_experiment(path, record)
        elif not self._config_verified:
            raise DataError(
                f"{path}: records no experiment (written by an older version) and config.json is missing or "
                "edited, so nothing shows that --resume continues the same experiment"
            )

    def _check_same_experiment(self, path: Path, saved: dict) -> None:
        """DataError naming the fields (up to 4) in which ``saved`` (a config dict as written by this
        or an older version) is another experiment than this run's config."""
        old = upgrade_saved_config(dict(saved), self.spec.default_config())
        new = self.config_payload()["config"]
        if old.get("method") not in (None, new["method"]):
            raise DataError(f"{path}: the run was trained with method {old['method']!r}, not {new['method']!r}")
        experiment = experiment_fields(type(self.config))
        old = {k: v for k, v in old.items() if k in experiment}
        new = {k: v for k, v in new.items() if k in experiment}
        diff = _config_diff(old, new)
        if diff:  # a resumed run must be the same experiment, or its results mean nothing
            shown = ", ".join(diff[:4]) + (f" and {len(diff) - 4} more" if len(diff) > 4 else "")
            raise DataError(
                f"{path}: --resume cannot change the experiment: {shown} "
                f"(resume with the saved settings, or start a new run)"
            )

    # ------------------------------------------------------------ checkpoints
    @property
    def checkpoint_dir(self) -> Path:
        return self.run_dir / "checkpoints"

    def _train_seconds(self) -> float:
        extra = time.perf_counter() - self._train_t0 if self._train_t0 is not None else 0.0
        return self._train_prior_s + extra

    def state_payload(self, step: int) -> dict:
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
            **rng_state(self.generator, self.device),
            "lr_factor": self.lr_factor,
            "skipped_steps": self.skipped_steps,
            "densify_skipped_steps": self.densify_skipped,
            "restores": self.restores,
            "timing": timing,
        }

    def save(self, step: int) -> Path:
        """Write the checkpoint of ``step`` (CheckpointError, one line, on failure).

        A stop signal that arrives meanwhile waits for the write to finish."""
        self._saving = True
        try:
            return save_checkpoint(self.checkpoint_dir, step, self.state_payload(step))
        finally:
            self._saving = False

    def _load_state(self, path: Path, ck: dict) -> None:
        dev = self.device
        self.model.restore(ck, dev)
        self.optimizers = self.model.make_optimizers()
        for k, o in self.optimizers.items():
            o.load_state_dict(ck["optimizers"][k])
        self.strategy_state = {
            k: (v.to(dev) if torch.is_tensor(v) else v) for k, v in ck["strategy_state"].items()
        }
        restore_rng_state(ck, self.generator, dev)
        self.lr_factor = float(ck.get("lr_factor", 1.0))
        self.start_step = int(ck["step"])

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
        and DataError for a checkpoint of another experiment (:meth:`_check_checkpoint_record`)."""
        self._check_checkpoint_record(path, ck)
        check_structure(path, ck, self.model.params, max_step=self.config.total_steps)
        try:
            self._load_state(path, ck)
        except (KeyError, ValueError, TypeError, IndexError, RuntimeError) as e:  # e.g. a crafted model_state
            first = (str(e).splitlines() or [""])[0]
            raise CheckpointError(f"{path}: cannot restore ({type(e).__name__}: {first})") from None
        return ck

    def request_stop(self, reason: str = "stop requested") -> None:
        """Stop after the current step, writing a checkpoint (what SIGINT/SIGTERM do)."""
        self.stop_reason = reason

    # ------------------------------------------------------------------ step
    def _set_learning_rates(self, step: int) -> None:
        """Every optimizer's rate from the model's schedule (:meth:`GaussianModel.learning_rates`,
        a pure function of the step), times the fault factor (never compounded)."""
        rates = self.model.learning_rates(step)
        for k, o in self.optimizers.items():
            for g in o.param_groups:
                g["lr"] = rates[k] * self.lr_factor

    def train_step(self, step: int) -> tuple[dict, float] | None:
        """One optimisation step; None when it was skipped (non-finite loss or gradients)."""
        with section("step"):
            return self._train_step(step)

    def _train_step(self, step: int) -> tuple[dict, float] | None:
        model = self.model
        model.on_step_start(step)
        self._set_learning_rates(step)
        camera, batch = self.datamanager.next_train(step)
        with section("forward"), model.training_render(step):
            outputs = model.get_outputs(camera, self.background)
        with section("loss"):
            losses = model.get_loss_dict(outputs, batch, camera, step)
            extra = self.strategy.loss(model.params, step)  # e.g. MCMC's regularisers; none by default
            if extra.keys() & losses.keys():
                raise ValueError(f"{type(self.strategy).__name__}.loss() names {sorted(extra.keys() & losses.keys())}, "
                                 "which the model's loss already has")
            losses |= extra
            loss = sum(losses.values())
        if not torch.isfinite(loss):
            return self._fault(step, "loss")
        densify = model.densify_now(step)
        if densify:
            self.strategy.step_pre_backward(model.params, self.optimizers, self.strategy_state, step, outputs.meta)
        with section("backward"):
            loss.backward()
        with section("finiteness checks"):
            bad = _first_nonfinite({k: p.grad for k, p in trainable_tensors(model)})
        if bad is not None:
            return self._fault(step, f"gradient of {bad}")
        with section("optimizer"):
            keys = model.trainable_keys(step)
            for k, opt in self.optimizers.items():
                if keys is None or k in keys:
                    opt.step()
                opt.zero_grad(set_to_none=True)
        with section("finiteness checks"):
            bad = _first_nonfinite({k: p.detach() for k, p in optimized_tensors(self.optimizers)})
        if bad is not None:
            return self._fault(step, f"parameter {bad}", corrupted=True)
        self.nonfinite_streak = 0
        n_before = model.num_gaussians
        with section("model hooks"):
            model.after_optimizer_step(step, losses, self.optimizers, self.strategy_state)
        # a hook that added/removed rows (e.g. SCGaussian's match filter) resized the
        # strategy state itself; this step's screen-space statistics no longer line up
        if densify and model.num_gaussians != n_before:
            if not self.densify_skipped:
                say(f"note: step {step}: {type(model).__name__}.after_optimizer_step changed the Gaussians "
                     f"({n_before} -> {model.num_gaussians}); densification skips such steps (counted in metrics.json)")
            self.densify_skipped += 1
            self.strategy.rows_changed(model.params, self.optimizers, self.strategy_state, step)
        elif densify:
            with section("densification"):
                with torch.no_grad():
                    model.prepare_for_strategy()
                self.strategy.step_post_backward(model.params, self.optimizers, self.strategy_state, step, outputs.meta)
        with section("metrics"), torch.no_grad():
            train_psnr = float(psnr(outputs.rgb.detach().clamp(0, 1), batch["image"]))
            return {k: float(v.detach()) for k, v in losses.items()} | {"loss": float(loss.detach())}, train_psnr

    def _fault(self, step: int, what: str, corrupted: bool = False) -> None:
        """Count a skipped step; restore the last checkpoint (halved lr) when faults persist."""
        for opt in self.optimizers.values():
            opt.zero_grad(set_to_none=True)
        for _, p in trainable_tensors(self.model):
            p.grad = None
        self.skipped_steps += 1
        self.nonfinite_streak += 1
        if self.nonfinite_streak == 1 and not corrupted:
            say(f"warning: step {step}: non-finite {what}, step skipped", "yellow")
        if not corrupted and self.nonfinite_streak < MAX_NONFINITE:
            return None
        why = f"non-finite {what} at step {step}" + ("" if corrupted else f" ({self.nonfinite_streak} steps in a row)")
        if self.restores >= MAX_RESTORES:
            raise TrainingDiverged(
                f"training diverged: {why}; {self.restores} checkpoint restores with lower learning rates did not help "
                f"({self.skipped_steps} steps skipped)"
            )
        found = self._load_latest_state()
        if found is None:
            raise TrainingDiverged(f"training diverged: {why} and no checkpoint to restore ({self.skipped_steps} steps skipped)")
        path, ck = found
        self.restores += 1
        self.lr_factor *= 0.5
        self.nonfinite_streak = 0
        say(f"warning: {why}: restored {path.name} (step {self.start_step}), learning rates x{self.lr_factor:g}", "yellow")
        raise _Restart()

    # ------------------------------------------------------------------- run
    def train(self) -> dict:
        """Train to the end, evaluate, write metrics.json; the run folder is released however it ends."""
        try:
            return self._train()
        finally:
            self.release()

    def _train(self) -> dict:
        cfg = self.config
        if cfg.resume:
            if not self.restore():
                say(f"warning: {self.checkpoint_dir}: no checkpoint to resume from; training from the start", "yellow")
            self.write_config()  # this run's config, now that the checkpoint's record agrees with it
        total = cfg.total_steps
        last = {"loss": float("nan")}
        tpsnr = float("nan")
        self._train_t0 = time.perf_counter()
        # without a terminal (logs, CI) the live bar cannot render: print a line every 5% instead
        plain_log = cfg.progress and not console.is_terminal
        plain_every = max(total // 20, 1)
        with _stop_signals(self), training_progress(cfg.progress and console.is_terminal) as progress:
            task = progress.add_task(
                "train", total=total, completed=self.start_step, loss=math.nan, psnr=math.nan, n=self.model.num_gaussians
            )
            step = self.start_step
            while step < total:
                try:
                    out = self.train_step(step)
                except _Restart:
                    step = self.start_step
                    progress.update(task, completed=step, n=self.model.num_gaussians)
                    continue
                if out is not None:
                    last, tpsnr = out
                step += 1
                progress.update(task, completed=step, loss=last["loss"], psnr=tpsnr, n=self.model.num_gaussians)
                if plain_log and (step % plain_every == 0 or step == total):
                    rate = (step - self.start_step) / max(time.perf_counter() - self._train_t0, 1e-9)
                    say(f"step {step}/{total}  loss {last['loss']:.4f}  PSNR {tpsnr:.2f}  {self.model.num_gaussians} gaussians  {rate:.2f} it/s")
                saved = False
                if cfg.checkpoint_every and step % cfg.checkpoint_every == 0 and step < total:
                    self.save(step)
                    saved = True
                if cfg.eval_every and step % cfg.eval_every == 0 and step < total:
                    m = evaluate(self.model, self.datamanager, self.background)
                    say(f"step {step}: test PSNR {m['mean']['psnr']:.2f}")
                for cb in self.callbacks:
                    cb(self, step)
                if self.stop_reason is not None:
                    path = self.save(step) if not saved else None
                    where = path or self.checkpoint_dir
                    raise TrainingInterrupted(
                        f"{self.stop_reason} at step {step}/{total}: checkpoint written to {where} (continue with --resume)"
                    )
            self._train_prior_s = self._train_seconds()
            self._train_t0 = None
            self.timing["train_s"] = self._train_prior_s
            self.save(step)  # == total, unless resumed past a shortened --steps
        t0 = time.perf_counter()
        results = evaluate(
            self.model, self.datamanager, self.background, self.run_dir / "renders" if cfg.save_renders else None,
            pose_steps=cfg.test_pose_steps,
        )
        self.timing["eval_s"] = time.perf_counter() - t0
        self.timing["total_s"] = sum(v for k, v in self.timing.items() if k != "total_s")
        metrics = {
            "method": cfg.method,
            "data": cfg.data,
            "steps": total,
            "mean": results["mean"],
            "per_view": results["per_view"],
            "timing": self.timing,
            "num_gaussians": self.model.num_gaussians,
            "strategy": f"{type(self.strategy).__module__}.{type(self.strategy).__qualname__}",
            "render_fps": results["fps"],
            "skipped_steps": self.skipped_steps,
            "densify_skipped_steps": self.densify_skipped,
            "restores": self.restores,
            "lpips_note": results["lpips_note"],
            "test_pose_steps": cfg.test_pose_steps,
        }
        metrics["init_stats"] = dict(self.model.init_stats)
        report = self.model.report(self.datamanager)
        if report is not None:
            metrics["model_report"] = report
        atomic_write_json(self.run_dir / "metrics.json", metrics)  # OSError (disk full): one line in the CLI
        print_summary(metrics, self.run_dir)
        return metrics


def train(
    config: TrainConfig, callbacks: Sequence[Callable[[Trainer, int], None]] = (), spec: MethodSpec | None = None
) -> dict:
    """Train ``config`` end to end and return metrics (also written to metrics.json); ``spec``: the
    method's registration when the caller has it (see :class:`Trainer`)."""
    return Trainer(config, callbacks, spec).train()
