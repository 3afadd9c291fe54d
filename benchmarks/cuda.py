"""The prepared GPU check of the Triton rasterizer (issue 81): one script for one call of a lent GPU.

What it measures, each step a subprocess with its own time limit inside ``--budget`` seconds:
  1. the machine (GPU, driver, torch, triton) and whether the project imports;
  2. the rasterizer's render and fwd+bwd at 10k / 100k / 500k Gaussians (504x378, median of 5),
     the torch kernels (``eager``: the code before, on CUDA) against ``triton``, with peak GPU memory
     (``benchmarks/rasterizer.py``);
  3. ``splat-train scgaussian --data llff/fern --device cuda`` from an empty cache (cold) and again
     (warm), launch to exit, then ``splat-train 3dgs --data llff/fern --steps 1000``: wall time,
     test PSNR / SSIM, render FPS, peak GPU memory, the rasterizer that ran (metrics.json);
  4. host syncs per training step on fern (``benchmarks/host_syncs.py``: torch's sync debug mode
     counts every synchronizing call) and the step's time;
  5. with ``--before DIR`` (the project's code before, e.g. a wheel installed with ``--target``),
     the same fern run cold and the same sync count with that code, for the before/after table.
Everything goes to ``--out`` (``$OUT`` on the device): logs, metrics, ``summary.md``.

Prepare on the development machine (``benchmarks/cuda_prepare.sh 3.12 BEFORE_COMMIT``: wheels into
``.whl/``, the code before into ``.whl/before/``, fern's ``images_8`` and poses into ``.devdata/``;
it prints what the call carries against its 64 MiB), dry-run here on the CPU with ``--dry-run`` (the
rasterizer at 300 Gaussians under ``TRITON_INTERPRET=1``, the runs 20 steps on the CPU's own kernels),
then on the device, with ``.whl`` and ``.devdata`` carried::

    python3 -m pip install -q --no-index --no-deps --target /tmp/site .whl/*.whl &&
    python3 -m pip install -q --no-index --no-deps --target /tmp/before .whl/before/*.whl &&
    python3 benchmarks/cuda.py --out $OUT --budget 480 --site /tmp/site --before /tmp/before
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


class Clock:
    """Seconds left of the budget."""

    def __init__(self, budget: float):
        self.end = time.monotonic() + budget

    def left(self) -> float:
        return self.end - time.monotonic()


def run(label: str, cmd: list[str], out: Path, clock: Clock, limit: float, env: dict, summary: list) -> dict:
    """``cmd`` with stdout and stderr in ``out/label.log``, at most ``limit`` s (and what the budget
    leaves less 10 s); a row of ``summary``."""
    left = min(limit, clock.left() - 10)
    if left < 20:
        summary.append({"step": label, "skipped": f"{clock.left():.0f} s of the budget left"})
        print(f"{label}: skipped ({clock.left():.0f} s left)", flush=True)
        return summary[-1]
    t0 = time.perf_counter()
    with open(out / f"{label}.log", "w") as log:
        try:
            rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, env=env, timeout=left, cwd=ROOT).returncode
        except subprocess.TimeoutExpired:
            rc = "timeout"
    row = {"step": label, "rc": rc, "wall_s": round(time.perf_counter() - t0, 1)}
    summary.append(row)
    print(f"{label}: rc={rc} wall {row['wall_s']} s", flush=True)
    print("".join((out / f"{label}.log").read_text(errors="replace").splitlines(True)[-12:]), flush=True)
    return row


def fern_row(row: dict, run_dir: Path, out: Path) -> dict:
    """The run's metrics.json figures added to ``row`` (and the file copied to ``out``)."""
    metrics = run_dir / "metrics.json"
    if not metrics.is_file():
        return row
    shutil.copy(metrics, out / f"{row['step']}-metrics.json")
    m = json.loads(metrics.read_text())
    mean = m.get("mean", {})
    row.update({"psnr": mean.get("psnr"), "ssim": mean.get("ssim"), "gaussians": m.get("num_gaussians"),
                "render_fps": m.get("render_fps"), "peak_gpu_mib": m.get("peak_gpu_memory_mib"),
                "rasterizer": m.get("rasterizer"), "train_s": m.get("timing", {}).get("train_s")})
    return row


def syncs_row(row: dict, path: Path) -> dict:
    """benchmarks/host_syncs.py's figures added to ``row``: host syncs per step (torch's own count on
    CUDA, else the project's counter) and the step's time."""
    if path.is_file():
        r = json.loads(path.read_text())
        row.update({"syncs_per_step": r.get("cuda_syncs_per_step", r.get("counted_per_step")),
                    "step_ms": r.get("step_ms"), "gaussians": r.get("gaussians")})
    return row


def machine(out: Path, env: dict) -> None:
    probe = ("import sys, torch; print(sys.version.split()[0], torch.__version__, torch.cuda.is_available(), "
             "torch.cuda.get_device_name() if torch.cuda.is_available() else 'no GPU'); import triton; "
             "print('triton', triton.__version__); import splat_framework, scg_plugin; print('project imports')")
    lines = [subprocess.run(c, capture_output=True, text=True, env=env, shell=True).stdout + "\n" for c in (
        "nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv 2>&1", "nproc", "uptime")]
    p = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env)
    text = "".join(lines) + p.stdout + p.stderr
    (out / "machine.txt").write_text(text)
    print(text, flush=True)


def write_summary(out: Path, summary: list, args) -> None:
    cols = ["step", "rc", "wall_s", "train_s", "psnr", "ssim", "gaussians", "render_fps", "peak_gpu_mib",
            "rasterizer", "syncs_per_step", "step_ms", "skipped"]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for row in summary:
        cells = []
        for c in cols:
            v = row.get(c, "")
            cells.append(f"{v:.4f}" if isinstance(v, float) and c in ("psnr", "ssim") else
                         f"{v:.1f}" if isinstance(v, float) else str(v if v is not None else ""))
        lines.append("| " + " | ".join(cells) + " |")
    bench = out / "rasterizer-cuda.md"
    text = "\n".join(lines) + "\n"
    if bench.is_file():
        text += "\n" + bench.read_text()
    (out / "summary.md").write_text(text)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(text, flush=True)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path(os.environ.get("OUT", "cuda-check")))
    p.add_argument("--budget", type=float, default=480, help="seconds for everything (default 480)")
    p.add_argument("--site", type=Path, default=None, help="folder the carried wheels were installed into")
    p.add_argument("--before", type=Path, default=None, help="folder holding the code before (installed wheel)")
    p.add_argument("--data", default=str(ROOT / ".devdata"), help="SPLAT_DATA (fern under llff/fern)")
    p.add_argument("--dry-run", action="store_true",
                   help="on a CPU: the rasterizer at 300 Gaussians under the interpreter, runs of 20 steps")
    args = p.parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    clock = Clock(args.budget)
    env = dict(os.environ, SPLAT_DATA=args.data, PYTHONUNBUFFERED="1", COLUMNS="100")
    paths = [str(ROOT / "src")] + ([str(args.site)] if args.site else [])
    env["PYTHONPATH"] = os.pathsep.join(paths + [env.get("PYTHONPATH", "")])
    device = "cpu" if args.dry_run else "cuda"
    machine(out, env)
    summary: list = []
    sizes = ["300"] if args.dry_run else ["10000", "100000", "500000"]
    run("rasterizer", [sys.executable, str(HERE / "rasterizer.py"), "--device", device, "--sizes", *sizes,
                       "--repeats", "1" if args.dry_run else "5", "--warmup", "1", "--scenes", "opaque",
                       "--modes", *(["triton"] if args.dry_run else ["eager", "triton"]),
                       "--json", str(out / "rasterizer-cuda.json"), "--md", str(out / "rasterizer-cuda.md")],
        out, clock, 120 if args.dry_run else 150, dict(env, TRITON_INTERPRET="1") if args.dry_run else env, summary)
    steps = ["--steps", "20"] if args.dry_run else []
    train = [sys.executable, "-m", "splat_framework.cli.train"]
    fern = ["--data", "llff/fern", "--device", device, "--no-progress", "--overwrite"]
    cache = Path("/tmp/splat-cuda-cache")
    shutil.rmtree(cache, ignore_errors=True)
    env_after = dict(env, SPLAT_CACHE=str(cache))
    for label in ("fern-cold", "fern-warm"):
        row = run(label, train + ["scgaussian", *fern, *steps, "--output", f"/tmp/{label}"], out, clock,
                  240 if label == "fern-cold" else 120, env_after, summary)
        fern_row(row, Path(f"/tmp/{label}"), out)
    row = run("3dgs-1000", train + ["3dgs", *fern, "--steps", "20" if args.dry_run else "1000",
                                    "--output", "/tmp/3dgs-1000"], out, clock, 90, env_after, summary)
    fern_row(row, Path("/tmp/3dgs-1000"), out)
    host_syncs = [sys.executable, str(HERE / "host_syncs.py"), "--data", "llff/fern", "--device", device,
                  "--warmup", "10" if args.dry_run else "30", "--steps", "5" if args.dry_run else "20"]
    syncs_row(run("host-syncs", host_syncs + ["--json", str(out / "host-syncs.json"), "--output", "/tmp/host-syncs"],
                  out, clock, 90, env_after, summary), out / "host-syncs.json")
    if args.before is not None:
        before_cache = Path("/tmp/splat-cuda-cache-before")
        shutil.rmtree(before_cache, ignore_errors=True)
        env_before = dict(env, SPLAT_CACHE=str(before_cache),
                          PYTHONPATH=os.pathsep.join([str(args.before)] + paths[1:]))
        row = run("before-fern-cold", train + ["scgaussian", *fern, *steps, "--output", "/tmp/before-fern-cold"],
                  out, clock, 240, env_before, summary)
        fern_row(row, Path("/tmp/before-fern-cold"), out)
        syncs_row(run("before-host-syncs", host_syncs + ["--json", str(out / "before-host-syncs.json"),
                                                         "--output", "/tmp/before-host-syncs"],
                      out, clock, 90, env_before, summary), out / "before-host-syncs.json")
    write_summary(out, summary, args)


if __name__ == "__main__":
    main()
