"""The terminal: one-line messages, the progress of each phase of a command and the end-of-run
summary table (rich).

Messages and progress go to stderr (``console``); the summary table to stdout. Every long step of a
command (loading data, matching, the SCGaussian warm-up, compiling kernels, training, evaluation,
``splat-process``'s steps) runs inside :func:`phase`, one mechanism for all: a live row in a
terminal, plain lines at a steady cadence in a log. A run's log file (:func:`add_log`) gets the
plain lines whatever the terminal shows: every message, each phase's lines as a log would, the
summary table.
"""

from __future__ import annotations

import io
import math
import re
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator, Sequence

from rich import box
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Column, Table
from rich.text import Text

from .runtime.threads import follow_load

console = Console(stderr=True)

_LOGS: list[Callable[[str], None]] = []
"""The open logs (a run's log file): each takes one line (no newline) of every message and phase."""


def add_log(write: Callable[[str], None]) -> None:
    """From now on, also hand every line a log would hold to ``write`` (one line, no newline):
    messages, plain progress lines of each phase (whatever the terminal shows), the summary table."""
    _LOGS.append(write)


def remove_log(write: Callable[[str], None]) -> None:
    """Stop handing lines to ``write`` (:func:`add_log`)."""
    if write in _LOGS:
        _LOGS.remove(write)


def _log(text: str) -> None:
    for write in list(_LOGS):
        for line in text.splitlines() or [""]:
            write(line)


def say(message: str, style: str | None = None) -> None:
    """One line on stderr, never wrapped, never parsed as markup (and in the open logs)."""
    console.print(Text(message, style=style or ""), soft_wrap=True)
    _log(message)


PLAIN_EVERY_S = 5.0
"""Without a terminal: the most seconds between two progress lines of a running phase."""
PLAIN_EVERY_FRACTION = 0.05
"""Without a terminal: a phase with a known total also prints a line each time this fraction of it is done."""
PLAIN_QUIET_S = 2.0
"""Without a terminal: a phase prints nothing before it has run this long (a quick phase, or a failed
start, leaves no progress lines; the error stays one line)."""

ETA_AFTER_UNITS = 10
"""A phase shows its remaining time once this many units are done since its clock started..."""
ETA_AFTER_FRACTION = 0.05
"""... or this fraction of its total, whichever comes first."""

_SHOW = {"enabled": True}


def show_progress(enabled: bool) -> None:
    """Whether phases show their progress from now on (``--progress``, on by default); messages
    (:func:`say`) are printed either way."""
    _SHOW["enabled"] = bool(enabled)


class Phase:
    """One phase of a command (loading data, matching, warm-up, compiling, training, evaluation) and
    its progress, shown by :func:`phase`: call :meth:`advance` or :meth:`update` as work is done."""

    def __init__(self, name: str, total: int | None, completed: int, unit: str, info: str, quiet_s: float,
                 clock_from_first: bool = False, costs: Sequence[tuple[int, float]] = ()):
        self.name, self.total, self.completed, self.unit, self.info = name, total, completed, unit, info
        self.costs = sorted((int(end), float(cost)) for end, cost in costs if cost > 0)
        """(end, relative cost): the units before ``end`` (and from the previous end on) each cost ``cost``
        (training: the coarse steps 0.5, the full-size ones 1); empty: every unit alike."""
        self.segment_started: tuple[int, float] | None = None  # (units, time) when the current segment's clock began
        self.updated_at = time.perf_counter()  # when the units done last changed
        self.quiet_s = quiet_s
        self.start_completed = completed
        self.t0 = time.perf_counter()
        self.clock_from_first = clock_from_first  # restart the clock once the first unit is done
        self.printed_at: float | None = None  # plain display: when its last line was printed
        self.printed_completed = completed
        self.display: _Terminal | _Plain | None = None
        self.log_display: _Plain | None = None  # the open logs' lines, when the display's do not reach them
        self.task = None  # the terminal display's rich task

    def advance(self, n: int = 1) -> None:
        """``n`` more units done."""
        self.update(self.completed + n)

    def update(self, completed: int | None = None, *, info: str | None = None) -> None:
        """Set the units done and/or the info text (e.g. the training loss)."""
        if completed is not None:
            if self.clock_from_first and completed > self.start_completed:
                self.clock_from_first = False  # the first unit (lazy loads, kernel builds) is behind us
                self.t0, self.start_completed = time.perf_counter(), completed
                self.segment_started = None
                for display in (self.display, self.log_display):
                    if display is not None:
                        display.restart(self)
            if self.costs and not self.clock_from_first:
                self._follow_segments(completed)
            self.completed = completed
            self.updated_at = time.perf_counter()
        if info is not None:
            self.info = info
        follow_load()  # every phase's threads follow the machine's load (runtime.threads)
        for display in (self.display, self.log_display):
            if display is not None:
                display.changed(self)

    def eta_due(self) -> bool:
        """Whether a remaining time is worth showing: after 10 units or 5 % of the total, whichever
        comes first, since the clock started (an estimate from 3 steps misleads)."""
        needed = max(1, min(ETA_AFTER_UNITS, math.ceil(ETA_AFTER_FRACTION * (self.total or 0))))
        return self.total is not None and self.completed - self.start_completed >= needed

    def _cost(self, unit: int) -> float:
        """The relative cost of unit ``unit`` (:attr:`costs`)."""
        return next((c for end, c in self.costs if unit < end), self.costs[-1][1] if self.costs else 1.0)

    def _cost_between(self, a: int, b: int) -> float:
        """The summed cost of the units ``a`` to ``b - 1``."""
        total, start = 0.0, 0
        for end, cost in self.costs:
            total += cost * max(0, min(b, end) - max(a, start))
            start = end
        return total + self.costs[-1][1] * max(0, b - max(a, start)) if self.costs else float(max(0, b - a))

    def _follow_segments(self, completed: int) -> None:
        """Start the segment clock anew at the first update that reaches a unit of another cost."""
        if self.segment_started is None:
            self.segment_started = (self.start_completed, self.t0)
        elif completed > self.completed and self._cost(completed - 1) != self._cost(self.segment_started[0]):
            self.segment_started = (self.completed, self.updated_at)  # the units since the last update are the new kind's

    def remaining_seconds(self) -> float | None:
        """The time the units left should take, the unit under way counted. The finished units give
        the seconds per unit, each unit weighted by its cost (:attr:`costs`: the full-size training
        steps after the coarse ones take about twice as long, not as long as the coarse ones did;
        the current segment's own rate once 10 of its units are done). The unit under way has run
        for some of its share: that time is taken off, so the estimate counts down between units;
        once it has run longer than its share, it counts as done now and the rate it then makes
        prices the units after it, so the estimate grows while it runs late (a pair of photos that
        matches slowly). None before any unit."""
        if self.total is None or self.completed <= self.start_completed:
            return None
        if self.completed >= self.total:
            return 0.0
        span_units, span_t = self.start_completed, self.t0
        if self.costs and self.segment_started is not None and self.completed - self.segment_started[0] >= ETA_AFTER_UNITS:
            span_units, span_t = self.segment_started  # seconds per unit of cost, measured in this segment
        done_cost = self._cost_between(span_units, self.completed)
        if done_cost <= 0 or self.updated_at <= span_t:
            return None
        per_cost = (self.updated_at - span_t) / done_cost
        now = time.perf_counter()
        running, current = max(0.0, now - self.updated_at), self._cost(self.completed)
        left = self._cost_between(self.completed, self.total)
        if running <= per_cost * current:
            return per_cost * left - running
        return (now - span_t) / (done_cost + current) * (left - current)

    def rate(self) -> float | None:
        """Units per second since the phase began (None before the first unit)."""
        done, dt = self.completed - self.start_completed, time.perf_counter() - self.t0
        return done / dt if done > 0 and dt > 0 else None

    def line(self, done: bool = False) -> str:
        """The plain one-line status: ``NAME: 120/1000 (12%), 0:00:12, 9.8 it/s, about 0:01:30 left, INFO``."""
        elapsed = time.perf_counter() - self.t0
        parts = []
        if self.total:
            parts.append(f"{self.completed}/{self.total}{' ' + self.unit if self.unit else ''}"
                         + ("" if done else f" ({100 * self.completed // max(self.total, 1)}%)"))
        parts.append(("done in " if done else "") + _clock(elapsed))
        rate = self.rate()
        if rate:
            parts.append(_speed(rate, self.unit))
            left = self.remaining_seconds() if self.total and not done and self.completed < self.total else None
            if left is not None and self.eta_due():
                parts.append(f"about {_clock(left)} left")
        if self.info:
            parts.append(self.info)
        return f"{self.name}: " + ", ".join(parts)


PROGRESS_LINE = re.compile(r"^[^:]+: (\d+/\d+[^,]*, )?(done in )?\d+:\d\d:\d\d\b")
"""What :meth:`Phase.line` prints, for readers of a log (the CLI tests): ``NAME: [DONE/TOTAL UNIT (P%),
]H:MM:SS[, ...]`` or ``NAME: [DONE/TOTAL UNIT, ]done in H:MM:SS[, ...]``."""


def _speed(rate: float, unit: str) -> str:
    """``12.34 it/s`` (steps, iterations), ``3.1 images/s`` (other units)."""
    per = "it" if unit in ("", "steps", "iterations") else unit
    return f"{rate:.2f} {per}/s" if rate < 100 else f"{rate:.0f} {per}/s"


def _clock(seconds: float) -> str:
    s = int(seconds)
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"


@contextmanager
def phase(name: str, total: int | None = None, *, completed: int = 0, unit: str = "", info: str = "",
          quiet_s: float = PLAIN_QUIET_S, clock_from_first: bool = False,
          costs: Sequence[tuple[int, float]] = ()) -> Iterator[Phase]:
    """Show one phase of a command while the block runs; yields its :class:`Phase` to report progress.

    In a terminal: a live row (name, bar, done/total, elapsed, remaining, rate, info) under any
    outer phase's, replaced by one summary line when the phase ends. Without a terminal (a log file,
    nohup, CI): plain lines, the first after ``quiet_s`` seconds, then one every
    :data:`PLAIN_EVERY_S` seconds or :data:`PLAIN_EVERY_FRACTION` of ``total``, whichever comes first,
    and the summary line (if any line was printed, or ``quiet_s`` is 0). A phase that fails prints
    no summary (its error does). Nothing is shown after ``show_progress(False)``. The remaining
    time shows once :meth:`Phase.eta_due`; with ``clock_from_first`` (training) the elapsed time
    and the rate start when the first unit is done, so what that unit waited for (building
    kernels, loading them) is its own phase and not part of the training clock. ``costs``: units of
    unlike cost, as (end, relative cost) (:meth:`Phase.remaining_seconds`)."""
    ph = Phase(name, total, completed, unit, info, quiet_s, clock_from_first, costs)
    if _SHOW["enabled"]:
        ph.display = _TERMINAL if console.is_terminal else _PLAIN
        ph.display.open(ph)
    if _LOGS and ph.display is not _PLAIN:  # the plain display's lines reach the logs through say()
        ph.log_display = _LOG_PLAIN
        ph.log_display.open(ph)
    ok = False
    try:
        yield ph
        ok = True
    finally:
        for display in (ph.display, ph.log_display):
            if display is not None:
                display.close(ph, ok)


@contextmanager
def starting(*, compiler: bool = False) -> Iterator[None]:
    """The start of a command that loads or trains a model, as a phase of its own: importing PyTorch
    takes 3-6 s on a 2-core CPU (and its compiler, which every optimiser's first use imports, 2 s
    more), which would otherwise be a silence at launch. The caller does its own heavy imports inside."""
    with phase("starting", info="loading PyTorch"), _interrupts_held():
        import torch  # noqa: F401

        if compiler:
            import torch._dynamo  # noqa: F401
        yield


@contextmanager
def _interrupts_held() -> Iterator[None]:
    """Ctrl-C and SIGTERM noted, not acted on, during the block, and acted on as it ends (the handlers
    that were in place, called then): a stop landing inside PyTorch's import left a half-initialised
    module whose errors replaced the command's one-line stop message with a traceback. Only the main
    thread may set handlers; elsewhere a no-op."""
    import signal

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    noted: list[int] = []
    before = {sig: signal.signal(sig, lambda signum, frame: noted.append(signum)) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in before.items():
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)  # None: a handler not set from Python
        if noted:  # one stop: the first, handled as it would have been
            signal.raise_signal(noted[0])


def track(items: Sequence, name: str, unit: str = "") -> Iterator:
    """Iterate ``items`` inside ``phase(name, len(items))``, one unit per item."""
    with phase(name, len(items), unit=unit) as ph:
        for item in items:
            yield item
            ph.advance()


class _Terminal:
    """Live rows (rich) on the terminal, one per open phase; finished phases leave a summary line."""

    def __init__(self):
        self.progress: Progress | None = None

    def open(self, ph: Phase) -> None:
        if self.progress is None:
            self.progress = _Rows(console=console, transient=True)
            self.progress.start()
        ph.task = self.progress.add_task(ph.name, total=ph.total, completed=ph.completed, info=ph.info, unit=ph.unit,
                                         phase=ph)

    def changed(self, ph: Phase) -> None:
        if self.progress is not None:
            self.progress.update(ph.task, completed=ph.completed, info=ph.info)

    def restart(self, ph: Phase) -> None:
        if self.progress is not None:
            self.progress.reset(ph.task, start=True, completed=ph.start_completed)

    def close(self, ph: Phase, ok: bool) -> None:
        if self.progress is None:
            return
        self.progress.remove_task(ph.task)
        self.progress.refresh()  # the finished row goes before its summary line is printed above the rows
        if ok:  # the terminal's only: a log's summary line comes from its own display
            console.print(Text(ph.line(done=True), style="dim"), soft_wrap=True)
        if not self.progress.tasks:
            self.progress.stop()
            self.progress = None


class _Rows(Progress):
    """The live rows, one table each so that one phase's long name does not squeeze another's
    columns; the time columns come before the info text, which is cut first (80 columns fit)."""

    def __init__(self, **kwargs):
        name = TextColumn("[bold]{task.description}", table_column=Column(no_wrap=True, overflow="ellipsis", max_width=NAME_WIDTH))
        info = TextColumn("{task.fields[info]}", table_column=Column(no_wrap=True, overflow="ellipsis", ratio=1))
        bar = BarColumn(bar_width=10)
        self.sized = (name, bar, _CountColumn(), TimeElapsedColumn(), _RemainingColumn(), _SpeedColumn(), info)
        long_name = TextColumn("[bold]{task.description}", table_column=Column(no_wrap=True, overflow="ellipsis", ratio=1))
        self.unsized = (long_name, bar, TimeElapsedColumn())
        super().__init__(*self.sized, expand=True, **kwargs)

    def get_renderables(self):
        for task in self.tasks:
            columns = self.sized if task.total is not None else self.unsized
            table = Table.grid(*(c.get_table_column().copy() for c in columns), padding=(0, 1), expand=True)
            table.add_row(*(c(task) for c in columns))
            yield table


NAME_WIDTH = 22
"""Terminal columns for a phase's name in a row with a bar and counts (longer names are cut)."""


class _CountColumn(TextColumn):
    def __init__(self):
        super().__init__("")

    def render(self, task):
        return Text(f"{task.completed:.0f}/{task.total:.0f}" if task.total is not None else "")


class _RemainingColumn(TextColumn):
    """The phase's remaining time, estimated anew at each refresh (the unit under way counted:
    :meth:`Phase.remaining_seconds`), not only when a unit ends."""

    def __init__(self):
        super().__init__("")

    def render(self, task):
        ph = task.fields.get("phase")
        due = ph is not None and task.total is not None and not task.finished and ph.eta_due()
        left = ph.remaining_seconds() if due else None
        return Text(f"~{_clock(left)}" if left is not None else "", style="progress.remaining")


class _SpeedColumn(TextColumn):
    def __init__(self):
        super().__init__("")

    def render(self, task):
        speed = task.finished_speed or task.speed
        return Text(_speed(speed, task.fields["unit"]) if speed else "", style="progress.data.speed")


class _Plain:
    """Plain progress lines for a log, each handed to ``emit``: a background thread prints the
    innermost phase when it has gone quiet (a compilation inside the training phase: its lines, not
    the waiting training's)."""

    def __init__(self, emit: Callable[[str], None] = say):
        self.emit = emit
        self.lock = threading.RLock()
        self.open_phases: list[Phase] = []
        self.thread: threading.Thread | None = None

    def open(self, ph: Phase) -> None:
        with self.lock:
            self.open_phases.append(ph)
            if self.thread is None or not self.thread.is_alive():
                self.thread = threading.Thread(target=self._tick, name="splat-progress", daemon=True)
                self.thread.start()

    def changed(self, ph: Phase) -> None:
        now = time.perf_counter()
        due = ph.total and ph.completed - ph.printed_completed >= PLAIN_EVERY_FRACTION * ph.total
        if ph.completed != ph.total and self._due(ph, now, bool(due)):  # the end has its summary line
            self._print(ph, now)

    def _due(self, ph: Phase, now: float, progressed: bool, ahead: float = 0.0) -> bool:
        """Whether ``ph`` prints a line at ``now``; ``ahead``: the ticker's period, so a heartbeat that
        would be late at the next tick prints at this one (lines at most PLAIN_EVERY_S apart)."""
        if now - ph.t0 < ph.quiet_s:
            return False
        if ph.printed_at is None:
            return True
        return progressed or now + ahead - ph.printed_at >= PLAIN_EVERY_S

    def restart(self, ph: Phase) -> None:
        """The clock restarted: a plain line needs nothing (each line reads the phase's clock)."""

    def _print(self, ph: Phase, now: float) -> None:
        with self.lock:
            ph.printed_at, ph.printed_completed = now, ph.completed
            self.emit(ph.line())

    def close(self, ph: Phase, ok: bool) -> None:
        with self.lock:
            self.open_phases.remove(ph)
            if ok and (ph.printed_at is not None or ph.quiet_s == 0):
                self.emit(ph.line(done=True))

    def _tick(self) -> None:
        while True:
            period = min(1.0, PLAIN_EVERY_S / 4)
            time.sleep(period)
            with self.lock:
                if not self.open_phases:
                    self.thread = None
                    return
                now, ph = time.perf_counter(), self.open_phases[-1]  # the innermost: the outer ones wait for it
                if self._due(ph, now, False, ahead=period):
                    self._print(ph, now)


_TERMINAL = _Terminal()
_PLAIN = _Plain(say)
_LOG_PLAIN = _Plain(_log)

def print_summary(metrics: dict, run_dir: Path) -> None:
    """The final rich table: test metrics, Gaussian count and time per phase."""
    table = Table(title=f"{metrics['method']} on {metrics['data']}")
    table.add_column("metric")
    table.add_column("value", justify="right")
    split = next((v.get("split", "test") for v in metrics.get("per_view") or []), "test")
    missing = [k for k, v in metrics["mean"].items() if v is None]  # explained below the table, not shown as n/a
    for k, v in metrics["mean"].items():
        if v is not None:
            table.add_row(f"{split} {k}", f"{v:.4f}")
    table.add_row("gaussians", str(metrics["num_gaussians"]))
    table.add_row("steps", str(metrics["steps"]))
    if metrics.get("skipped_steps"):
        table.add_row("skipped steps", str(metrics["skipped_steps"]))
    if metrics.get("render_fps"):
        table.add_row("render fps", f"{metrics['render_fps']:.1f}")
    if metrics.get("rasterizer"):
        table.add_row("rasterizer", metrics["rasterizer"])
    for k, v in metrics["timing"].items():
        table.add_row(k, f"{v:.1f}")
    if st := metrics.get("step_times"):
        ratio = f", {st['max_over_median']:.1f}x median" if st["max_over_median"] else ""
        table.add_row("slowest step", f"{st['max_s']:.2f} s at {st['slowest_step']}{ratio}")
    table.add_row("run folder", str(run_dir))
    Console().print(table)
    if _LOGS:
        text = io.StringIO()
        table.box = box.ASCII  # a log's table in plain characters
        Console(file=text, width=100, color_system=None).print(table)
        _log(text.getvalue().rstrip("\n"))
    if split == "train":
        say("Training-view metrics: the scene has no held-out test view (every photo is a training view; "
            "--test-every K holds out every K-th); splat-render RUN --path auto renders a video of novel views", "yellow")
    for line in _missing_metric_lines(missing, metrics.get("lpips_note")):
        say(line, "yellow")


def _missing_metric_lines(missing: list[str], lpips_note: str | None) -> list[str]:
    """Why the summary table leaves out each metric it could not compute: one line per reason."""
    reasons: dict[str, list[str]] = {}
    for k in missing:
        if k.startswith("lpips"):
            why = lpips_note or "not computed"
        elif k == "avg":
            why = "AVG combines PSNR, SSIM and LPIPS, and LPIPS was not computed"
        elif k.startswith("depth"):
            why = "the dataset has no ground-truth depth (the built-in scenes have)"
        else:
            why = "not computed for this run"
        reasons.setdefault(why, []).append(k)
    return [f"not in the table: {', '.join(keys)}: {why}" for why, keys in reasons.items()]
