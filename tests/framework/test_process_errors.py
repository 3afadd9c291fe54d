"""splat-process (issue 40): a photo that does not decode completely is refused by name, and the
hidden work folder a killed run leaves beside --out is removed by the next run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from cli_harness import cli_env, run_cli

from splat_framework.errors import DataError
from splat_framework.work_folder import OWNER_FILE, make_work_folder, remove_stale_work_folders


def noise_photos(folder: Path, n: int, w: int, h: int, ext: str = ".jpg") -> list[Path]:
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    paths = [folder / f"p{k}{ext}" for k in range(n)]
    for p in paths:
        assert cv2.imwrite(str(p), rng.integers(0, 256, (h, w, 3), dtype=np.uint8))
    return paths


def truncate(path: Path, fraction: float = 0.5) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * fraction)])


def test_read_photo_refuses_a_truncated_jpeg_that_opencv_decodes_half_grey(tmp_path):
    from splat_framework.data.images import read_photo

    (p,) = noise_photos(tmp_path / "ph", 1, 64, 48)
    assert read_photo(p).shape == (48, 64, 3)
    truncate(p)
    assert cv2.imread(str(p)) is not None  # what splat-process used: a grey lower half, no error
    with pytest.raises(DataError, match=r"p0\.jpg: truncated JPEG"):
        read_photo(p)


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_stale_work_folders_are_removed_and_live_or_foreign_ones_kept(tmp_path):
    out = tmp_path / "scene"
    stale, live, foreign, ownerless = (make_work_folder(out) for _ in range(4))
    (stale / "input").mkdir()
    (stale / "input" / "link").symlink_to(tmp_path / "keep")  # unlinked, never followed
    (tmp_path / "keep").mkdir()
    (tmp_path / "keep" / "file").write_text("mine")
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        owner = json.loads((stale / OWNER_FILE).read_text())
        (stale / OWNER_FILE).write_text(json.dumps(owner | {"pid": _dead_pid()}))
        (live / OWNER_FILE).write_text(json.dumps(owner | {"pid": sleeper.pid}))
        (foreign / OWNER_FILE).write_text(json.dumps(owner | {"pid": _dead_pid(), "host": "another-host"}))
        (ownerless / OWNER_FILE).unlink()
        other = make_work_folder(tmp_path / "other")  # another output's work folder
        (other / OWNER_FILE).write_text(json.dumps(owner | {"pid": _dead_pid()}))
        os.symlink(tmp_path / "keep", tmp_path / f".{out.name}.work-link")
        assert remove_stale_work_folders(out) == [stale]
    finally:
        sleeper.kill()
        sleeper.wait()
    assert not stale.exists() and live.is_dir() and foreign.is_dir() and ownerless.is_dir() and other.is_dir()
    assert (tmp_path / "keep" / "file").read_text() == "mine"


def test_a_killed_process_leaves_a_work_folder_that_the_next_run_removes_then_a_truncated_jpeg_is_refused(tmp_path):
    pytest.importorskip("pycolmap", reason='splat-process needs pycolmap (pip install "splat[process]")')
    noise_photos(tmp_path / "photos", 4, 640, 480)  # SIFT on noise: seconds of work to be killed in
    out = tmp_path / "scene"
    proc = subprocess.Popen(
        [sys.executable, "-m", "splat_framework.cli.process", "images", str(tmp_path / "photos"), "--out", str(out),
         "--matcher", "sift"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=cli_env(),
    )
    deadline = time.monotonic() + 120
    work = []
    while not work and proc.poll() is None and time.monotonic() < deadline:
        work = [p for p in tmp_path.glob(".scene.work-*") if (p / OWNER_FILE).is_file()]
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert work and proc.returncode == -signal.SIGKILL, "splat-process ended before it could be killed"
    assert work[0].is_dir()  # a crash runs no cleanup
    truncate(tmp_path / "photos" / "p2.jpg")  # the next run cleans up, then refuses the photo by name
    run_cli("process", "images", tmp_path / "photos", "--out", out, "--matcher", "sift",
            code=2, match=("p2.jpg", "truncated JPEG"), watch=[tmp_path], allowed=[work[0], tmp_path / "photos" / "p2.jpg"])
    assert not work[0].exists() and sorted(p.name for p in tmp_path.iterdir()) == ["photos"]


@pytest.mark.parametrize(
    "args, words",
    [
        (["images", "photos", "--out", "s", "--mapper", "nosuch"], ("--mapper", "nosuch")),
        (["video", "v.mp4", "--out", "s", "--frames", "abc"], ("--frames", "abc")),
        (["pictures"], ("pictures",)),
        ([], ("missing subcommand", "images", "video")),
    ],
)
def test_process_arguments_are_parsed_to_one_line(args, words):
    """tyro's refusals (an unknown mapper, a count that is not a number, an unknown subcommand)
    are one DataError line (cli.common.parse_cli), not a usage box."""
    from splat_framework.cli.common import parse_cli
    from splat_framework.cli.process import Args

    with pytest.raises(DataError) as e:
        parse_cli(Args, prog="splat-process", args=args)
    message = str(e.value)
    assert "\n" not in message and all(w in message for w in words), message
