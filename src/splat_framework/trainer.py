"""The training loop: seeded, checkpointed, resumable, with a live progress bar.

One step reads top to bottom in :meth:`Trainer.train_step`::

    camera, batch = datamanager.next_train(step)
    outputs = model.get_outputs(camera, background)
    losses = model.get_loss_dict(outputs, batch, camera, step)
    sum(losses).backward(); optimizers step; strategy densifies
"""

from __future__ import annotations

import json
import math
import signal
import time
from contextlib import contextmanager
from datetime import datetime
from pathlib import Path

import torch
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from .checkpoint import CheckpointError, load_latest, save_checkpoint
from .config import TrainConfig, resolve_steps, save_config
from .data import DataError, DataManager, load_scene, resolve_data_path
from .evaluation import evaluate
from .io import atomic_write_text
from .metrics import psnr
from .model.strategy import DefaultStrategy
from .registry import get_method

console = Console(stderr=True)

MAX_NONFINITE = 20
"""Consecutive non-finite steps tolerated before restoring the last checkpoint."""
MAX_RESTORES = 2
"""Checkpoint restores (each halving the learning rates) before giving up."""


class TrainingInterrupted(Exception):
    """SIGINT/SIGTERM arrived; a checkpoint was written."""


def default_run_dir(config: TrainConfig) -> Path:
    scene = Path(config.data).name or "scene"
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path("outputs") / scene / config.method / stamp


def prepare_run_dir(config: TrainConfig) -> Path:
    """The run folder; never silently overwrite an existing run."""
    run_dir = Path(config.output) if config.output is not None else default_run_dir(config)
    if run_dir.exists() and any(run_dir.iterdir()) and not (config.resume or config.overwrite):
        raise DataError(f"{run_dir}: run folder exists and is not empty (use --resume or --overwrite)")
    run_dir.mkdir(parents=True, exist_ok=True)
    return run_dir


def seed_everything(seed: int) -> torch.Generator:
    import random

    import numpy as np

    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)
    return torch.Generator().manual_seed(seed)


@contextmanager
def _stop_signals():
    """Turn SIGINT/SIGTERM into a flag the loop checks between steps."""
    flag = {"stop": None}

    def handler(signum, frame):
        flag["stop"] = signal.Signals(signum).name

    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        for s in old:
            signal.signal(s, handler)
    except ValueError:  # not in the main thread: no handlers
        pass
    try:
        yield flag
    finally:
        for s, h in old.items():
            try:
                signal.signal(s, h)
            except ValueError:
                pass


class Trainer:
    """Owns the data, the model, its optimizers and the densification strategy."""

    def __init__(self, config: TrainConfig):
        self.config = resolve_steps(config)
        self.run_dir = prepare_run_dir(self.config)
        self.device = torch.device(self.config.device)
        self.timing: dict[str, float] = {}
        self.generator = seed_everything(self.config.seed)
        t0 = time.perf_counter()
        data_path = resolve_data_path(self.config.data)
        scene = load_scene(
            data_path, format=self.config.format, views=self.config.views, downscale=self.config.downscale
        )
        self.datamanager = DataManager(scene, device=self.device, seed=self.config.seed)
        self.timing["data_s"] = time.perf_counter() - t0
        bg = 1.0 if scene.white_background else 0.0
        self.background = torch.full((3,), bg, device=self.device)
        spec = get_method(self.config.method)
        t0 = time.perf_counter()
        self.model = spec.model_class().from_data(self.config, self.datamanager, self.generator).to(self.device)
        self.timing.update(getattr(self.model, "init_timing", {}))
        self.timing["init_s"] = time.perf_counter() - t0 - sum(getattr(self.model, "init_timing", {}).values())
        self.optimizers = self.model.make_optimizers()
        self.strategy = DefaultStrategy(self.config.strategy)
        self.strategy_state = self.strategy.initialize_state(scene_scale=self.model.scene_scale)
        self.start_step = 0
        self.nonfinite_steps = 0
        self.restores = 0
        self.lr_factor = 1.0
        save_config(self.config, self.run_dir / "config.json")

    # ------------------------------------------------------------ checkpoints
    @property
    def checkpoint_dir(self) -> Path:
        return self.run_dir / "checkpoints"

    def state_payload(self, step: int) -> dict:
        return {
            "step": step,
            "params": {k: v.detach().cpu() for k, v in self.model.params.items()},
            "optimizers": {k: o.state_dict() for k, o in self.optimizers.items()},
            "strategy_state": {
                k: (v.cpu() if torch.is_tensor(v) else v) for k, v in self.strategy_state.items()
            },
            "model_state": self.model.extra_state() if hasattr(self.model, "extra_state") else {},
            "torch_rng": torch.get_rng_state(),
            "generator_rng": self.generator.get_state(),
            "lr_factor": self.lr_factor,
            "timing": dict(self.timing),
        }

    def save(self, step: int) -> None:
        save_checkpoint(self.checkpoint_dir, step, self.state_payload(step))

    def restore(self) -> bool:
        """Load the newest good checkpoint; False when there is none."""
        found = load_latest(self.checkpoint_dir)
        if found is None:
            return False
        path, ck = found
        dev = self.device
        self.model.params = torch.nn.ParameterDict(
            {
                k: torch.nn.Parameter(v.to(dev), requires_grad=self.model.params[k].requires_grad)
                for k, v in ck["params"].items()
            }
        )
        self.optimizers = self.model.make_optimizers()
        for k, o in self.optimizers.items():
            o.load_state_dict(ck["optimizers"][k])
        self.strategy_state = {
            k: (v.to(dev) if torch.is_tensor(v) else v) for k, v in ck["strategy_state"].items()
        }
        if ck.get("model_state") and hasattr(self.model, "load_extra_state"):
            self.model.load_extra_state(ck["model_state"])
        torch.set_rng_state(ck["torch_rng"])
        self.generator.set_state(ck["generator_rng"])
        self.lr_factor = ck.get("lr_factor", 1.0)
        self.timing.update(ck.get("timing", {}))
        self.start_step = ck["step"]
        console.print(f"[cyan]resumed from {path} (step {self.start_step})")
        return True

    # ------------------------------------------------------------------ step
    def train_step(self, step: int) -> tuple[dict, float]:
        model, cfg = self.model, self.config
        model.on_step_start(step)
        model.update_learning_rates(self.optimizers, step, cfg.total_steps)
        if self.lr_factor != 1.0:
            for o in self.optimizers.values():
                for g in o.param_groups:
                    g["lr"] *= self.lr_factor
        camera, batch = self.datamanager.next_train(step)
        outputs = model.get_outputs(camera, self.background)
        losses = model.get_loss_dict(outputs, batch, camera, step)
        loss = sum(losses.values())
        densify = model.densify_now(step)
        if densify:
            self.strategy.step_pre_backward(model.params, self.optimizers, self.strategy_state, step, outputs.meta)
        if not torch.isfinite(loss):
            return self._skip_nonfinite(step, "loss")
        loss.backward()
        keys = model.trainable_keys(step)
        for k, p in model.params.items():
            if p.grad is not None and not torch.isfinite(p.grad).all():
                return self._skip_nonfinite(step, f"gradient of {k}")
        self.nonfinite_steps = 0
        for k, opt in self.optimizers.items():
            if keys is None or k in keys:
                opt.step()
            opt.zero_grad(set_to_none=True)
        model.after_optimizer_step(step, losses, self.optimizers, self.strategy_state)
        if densify:
            with torch.no_grad():
                model.prepare_for_strategy()
            self.strategy.step_post_backward(model.params, self.optimizers, self.strategy_state, step, outputs.meta)
        with torch.no_grad():
            train_psnr = float(psnr(outputs.rgb.detach().clamp(0, 1), batch["image"]))
        return {k: float(v.detach()) for k, v in losses.items()} | {"loss": float(loss.detach())}, train_psnr

    def _skip_nonfinite(self, step: int, what: str):
        for opt in self.optimizers.values():
            opt.zero_grad(set_to_none=True)
        self.nonfinite_steps += 1
        self.skipped_steps = getattr(self, "skipped_steps", 0) + 1
        if self.nonfinite_steps >= MAX_NONFINITE:
            if self.restores < MAX_RESTORES and self.restore():
                self.restores += 1
                self.lr_factor *= 0.5
                self.nonfinite_steps = 0
                console.print(f"[yellow]non-finite {what} {MAX_NONFINITE} times: restored the last checkpoint, learning rates x{self.lr_factor}")
                raise _Restart()
            raise RuntimeError(f"training diverged: non-finite {what} at step {step} (restores exhausted)")
        return {"loss": float("nan")}, float("nan")

    # ------------------------------------------------------------------- run
    def train(self) -> dict:
        cfg = self.config
        if cfg.resume:
            self.restore()
        total = cfg.total_steps
        t_train = time.perf_counter()
        last = {"loss": float("nan")}
        tpsnr = float("nan")
        with _stop_signals() as stop, _progress(cfg.progress) as progress:
            task = progress.add_task("train", total=total, completed=self.start_step, loss=math.nan, psnr=math.nan, n=self.model.num_gaussians)
            step = self.start_step
            while step < total:
                try:
                    last, tpsnr = self.train_step(step)
                except _Restart:
                    step = self.start_step
                    continue
                step += 1
                progress.update(task, completed=step, loss=last["loss"], psnr=tpsnr, n=self.model.num_gaussians)
                if stop["stop"]:
                    self.save(step)
                    raise TrainingInterrupted(f"{stop['stop']} at step {step}: checkpoint written to {self.checkpoint_dir}")
                if cfg.checkpoint_every and step % cfg.checkpoint_every == 0 and step < total:
                    self.save(step)
                if cfg.eval_every and step % cfg.eval_every == 0 and step < total:
                    m = evaluate(self.model, self.datamanager, self.background)
                    console.print(f"step {step}: test PSNR {m['mean']['psnr']:.2f}")
        self.timing["train_s"] = self.timing.get("train_s", 0.0) + time.perf_counter() - t_train
        self.save(total)
        t0 = time.perf_counter()
        results = evaluate(
            self.model, self.datamanager, self.background, self.run_dir / "renders" if cfg.save_renders else None
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
            "render_fps": results["fps"],
            "skipped_steps": getattr(self, "skipped_steps", 0),
            "lpips_note": results["lpips_note"],
        }
        metrics["init_stats"] = getattr(self.model, "init_stats", {})
        if hasattr(self.model, "report"):
            metrics["model_report"] = self.model.report(self.datamanager)
        atomic_write_text(self.run_dir / "metrics.json", json.dumps(metrics, indent=2))
        print_summary(metrics, self.run_dir)
        return metrics


class _Restart(Exception):
    pass


@contextmanager
def _progress(enabled: bool):
    progress = Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TextColumn("[cyan]loss {task.fields[loss]:.4f}"),
        TextColumn("[green]PSNR {task.fields[psnr]:.2f}"),
        TextColumn("[magenta]{task.fields[n]} gaussians"),
        _SpeedColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        disable=not enabled,
    )
    with progress:
        yield progress


class _SpeedColumn(TextColumn):
    def __init__(self):
        super().__init__("")

    def render(self, task):
        from rich.text import Text

        speed = task.finished_speed or task.speed
        return Text(f"{speed:.2f} it/s" if speed else "-- it/s")


def print_summary(metrics: dict, run_dir: Path) -> None:
    """The final rich table: test metrics, Gaussian count and time per phase."""
    table = Table(title=f"{metrics['method']} on {metrics['data']}")
    table.add_column("metric")
    table.add_column("value", justify="right")
    for k, v in metrics["mean"].items():
        table.add_row(f"test {k}", "n/a" if v is None else f"{v:.4f}")
    table.add_row("gaussians", str(metrics["num_gaussians"]))
    table.add_row("steps", str(metrics["steps"]))
    if metrics.get("render_fps"):
        table.add_row("render fps", f"{metrics['render_fps']:.1f}")
    for k, v in metrics["timing"].items():
        table.add_row(k, f"{v:.1f}")
    table.add_row("run folder", str(run_dir))
    Console().print(table)
    if metrics.get("lpips_note"):
        console.print(f"[yellow]LPIPS not computed: {metrics['lpips_note']}")


def train(config: TrainConfig) -> dict:
    """Train ``config`` end to end and return metrics (also written to metrics.json)."""
    return Trainer(config).train()
