"""What the anchor-based methods cost per iteration against 3DGS at the same rendered Gaussians.

For each finished run of an anchor method (``scaffold-gs*``, ``octree-gs*``; e.g. the
runs of ``ablation.py --table comp-tria``), the trained model is loaded and its neural
Gaussians drawn for the first training view are exported as ordinary 3DGS Gaussians
(``model.export_gaussians(camera)``, SH degree 3 with zero higher bands, as ``3dgs``
trains). Both models then take the same training step on that view, repeated: render,
loss (L1 + D-SSIM; the anchor method adds its scale regulariser), backward, Adam step,
no densification. The anchor step includes the per-view MLP decoding; its forward alone
is timed too. So the two columns differ only by how the Gaussians are produced.

Each (run, model) measurement is a fresh process (spawned) so that its peak resident
memory (``ru_maxrss``) is its own; measurements alternate between the models, ``--rounds``
times, and the median of each model's step times is reported. Time them on an idle
machine, or read only the ratios: the load average is printed under the table.

Usage:
    SPLAT_DATA=../shared/data python benchmarks/anchor_cost.py RUN [RUN ...] [--steps 10] [--warmup 3]
        [--rounds 2] [--threads 2] [--json docs/measurements/anchor_cost.json] [--readme README.md]
        [--no-measure]   # the table again from --json

``--readme`` replaces the block between ``<!-- bench:anchor_cost -->`` and ``<!-- /bench:anchor_cost -->``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+", type=Path, help="finished run folders of anchor methods")
    p.add_argument("--steps", type=int, default=10, help="timed steps per measurement")
    p.add_argument("--warmup", type=int, default=3, help="untimed steps first")
    p.add_argument("--rounds", type=int, default=2, help="measurements per (run, model), alternated")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default: all cores)")
    p.add_argument("--json", type=Path, default=Path("docs/measurements/anchor_cost.json"))
    p.add_argument("--readme", type=Path, default=None)
    p.add_argument("--no-measure", action="store_true", help="rewrite the table from --json of an earlier run")
    return p.parse_args(argv)


def _rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def measure(run: str, as_3dgs: bool, steps: int, warmup: int, threads: int | None) -> dict:
    """One measurement in this (fresh) process: the run's model, or its first training view's
    Gaussians as a 3DGS model; seconds per step, decode forward seconds, Gaussians drawn, peak RSS."""
    import torch

    from splat_framework.config import RunFacts
    from splat_framework.engine.run import load_run
    from splat_framework.model.gaussians import GaussianModel
    from splat_framework.pipeline.scene import background_for
    from splat_framework.registry import get_method

    if threads:
        torch.set_num_threads(threads)
    config, dm, model = load_run(Path(run))
    camera, batch = dm.train_views()[0]
    method = config.method
    if as_3dgs:
        base = get_method("3dgs").default_config()
        g = model.export_gaussians(camera)
        k = (base.model.sh_degree + 1) ** 2
        g["shN"] = g["sh0"].new_zeros(g["sh0"].shape[0], k - 1, 3)
        model = GaussianModel.from_checkpoint(base.model, RunFacts.of(base), model.scene_scale, {"params": {k: v.detach() for k, v in g.items()}})
        method = "3dgs"
    optimizers = model.make_optimizers()
    background = background_for(dm.scene, config.device)
    rss_before = _rss_mb()
    times, drawn = [], 0
    for i in range(warmup + steps):
        t0 = time.perf_counter()
        out = model.get_outputs(camera, background)
        loss = sum(model.get_loss_dict(out, batch, camera, 1000).values())
        loss.backward()
        for opt in optimizers.values():
            opt.step()
            opt.zero_grad(set_to_none=True)
        if i >= warmup:
            times.append(time.perf_counter() - t0)
        drawn = int(out.meta["means2d"].shape[0])
    decode = None
    if hasattr(model, "decode"):
        decode_times = []
        for _ in range(steps):
            t0 = time.perf_counter()
            model.decode(camera.center, model.visible_anchors(camera) & model.lod_mask(camera.center))
            decode_times.append(time.perf_counter() - t0)
        decode = statistics.median(decode_times)
    return {"run": run, "method": method, "model": "3dgs" if as_3dgs else "anchor", "step_s": statistics.median(times),
            "decode_s": decode, "drawn": drawn, "peak_rss_mb": _rss_mb(), "step_rss_mb": _rss_mb() - rss_before,
            "anchors": getattr(model, "num_anchors", None), "size": f"{camera.width}x{camera.height}"}


def markdown(results: list[dict], command: str, threads: int | None) -> str:
    from ablation import footer

    lines = [
        "| Run | Model | Anchors | Gaussians drawn | Step (s) | Decode fwd (s) | Step / 3DGS step | Peak RSS (MB) | RSS growth in steps (MB) |",
        "|---|---|--:|--:|--:|--:|--:|--:|--:|",
    ]
    for run in dict.fromkeys(r["run"] for r in results):
        by = {m: [r for r in results if r["run"] == run and r["model"] == m] for m in ("anchor", "3dgs")}
        step = {m: statistics.median(r["step_s"] for r in rs) for m, rs in by.items() if rs}
        for m, rs in by.items():
            if not rs:
                continue
            r = rs[0]
            cells = [
                f"{Path(run).parent.name}/{Path(run).name}",
                f"`{r['method']}`" if m == "anchor" else "`3dgs` on its Gaussians",
                f"{r['anchors']:,}" if r["anchors"] else "n/a",
                f"{r['drawn']:,}",
                f"{step[m]:.3f}",
                f"{statistics.median(x['decode_s'] for x in rs):.3f}" if r["decode_s"] is not None else "n/a",
                f"{step[m] / step['3dgs']:.2f}" if "3dgs" in step else "n/a",
                f"{max(x['peak_rss_mb'] for x in rs):.0f}",
                f"{max(x['step_rss_mb'] for x in rs):.0f}",
            ]
            lines.append("| " + " | ".join(cells) + " |")
    size = results[0]["size"] if results else "?"
    rounds = len(results) // max(2 * len({r["run"] for r in results}), 1)
    lines += ["", f"Median over {rounds} alternated measurement(s) per row; one training view at {size}; "
              "steps without densification."]
    return "\n".join(lines + footer(command, threads))


def main(argv: list[str] | None = None) -> list[dict]:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from ablation import publish

    args = parse_args(argv)
    results = json.loads(args.json.read_text()) if args.no_measure else []
    ctx = get_context("spawn")
    for _ in range(0 if args.no_measure else args.rounds):
        for run in args.runs:
            for as_3dgs in (False, True):
                with ProcessPoolExecutor(max_workers=1, mp_context=ctx) as pool:
                    r = pool.submit(measure, str(run), as_3dgs, args.steps, args.warmup, args.threads).result()
                print(f"{Path(run).name} {r['model']}: {r['step_s']:.3f} s/step, {r['drawn']} Gaussians, "
                      f"peak {r['peak_rss_mb']:.0f} MB", flush=True)
                results.append(r)
    command = "python benchmarks/anchor_cost.py " + " ".join(sys.argv[1:] if argv is None else argv)
    publish(args.json, results, markdown(results, command, args.threads), args.readme, "anchor_cost", prefix="bench")
    return results


if __name__ == "__main__":
    main()
