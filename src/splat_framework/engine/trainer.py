"""The training loop: seeded, checkpointed, resumable, each phase shown (:func:`splat_framework.console.phase`).

One step reads top to bottom in :meth:`Trainer.train_step`::

    camera, batch = datamanager.next_train(step)
    outputs = model.get_outputs(camera, background, step=step)
    losses = model.get_loss_dict(outputs, batch, camera, step)
    sum(losses).backward(); optimizers step; strategy densifies

Reliability contract:

- **Run folders** are never overwritten silently: without ``--output`` a new
  timestamped folder is made; an existing non-empty ``--output`` needs
  ``--resume`` (continue it) or ``--overwrite`` (start again; its old
  checkpoints and metrics are removed first).
- **One owner**: the run folder is locked by this process before the data
  is loaded (:mod:`splat_framework.files.run_lock`); a second ``splat-train`` on the
  same ``--output``, fresh or ``--resume``, or a ``splat-eval`` of it, is
  refused in one line naming the holder; the lock is released when
  :meth:`Trainer.train` ends, however it ends.
- **Provenance**: ``--resume`` needs the run's own config.json (present,
  checksum intact) unless ``--trust-edited-config``, and refuses any change of
  an experiment field (all but the ``RUN_OPTION`` ones) against config.json
  and against the experiment every checkpoint records under its own checksum;
  config.json is rewritten only after that check, with this run's config
  (:mod:`splat_framework.engine.resume_check`).
- **Checkpoints** hold everything the next step depends on (parameters, Adam
  states, densification state, model extra state, all RNG states, the
  learning-rate factor); the view order is a pure function of (seed, step).
  So a run stopped at step s and resumed gives the same parameters as an
  uninterrupted run. Checkpoints, ``config.json`` and ``metrics.json`` are
  written atomically with a checksum; ``--resume`` skips a corrupt checkpoint
  (one-line warning) and uses the previous good one
  (:mod:`splat_framework.engine.train_state`).
- **Signals**: SIGINT/SIGTERM finish the current step, write a checkpoint and
  raise :class:`TrainingInterrupted` (the CLI exits with code 130); a second
  one stops at once and the message says what was saved
  (:mod:`splat_framework.engine.stop_signals`). Either message ends with how to
  continue: from the CLI, the exact command (:meth:`Trainer.continue_hint`).
- **A failed start** (bad data, a stop during setup) of a new run leaves no
  empty run folder behind.
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
import time
from typing import Callable, Sequence

import torch
from torch import Tensor

from ..config import TrainConfig
from ..console import phase, print_summary, say, show_progress
from ..devices import resolve_config_devices
from ..pipeline import resolve_run_config
from ..registry import MethodSpec, get_method
from ..render import RenderSettings, backend_name, prepare_kernels
from ..runtime.process import prepare_training_process
from ..runtime.profiling import section
from ..runtime.rng import seed_everything
from .numerics import first_nonfinite as _first_nonfinite
from .numerics import optimized_tensors, trainable_tensors
from .parts import build_strategy, resolve_parts
from .run_folder import continue_command, prepare_run_dir, release_run_dir, remove_if_unused, starts_fresh
from .run_outputs import RunLog, run_metrics, write_run_outputs
from .stop_signals import abandoned_message, evaluation_stopped_message, stop_signals
from .train_state import TrainState

MAX_NONFINITE = 20
"""Consecutive non-finite steps tolerated before restoring the last checkpoint."""
MAX_RESTORES = 2
"""Checkpoint restores (each halving the learning rates) before giving up."""
INFO_EVERY_S = 0.5
"""Seconds between two reads of the step's loss and PSNR for the progress row (a read waits for the device)."""


class TrainingInterrupted(Exception):
    """SIGINT/SIGTERM arrived; the message says what was saved (a checkpoint, or nothing during
    setup). The CLIs exit with code 130."""

    cli_exit_code = 130
    cli_prefix = "stopped"


class TrainingDiverged(RuntimeError):
    """Non-finite losses/gradients persisted through checkpoint restores (one-line message)."""

    cli_exit_code = 1
    cli_prefix = "error"


def extreme_values_hint(config) -> str:
    """``" (check --model.reg.depth-smoothness 1e+308)"``: the config's numbers so large (>= 1e30) or
    non-finite that they likely made every loss non-finite, as flags; "" when there are none."""
    found = []

    def walk(value, path: str) -> None:
        if isinstance(value, dict):
            for k, v in value.items():
                walk(v, f"{path}.{k}" if path else str(k))
        elif isinstance(value, float) and not (abs(value) < 1e30):
            found.append(f"--{path.replace('_', '-')} {value:g}")

    walk(config.model_dump(mode="python"), "")
    return f" (check {', '.join(found)})" if found else " (check the loss weights and learning rates)"


def row_count(model) -> int:
    """The rows of ``model.params`` (Gaussians; anchors of an anchor-based model)."""
    return next(iter(model.params.values())).shape[0]


def check_row_change(model, n_before: int, change) -> None:
    """ValueError unless ``model.after_optimizer_step``'s return ``change`` (a RowChange or None)
    says how the rows of ``model.params`` went from ``n_before`` to their count now."""
    n = row_count(model)
    name = f"{type(model).__name__}.after_optimizer_step"
    if change is None:
        if n != n_before:
            raise ValueError(f"{name} changed the Gaussians ({n_before} -> {n}) but returned None: return the "
                             "RowChange that ops.remove / ops.append gave, so the strategy resizes its state")
    elif (change.old_rows, change.new_rows) != (n_before, n):
        raise ValueError(f"{name} returned a RowChange of {change.old_rows} -> {change.new_rows}, but the "
                         f"Gaussians went {n_before} -> {n}")


class _Restart(Exception):
    """Internal: a checkpoint was restored; continue the loop from ``Trainer.start_step``."""


# ---------------------------------------------------------------- trainer
class Trainer(TrainState):
    """Drives a run: the loop, the optimizers, the densification strategy, checkpoints and resume.

    The data and the model belong to the method's :class:`~splat_framework.pipeline.Pipeline`
    (``self.pipeline``; ``self.datamanager`` and ``self.model`` are the same objects), which gives
    each step's render, batch and loss terms and runs the evaluation.

    Args:
        config: the run config.
        callbacks: ``callback(trainer, step)`` called after every completed
            step (after its periodic checkpoint); a callback may call
            :meth:`request_stop` to stop the run like SIGINT would.
        spec: the registered method ``config.method`` names, when the caller already looked it
            up (the CLI); else it is looked up here, once.
        command: the ``splat-train`` arguments that started the run (the CLI's), so that a stop
            names the exact command that continues it (:func:`continue_command`); else it says
            ``--resume``.
        defaults: the config the user's settings were applied to (``--load-config``'s); else the
            method's registered defaults. An iteration count that differs from it is the user's and
            keeps its number when ``--steps`` or the views rescale the schedule.
    """

    def __init__(
        self, config: TrainConfig, callbacks: Sequence[Callable[["Trainer", int], None]] = (),
        spec: MethodSpec | None = None, command: Sequence[str] | None = None, defaults: TrainConfig | None = None,
    ):
        self.spec = get_method(config.method) if spec is None else spec
        self.command = None if command is None else list(command)
        defaults = self.spec.default_config() if defaults is None else defaults
        # views first: more may lengthen the schedule
        self.config = resolve_run_config(config, defaults)
        self.callbacks = list(callbacks)
        self.device = resolve_config_devices(self.config)["device"]  # every device field, before anything is written
        fresh = starts_fresh(self.config.output)
        self.run_dir = prepare_run_dir(self.config)  # owned by this process from here on (run_lock)
        show_progress(self.config.progress)
        try:
            self.run_log = RunLog(self.run_dir, self.command, self.config.resume)  # train.log from here on
            # before any data or model work; whether config.json vouches for the checkpoints
            self._config_verified = self.check_saved_config() if self.config.resume else True
            try:
                self._setup()
            except KeyboardInterrupt:
                raise TrainingInterrupted(self._setup_interrupted(fresh)) from None
        except BaseException:
            self.release()  # deletes the lock file: an empty folder is then truly empty
            if fresh:  # a failed start leaves no empty run folder behind
                remove_if_unused(self.run_dir, default_location=self.config.output is None)
            raise

    def _setup(self) -> None:
        """The plugin's parts checked, the kernels, then the method's pipeline (data, model:
        SCGaussian's matching and warm-up), then the optimizers and the strategy."""
        self.parts = resolve_parts(self.spec, self.config)  # a plugin's broken part: one line, before anything loads
        # built, loaded or compiled now, a phase of its own, not inside the first training step; a
        # rasterizer named that cannot run here is one line (DataError) before anything is loaded
        t_kernels = time.perf_counter()
        self.render_settings = prepare_kernels(self.device, RenderSettings.from_config(self.config))
        self.rasterizer = backend_name(self.device, self.render_settings)
        # the kernels' build or load is a row of its own, and total_s counts it
        self.timing: dict[str, float] = {"kernels_s": time.perf_counter() - t_kernels}
        self.generator = seed_everything(self.config.seed)
        prepare_training_process()
        self.pipeline = self.parts.pipeline(self.config, self.parts.model, self.device, self.generator)
        self.config = self.pipeline.config  # with the data's folder and split recorded
        self.timing.update(self.pipeline.timing)
        self.model.render_settings = self.render_settings  # the model's renders use the kernels proven here
        self.optimizers = self.model.make_optimizers()
        strategy_config = self.pipeline.strategy_config()
        self.strategy = build_strategy(strategy_config)
        self.densifies = strategy_config.enabled
        self.model.absgrad = self.strategy.absgrad
        self.strategy.check_sanity(self.model.params, self.optimizers)  # a model breaking the ops conventions fails here
        self.strategy_state = self.strategy.initialize_state(scene_scale=self.model.scene_scale)
        self.start_step = 0
        self.nonfinite_streak = 0
        self.skipped_steps = 0
        self.densify_skipped = 0  # steps whose model hook resized the model, so the strategy did not run
        self.densified: dict[str, int] = {}  # the strategy's counts (n_clone, ...) summed over the run
        self.restores = 0
        self._unchecked_update = False  # the last optimizer step's parameters are not yet checked for NaN / inf
        self._shown: tuple[dict, Tensor] | None = None  # the last finished step's losses and PSNR, on the device
        self._shown_at = -math.inf
        self.step_seconds: list[tuple[int, float]] = []  # (step, counted from 1; wall s) of this process's steps
        self.lr_factor = 1.0
        self.stop_reason: str | None = None
        self.saving = False  # a checkpoint is being written (a second stop signal waits for it)
        self._train_prior_s = 0.0
        self._train_t0: float | None = None
        if not self.config.resume:  # a resumed run's is written once its checkpoint's record is checked
            self.write_config()

    @property
    def datamanager(self):
        """The pipeline's data manager."""
        return self.pipeline.datamanager

    @property
    def model(self):
        """The pipeline's model."""
        return self.pipeline.model

    @property
    def background(self) -> Tensor:
        """[3] the background colour the pipeline's renders composite over."""
        return self.pipeline.background

    @property
    def camera_refiner(self):
        """The pipeline's camera refiner (None unless ``--camera-refine.mode`` refines poses)."""
        return self.pipeline.camera_refiner

    def _setup_interrupted(self, fresh: bool) -> str:
        """The one-line message of a stop during setup; a run folder this run created (still empty) is removed."""
        what = "interrupted during setup (data, matching, warm-up), before any training step"
        self.release()  # deletes the lock file: an empty folder is then truly empty
        if fresh and remove_if_unused(self.run_dir, default_location=self.config.output is None):
            return f"{what}: nothing was trained, {self.run_dir} removed (start the run again)"
        return f"{what}: {self.run_dir} is unchanged" + (f"; {self.continue_hint()}" if self.config.resume else "")

    def continue_hint(self) -> str:
        """How the user continues this run after a stop: the exact command, when the CLI gave its arguments."""
        if self.command is None:
            return "continue with --resume"
        return f"continue with: {continue_command(self.command, self.run_dir)}"

    def release(self) -> None:
        """Give up the run folder: its log closed (:class:`~splat_framework.engine.run_outputs.RunLog`),
        then its lock (:mod:`splat_framework.files.run_lock`): done writing."""
        if getattr(self, "run_log", None) is not None:  # None: released before the log opened
            self.run_log.close()
        release_run_dir(self.run_dir)

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
        if self.camera_refiner is not None:
            self.camera_refiner.set_learning_rates(step, self.lr_factor)

    def train_step(self, step: int) -> tuple[dict[str, Tensor], Tensor] | None:
        """One optimisation step: its loss terms (name -> 0-dim tensor, "loss" their sum) and its train
        PSNR, left on the device (``float()`` them to read); None when it was skipped (non-finite loss
        or gradients). On CUDA the step reads one value on the host: whether it was finite."""
        with section("step"):
            return self._train_step(step)

    def _train_step(self, step: int) -> tuple[dict[str, Tensor], Tensor] | None:
        model = self.model
        model.on_step_start(step)
        self._set_learning_rates(step)
        outputs, batch, losses = self.pipeline.train_losses(step)  # the step's view(s), render and model's terms
        with section("loss"):
            extra = self.strategy.loss(model.params, step)  # e.g. MCMC's regularisers; none by default
            if extra.keys() & losses.keys():
                raise ValueError(f"{type(self.strategy).__name__}.loss() names {sorted(extra.keys() & losses.keys())}, "
                                 "which the model's loss already has")
            losses |= extra
            loss = sum(losses.values())
        densify = self.densifies
        if densify:
            self.strategy.step_pre_backward(model.params, self.optimizers, self.strategy_state, step, outputs.meta)
        with section("backward"):
            loss.backward()
        with section("finiteness checks"):  # the step's one host read (see _checked_tensors)
            bad = _first_nonfinite(self._checked_tensors(loss))
        if bad is not None:
            if bad.startswith("parameter "):  # the previous step's update
                return self._fault(step - 1, bad, corrupted=True)
            return self._fault(step, bad)
        with section("optimizer"):
            keys = model.trainable_keys(step)
            for k, opt in self.optimizers.items():
                if keys is None or k in keys:
                    opt.step()
                opt.zero_grad(set_to_none=True)
            if self.camera_refiner is not None:
                self.camera_refiner.step()
        self._unchecked_update = True
        self.nonfinite_streak = 0
        n_before, gaussians_before = row_count(model), model.num_gaussians
        with section("model hooks"):
            change = model.after_optimizer_step(step, losses, self.optimizers)
        check_row_change(model, n_before, change)
        if change is not None:  # e.g. SCGaussian's match filter: the strategy resizes its own state
            self.strategy.rows_changed(model.params, self.optimizers, self.strategy_state, step, change)
            if densify:  # this step's screen-space statistics no longer line up with the rows
                if not self.densify_skipped:
                    say(f"note: step {step}: {type(model).__name__}.after_optimizer_step changed the Gaussians "
                        f"({gaussians_before} -> {model.num_gaussians}); densification skips such steps (counted in metrics.json)")
                self.densify_skipped += 1
        elif densify:
            with section("densification"):
                with torch.no_grad():
                    model.prepare_for_strategy()
                counts = self.strategy.step_post_backward(model.params, self.optimizers, self.strategy_state, step,
                                                          outputs.meta)
            for k, v in (counts or {}).items():
                self.densified[k] = self.densified.get(k, 0) + int(v)
        with section("metrics"), torch.no_grad():  # kept on the device: read when shown (_step_info)
            train_psnr = self.pipeline.train_psnr(outputs, batch)
            return {k: v.detach() for k, v in losses.items()} | {"loss": loss.detach()}, train_psnr

    def _checked_tensors(self, loss: Tensor) -> dict[str, Tensor | None]:
        """What a step checks for NaN and inf in its one host read, after its backward: the parameters
        the previous step's optimizers wrote (checked here rather than in a read of their own; before a
        checkpoint by :meth:`_check_update`), then the loss, then every gradient."""
        checked: dict[str, Tensor | None] = self._unchecked_parameters()
        checked["loss"] = loss.detach()
        return checked | {f"gradient of {k}": p.grad for k, p in self._trained_tensors()}

    def _unchecked_parameters(self) -> dict[str, Tensor]:
        """``"parameter NAME"`` -> tensor of what the last optimizer step wrote, once (then none until
        the next step writes again)."""
        if not self._unchecked_update:
            return {}
        self._unchecked_update = False
        return {f"parameter {k}": p.detach() for k, p in self._optimized_tensors()}

    def _check_update(self, step: int) -> None:
        """Before a checkpoint: the parameters the last step wrote are finite, else the last good
        checkpoint is restored (:meth:`_fault`, which raises)."""
        bad = _first_nonfinite(self._unchecked_parameters())
        if bad is not None:
            self._fault(step - 1, bad, corrupted=True)

    def _trained_tensors(self) -> list[tuple[str, Tensor]]:
        """The model's trainable tensors, then the camera corrections when they are refined."""
        refined = self.camera_refiner.tensors().items() if self.camera_refiner is not None else []
        return [*trainable_tensors(self.model), *refined]

    def _optimized_tensors(self) -> list[tuple[str, Tensor]]:
        refined = self.camera_refiner.tensors().items() if self.camera_refiner is not None else []
        return [*optimized_tensors(self.optimizers), *refined]

    def _fault(self, step: int, what: str, corrupted: bool = False) -> None:
        """Count a skipped step; restore the last checkpoint (halved lr) when faults persist."""
        for opt in self.optimizers.values():
            opt.zero_grad(set_to_none=True)
        if self.camera_refiner is not None:
            self.camera_refiner.zero_grad()
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
                say(f"no checkpoint in {self.checkpoint_dir} yet: training from the start")  # a fresh sweep run
            self.write_config()  # this run's config, now that the checkpoint's record agrees with it
        total = cfg.total_steps
        self._train_t0 = time.perf_counter()
        with stop_signals(self), phase(
            "training", total, completed=self.start_step, unit="steps", info=self._step_info(None), quiet_s=0,
            clock_from_first=True, costs=step_costs(cfg),
        ) as progress:
            first = self.start_step
            try:
                step = self._loop(progress)
            except KeyboardInterrupt:  # a second Ctrl-C: stopped within a step, before its checkpoint
                raise TrainingInterrupted(
                    abandoned_message(self.stop_reason, progress.completed, total, self.checkpoint_dir,
                                      self.continue_hint())) from None
            if step > first and self.nonfinite_streak >= step - first:
                raise TrainingDiverged(
                    f"training diverged: every step of this run ({step - first}) had a non-finite loss or gradient "
                    f"and was skipped; nothing was evaluated or saved{extreme_values_hint(cfg)}")
            self._train_prior_s = self._train_seconds()
            self._train_t0 = None
            self.timing["train_s"] = self._train_prior_s
            self.save(step)  # == total, unless resumed past a shortened --steps
        self.pipeline.use_trained_poses()  # training views are scored at the poses they trained at
        write_run_outputs(self.run_dir, self.datamanager, self.model, step)  # the reference's point_cloud/, cameras.json
        t0 = time.perf_counter()
        try:
            results = self.pipeline.evaluate(self.run_dir / "renders" if cfg.save_renders else None,
                                             pose_steps=cfg.test_pose_steps)
        except KeyboardInterrupt:  # Ctrl-C or SIGTERM (the CLI's) while scoring: the training is saved
            raise TrainingInterrupted(evaluation_stopped_message(self.checkpoint_dir, self.continue_hint())) from None
        self.timing["eval_s"] = time.perf_counter() - t0
        self.timing["total_s"] = sum(v for k, v in self.timing.items() if k != "total_s")
        metrics = run_metrics(self, results)
        print_summary(metrics, self.run_dir)
        return metrics

    def _loop(self, progress) -> int:
        """The training steps from ``start_step`` to the total (``progress``: the training phase);
        the step reached. Raises TrainingInterrupted after a stop request's checkpoint."""
        step = self.start_step
        while step < self.config.total_steps:
            t0 = time.perf_counter()
            try:
                out = self.train_step(step)
                step += 1
                self._after_step(step, out, time.perf_counter() - t0, progress)
            except _Restart:
                step = self.start_step
                progress.update(step, info=self._step_info(None))
        return step

    def _after_step(self, step: int, out: tuple[dict, Tensor] | None, seconds: float, progress) -> None:
        """What follows step ``step`` (counted from 1): its progress, a periodic checkpoint or
        evaluation, the callbacks, a requested stop."""
        cfg, total = self.config, self.config.total_steps
        self.step_seconds.append((step, seconds))
        if out is not None:
            self._shown = out
        now = time.perf_counter()
        if self._shown is not None and (now - self._shown_at >= INFO_EVERY_S or step == total):
            progress.update(step, info=self._step_info(self._shown))  # a host read, not one every step
            self._shown_at = now
        else:
            progress.update(step)
        saved = False
        if cfg.checkpoint_every and step % cfg.checkpoint_every == 0 and step < total:
            self._check_update(step)
            self.save(step)
            saved = True
        if cfg.eval_every and step % cfg.eval_every == 0 and step < total:
            m = self.pipeline.evaluate()
            say(f"step {step}: test PSNR {m['mean']['psnr']:.2f}")
        for cb in self.callbacks:
            cb(self, step)
        if step == total or self.stop_reason is not None:
            self._check_update(step)  # the checkpoint that follows holds the last update
        if self.stop_reason is not None:
            path = self.save(step) if not saved else None
            where = path or self.checkpoint_dir
            raise TrainingInterrupted(
                f"{self.stop_reason} at step {step}/{total}: checkpoint written to {where}; {self.continue_hint()}"
            )

    def _step_info(self, out: tuple[dict[str, Tensor], Tensor] | None) -> str:
        """The training phase's info: the last step's loss and train PSNR (none before the first
        step: never a NaN placeholder) and the Gaussian count."""
        n = f"{self.model.num_gaussians} gaussians"
        if out is None:
            return n
        losses, train_psnr = out
        loss, value = torch.stack([losses["loss"].double(), train_psnr.double()]).tolist()  # one host read
        return f"loss {loss:.4f}  PSNR {value:.2f}  {n}"


def step_costs(config: TrainConfig) -> list[tuple[int, float]]:
    """The training phase's relative step costs for its remaining time: the first ``coarse_steps``
    at the images' ``coarse_scale`` cost that fraction of a full-size step (half-size steps take
    about half the time: fern, 2-core CPU), until the full-size steps' own rate is measured."""
    if config.coarse_steps <= 0 or config.coarse_steps >= config.total_steps:
        return []
    return [(config.coarse_steps, float(config.coarse_scale)), (config.total_steps, 1.0)]


def train(
    config: TrainConfig, callbacks: Sequence[Callable[[Trainer, int], None]] = (), spec: MethodSpec | None = None,
    command: Sequence[str] | None = None, defaults: TrainConfig | None = None,
) -> dict:
    """Train ``config`` end to end and return metrics (also written to metrics.json); ``spec``: the
    method's registration when the caller has it, ``command``: the CLI's arguments, ``defaults``: what
    the user's settings were applied to (see :class:`Trainer`)."""
    return Trainer(config, callbacks, spec, command, defaults).train()
