"""What a new user waits for, launch to exit: the commands of a first hour, timed one after another.

    SPLAT_DATA=../shared/data python benchmarks/first_hour.py [--work /tmp/first-hour] \
        [--jobs first fern photos photos-warm export 3dgs-again] [--json docs/measurements/first_hour.json]

Jobs (each a real command in its own process, on an idle machine):

- ``first``: the README's first command (``splat-train scgaussian --data synthetic/forward``) with an
  empty ``$SPLAT_CACHE``: the scene's generation and the native kernels' build included.
- ``fern``: ``splat-train scgaussian --data llff/fern`` (the default), kernels built.
- ``photos``: a plain folder of 8 of fern's photos (copied from ``images_8``, no poses) through
  ``splat-train scgaussian --data FOLDER`` with an empty photo and match cache: posing, the
  prior's matching, training; ``photos-warm``: the same command again (poses and matches cached).
- ``export``: ``splat-export`` of the ``fern`` run.
- ``3dgs-again``: ``splat-train 3dgs --data llff/fern --steps 15``, run twice; the second is timed.

Each record has the wall time, the longest stretch without an output line (a command must not be
silent for more than 5 s), the run's phase times and slowest training step against the median
(``step_times``) from its metrics.json, and the load average
before it started; the Markdown table goes to ``--md`` and the records to ``--json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from datetime import datetime, timezone
from pathlib import Path

JOBS = ("first", "fern", "photos", "photos-warm", "export", "3dgs-again")
PHASES = ("data_s", "matching_s", "warmup_s", "init_s", "train_s", "eval_s")


def loadavg() -> float:
    try:
        return float(Path("/proc/loadavg").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return float("nan")


def timed(cmd: list[str], env: dict) -> dict:
    """Run ``cmd``; its wall time, exit code, the longest gap between two output lines (from launch
    to the first line, between lines, and from the last line to exit) and its last lines."""
    record = {"command": " ".join(cmd), "load_before": loadavg()}
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    stamps, tail, lines = [], [], []

    def read():
        for line in proc.stdout:
            stamps.append(time.perf_counter() - t0)
            lines.append(line.strip()[:160])
            tail.append(line)
            del tail[:-15]

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    record["exit"] = proc.wait()
    reader.join()
    record["wall_s"] = time.perf_counter() - t0
    record["longest_silence_s"] = longest_gap(stamps, record["wall_s"])
    record["silence_after"] = silence_after(stamps, lines, record["wall_s"])
    record["tail"] = "".join(tail)
    return record


def longest_gap(stamps: list[float], end: float) -> float:
    """The longest time between launch (0), each output line's time in ``stamps`` and ``end``."""
    points = [0.0, *stamps, end]
    return max(b - a for a, b in zip(points, points[1:]))


def silence_after(stamps: list[float], lines: list[str], end: float) -> str:
    """The output line the longest silence followed ("(launch)" when it came before the first line)."""
    points = [0.0, *stamps, end]
    gaps = [b - a for a, b in zip(points, points[1:])]
    i = max(range(len(gaps)), key=gaps.__getitem__)
    return "(launch)" if i == 0 else lines[i - 1]


def _metrics(run: Path) -> dict:
    try:
        return json.loads((run / "metrics.json").read_text())
    except (OSError, ValueError):
        return {}


def phases_of(run: Path) -> dict:
    """The phase times a run folder's metrics.json records (empty when it has none)."""
    timing = _metrics(run).get("timing", {})
    return {k: round(float(timing[k]), 1) for k in PHASES if k in timing}


def slowest_step_of(run: Path) -> dict | None:
    """The run's step_times (its slowest training step against the median; None when not recorded)."""
    return _metrics(run).get("step_times")


def markdown(records: list[dict], machine: str, date: str) -> str:
    rows = ["| job | wall (s) | longest silence (s) | phases (s) | slowest step | load before | exit |",
            "|---|--:|--:|---|---|--:|--:|"]
    for r in records:
        phases = ", ".join(f"{k.removesuffix('_s')} {v:g}" for k, v in r.get("phases", {}).items()) or "-"
        st = r.get("step_times")
        slowest = (f"{st['max_s']:.2f} s, step {st['slowest_step']}, {st['max_over_median']:.1f}x the median"
                   if st and st.get("max_over_median") else "-")
        rows.append(f"| {r['job']} | {r['wall_s']:.1f} | {r['longest_silence_s']:.1f} | {phases} | {slowest} | "
                    f"{r['load_before']:.2f} | {r['exit']} |")
    return "\n".join(rows + ["", f"{machine}; {date}; `python benchmarks/first_hour.py`"]) + "\n"


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("/tmp/splat-first-hour"))
    ap.add_argument("--jobs", nargs="+", choices=JOBS, default=list(JOBS))
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--md", type=Path, default=None)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(Path(__file__).parent))
    from full_run import machine

    data = Path(os.environ.get("SPLAT_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    work = args.work
    cache = work / "cache"
    bin_dir = Path(sys.executable).parent
    env = dict(os.environ, SPLAT_DATA=str(data), SPLAT_CACHE=str(cache))
    work.mkdir(parents=True, exist_ok=True)

    def train(*words: str, out: str) -> list[str]:
        return [str(bin_dir / "splat-train"), *words, "--output", str(work / out), "--overwrite"]

    photos = work / "photos"
    if "photos" in args.jobs or "photos-warm" in args.jobs:
        shutil.rmtree(photos, ignore_errors=True)
        photos.mkdir()
        for p in sorted((data / "llff" / "fern" / "images_8").glob("*.png"))[:8]:
            shutil.copy(p, photos / p.name)
    records = []
    for job in args.jobs:
        run = None
        if job == "first":
            fresh = work / "empty-cache"
            shutil.rmtree(fresh, ignore_errors=True)
            rec = timed(train("scgaussian", "--data", "synthetic/forward", out="first"), dict(env, SPLAT_CACHE=str(fresh)))
            run = work / "first"
            if not (cache / "native").exists():  # the other jobs run with the kernels built, as on a machine used before
                shutil.copytree(fresh / "native", cache / "native")
        elif job == "fern":
            rec = timed(train("scgaussian", "--data", "llff/fern", out="fern"), env)
            run = work / "fern"
        elif job in ("photos", "photos-warm"):
            if job == "photos":
                for sub in ("photos", "matches"):
                    shutil.rmtree(cache / sub, ignore_errors=True)
            rec = timed(train("scgaussian", "--data", str(photos), out=f"run-{job}"), env)  # not into the photos
            run = work / f"run-{job}"
        elif job == "export":
            rec = timed([str(bin_dir / "splat-export"), str(work / "fern"), "--ply", str(work / "fern.ply"), "--overwrite"], env)
        else:
            timed(train("3dgs", "--data", "llff/fern", "--steps", "15", out="3dgs-once"), env)
            rec = timed(train("3dgs", "--data", "llff/fern", "--steps", "15", out="3dgs-again"), env)
            run = work / "3dgs-again"
        rec["job"] = job
        rec["phases"] = phases_of(run) if run is not None else {}
        rec["step_times"] = slowest_step_of(run) if run is not None else None
        print(f"{job}: {rec['wall_s']:.1f} s, longest silence {rec['longest_silence_s']:.1f} s "
              f"(after: {rec['silence_after']}), exit {rec['exit']}",
              flush=True)
        records.append(rec)
    date = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    table = markdown(records, machine(), date)
    print(table)
    if args.json:
        args.json.write_text(json.dumps({"machine": machine(), "date": date, "records": records}, indent=1))
    if args.md:
        args.md.write_text(table)
    return records


if __name__ == "__main__":
    main()
