"""What a new user waits for, launch to exit: the commands of a first hour, timed one after another.

    SPLAT_DATA=../shared/data python benchmarks/first_hour.py [--work /tmp/first-hour] \
        [--jobs first fern photos photos-warm export 3dgs-again] [--json docs/measurements/first_hour.json] \
        [--against SRC --rounds 2]

Jobs (each a real command in its own process, on an idle machine):

- ``first``: the README's first command (``splat-train scgaussian --data synthetic/forward``) with an
  empty ``$SPLAT_CACHE``: the scene's generation and the native kernels' build included.
- ``fern``: ``splat-train scgaussian --data llff/fern`` (the default), kernels built.
- ``photos``: a plain folder of 8 of fern's photos (copied from ``images_8``, no poses) through
  ``splat-train scgaussian --data FOLDER`` with an empty photo and match cache: posing, the
  prior's matching, training; ``photos-warm``: the same command again (poses and matches cached).
- ``export``: ``splat-export`` of the ``fern`` run.
- ``3dgs-again``: ``splat-train 3dgs --data llff/fern --steps 15``, run twice; the second is timed.

``--against SRC`` (another source tree, e.g. ``git worktree add --detach /tmp/old COMMIT``) makes the
``fern`` job an alternated comparison: the fern default (``--seed 0``) runs ``--rounds`` times on each
tree, SRC first, then this tree, and so on, each tree's kernels built and fern's matches cached first
by an untimed ``--steps 3`` run; both trees run from their ``src`` on ``PYTHONPATH``. The table then
has a row per run and the ratio of the means, and each of this tree's runs against the mean of
SRC's runs around it (the load drifts, so the neighbours are the fair comparison).

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


def tree_label(tree: Path) -> str:
    """A source tree's commit (short hash, ``+`` when it has uncommitted changes), else its path."""
    def git(*words):
        return subprocess.run(["git", "-C", str(tree), *words], capture_output=True, text=True)

    head = git("rev-parse", "--short", "HEAD")
    if head.returncode != 0:
        return str(tree)
    dirty = git("status", "--porcelain", "--untracked-files=no", "--", "src").stdout.strip()
    return head.stdout.strip() + ("+" if dirty else "")


def alternated_ratio(records: list[dict], this: str, other: str) -> str:
    """One line: the mean wall time of ``this`` tree's runs over ``other``'s, and each of this tree's
    runs against the mean of the other tree's runs just before and after it (records in run order)."""
    walls = [(r["tree"], r["wall_s"]) for r in records if r.get("tree") in (this, other)]
    mine = [w for t, w in walls if t == this]
    theirs = [w for t, w in walls if t == other]
    if not mine or not theirs:
        return ""
    each = []
    for i, (t, w) in enumerate(walls):
        if t != this:
            continue
        around = [walls[j][1] for j in (i - 1, i + 1) if 0 <= j < len(walls) and walls[j][0] == other]
        each.append(f"{w / (sum(around) / len(around)):.2f}x")
    ratio = (sum(mine) / len(mine)) / (sum(theirs) / len(theirs))
    return (f"fern, alternated: {this} {ratio:.2f}x the wall time of {other} (means {sum(mine) / len(mine):.1f} s "
            f"and {sum(theirs) / len(theirs):.1f} s; each run against its neighbours: {', '.join(each)})")


def markdown(records: list[dict], machine: str, date: str, note: str = "") -> str:
    rows = ["| job | wall (s) | longest silence (s) | phases (s) | slowest step | load before | exit |",
            "|---|--:|--:|---|---|--:|--:|"]
    for r in records:
        phases = ", ".join(f"{k.removesuffix('_s')} {v:g}" for k, v in r.get("phases", {}).items()) or "-"
        st = r.get("step_times")
        slowest = (f"{st['max_s']:.2f} s, step {st['slowest_step']}, {st['max_over_median']:.1f}x the median"
                   if st and st.get("max_over_median") else "-")
        job = f"{r['job']} ({r['tree']})" if r.get("tree") else r["job"]
        rows.append(f"| {job} | {r['wall_s']:.1f} | {r['longest_silence_s']:.1f} | {phases} | {slowest} | "
                    f"{r['load_before']:.2f} | {r['exit']} |")
    return "\n".join(rows + ["", *([note, ""] if note else []), f"{machine}; {date}; `python benchmarks/first_hour.py`"]) + "\n"


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("/tmp/splat-first-hour"))
    ap.add_argument("--jobs", nargs="+", choices=JOBS, default=list(JOBS))
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--md", type=Path, default=None)
    ap.add_argument("--against", type=Path, default=None, metavar="SRC",
                    help="another source tree: the fern job alternates between it and this tree")
    ap.add_argument("--rounds", type=int, default=2, help="with --against: fern runs on each tree")
    args = ap.parse_args(argv)
    if args.against is not None and not (args.against / "src" / "splat_framework").is_dir():
        ap.error(f"--against {args.against}: no src/splat_framework there (give a checkout of this project)")
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
    this_tree = Path(__file__).resolve().parents[1]
    trees = {tree_label(this_tree): this_tree}
    if args.against is not None:
        other = tree_label(args.against.resolve())
        if other in trees:  # the same commit checked out twice: tell the rows apart by path
            other = f"{other} {args.against.resolve()}"
        trees = {other: args.against.resolve(), **trees}
    for job in args.jobs:
        if job == "fern" and args.against is not None:
            def fern(tree: Path, out: str, *more: str) -> dict:
                cmd = [sys.executable, "-m", "splat_framework.cli.train", "scgaussian", "--data", "llff/fern",
                       "--seed", "0", *more, "--output", str(work / out), "--overwrite"]
                return timed(cmd, dict(env, PYTHONPATH=str(tree / "src")))

            for tree in trees.values():  # kernels built, matches cached: untimed
                fern(tree, "fern-prepare", "--steps", "3")
            for _ in range(args.rounds):
                for label, tree in trees.items():
                    out = "fern" if tree == this_tree else "fern-against"  # the export job reads "fern"
                    rec = fern(tree, out)
                    rec.update(job="fern", tree=label, phases=phases_of(work / out),
                               step_times=slowest_step_of(work / out))
                    print(f"fern ({label}): {rec['wall_s']:.1f} s, exit {rec['exit']}", flush=True)
                    records.append(rec)
            continue
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
            rec = timed([str(bin_dir / "splat-export"), str(work / "fern"), "--out", str(work / "fern.ply"), "--overwrite"], env)
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
    labels = list(trees)
    note = alternated_ratio(records, labels[-1], labels[0]) if len(labels) == 2 else ""
    table = markdown(records, machine(), date, note)
    print(table)
    if args.json:
        args.json.write_text(json.dumps({"machine": machine(), "date": date, "records": records, "ratio": note},
                                        indent=1))
    if args.md:
        args.md.write_text(table)
    return records


if __name__ == "__main__":
    main()
