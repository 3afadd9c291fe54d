"""``splat-eval RUN_DIR``: recompute a run's test metrics from its newest checkpoint."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from tyro.conf import Positional, arg


@dataclass
class EvalArgs:
    run_dir: Annotated[Positional[Path], arg(metavar="RUN_DIR")]
    """Run folder written by splat-train."""
    device: str | None = None
    """Torch device (default: the run's)."""
    trust_edited_config: bool = False
    """Use the run's config.json even when its checksum is missing or does not match (edited by hand)."""
    renders: bool = True
    """Rewrite the test-view pictures into RUN_DIR/renders."""
    test_pose_steps: int | None = None
    """Fit each test camera's pose to its photo by this many Adam steps before scoring it, the model frozen (the protocol of pose-free methods: BARF, CF-3DGS); for runs on poses estimated from the training photos alone (splat-process), whose test cameras inherit the estimate's error. 0 = score the dataset's test poses as they are; default: the run's own --test-pose-steps."""


class EvaluationInterrupted(Exception):
    """Ctrl-C or SIGTERM stopped splat-eval; the message says what is on disk and how to go on (exit 130)."""

    cli_exit_code = 130
    cli_prefix = "stopped"


def main(args: EvalArgs) -> dict:
    """Rescore the run, owning its folder meanwhile (it rewrites metrics.json and renders/)."""
    import shlex

    from ..files.run_lock import owned

    if args.test_pose_steps is not None and args.test_pose_steps < 0:
        print(f"error: --test-pose-steps must be >= 0, got {args.test_pose_steps}", file=sys.stderr)
        sys.exit(2)
    try:
        with owned(args.run_dir):
            return evaluate_run(args)
    except KeyboardInterrupt:  # metrics.json is replaced at the end, atomically: still the previous one
        raise EvaluationInterrupted(
            f"interrupted during the evaluation: {args.run_dir / 'metrics.json'} is unchanged (renders/ may hold "
            f"some views of this evaluation); run it again: {shlex.join(['splat-eval', *sys.argv[1:]])}") from None


def evaluate_run(args: EvalArgs) -> dict:
    from ..console import print_summary, starting

    with starting():
        from ..engine.run import load_run
        from ..evaluation.held_out import evaluate
        from ..pipeline.scene import background_for
        from ..runtime.io import atomic_write_json, read_json

    config, dm, model = load_run(args.run_dir, args.device, args.trust_edited_config)
    pose_steps = config.test_pose_steps if args.test_pose_steps is None else args.test_pose_steps
    results = evaluate(model, dm, background_for(dm.scene, config.device), args.run_dir / "renders" if args.renders else None,
                       pose_steps=pose_steps)
    path = args.run_dir / "metrics.json"
    metrics = read_json(path) if path.is_file() else {"method": config.method, "data": config.data, "timing": {}}
    metrics.update(
        mean=results["mean"], per_view=results["per_view"], render_fps=results["fps"],
        num_gaussians=model.num_gaussians, lpips_note=results["lpips_note"], test_pose_steps=pose_steps,
    )
    metrics.setdefault("steps", config.total_steps)
    atomic_write_json(path, metrics)
    print_summary(metrics, args.run_dir)
    return metrics


def entrypoint() -> None:
    from .common import parse_cli, run_cli

    run_cli(lambda: main(parse_cli(EvalArgs, prog="splat-eval")))


if __name__ == "__main__":
    entrypoint()
