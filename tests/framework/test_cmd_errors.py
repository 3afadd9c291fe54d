"""splat-match, splat-scene and splat-sweep under cli.common.run_cli (issue 40): bad arguments,
bad grid files and failed runs end in one line and an exit code (0/1/2/130), nothing half-written."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cli_harness import changed_paths, cli_env, run_cli, snapshot
from splat_framework.cli.common import ArgumentsError
from splat_framework.errors import DataError
from splat_framework.sweep.grid import GRID_KEYS
from support import make_llff

REFUSED = (DataError, ArgumentsError)
"""What cli.common.parse_cli raises for a command line it refuses (run_cli: one line, exit 2)."""


@pytest.fixture(scope="module")
def llff(tmp_path_factory) -> Path:
    """A 4-view LLFF scene of random 64x48 photos (parse-time errors never read it)."""
    return make_llff(tmp_path_factory.mktemp("llff") / "scene", 4, w=64, h=48, full_factor=1, folder="images")


# ------------------------------------------------------------------ splat-match


@pytest.mark.parametrize(
    "args, words",
    [
        (["--max-lines", "-5"], ("max_lines", "greater than or equal to 0")),
        (["--seed", "-1"], ("seed", "greater than or equal to 0")),
        (["--kind", "nosuch"], ("--kind", "nosuch")),
        (["--views", "abc"], ("--views", "abc")),
    ],
)
@pytest.mark.bad_input("bad arguments of splat-match, splat-scene, splat-process, splat-sweep (`--max-lines -5`, `--seed -1`, an unknown matcher, `--width -5`, `--views 0`, `--mapper nosuch`, ...)", "exit 2 at parse time, one line naming the field; nothing written")
def test_match_bad_arguments_exit_2_in_one_line_writing_nothing(llff, tmp_path, args, words):
    run_cli("match", "--data", llff, "--out", tmp_path / "m", *args, code=2, match=words, watch=[tmp_path, llff])


@pytest.mark.parametrize(
    "args, words",
    [
        (["--max-lines", "abc"], ("--max-lines", "abc")),
        (["--max-lines", "1000000"], ("max_lines", "less than or equal to")),
        (["--views", "0"], ("views", "at least 1")),
        (["--seed", str(2**32)], ("seed",)),
        (["--no-such-flag", "1"], ("unrecognized", "--no-such-flag")),
        ([], ("missing", "--out")),
    ],
)
@pytest.mark.bad_input("bad arguments of splat-match, splat-scene, splat-process, splat-sweep (`--max-lines -5`, `--seed -1`, an unknown matcher, `--width -5`, `--views 0`, `--mapper nosuch`, ...)", "exit 2 at parse time, one line naming the field; nothing written")
def test_match_arguments_are_parsed_to_one_line(tmp_path, args, words):
    """The same parser in-process (cli.common.parse_cli): every refusal is one line (DataError or ArgumentsError)."""
    from splat_framework.cli.common import parse_cli
    from splat_framework.cli.match import MatchArgs
    out = [] if not args else ["--out", str(tmp_path / "m")]
    with pytest.raises(REFUSED) as e:
        parse_cli(MatchArgs, prog="splat-match", args=["--data", "x", *out, *args], field_prefix="")
    message = str(e.value)
    assert "\n" not in message and all(w.lower() in message.lower() for w in words), message


@pytest.mark.bad_input("an output path that is a FIFO or a device node, lies below a file, or is in a folder that cannot be written", "exit 2 (1 when not writable), one line; nothing opened or renamed over it")
def test_match_out_through_a_file_is_one_line_exit_2(llff, tmp_path):
    """A path the user gave that cannot be a folder (--out a file, or a folder under one): exit 2
    naming it (the output guard, and behind it cli.common.run_cli's path errors), the file untouched."""
    (tmp_path / "file").write_text("mine")
    for out in (tmp_path / "file", tmp_path / "file" / "m"):
        run_cli("match", "--data", llff, "--out", out, "--kind", "dense", code=2,
                match=str(tmp_path / "file"), watch=[tmp_path, llff])


@pytest.mark.bad_input("an output path that is a FIFO or a device node, lies below a file, or is in a folder that cannot be written", "exit 2 (1 when not writable), one line; nothing opened or renamed over it")
def test_a_path_through_a_file_is_one_line_exit_2_wherever_it_is_met(tmp_path, capsys):
    """run_cli: an OSError that a path the user gave causes (ENOTDIR, EISDIR, ...) is one line
    naming it and exit 2, whichever command meets it and wherever."""
    from splat_framework.cli.common import run_cli as run

    (tmp_path / "file").write_text("mine")
    sigterm = signal.getsignal(signal.SIGTERM)  # run_cli installs its own
    try:
        with pytest.raises(SystemExit) as e:
            run(lambda: (tmp_path / "file" / "sub").mkdir(parents=True))
    finally:
        signal.signal(signal.SIGTERM, sigterm)
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and err == f"error: {tmp_path / 'file' / 'sub'}: Not a directory", err


def _as_from_a_terminal() -> None:
    """A child's SIGINT as a terminal's foreground command has it (the default, so Python raises
    KeyboardInterrupt): a suite started in the background (``cmd &``) hands its children SIGINT
    ignored, and Python then keeps it ignored, as a background command should."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.bad_input("Ctrl-C during `splat-match` or `splat-scene`", "exit 130, `interrupted`; nothing half-written (`matches.npz` written last and atomically; a scene built aside and moved in at the end)")
def test_match_ctrl_c_exits_130_and_leaves_nothing_half_written(tmp_path):
    """SIGINT while pairs are being matched: exit 130, one line "interrupted", no result written
(the output folder claimed before the work holds its marker only)."""
    scene = make_llff(tmp_path / "scene", 6, w=240, h=180, full_factor=1, folder="images")  # SIFT on noise: slow pairs
    out = tmp_path / "m"
    before = snapshot(tmp_path)
    proc = subprocess.Popen(
        [sys.executable, "-m", "splat_framework.cli.match", "--data", str(scene), "--out", str(out),
         "--views", "all", "--kind", "sift", "--no-cache"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=cli_env(), preexec_fn=_as_from_a_terminal,
    )
    line = proc.stdout.readline()  # "matching 5 views (10 pairs) with sift...": inside run_cli, matching
    assert line.startswith("matching "), (line, proc.stderr.read() if proc.poll() is not None else "")
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, (stdout, stderr)
    assert "Traceback" not in stderr and stderr.strip().splitlines()[-1] == "interrupted", stderr  # after per-pair warnings
    changed = changed_paths(before, snapshot(tmp_path))
    assert changed <= {"m", os.path.join("m", ".splat-output.json")}, changed  # at most the claimed folder, no result


@pytest.mark.bad_input("Ctrl-C during `splat-match` or `splat-scene`", "exit 130, `interrupted`; nothing half-written (`matches.npz` written last and atomically; a scene built aside and moved in at the end)")
def test_match_writes_matches_npz_last(tmp_path, monkeypatch):
    """Interrupted while drawing the pictures: each written picture is whole and there is no matches.npz."""
    import splat_framework.matching as matching
    from splat_framework.cli.match import run_matching
    from splat_framework.config import match_config

    rng = np.random.default_rng(0)
    images = [rng.random((48, 64, 3)).astype(np.float32) for _ in range(3)]
    drawn = []
    real = matching.draw_matches

    def draw_then_interrupt(*args, **kwargs):
        if drawn:
            raise KeyboardInterrupt
        drawn.append(real(*args, **kwargs))

    monkeypatch.setattr(matching, "draw_matches", draw_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        run_matching(images, None, [0, 1, 2], match_config("dense", epipolar_check=False), tmp_path / "m")
    assert not (tmp_path / "m" / "matches.npz").exists()
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == [drawn[0].name]  # whole, no temp file
    import cv2

    assert cv2.imread(str(drawn[0])).shape == (48, 128, 3)


@pytest.mark.bad_input("Ctrl-C during `splat-match` or `splat-scene`", "exit 130, `interrupted`; nothing half-written (`matches.npz` written last and atomically; a scene built aside and moved in at the end)")
def test_match_pictures_and_cache_are_written_atomically(tmp_path, monkeypatch):
    """A write that fails (disk full at fsync) leaves no file at the target and no temp file,
    for the pictures (drawing) and the match set / cache (MatchSet.save) alike."""
    import errno

    import splat_framework.runtime.io as sio
    from splat_framework.matching import MatchSet, draw_matches

    img = np.zeros((8, 8, 3), np.float32)
    ms = MatchSet(view_ids=[0, 1], matches={(0, 1): (np.zeros((2, 2)), np.ones((2, 2)))})
    ms.save(tmp_path / "cache.npz")
    old = (tmp_path / "cache.npz").read_bytes()

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(sio.os, "fsync", full)
    with pytest.raises(OSError):
        draw_matches(img, img, np.zeros((1, 2)), np.zeros((1, 2)), tmp_path / "pic.png")
    with pytest.raises(OSError):
        MatchSet(view_ids=[0, 1], matches={}).save(tmp_path / "cache.npz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache.npz"]
    assert (tmp_path / "cache.npz").read_bytes() == old


# ------------------------------------------------------------------ splat-scene


@pytest.mark.parametrize(
    "args, words",
    [
        (["--width", "-5"], ("width", "greater than or equal to 4")),
        (["--width", "1000000000"], ("width", "less than or equal to 8192")),
        (["--views", "0"], ("views", "greater than or equal to 1")),
    ],
)
@pytest.mark.bad_input("bad arguments of splat-match, splat-scene, splat-process, splat-sweep (`--max-lines -5`, `--seed -1`, an unknown matcher, `--width -5`, `--views 0`, `--mapper nosuch`, ...)", "exit 2 at parse time, one line naming the field; nothing written")
def test_scene_bad_values_exit_2_at_parse_time(tmp_path, args, words):
    run_cli("scene", "forward", "--out", tmp_path / "s", *args, code=2, match=words, watch=[tmp_path])


@pytest.mark.parametrize(
    "args, words",
    [
        (["forward", "--height", "0"], ("height",)),
        (["object", "--views", "100000"], ("views", "less than or equal to 1000")),
        (["forward", "--seed", "-1"], ("seed",)),
        (["forward", "--height", "abc"], ("--height", "abc")),
        (["forwar"], ("forwar", "not one of", "forward")),
    ],
)
@pytest.mark.bad_input("bad arguments of splat-match, splat-scene, splat-process, splat-sweep (`--max-lines -5`, `--seed -1`, an unknown matcher, `--width -5`, `--views 0`, `--mapper nosuch`, ...)", "exit 2 at parse time, one line naming the field; nothing written")
def test_scene_arguments_are_parsed_to_one_line(args, words):
    from splat_framework.cli.common import parse_cli
    from splat_framework.cli.scene import SceneArgs

    with pytest.raises(REFUSED) as e:
        parse_cli(SceneArgs, prog="splat-scene", args=args, field_prefix="")
    message = str(e.value)
    assert "\n" not in message and all(w.lower() in message.lower() for w in words), message


@pytest.mark.bad_input("Ctrl-C during `splat-match` or `splat-scene`", "exit 130, `interrupted`; nothing half-written (`matches.npz` written last and atomically; a scene built aside and moved in at the end)")
def test_scene_ctrl_c_exits_130_and_leaves_nothing(tmp_path):
    """SIGINT while the scene renders (in its work folder beside --out): exit 130, one line,
    no --out and no work folder left."""
    out = tmp_path / "s"
    proc = subprocess.Popen(
        [sys.executable, "-m", "splat_framework.cli.scene", "forward", "--out", str(out), "--views", "300",
         "--width", "160", "--height", "120"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=cli_env(), preexec_fn=_as_from_a_terminal,
    )
    deadline = time.monotonic() + 60
    while proc.poll() is None and time.monotonic() < deadline and not list(tmp_path.glob(".s.work-*/images/*.png")):
        time.sleep(0.01)  # the first picture is written: rendering
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130 and stderr.strip() == "interrupted", stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.bad_input("Ctrl-C during `splat-match` or `splat-scene`", "exit 130, `interrupted`; nothing half-written (`matches.npz` written last and atomically; a scene built aside and moved in at the end)")
def test_building_installs_a_finished_folder_and_nothing_of_an_interrupted_one(tmp_path):
    import stat

    from splat_framework.files.run_lock import LOCK_NAME
    from splat_framework.files.work_folder import building

    out = tmp_path / "out"
    with building(out, os.rename) as work:
        (work / "images").mkdir()
        (work / "images" / "a.png").write_text("new")
        assert work.parent == tmp_path and work.name.startswith(".out.work-")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"] and not (out / LOCK_NAME).exists()
    assert stat.S_IMODE(out.stat().st_mode) == 0o777 & ~_umask()
    with pytest.raises(KeyboardInterrupt), building(tmp_path / "other", os.rename) as work:
        (work / "half.png").write_text("half")
        raise KeyboardInterrupt
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# ------------------------------------------------------------------ splat-sweep

GRID = 'methods = ["3dgs"]\ndata = ["synthetic/forward-tiny"]\nout = "o"\n'


@pytest.mark.parametrize(
    "name, content, words",
    [
        ("binary.toml", bytes(range(256)) * 4, ("binary.toml", "not a UTF-8 text file")),
        ("utf16.toml", GRID.encode("utf-16"), ("utf16.toml", "not a UTF-8 text file")),
        ("mem.toml", (GRID + 'mem_per_run_gb = "abc"\n').encode(), ("mem.toml", "mem_per_run_gb", "not a number")),
    ],
)
@pytest.mark.bad_input("a binary, UTF-16, FIFO or wrongly typed sweep grid file", "exit 2, one line naming the file and field; a FIFO is never waited on")
def test_sweep_bad_grid_file_exits_2_naming_file_and_field(tmp_path, name, content, words):
    grid = tmp_path / name
    grid.write_bytes(content)
    run_cli("sweep", grid, code=2, match=words, watch=[tmp_path], cwd=tmp_path)


@pytest.mark.parametrize(
    "name, content, words",
    [
        ("inf.toml", GRID + "mem_per_run_gb = inf\n", ("mem_per_run_gb", "finite")),
        ("flag.toml", GRID + "mem_per_run_gb = true\n", ("mem_per_run_gb", "not a number")),
        ("data.toml", 'methods = ["3dgs"]\ndata = [1]\nout = "o"\n', ("data", "not a string")),
        ("seeds.toml", GRID + "seeds = [1.5]\n", ("seeds", "not an integer")),
        ("seedneg.toml", GRID + "seeds = [-1]\n", ("seeds",)),
        ("out.toml", 'methods = ["3dgs"]\ndata = ["x"]\nout = [1]\n', ("out", "not a string")),
        ("steps.json", '{"methods": ["3dgs"], "data": ["x"], "out": "o", "steps": "many"}', ("steps", "not an integer")),
        ("views.toml", GRID + "views = [2.5]\n", ("views",)),
    ],
)
@pytest.mark.bad_input("a binary, UTF-16, FIFO or wrongly typed sweep grid file", "exit 2, one line naming the file and field; a FIFO is never waited on")
def test_sweep_grid_values_of_the_wrong_type_name_file_and_field(tmp_path, name, content, words):
    from splat_framework.sweep import SweepError, load_grid_file

    grid = tmp_path / name
    grid.write_text(content)
    with pytest.raises(SweepError) as e:
        load_grid_file(grid)
    message = str(e.value)
    assert message.startswith(f"{grid}: ") and all(w in message for w in words), message


@pytest.mark.bad_input("a binary, UTF-16, FIFO or wrongly typed sweep grid file", "exit 2, one line naming the file and field; a FIFO is never waited on")
def test_sweep_grid_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "grid.toml"
    os.mkfifo(fifo)
    run_cli("sweep", fifo, code=2, match=("grid.toml", "not a regular file"), watch=[tmp_path], timeout=60)


@pytest.mark.bad_input("bad arguments of splat-match, splat-scene, splat-process, splat-sweep (`--max-lines -5`, `--seed -1`, an unknown matcher, `--width -5`, `--views 0`, `--mapper nosuch`, ...)", "exit 2 at parse time, one line naming the field; nothing written")
def test_sweep_argument_errors_are_one_line(tmp_path):
    run_cli("sweep", "--workers", code=2, match="--workers", watch=[tmp_path], cwd=tmp_path)
    run_cli("sweep", "--methods", "3dgs", "--data", "x", "--out", "o", "--backend", "nosuch", code=2,
            match=("--backend", "nosuch"), watch=[tmp_path], cwd=tmp_path)


@pytest.mark.bad_input("a sweep in which some runs fail", "exit 1, one line naming the failed runs and their logs; exit 0 only when every run succeeded")
def test_sweep_exits_1_naming_the_failed_runs_and_0_only_when_all_succeeded(tmp_path):
    """One run finished earlier (its metrics.json), one has a dataset whose photo is truncated
    (fails while it runs: it has a log), one names a missing dataset (fails before it starts):
    exit 1 naming the two failed runs, with the log of the one that ran. A sweep of the
    finished run alone exits 0."""
    import json

    broken = make_llff(tmp_path / "broken", 4, w=16, h=12, full_factor=1, folder="images")
    png = broken / "images" / "img001.png"
    png.write_bytes(png.read_bytes()[:40])
    out = tmp_path / "sw"
    good = out / "runs" / "good-scene" / "3dgs" / "v3-s0"
    good.mkdir(parents=True)
    (good / "metrics.json").write_text(json.dumps({"method": "3dgs", "data": "good/scene", "steps": 3,
                                                   "mean": {"psnr": 20.0}, "timing": {}}))
    common = ["--methods", "3dgs", "--seeds", "0", "--steps", "3", "--out", out, "--backend", "serial", "--no-live"]
    r = run_cli("sweep", "--data", "good/scene", broken, tmp_path / "missing", *common,
                code=1, match=("2 of 3 run(s) failed", "sweep.log", "missing"), watch=[tmp_path], allowed=[out])
    assert str(good) not in r.message
    failed_log = next((out / "runs").glob("*broken*/3dgs/v3-s0/sweep.log"))
    assert str(failed_log) in r.message and "img001.png" in failed_log.read_text()
    run_cli("sweep", "--data", "good/scene", *common, code=0, watch=[tmp_path], allowed=[out])


_GRID_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-2**40, 2**40) | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner, max_size=3),
    max_leaves=6,
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(doc=st.dictionaries(st.sampled_from(sorted(GRID_KEYS) + ["nosuch"]), _GRID_VALUES, max_size=6),
       blob=st.binary(max_size=64), as_json=st.booleans())
@pytest.mark.bad_input("fuzzed sweep grid files (random bytes, random values of every key)",
                       "normalised settings or one `SweepError` line naming the file, never another exception")
def test_fuzzed_grid_files_load_or_name_the_file(tmp_path, doc, blob, as_json):
    """Any grid document, well-formed or not, loads into settings of the documented types or raises one
    line naming the file: never another exception."""
    from splat_framework.sweep import SweepError, load_grid_file

    grid = tmp_path / ("grid.json" if as_json else "grid.toml")
    for content in (json.dumps(doc).encode(), blob + json.dumps(doc).encode()):
        grid.write_bytes(content)
        try:
            settings_ = load_grid_file(grid)
        except SweepError as e:
            assert str(e).startswith(f"{grid}: ") and "\n" not in str(e), str(e)
            continue
        for key in ("methods", "data"):
            assert all(isinstance(x, str) for x in settings_.get(key, []))
        assert all(isinstance(x, int) and 0 <= x < 2**32 for x in settings_.get("seeds", []))
        assert all(isinstance(settings_[k], int) and settings_[k] >= 1 for k in ("steps", "workers", "threads") if k in settings_)
        if "mem_per_run_gb" in settings_:
            assert math.isfinite(settings_["mem_per_run_gb"]) and settings_["mem_per_run_gb"] > 0
