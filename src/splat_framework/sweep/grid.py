"""The grid of a sweep: methods x scenes x view counts x seeds, its file format and run folders."""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any, Iterable

from ..errors import DataError

METRICS = ("psnr", "ssim", "lpips", "lpips_alex", "avg", "st_lpips", "psnr_before_pose_fit")
"""Test metrics reported per run (``metrics.json`` ``mean``; the last only with ``test_pose_steps``)."""
PHASES = ("matching_s", "warmup_s", "train_s", "eval_s", "total_s")
"""Wall-time phases reported per run (``metrics.json`` ``timing``)."""
NUMERIC_FIELDS = METRICS + PHASES + ("peak_rss_mb", "peak_gpu_mb", "num_gaussians", "render_fps", "load_average")
"""Every per-run number the table aggregates over seeds (``load_average``: the machine's 1-minute
load average when the run started, from its ``sweep.json``, so that a table regenerated later still
states the load its times were measured under)."""
BACKENDS = ("local", "ray", "serial")
GRID_KEYS = {
    "methods", "data", "views", "seeds", "steps", "overrides",
    "out", "workers", "threads", "backend", "address", "mem_per_run_gb",
}
"""Keys a grid file (TOML or JSON) may hold."""
DEFAULT_MEM_PER_RUN_GB = 2.0
RAY_HINT = "--backend ray needs Ray, which is not installed: pip install \"splat-framework[ray]\""


class SweepError(DataError):
    """Bad sweep input (grid file, options); one line, CLI exit code 2."""


@dataclass(frozen=True)
class RunSpec:
    """One training run of a sweep."""

    method: str
    data: str
    views: int | str
    seed: int
    steps: int | None
    run_dir: Path
    overrides: dict = field(default_factory=dict, compare=False, hash=False)

    @property
    def group(self) -> tuple:
        """The table row this run belongs to (seeds are aggregated)."""
        return (self.method, self.data, self.views)

    @property
    def label(self) -> str:
        return f"{self.method} {self.data} v{self.views} s{self.seed}"

    def to_json(self) -> dict:
        d = asdict(self)
        d["run_dir"] = str(self.run_dir)
        return d


@dataclass
class Grid:
    """Methods x scenes x view counts x seeds, with shared steps and config overrides."""

    methods: list[str]
    data: list[str]
    views: list[int | str] = field(default_factory=lambda: [3])
    seeds: list[int] = field(default_factory=lambda: [0])
    steps: int | None = None
    overrides: dict = field(default_factory=dict)

    def runs(self, out: Path) -> list[RunSpec]:
        """Every run, ordered scene, views, method, seed (the table's row order)."""
        if not self.methods:
            raise SweepError("sweep: no methods given")
        if not self.data:
            raise SweepError("sweep: no datasets given")
        slugs: dict[str, str] = {}
        for d in self.data:
            s = scene_slug(d)
            if s in slugs and slugs[s] != d:
                raise SweepError(f"sweep: datasets '{slugs[s]}' and '{d}' share the run-folder name '{s}'")
            slugs[s] = d
        out = Path(out)
        return [
            RunSpec(m, d, v, s, self.steps, run_dir(out, d, m, v, s), self.overrides)
            for d in unique(self.data)
            for v in unique(self.views)
            for m in unique(self.methods)
            for s in unique(self.seeds)
        ]


def unique(xs: Iterable) -> list:
    seen, out = set(), []
    for x in xs:
        if x not in seen:
            seen.add(x)
            out.append(x)
    return out


def scene_slug(data: str) -> str:
    """Folder name of a dataset spec: ``llff/fern`` -> ``llff-fern``.

    Absolute paths keep their last two components (``/d/nerf_llff/fern`` ->
    ``nerf_llff-fern``); anything but letters, digits and ``._+-`` becomes ``_``.
    """
    text = str(data).replace("\\", "/").strip()
    parts = [p for p in PurePosixPath(text).parts if p not in ("/", ".", "..", "~")]
    if text.startswith(("/", "~")) and len(parts) > 2:
        parts = parts[-2:]
    slug = re.sub(r"[^A-Za-z0-9._+-]+", "_", "-".join(parts)).strip("._-")
    return slug or "scene"


def group_key(data: str, views) -> str:
    """Name of a (scene, view count) group: ``llff-fern-v3`` (its comparison figure's file stem)."""
    return f"{scene_slug(data)}-v{views}"

def run_dir(out: Path, data: str, method: str, views: int | str, seed: int) -> Path:
    """``<out>/runs/<scene-slug>/<method>/v<views>-s<seed>``."""
    return Path(out) / "runs" / scene_slug(data) / method / f"v{views}-s{seed}"


def parse_views(value: Any) -> int | str:
    """``3`` / ``"3"`` -> 3, ``"all"`` -> "all"."""
    if isinstance(value, bool):
        raise SweepError(f"views: {value!r} is not a view count or 'all'")
    if isinstance(value, int):
        if value < 1:
            raise SweepError(f"views: {value} must be at least 1")
        return value
    text = str(value).strip().lower()
    if text == "all":
        return "all"
    try:
        return parse_views(int(text))
    except ValueError:
        raise SweepError(f"views: {value!r} is not a view count or 'all'") from None


def _as_list(key: str, value: Any) -> list:
    if isinstance(value, (list, tuple)):
        return list(value)
    if isinstance(value, (str, int)):
        return [value]
    raise SweepError(f"{key}: expected a value or a list, got {type(value).__name__}")


def _as_int(key: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, str)):
        raise SweepError(f"{key}: {value!r} is not an integer")
    try:
        return int(value)
    except ValueError:
        raise SweepError(f"{key}: {value!r} is not an integer") from None


MAX_GRID_BYTES = 1 << 20
"""Largest grid file read (1 MiB: a grid is a few lines)."""


def read_grid_text(path: Path) -> str:
    """The text of a grid file: a regular file (never a FIFO or device, which could block),
    at most :data:`MAX_GRID_BYTES`, UTF-8 (a binary or UTF-16 file is a :class:`SweepError`)."""
    import os
    import stat

    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            raise SweepError(f"{path}: not a regular file (a grid file is a .toml or .json text file)")
        if st.st_size > MAX_GRID_BYTES:
            raise SweepError(f"{path}: {st.st_size} bytes, more than a grid file's {MAX_GRID_BYTES}")
        data = path.read_bytes()
    except OSError as e:
        raise SweepError(f"{path}: cannot read grid file ({e.strerror or e})") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise SweepError(f"{path}: not a UTF-8 text file (byte {e.start}: binary or UTF-16?)") from None


def load_grid_file(path: Path) -> dict:
    """Settings of a grid file (``.toml`` or ``.json``), validated and normalised.

    Keys: methods, data, views, seeds (a value or a list each), steps, overrides
    (nested config overrides applied to every run, e.g. ``[overrides.model]``),
    out, workers, threads, backend, address, mem_per_run_gb.
    """
    path = Path(path)
    text = read_grid_text(path)
    try:
        if path.suffix.lower() == ".json":
            doc = json.loads(text)
        else:
            import tomllib

            doc = tomllib.loads(text)
    except (ValueError, RecursionError) as e:  # TOMLDecodeError and JSONDecodeError are ValueErrors
        raise SweepError(f"{path}: not valid {'JSON' if path.suffix.lower() == '.json' else 'TOML'} ({e})") from None
    if not isinstance(doc, dict):
        raise SweepError(f"{path}: the grid must be a table/object")
    unknown = sorted(set(doc) - GRID_KEYS)
    if unknown:
        raise SweepError(f"{path}: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(GRID_KEYS))})")
    try:
        return normalise_settings(doc)
    except SweepError as e:
        raise SweepError(f"{path}: {e}") from None


def _as_str(key: str, value: Any) -> str:
    if not isinstance(value, str):
        raise SweepError(f"{key}: {value!r} is not a string")
    return value


def _as_positive_float(key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise SweepError(f"{key}: {value!r} is not a number")
    try:
        x = float(value)
    except ValueError:
        raise SweepError(f"{key}: {value!r} is not a number") from None
    if not math.isfinite(x) or x <= 0:
        raise SweepError(f"{key}: {value!r} must be a finite number > 0")
    return x


def normalise_settings(doc: dict) -> dict:
    """Type-check and normalise grid settings (values None are left out); a wrongly typed
    value is a :class:`SweepError` naming its key."""
    s: dict[str, Any] = {}
    for key, value in doc.items():
        if value is None:
            continue
        if key in ("methods", "data"):
            s[key] = [_as_str(key, x) for x in _as_list(key, value)]
        elif key == "views":
            s[key] = [parse_views(x) for x in _as_list(key, value)]
        elif key == "seeds":
            s[key] = [_as_int(key, x) for x in _as_list(key, value)]
            if any(not 0 <= x < 2**32 for x in s[key]):
                raise SweepError(f"{key}: {value!r}: a seed is in [0, 2^32)")
        elif key in ("steps", "workers", "threads"):
            n = _as_int(key, value)
            if n < 1:
                raise SweepError(f"{key}: {n} must be at least 1")
            s[key] = n
        elif key == "overrides":
            if not isinstance(value, dict):
                raise SweepError("overrides: expected a table of config overrides")
            s[key] = value
        elif key == "backend":
            if value not in BACKENDS:
                raise SweepError(f"backend: '{value}' is not one of {', '.join(BACKENDS)}")
            s[key] = value
        elif key == "mem_per_run_gb":
            s[key] = _as_positive_float(key, value)
        else:
            s[key] = _as_str(key, value)
    return s


def parse_override(text: str) -> dict:
    """``model.init.num_points=300`` -> ``{"model": {"init": {"num_points": 300}}}`` (value JSON, else string)."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise SweepError(f"--override {text!r}: expected KEY=VALUE, e.g. model.lambda_rg=0.0")
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw
    out: dict = {}
    node = out
    parts = key.strip().split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
    node[parts[-1]] = value
    return out
