"""What a user sees while a command runs (console.phase) and the start-up papercuts of issue 42:
phase lines in a log, no NaN placeholders, a double Ctrl-C that says what was saved, no empty run
folder after a failed start, "did you mean", a resume refusal naming only the changed fields, the
README's comparison at equal iterations, rows that fit 80 columns."""

from __future__ import annotations

import io
import json
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rich.console import Console

from cli_harness import cli_env, message_lines, run_cli
from splat_framework import console as console_mod
from tiers import seed_kernels

README = Path(__file__).resolve().parents[2] / "README.md"


@pytest.fixture
def terminal(monkeypatch):
    """The console as an 80-column terminal; yields the buffer it writes to."""
    buf = io.StringIO()
    monkeypatch.setattr(console_mod, "console", Console(file=buf, force_terminal=True, width=80, color_system=None))
    monkeypatch.setattr(console_mod, "_SHOW", {"enabled": True})
    return buf


def test_terminal_rows_keep_their_time_columns_in_80_columns(terminal):
    """Each phase is a row of its own; at 80 columns the count, elapsed and remaining time and the
    rate are whole (the info text is what gets cut), even beside a phase with a long name."""
    with console_mod.phase("training", 30000, unit="steps", info="loss 0.0123  PSNR 23.45  123456 gaussians") as ph:
        for k in range(1, 4):
            time.sleep(0.05)
            ph.update(1000 * k)
        with console_mod.phase("compiling the rasterizer kernels (forward), about 60 s the first time"):
            screen = Console(file=io.StringIO(), width=80, color_system=None, force_terminal=True)
            for row in console_mod._TERMINAL.progress.get_renderables():
                screen.print(row)
    rows = screen.file.getvalue().splitlines()
    assert len(rows) == 2 and all(len(r) <= 80 for r in rows), rows
    assert re.search(r"3000/30000 0:00:00 ~\d:\d\d:\d\d [\d.]+ it/s loss", rows[0]), rows[0]
    assert rows[1].startswith("compiling the rasterizer kernels") and rows[1].endswith("0:00:00"), rows[1]
    done = terminal.getvalue()  # each finished phase leaves one summary line
    assert "compiling the rasterizer kernels (forward), about 60 s the first time: done in" in done
    assert "training: 3000/30000 steps, done in" in done


def test_a_log_gets_a_line_every_few_seconds_or_5_percent(monkeypatch):
    """Without a terminal: a phase that reports no progress (a compilation, COLMAP's mapping) still
    prints a line every PLAIN_EVERY_S; one that counts prints every 5 %; a quick one prints nothing."""
    buf = io.StringIO()
    monkeypatch.setattr(console_mod, "console", Console(file=buf, force_terminal=False, width=200))
    monkeypatch.setattr(console_mod, "_SHOW", {"enabled": True})
    monkeypatch.setattr(console_mod, "PLAIN_EVERY_S", 0.2)
    with console_mod.phase("quick"):
        pass
    with console_mod.phase("silent", quiet_s=0.1):
        time.sleep(2.0)  # the ticker of an earlier test may be in a sleep of up to 1 s when the phase opens
    # the counted lines come from the 5 % steps only (a loaded machine may not advance 100 steps within 0.2 s)
    monkeypatch.setattr(console_mod, "PLAIN_EVERY_S", 60.0)
    with console_mod.phase("counted", 100, quiet_s=0) as ph:
        for _ in range(100):
            ph.advance()
    lines = buf.getvalue().splitlines()
    assert not any(ln.startswith("quick") for ln in lines), lines
    silent = [ln for ln in lines if ln.startswith("silent: 0:00:0")]
    assert len(silent) >= 2 and lines.count(next(ln for ln in lines if ln.startswith("silent: done in"))) == 1, lines
    counted = [ln for ln in lines if ln.startswith("counted: ")]
    assert counted[0].startswith("counted: 1/100 (1%)") and counted[-1].startswith("counted: 100/100, done in")
    assert 19 <= len(counted) <= 22, counted  # the first, every 5 %, the summary


def test_the_ticker_prints_a_heartbeat_that_would_be_late_at_its_next_tick():
    """The plain ticker wakes every `period` s: a heartbeat due before its next wake-up prints now,
    so two lines of a silent phase are at most PLAIN_EVERY_S apart, not PLAIN_EVERY_S + period
    (the 5.9 s silences the first-hour benchmark measured inside a matching phase)."""
    from types import SimpleNamespace

    plain, every, period = console_mod._Plain(), console_mod.PLAIN_EVERY_S, 1.0
    ph = SimpleNamespace(t0=0.0, quiet_s=2.0, printed_at=10.0)
    assert not plain._due(ph, 10.0 + every - period - 0.01, False, ahead=period)
    assert plain._due(ph, 10.0 + every - period + 0.01, False, ahead=period)
    assert not plain._due(ph, 10.0 + every - 0.01, False)  # a progress update never looks ahead
    assert not plain._due(SimpleNamespace(t0=0.0, quiet_s=2.0, printed_at=None), 1.5, False, ahead=period)


def test_a_commands_start_is_a_phase_and_the_cli_harness_reads_errors_past_it(monkeypatch):
    """Importing PyTorch takes 3-6 s on a 2-core CPU: ``starting`` (the first phase of splat-train,
    -eval, -export, -render) shows it like any phase, so a log hears from a command within 2 s of its
    arguments being read; the CLI tests' one-line error is the one line besides such progress."""
    buf = io.StringIO()
    monkeypatch.setattr(console_mod, "console", Console(file=buf, force_terminal=False, width=200))
    monkeypatch.setattr(console_mod, "_SHOW", {"enabled": True})
    with console_mod.starting():
        time.sleep(console_mod.PLAIN_QUIET_S + 1.2)
    lines = buf.getvalue().splitlines()
    assert lines[0].startswith("starting: 0:00:0") and lines[0].endswith(", loading PyTorch"), lines
    assert lines[-1].startswith("starting: done in 0:00:0"), lines
    error = "error: runs/x: is not empty and is not a run folder written by splat-train"
    assert message_lines(buf.getvalue() + "\n" + error + "\n") == [error]
    assert message_lines("training: 3/60 steps (5%), 0:00:01, 2.1 it/s\nwarning: a.png: dark") == ["warning: a.png: dark"]


def test_a_stop_while_pytorch_is_imported_is_acted_on_once_the_imports_end():
    # a SIGTERM landing inside torch's import left a half-initialised module, and a traceback instead of the stop's line
    before = signal.signal(signal.SIGINT, signal.default_int_handler)  # a command's (an xdist worker ignores SIGINT)
    try:
        handlers = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
        reached = []
        with pytest.raises(KeyboardInterrupt):
            with console_mod.starting():
                signal.raise_signal(signal.SIGINT)
                signal.raise_signal(signal.SIGINT)
                reached.append("the rest of the imports")
        assert reached == ["the rest of the imports"]
        assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == handlers  # as they were
    finally:
        signal.signal(signal.SIGINT, before)


def test_the_training_clock_starts_at_the_first_step_and_no_eta_before_10_steps(terminal):
    """Issue 61: what the first step waited for (building or loading kernels) is not on the training
    clock, and no remaining time is guessed from a handful of steps (10, or 5 % of the total)."""
    with console_mod.phase("training", 1000, unit="steps", quiet_s=0, clock_from_first=True) as ph:
        time.sleep(1.2)  # the first step: a kernel build
        ph.update(1)
        assert ph.line().startswith("training: 1/1000 steps (0%), 0:00:00") and "left" not in ph.line()
        for k in range(2, 11):
            ph.update(k)
            assert "left" not in ph.line(), ph.line()
        time.sleep(0.01)
        ph.update(11)
        assert re.search(r"it/s, about \d:\d\d:\d\d left", ph.line()), ph.line()
        rows = [r for r in console_mod._TERMINAL.progress.get_renderables()]
        screen = Console(file=io.StringIO(), width=100, color_system=None, force_terminal=True)
        for row in rows:
            screen.print(row)
        assert re.search(r"11/1000 0:00:00 ~\d:\d\d:\d\d", screen.file.getvalue()), screen.file.getvalue()
    with console_mod.phase("matching", 4, unit="pairs", quiet_s=0) as ph:  # 5 % of 4 pairs: after the first
        ph.update(1)
        assert "left" in ph.line()


def test_the_summary_leaves_out_what_it_could_not_compute_and_says_why(capsys, monkeypatch, tmp_path):
    monkeypatch.setattr(console_mod, "console", Console(file=sys.stderr, width=200))
    metrics = {"method": "3dgs", "data": "photos", "num_gaussians": 10, "steps": 2, "timing": {"total_s": 1.0},
               "mean": {"psnr": 20.0, "ssim": 0.5, "lpips": None, "lpips_alex": None, "avg": None, "st_lpips": 0.7,
                        "depth_abs_rel": None}, "lpips_note": "package 'lpips' is not installed"}
    console_mod.print_summary(metrics, tmp_path)
    out = capsys.readouterr()
    assert "n/a" not in out.out and "test psnr" in out.out and "test lpips" not in out.out
    assert out.err.splitlines() == [
        "not in the table: lpips, lpips_alex: package 'lpips' is not installed",
        "not in the table: avg: AVG combines PSNR, SSIM and LPIPS, and LPIPS was not computed",
        "not in the table: depth_abs_rel: the dataset has no ground-truth depth (the built-in scenes have)"]


def test_the_first_compiled_kernel_call_is_a_phase_of_its_own(terminal):
    """The kernel compilation (torch.compile's first call) is announced once per kernel."""
    import torch

    from splat_framework.render._kernels import _with_fallback

    calls = []
    run = _with_fallback(lambda *a: calls.append("compiled") or "c", lambda *a: "e", 0, "forward")
    active = torch.zeros(2)  # two active tiles: the compiled path
    assert run(active) == "c" and run(active) == "c" and calls == ["compiled", "compiled"]
    assert terminal.getvalue().count("compiling the rasterizer kernels (forward) for this process: done") == 1


def test_building_a_model_from_start_points_is_a_phase_and_loading_one_is_not(terminal):
    """Building the rows from many start points (nearest-neighbour scales: 18.9 s without a line for
    SCGaussian's 680k rows) is a phase of its own; rebuilding a trained model from its rows is not."""
    import torch

    from splat_framework.config import RunFacts
    from splat_framework.model.gaussians import GaussianModel
    from splat_framework.registry import get_method

    cfg = get_method("3dgs").default_config()
    model = GaussianModel(cfg.model, RunFacts.of(cfg), 1.0, torch.rand(50, 3), torch.rand(50, 3))
    assert terminal.getvalue().count("building the model: done") == 1
    GaussianModel(cfg.model, RunFacts.of(cfg), 1.0, None, None, rows={k: v.detach() for k, v in model.params.items()})
    assert terminal.getvalue().count("building the model: done") == 1


@pytest.mark.bad_input("Ctrl-C twice during a training step", "exit 130 at once; the last line says what is on disk (the newest checkpoint, or that nothing was saved)")
def test_a_log_shows_every_phase_and_a_double_ctrl_c_says_nothing_was_saved(tmp_path):
    """splat-train into a pipe (a log): the training phase prints plain lines from its first steps,
    never a NaN placeholder, and with SPLAT_COMPILE=0 no compile line. Ctrl-C (a real SIGINT)
    says that the run stops after the step with a checkpoint; a second one before that stops at
    once, exit 130, and the last line says that nothing was saved."""
    from splat_framework.data.synthetic import ensure_scene

    data = ensure_scene("forward-tiny")
    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "splat_framework.cli.train", "3dgs", "--data", str(data), "--steps", "200",
           "--output", str(run), "--checkpoint-every", "0", "--model.init.num-points", "300000"]
    # 300,000 Gaussians: a step of about 0.75 s (eager), so that the second Ctrl-C lands inside the
    # step the first one interrupted (with 20,000, a 0.16 s step, a loaded machine lost the race)
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            env=cli_env(SPLAT_COMPILE="0"), stdin=subprocess.DEVNULL)
    seen = []
    try:
        for line in proc.stderr:
            seen.append(line)
            if line.startswith("training: "):
                break
        assert seen and seen[-1].startswith("training: "), "".join(seen)
        proc.send_signal(signal.SIGINT)
        for line in proc.stderr:
            seen.append(line)
            if line.startswith("SIGINT: stopping after this step"):
                proc.send_signal(signal.SIGINT)
                break
        rest = proc.stderr.read()
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    err = "".join(seen) + rest
    shown = f"{shlex.join(cmd)}\nexit {proc.returncode}\n{err}"
    assert proc.returncode == 130, shown
    assert "nan" not in err.lower() and "compiling" not in err and "Traceback" not in err, shown
    assert re.search(r"^training: \d+/200 steps \(\d+%\), 0:00:\d\d", err, re.M), shown
    last = err.strip().splitlines()[-1]
    assert last.startswith("stopped: SIGINT again during step ") and "nothing was saved" in last, shown
    assert not (run / "checkpoints").exists() or not any((run / "checkpoints").iterdir()), shown


@pytest.mark.bad_input("a mistyped `--data` (`llff/fren`, `synthetic/forwrd-tiny`)",
                       "exit 2, one line with \"did you mean\"; no empty run folder left under `outputs/`")
def test_failed_starts_leave_no_run_folder_and_suggest_the_name(tmp_path, monkeypatch):
    """Three mistyped datasets: three one-line errors with a suggestion, and no outputs/ folder left
    behind (in-process); and once through the CLI."""
    from splat_framework.data import DataError
    from splat_framework.engine.trainer import Trainer
    from splat_framework.registry import get_method

    data_root = tmp_path / "data"
    (data_root / "llff" / "fern").mkdir(parents=True)
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.setenv("SPLAT_DATA", str(data_root))
    monkeypatch.chdir(work)
    for typo, hint in [("llff/fren", "llff/fern"), ("lff/fern", "llff/fern"), ("synthetic/forwrd-tiny", "forward-tiny")]:
        cfg = get_method("3dgs").default_config().model_copy(update={"data": typo, "steps": 2, "progress": False})
        with pytest.raises(DataError, match=f"did you mean '{hint}'"):
            Trainer(cfg)
    assert not (work / "outputs").exists()
    run_cli("train", "3dgs", "--data", "llff/fren", "--steps", "2", code=2, match="did you mean 'llff/fern'?",
            watch=[work], cwd=work, env=cli_env(SPLAT_DATA=str(data_root), SPLAT_COMPILE="0"))


@pytest.mark.parametrize("method", ["3dgs", "scgaussian"])
def test_resume_refusal_names_only_the_fields_the_user_changed(tmp_path, method):
    """--resume with another --steps and --seed: the refusal names steps and seed, not the internal
    default_steps nor the schedule fields --steps rescales (scgaussian's opacity decay among them)."""
    from splat_framework.config import resolve_steps, save_config
    from splat_framework.data.run_data import resolve_views
    from splat_framework.registry import get_method

    run = tmp_path / "run"
    run.mkdir()
    cfg = get_method(method).default_config().model_copy(update={"steps": 20, "data": "synthetic/forward-tiny"})
    save_config(resolve_steps(resolve_views(cfg)), run / "config.json")  # as a run records it
    res = run_cli("train", method, "--data", "synthetic/forward-tiny", "--output", run, "--resume",
                  "--steps", "30", "--seed", "1", code=2, match="--resume cannot change the experiment",
                  watch=[run], env=cli_env(SPLAT_COMPILE="0"))
    changed = res.message.split("experiment: ")[1].split(" (resume with")[0]
    assert changed == "--steps (20 -> 30), --seed (0 -> 1)", res.message


@pytest.mark.bad_input("`--resume` without the `--checkpoint-every 5` the run was started with (`--steps 10`)",
                       "exit 2, one line naming the flag with the number typed: `--checkpoint-every (5 -> 3)`")
def test_the_users_own_iteration_counts_are_kept_and_a_refused_resume_names_them_as_typed(tmp_path):
    """Issue 85: ``--steps 10 --checkpoint-every 5`` checkpoints every 5 iterations (a number the user
    typed is not rescaled by --steps; the method's defaults are), and a ``--resume`` that leaves the
    flag out is refused naming it with the typed 5 and the default 3 (1000 rescaled to 10 steps)."""
    run = tmp_path / "run"
    env = cli_env(SPLAT_COMPILE="0")
    run_cli("train", "3dgs", "--data", "synthetic/forward-tiny", "--steps", "10", "--checkpoint-every", "5",
            "--output", run, code=0, env=env)
    saved = json.loads((run / "config.json").read_text())["config"]
    assert (saved["steps"], saved["checkpoint_every"]) == (10, 5)
    assert sorted(p.name for p in (run / "checkpoints").glob("*.ckpt"))[-2:] == ["step-0000005.ckpt", "step-0000010.ckpt"]
    res = run_cli("train", "3dgs", "--data", "synthetic/forward-tiny", "--steps", "10", "--output", run, "--resume",
                  code=2, match="--resume cannot change the experiment", watch=[run], env=env)
    assert "--checkpoint-every (5 -> 3)" in res.message, res.message


def test_the_readme_compares_methods_at_the_same_iterations():
    """The README's commands that train 3dgs and scgaussian on the same scene and views resolve to
    the same number of iterations (3dgs's own default is 3000, scgaussian's 1000 for 3 views)."""
    import tyro

    from splat_framework.cli.train import build_parser_type
    from splat_framework.config import resolve_steps

    runs: dict[tuple, dict[str, int]] = {}
    for line in README.read_text().splitlines():
        words = shlex.split(line.split("#")[0]) if line.startswith("splat-train ") else []
        if len(words) > 1 and words[1] in ("3dgs", "scgaussian"):
            config = resolve_steps(tyro.cli(build_parser_type(asked=words[1], argv=words[1:]), args=words[1:]))
            runs.setdefault((config.data, config.views), {})[words[1]] = config.total_steps
    compared = {k: v for k, v in runs.items() if len(v) == 2}
    assert compared, runs
    for scene, steps in compared.items():
        assert steps["3dgs"] == steps["scgaussian"], (scene, steps)


def test_a_first_run_says_what_it_does_from_the_start_and_its_table_has_no_placeholders(tmp_path):
    """Issue 61, as a user sees it (a subprocess, a log): the summary table shows no `n/a` (what was
    not computed is one line each, with the reason), and a missing relative --data says how to set
    $SPLAT_DATA. (The scene's generation is a phase like any other: a line after 2 s; the tiny
    scene takes less.)"""
    env = cli_env(SPLAT_CACHE=str(seed_kernels(tmp_path / "cache")))
    env.pop("SPLAT_DATA", None)
    res = run_cli("train", "3dgs", "--data", "synthetic/forward-tiny", "--steps", "12", "--output", tmp_path / "run",
                  code=0, env=env)
    assert "n/a" not in res.stdout and "test psnr" in res.stdout
    missing = [ln for ln in res.stderr.splitlines() if ln.startswith("not in the table: ")]
    assert all(": " in ln.removeprefix("not in the table: ") for ln in missing), missing
    run_cli("train", "3dgs", "--data", "llff/fren", code=2, env=env, cwd=tmp_path,
            match="llff/fren: no such dataset folder; a relative name is also looked up under $SPLAT_DATA, which is "
                  "not set: export SPLAT_DATA=/path/to/your/datasets (docs/data.md)")


def test_a_commands_exit_leaves_its_objects_to_the_garbage_collectors_freeze():
    """``run_cli`` freezes what is left when the command returns (``gc.freeze`` as an atexit
    handler, once however many times it runs), so the interpreter's final collections do not walk
    PyTorch's objects: 1-2 s of every command's exit on a 2-core CPU, 3-6 s after training."""
    code = (
        "import atexit, gc\n"
        "atexit.register(lambda: print('frozen', gc.get_freeze_count()))\n"  # LIFO: runs after run_cli's
        "from splat_framework.cli.common import run_cli\n"
        "run_cli(lambda: None)\n"
        "run_cli(lambda: None)\n"
        "print('before exit', gc.get_freeze_count())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=cli_env())
    assert out.returncode == 0, out.stderr
    lines = out.stdout.split("\n")
    assert lines[0] == "before exit 0", out.stdout  # nothing is frozen while the command runs
    frozen = int(lines[1].split()[1])
    assert frozen > 1000, out.stdout  # the modules, configs and everything else left at exit


@pytest.mark.parametrize(("data", "said"), [
    ("llff/fren", "llff/fren: no such dataset folder (did you mean 'llff/fern'?)"),
    ("synthetic/forwad", "synthetic/forwad: unknown synthetic scene (did you mean 'forward'?) (known: forward,"),
])
def test_a_mistyped_data_is_refused_before_pytorch_loads(tmp_path, data, said):
    """``splat-train``'s ``--data`` that names nothing (a folder, a built-in scene): the run's own
    one-line error, with its suggestion, before the ``starting`` phase imports PyTorch (at once, not
    after 3-6 s)."""
    (tmp_path / "llff" / "fern").mkdir(parents=True)
    code = (
        "import sys\n"
        "from splat_framework.cli.train import main\n"
        "try:\n"
        f"    main(['3dgs', '--data', {data!r}, '--steps', '3'])\n"
        "except Exception as e:\n"
        "    print(type(e).__name__, e)\n"
        "print('loaded:', sorted(m for m in ('torch', 'cv2', 'numpy') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env=cli_env(SPLAT_DATA=str(tmp_path)))
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().split("\n")
    assert lines[0].startswith(f"DataError {said}"), out.stdout
    assert lines[1] == "loaded: []", out.stdout


@pytest.mark.bad_input("a mistyped built-in scene (`--data synthetic/forwad`)",
                       "exit 2, one line with \"did you mean\" and the known names, before PyTorch loads (under 2 s)")
def test_a_mistyped_builtin_scene_is_refused_at_once(tmp_path):
    """Through the CLI: one line with the suggestion, in the time of a Python start and the config
    module (0.8 s measured at load 5 on 2 cores, where loading PyTorch alone took 9 s; the bound
    leaves a loaded machine room but not PyTorch's import)."""
    t0 = time.perf_counter()
    run_cli("train", "3dgs", "--data", "synthetic/forwad", "--output", tmp_path / "run", code=2,
            match=("synthetic/forwad: unknown synthetic scene", "did you mean 'forward'?"), watch=[tmp_path])
    assert time.perf_counter() - t0 < 5.0


def test_the_remaining_time_counts_the_unit_under_way(terminal, monkeypatch):
    """Issue 107: 3 pairs, the first matched in 28.5 s: the remaining time counts down while the
    second runs (the terminal's row too, between two updates: not ``~0:00:57`` at 0:00:32 and
    0:00:46 alike), and grows once the second runs longer than the first did; the plain line alike."""
    clock = [100.0]
    monkeypatch.setattr(console_mod.time, "perf_counter", lambda: clock[0])

    def row() -> str:
        screen = Console(file=io.StringIO(), width=100, color_system=None, force_terminal=True)
        for r in console_mod._TERMINAL.progress.get_renderables():
            screen.print(r)
        return screen.file.getvalue()

    with console_mod.phase("matching", 3, unit="pairs", quiet_s=0) as ph:
        assert ph.remaining_seconds() is None  # nothing measured yet
        clock[0] += 28.5
        ph.update(1)
        seen = {}
        for t in (28.5, 32.0, 46.0, 57.0, 60.0, 80.0):  # seconds since the phase began; no update meanwhile
            clock[0] = 100.0 + t
            seen[t] = ph.remaining_seconds()
        assert seen[28.5] == pytest.approx(57.0) and seen[32.0] == pytest.approx(53.5)
        assert seen[46.0] == pytest.approx(39.5) and seen[57.0] == pytest.approx(28.5)  # its share: 28.5 s
        assert seen[60.0] == pytest.approx(30.0) and seen[80.0] == pytest.approx(40.0)  # late: 80 s for 2 pairs
        clock[0] = 132.0
        assert "1/3 " in row() and "~0:00:53" in row(), row()
        clock[0] = 146.0
        assert "~0:00:39" in row() and "about 0:00:39 left" in ph.line(), row()
        clock[0] = 180.0
        assert "~0:00:40" in row() and "about 0:00:40 left" in ph.line(), row()
        ph.update(2)  # the second pair took 51.5 s: 80 s for 2, 40 s a pair
        assert ph.remaining_seconds() == pytest.approx(40.0)
        clock[0] = 190.0
        assert ph.remaining_seconds() == pytest.approx(30.0)
        ph.update(3)
        assert ph.remaining_seconds() == 0.0


def test_the_remaining_time_weights_coarse_and_full_steps(monkeypatch):
    """Half-size coarse steps of 1 s, then full-size steps of 2 s: at the switch the remaining time is
    the full steps' (not the coarse rate extrapolated), and from 10 full steps on their own rate."""
    import splat_framework.console as console

    clock = [0.0]
    monkeypatch.setattr(console.time, "perf_counter", lambda: clock[0])
    ph = console.Phase("training", 100, 0, "steps", "", 0, costs=[(50, 0.5), (100, 1.0)])
    plain = console.Phase("training", 100, 0, "steps", "", 0)
    seen = {}
    for step in range(1, 101):
        clock[0] += 1.0 if step <= 50 else 2.5  # full steps a little slower than the prior says
        ph.update(step)
        plain.update(step)
        seen[step] = ph.remaining_seconds(), plain.remaining_seconds()
    real = {s: (100 - s) * 2.5 for s in (50, 61, 80)}
    assert seen[50][0] == pytest.approx(100.0)  # 50 steps at twice the coarse ones' 1 s: the prior
    assert abs(seen[50][0] - real[50]) <= 0.25 * real[50] < abs(seen[50][1] - real[50])  # within 25 %, unlike the mean
    assert seen[61][0] == pytest.approx(real[61]) and seen[80][0] == pytest.approx(real[80])  # measured


def test_the_trainer_weights_its_coarse_steps():
    from splat_framework.config import TrainConfig
    from splat_framework.engine.trainer import step_costs

    cfg = TrainConfig(method="3dgs", steps=1000, default_steps=1000, coarse_steps=500, coarse_scale=0.5)
    assert step_costs(cfg) == [(500, 0.5), (1000, 1.0)]
    assert step_costs(cfg.model_copy(update={"coarse_steps": 0})) == []
