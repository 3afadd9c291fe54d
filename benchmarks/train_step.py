"""Where a real training step spends its time: whole steps of `3dgs` and `scgaussian` on a real scene.

For each method, a real run (default: fern, 3 views, the method's default schedule)
is trained once and snapshotted at iterations 0, 500 and 1000 (full training state:
parameters, optimizers, densification statistics, RNG). Each snapshot is then
loaded into a fresh trainer, ``--warmup`` steps are run and ``--steps`` steps are
timed, with the phases of the step measured by :mod:`splat_framework.runtime.profiling`
sections (projection, binning, compositing forward and backward, photometric
loss, rendering-geometry loss, the rest of backward, finiteness checks,
optimizer, densification, model hooks, metrics). A second pass of the same steps
under ``torch.profiler`` gives the time spent inside tensor operations (ATen
operators and compiled graphs); the rest
of the wall time is Python, dispatch and host-sync overhead.

Snapshots are kept under ``--work`` (default ``$SPLAT_CACHE/bench-train-step``,
else ``~/.cache/splat/bench-train-step``) and reused, so comparing two versions
of the code costs the profiling only: run the script once per source tree,
alternating (``PYTHONPATH=/path/to/other/src python benchmarks/train_step.py``),
and compare the step times of runs taken at the same load.

Usage:
    SPLAT_DATA=../shared/data python benchmarks/train_step.py [--data llff/fern --views 3]
        [--methods 3dgs scgaussian] [--at 0 500 1000] [--steps 20] [--warmup 3]
        [--json docs/measurements/train_step.json] [--readme README.md]

``--readme`` replaces the block between ``<!-- bench:train_step -->`` and
``<!-- /bench:train_step -->``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import time
from contextlib import contextmanager
from pathlib import Path

#: Phases reported, as (label, section paths whose exclusive time they sum; "*" = any parent).
PHASES: list[tuple[str, tuple[str, ...]]] = [
    ("projection (forward)", ("step/forward/projection",)),
    ("binning", ("step/forward/binning", "step/forward/compositing/binning")),
    ("compositing forward", ("step/forward/compositing",)),
    ("other forward (activations, SH concat)", ("step/forward",)),
    ("photometric loss (L1 + SSIM) forward", ("step/loss/photometric",)),
    ("rendering-geometry loss forward", ("step/loss/rendering geometry",)),
    ("other loss forward", ("step/loss", "step/loss/gaussian position")),
    ("compositing backward", ("step/backward/compositing backward",)),
    ("projection backward", ("step/backward/projection backward",)),
    ("other backward (SSIM, L1, L_rg, activations)", ("step/backward",)),
    ("finiteness checks", ("step/finiteness checks",)),
    ("optimizer", ("step/optimizer",)),
    ("densification", ("step/densification",)),
    ("model hooks (SCGaussian cache-and-filter)", ("step/model hooks",)),
    ("metrics (train PSNR, loss to float)", ("step/metrics",)),
    ("rest of the step (data, schedules, densify stats)", ("step",)),
]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default="llff/fern")
    p.add_argument("--views", type=int, default=3)
    p.add_argument("--methods", nargs="+", default=["3dgs", "scgaussian"])
    p.add_argument("--at", nargs="+", type=int, default=[0, 500, 1000], help="snapshot iterations")
    p.add_argument("--train-steps", type=int, default=1000, help="length of the run the snapshots come from")
    p.add_argument("--steps", type=int, default=20, help="timed steps per snapshot")
    p.add_argument("--warmup", type=int, default=3, help="untimed steps before timing")
    p.add_argument("--no-torch-profiler", action="store_true", help="skip the op-time pass")
    p.add_argument("--work", type=Path, default=None, help="snapshot folder")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    p.add_argument("--json", type=Path, default=Path("docs/measurements/train_step.json"))
    p.add_argument("--readme", type=Path, default=None)
    p.add_argument("--compare", nargs="+", type=Path, default=None, metavar="BEFORE_JSON",
                   help="no measuring: JSON files of a baseline's passes, compared with --to "
                        "(writes --json and the README block bench:train_step_speedup)")
    p.add_argument("--to", nargs="+", type=Path, default=None, metavar="AFTER_JSON",
                   help="JSON files of this code's passes, taken alternately with --compare's")
    p.add_argument("--label", default="baseline", help="the baseline's name in the comparison (e.g. its commit)")
    return p.parse_args(argv)


def work_dir(arg: Path | None) -> Path:
    if arg is not None:
        return arg
    base = os.environ.get("SPLAT_CACHE")
    return (Path(base) if base else Path.home() / ".cache" / "splat") / "bench-train-step"


def method_config(method: str, data: str, views: int, steps: int, output: Path):
    from splat_framework.registry import get_method

    base = get_method(method).default_config()
    return base.model_copy(update={
        "data": data, "views": views, "steps": steps, "output": output, "overwrite": True,
        "checkpoint_every": 0, "save_renders": False, "progress": True,
    })


def snapshots(method: str, args: argparse.Namespace) -> dict[int, Path]:
    """{iteration: checkpoint file} of the method's reference run, training it when missing."""
    from splat_framework.engine.trainer import Trainer

    folder = work_dir(args.work) / f"{args.data.replace('/', '-')}-v{args.views}-{method}-{args.train_steps}"
    snaps = {s: folder / "snapshots" / f"step-{s:06d}.pt" for s in args.at}
    if all(p.is_file() for p in snaps.values()):
        return snaps
    (folder / "snapshots").mkdir(parents=True, exist_ok=True)
    config = method_config(method, args.data, args.views, args.train_steps, folder / "run")

    def keep(trainer, step: int) -> None:
        if step in snaps:
            shutil.copyfile(trainer.save(step), snaps[step])

    print(f"{method}: training the reference run ({args.train_steps} steps) for snapshots {args.at}", flush=True)
    trainer = Trainer(config, callbacks=[keep])
    keep(trainer, 0)
    metrics = trainer.train()
    (folder / "snapshots" / "metrics.json").write_text(json.dumps(metrics["mean"]))
    return snaps


def time_steps(trainer, start: int, steps: int, warmup: int, device) -> dict:
    """Section totals (s per step) and wall time of ``steps`` steps after ``warmup`` untimed ones.

    Code older than the profiling sections (a baseline checkout) gets the wall time only."""
    try:
        from splat_framework.runtime.profiling import exclusive, profiling
    except ImportError:
        exclusive, profiling = dict, _no_sections

    for k in range(warmup):
        trainer.train_step(start + k)
    first = start + warmup
    t0 = time.perf_counter()
    with profiling(device) as totals:
        for k in range(steps):
            trainer.train_step(first + k)
    wall = time.perf_counter() - t0
    ex = exclusive(totals)
    phases = {}
    for label, keys in PHASES:
        phases[label] = sum(ex.get(k, 0.0) for k in keys) / steps
    return {"step_s": wall / steps, "phases_s": phases, "sections_s": {k: v / steps for k, v in totals.items()}}


@contextmanager
def _no_sections(device):
    yield {}


def load_snapshot(trainer, path: Path) -> None:
    """``trainer.load`` (older code: its private loader)."""
    if hasattr(trainer, "load"):
        trainer.load(path)
    else:
        from splat_framework.engine.checkpoint import load_checkpoint

        trainer._load_state(path, load_checkpoint(path))


def op_time(trainer, start: int, steps: int) -> dict:
    """Fraction of the wall time spent inside ATen operators and compiled graphs (torch.profiler, CPU)."""
    from torch.profiler import ProfilerActivity, profile

    t0 = time.perf_counter()
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for k in range(steps):
            trainer.train_step(start + k)
    wall = time.perf_counter() - t0
    events = prof.key_averages()
    ops = [e for e in events if _is_tensor_op(e.key)]
    ops_us = sum(e.self_cpu_time_total for e in ops)
    top = sorted(ops, key=lambda e: -e.self_cpu_time_total)[:12]
    return {
        "wall_s": wall / steps,
        "ops_s": ops_us / 1e6 / steps,
        "top_ops": [{"op": e.key, "ms_per_step": e.self_cpu_time_total / 1e3 / steps, "calls_per_step": e.count / steps}
                    for e in top],
    }


def _is_tensor_op(key: str) -> bool:
    """An ATen operator or a call of a torch.compile'd graph (its fused kernels run inside it)."""
    return key.startswith("aten::") or key.startswith("## Call CompiledFxGraph")


def measure(method: str, args: argparse.Namespace) -> list[dict]:
    from splat_framework.engine.trainer import Trainer

    snaps = snapshots(method, args)
    out_dir = work_dir(args.work) / "scratch"
    config = method_config(method, args.data, args.views, args.train_steps, out_dir).model_copy(
        update={"progress": False})
    trainer = Trainer(config)
    settings = getattr(trainer, "render_settings", None)
    if settings is not None:
        from splat_framework.render import backend_name

        compiled, kernels = settings.compile, backend_name(trainer.device, settings)
    else:  # older code: process-wide settings
        compiled, kernels = _process_kernels(trainer)
    records = []
    for at, path in sorted(snaps.items()):
        load_snapshot(trainer, path)
        n = trainer.model.num_gaussians
        rec = {"method": method, "at": at, "num_gaussians": n, "compiled": compiled, "kernels": kernels,
               **time_steps(trainer, at, args.steps, args.warmup, trainer.device)}
        if not args.no_torch_profiler:
            load_snapshot(trainer, path)
            rec["profiler"] = op_time(trainer, at, args.steps)
        records.append(rec)
        print(f"{method} @ {at}: {n} Gaussians, {rec['step_s'] * 1e3:.0f} ms/step "
              f"({1 / rec['step_s']:.2f} it/s)", flush=True)
    return records


def _kernels_label(record: dict) -> str:
    """The compositing kernels a record ran (records older than the native kernels: compiled or eager)."""
    return record.get("kernels") or ("compiled" if record.get("compiled") else "eager")


def markdown(records: list[dict], info: dict, command: str) -> str:
    cols = [f"`{r['method']}` @ {r['at']} ({r['num_gaussians']:,} G, {_kernels_label(r)})" for r in records]
    lines = ["| ms per step | " + " | ".join(cols) + " |", "|---|" + "--:|" * len(cols)]
    for label, _ in PHASES:
        vals = [r["phases_s"][label] * 1e3 for r in records]
        if max(vals) < 0.05:
            continue
        lines.append(f"| {label} | " + " | ".join(f"{v:.1f}" for v in vals) + " |")
    lines.append("| **whole step** | " + " | ".join(f"**{r['step_s'] * 1e3:.0f}**" for r in records) + " |")
    lines.append("| steps per second | " + " | ".join(f"{1 / r['step_s']:.2f}" for r in records) + " |")
    if all("profiler" in r for r in records):
        lines.append("| inside tensor ops (torch.profiler) | " + " | ".join(
            f"{100 * r['profiler']['ops_s'] / r['profiler']['wall_s']:.0f} %" for r in records) + " |")
    from ablation import footer

    return "\n".join(lines + footer(command, info["torch_threads"]))


def step_times(passes: list[dict]) -> dict[tuple[str, int], dict]:
    """{(method, snapshot): {"num_gaussians", "step_ms": [one per pass]}} of train_step JSON payloads."""
    out: dict[tuple[str, int], dict] = {}
    for payload in passes:
        for r in payload["records"]:
            row = out.setdefault((r["method"], r["at"]), {"num_gaussians": r["num_gaussians"], "step_ms": []})
            row["step_ms"].append(r["step_s"] * 1e3)
    return out


def comparison(before: list[dict], after: list[dict], label: str) -> dict:
    """Per snapshot: mean step time of each side over its passes and the speed-up (before / after)."""
    b, a = step_times(before), step_times(after)
    rows = []
    for key in b.keys() & a.keys():
        mb, ma = sum(b[key]["step_ms"]) / len(b[key]["step_ms"]), sum(a[key]["step_ms"]) / len(a[key]["step_ms"])
        rows.append({"method": key[0], "at": key[1], "num_gaussians": a[key]["num_gaussians"],
                     "before_ms": b[key]["step_ms"], "after_ms": a[key]["step_ms"], "speedup": mb / ma})
    rows.sort(key=lambda r: (r["method"], r["at"]))
    loads = [p["machine"].get("loadavg_at_start", [None])[0] for p in before + after]
    return {"baseline": label, "rows": rows, "loads": [x for x in loads if x is not None]}


def comparison_markdown(result: dict, command: str, threads: int | None) -> str:
    from ablation import footer

    lines = [f"| snapshot | Gaussians | {result['baseline']} (ms per step) | this code (ms per step) | speed-up | "
             "this code (it/s) |", "|---|--:|--:|--:|--:|--:|"]
    for r in result["rows"]:
        after = sum(r["after_ms"]) / len(r["after_ms"])
        lines.append(f"| `{r['method']}` @ {r['at']} | {r['num_gaussians']:,} | "
                     f"{' / '.join(f'{v:.0f}' for v in r['before_ms'])} | "
                     f"{' / '.join(f'{v:.0f}' for v in r['after_ms'])} | **{r['speedup']:.2f}x** | "
                     f"{1e3 / after:.2f} |")
    loads = ", ".join(f"{x:.2f}" for x in result.get("loads", []))
    note = ["", "Passes alternated baseline / this code in one session; load average at the start of each pass: "
            f"{loads}."] if loads else []
    return "\n".join(lines + note + footer(command, threads))


def main(argv: list[str] | None = None) -> Path:
    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from ablation import publish
    from rasterizer import machine_info

    args = parse_args(argv)
    command = "python benchmarks/train_step.py " + " ".join(sys.argv[1:] if argv is None else argv)
    if args.compare:
        if not args.to:
            raise SystemExit("--compare needs --to: the JSON files of this code's passes")
        passes = [[json.loads(f.read_text()) for f in files] for files in (args.compare, args.to)]
        result = comparison(*passes, args.label)
        threads = passes[1][0]["machine"].get("torch_threads")
        publish(args.json, result, comparison_markdown(result, command, threads), args.readme,
                "train_step_speedup", prefix="bench")
        return args.json
    if args.threads:
        torch.set_num_threads(args.threads)
    info = machine_info("cpu", args.threads) | {"data": args.data, "views": args.views, "steps": args.steps,
                                                 "python_platform": platform.platform()}
    records = [r for m in args.methods for r in measure(m, args)]
    publish(args.json, {"machine": info, "records": records}, markdown(records, info, command), args.readme,
            "train_step", prefix="bench")
    return args.json



def _process_kernels(trainer) -> tuple[bool, str]:
    """(compiled, kernels) of older code, whose render settings were process-wide."""
    try:
        from splat_framework.render import compile_requested
    except ImportError:  # older code: the environment variable only
        compiled = os.environ.get("SPLAT_COMPILE", "0") == "1"
    else:
        compiled = compile_requested()
    try:
        from splat_framework.render import backend_name
    except ImportError:  # older code: native or torch kernels only
        try:
            from splat_framework.render._native import native_for
        except ImportError:  # older code: no native kernels
            return compiled, "compiled" if compiled else "eager"
        return compiled, "native" if native_for(trainer.device) is not None else ("compiled" if compiled else "eager")
    return compiled, backend_name(trainer.device)

if __name__ == "__main__":
    main()
