"""Training on a machine that is doing something else: wall time alone, two runs at once, beside a busy loop.

Each scenario launches real ``splat-train`` processes (default: ``3dgs`` on fern, 3 views,
300 iterations, seed 0, compiled kernels as the user gets them) and times them from launch to
exit, and from launch to their first training step:

    alone      one run, nothing else                       alone-1   the same, SPLAT_THREADS=1
    pair       two runs started together                   pair-1    both with SPLAT_THREADS=1
    hog        one run beside a 1-thread Python busy loop  hog-1     the run with SPLAT_THREADS=1

and compares: two runs together against running them back to back (twice ``alone``), a run
beside the busy loop against the 1-thread run on the idle machine (``alone-1``). Every run has the
same seed, so its test PSNR (from its metrics.json) says whether the load moved the result: with a
pinned thread count (the ``-1`` scenarios) it must not, to the last digit. Scenarios are
repeated ``--reps`` times, alternated (all scenarios, then all again), the machine's load
(runnable threads, /proc/loadavg) recorded before each and sampled during it. A first run
fills the compile cache (not timed) unless ``--no-warm``.

Usage:
    SPLAT_DATA=../shared/data python benchmarks/contention.py [--method 3dgs] [--data llff/fern]
        [--steps 300] [--reps 2] [--scenarios alone pair ...] [--env NAME=VALUE ...]
        [--json docs/measurements/contention.json] [--readme README.md docs/rasterizer.md]

``--env`` sets a variable for every run (to measure one lever, e.g. ``OMP_WAIT_POLICY=ACTIVE``);
``--readme`` replaces the block between ``<!-- bench:contention -->`` and ``<!-- /bench:contention -->``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from datetime import date
from pathlib import Path

SCENARIOS = {  # name: (runs at once, SPLAT_THREADS or None, beside a busy loop)
    "alone": (1, None, False), "alone-1": (1, "1", False),
    "pair": (2, None, False), "pair-1": (2, "1", False),
    "hog": (1, None, True), "hog-1": (1, "1", True),
}
HOG = "while True: pass"


def runnable() -> int:
    """Runnable threads on the machine right now (/proc/loadavg's 4th field)."""
    try:
        return int(Path("/proc/loadavg").read_text().split()[3].split("/")[0])
    except (OSError, ValueError, IndexError):
        return -1


def loadavg() -> float:
    try:
        return float(Path("/proc/loadavg").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return float("nan")


class Sampler(threading.Thread):
    """Samples the runnable threads every half second while a scenario runs."""

    def __init__(self):
        super().__init__(daemon=True)
        self.samples: list[int] = []
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.wait(0.5):
            self.samples.append(runnable())


def launch(args, threads: str | None, folder: Path) -> tuple[subprocess.Popen, dict]:
    """Start one training run; returns the process and its record (filled by a reader thread)."""
    env = dict(os.environ, **dict(kv.split("=", 1) for kv in args.env))
    if threads is not None:
        env["SPLAT_THREADS"] = threads
    train = Path(sys.executable).with_name("splat-train")
    cmd = [str(train), args.method, "--data", args.data, "--views", str(args.views), "--steps", str(args.steps),
           "--seed", "0", "--output", str(folder)]
    record: dict = {"t0": time.perf_counter(), "first_step_s": None}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)

    def read():
        tail = []
        for line in proc.stdout:
            if record["first_step_s"] is None and line.startswith("training: "):
                record["first_step_s"] = time.perf_counter() - record["t0"]
            tail = (tail + [line])[-20:]
        record["tail"] = "".join(tail)

    record["reader"] = threading.Thread(target=read, daemon=True)
    record["reader"].start()
    return proc, record


def run_scenario(args, name: str, work: Path) -> dict:
    count, threads, hog = SCENARIOS[name]
    before = {"loadavg": loadavg(), "runnable": runnable()}
    sampler = Sampler()
    sampler.start()
    busy = subprocess.Popen([sys.executable, "-c", HOG]) if hog else None
    try:
        if busy:
            time.sleep(1.0)  # the busy loop is running before training starts
        started = [launch(args, threads, work / f"{name}-{k}") for k in range(count)]
        walls, first, psnrs = [], [], []
        for k, (proc, record) in enumerate(started):
            rc = proc.wait()
            record["reader"].join()
            if rc != 0:
                raise SystemExit(f"{name}: splat-train failed (exit {rc}):\n{record['tail']}")
            walls.append(time.perf_counter() - record["t0"])
            first.append(record["first_step_s"])
            psnrs.append(json.loads((work / f"{name}-{k}" / "metrics.json").read_text())["mean"]["psnr"])
    finally:
        if busy:
            busy.kill()
            busy.wait()
        sampler.stop.set()
        sampler.join()
    during = statistics.fmean(sampler.samples) if sampler.samples else float("nan")
    return {"scenario": name, "walls_s": walls, "first_step_s": first, "psnr": psnrs, "before": before,
            "runnable_during": during}


def summarise(records: list[dict], reps: int) -> dict:
    """Per scenario: every wall time; and the two ratios of the issue's targets, per repetition."""
    by = {}
    for r in records:
        by.setdefault(r["scenario"], []).append(r)
    out = {"walls": {k: [max(r["walls_s"]) for r in v] for k, v in by.items()}}
    ratios: dict[str, list[float]] = {}
    for rep in range(reps):
        def wall(name):
            rows = by.get(name, [])
            return max(rows[rep]["walls_s"]) if rep < len(rows) else None

        for pair, alone in (("pair", "alone"), ("pair-1", "alone")):
            if wall(pair) and wall(alone):
                ratios.setdefault(f"{pair} / back to back", []).append(wall(pair) / (2 * wall(alone)))
        for hog in ("hog", "hog-1"):
            if wall(hog) and wall("alone-1"):
                ratios.setdefault(f"{hog} / alone-1", []).append(wall(hog) / wall("alone-1"))
    out["ratios"] = ratios
    psnrs = {k: sorted({p for r in v for p in r.get("psnr", [])}) for k, v in by.items()}
    out["psnr"] = psnrs
    pinned = sorted({p for k, v in psnrs.items() if k.endswith("-1") for p in v})
    out["pinned_same_psnr"] = len(pinned) == 1 if pinned else None  # every 1-thread run gave the same digits
    return out


def markdown(result: dict, command: str) -> str:
    fmt = lambda xs, p=0: " / ".join(f"{x:.{p}f}" for x in xs if x is not None) or "n/a"  # noqa: E731
    against = {"pair": "pair / back to back", "pair-1": "pair-1 / back to back",
               "hog": "hog / alone-1", "hog-1": "hog-1 / alone-1"}
    lines = [
        f"`{result['method']}` on `{result['data']}`, {result['views']} views, {result['steps']} iterations, "
        f"{result['reps']} repetitions (each cell: one value per repetition){result['env_note']}.",
        "",
        "| how it ran | SPLAT_THREADS | wall s (slowest run) | launch to step 1, s | against | load before / runnable during | test PSNR (seed 0) |",
        "|---|---|---|---|---|---|---|",
    ]
    described = {"alone": "alone", "pair": "two runs started together", "hog": "beside a 1-thread busy loop"}
    for name in SCENARIOS:
        rows = [r for r in result["records"] if r["scenario"] == name]
        if not rows:
            continue
        walls = [max(r["walls_s"]) for r in rows]
        firsts = [max((f for f in r["first_step_s"] if f is not None), default=None) for r in rows]
        ratio = result["summary"]["ratios"].get(against.get(name, ""), [])
        load = " ; ".join(f"{r['before']['loadavg']:.1f} / {r['runnable_during']:.1f}" for r in rows)
        lines.append(
            f"| {described[name.split('-')[0]]} | {'1' if name.endswith('-1') else 'default'} | {fmt(walls)} "
            f"| {fmt(firsts, 1)} | {fmt(ratio, 2) + 'x ' + against[name].split(' / ')[1] if ratio else ''} | {load} "
            f"| {fmt(result['summary'].get('psnr', {}).get(name, []), 6)} |"
        )
    same = result["summary"].get("pinned_same_psnr")
    if same is not None:
        lines += ["", "Every run with `SPLAT_THREADS=1`, alone, beside another or beside the busy loop, gave "
                  + ("the same test PSNR to every digit." if same else "**not** the same test PSNR.")]
    lines += ["", f"Machine: {result['machine']}; {result['date']}.", f"Reproduce: `{command}`", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> Path:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--method", default="3dgs")
    ap.add_argument("--data", default="llff/fern")
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=list(SCENARIOS))
    ap.add_argument("--env", nargs="*", default=[], help="NAME=VALUE set for every run (one lever at a time)")
    ap.add_argument("--no-warm", action="store_true", help="do not fill the compile cache with an untimed first run")
    ap.add_argument("--json", type=Path, default=Path("docs/measurements/contention.json"))
    ap.add_argument("--readme", type=Path, nargs="*", default=[], help="Markdown files whose bench:contention block gets the table")
    args = ap.parse_args(argv)

    sys.path.insert(0, str(Path(__file__).parent))
    from ablation import publish
    from full_run import machine

    records = []
    with tempfile.TemporaryDirectory(prefix="splat-contention-") as tmp:
        work = Path(tmp)
        if not args.no_warm:
            for threads in ({SCENARIOS[s][1] for s in args.scenarios}):  # each thread count has its own graph
                run_scenario(args, "alone-1" if threads else "alone", work / "warm")
        for rep in range(args.reps):
            for name in args.scenarios:
                records.append(run_scenario(args, name, work / f"rep{rep}"))
                print(f"rep {rep + 1}/{args.reps} {name}: {' / '.join(f'{w:.1f}' for w in records[-1]['walls_s'])} s",
                      flush=True)
    result = {
        "method": args.method, "data": args.data, "views": args.views, "steps": args.steps, "reps": args.reps,
        "env": args.env, "env_note": f", with {' '.join(args.env)}" if args.env else "",
        "machine": machine(), "date": str(date.today()), "records": records,
    }
    result["summary"] = summarise(records, args.reps)
    command = "python benchmarks/contention.py " + " ".join(argv if argv is not None else sys.argv[1:])
    for readme in args.readme or [None]:
        publish(args.json, result, markdown(result, command), readme, "contention", prefix="bench")
    return args.json


if __name__ == "__main__":
    main()
