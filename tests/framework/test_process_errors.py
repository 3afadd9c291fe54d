"""splat-process (issue 40): a photo that does not decode completely is refused by name, and the
hidden work folder a killed run leaves beside --out is removed by the next run."""

from __future__ import annotations

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
from splat_framework.cli.common import ArgumentsError
from splat_framework.errors import DataError
from splat_framework.files.run_lock import LOCK_NAME
from splat_framework.files.work_folder import make_work_folder, remove_stale_work_folders, remove_work_folder, scratch


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


@pytest.mark.bad_input("`splat-process` killed with kill -9", "its hidden work folder is removed by the next run (folders in use are kept)")
def test_a_scratch_folder_is_removed_at_the_end_even_by_an_error_and_after_a_kill(tmp_path):
    """Intermediate files (a video's frames) live in a work folder beside the output, not in /tmp,
    so a run killed with kill -9 leaves nothing that the next run for that output does not remove."""
    out = tmp_path / "scene"
    stale, _ = _work_folder_of_another_process(out, stay=False)
    with pytest.raises(RuntimeError, match="stop"), scratch(out) as work:
        assert not stale.exists() and work.is_dir() and work.parent == tmp_path
        raise RuntimeError("stop")
    assert list(tmp_path.iterdir()) == []


def test_a_scratch_folder_outlives_a_nested_one_of_the_same_output(tmp_path):
    """A video's frames (one scratch folder of --out) stay while estimate_scene, which opens its own
    scratch folder of --out and removes the stale ones first, runs: a live folder is never stale."""
    out = tmp_path / "scene"
    with scratch(out) as frames:
        (frames / "f.png").write_bytes(b"x")
        with scratch(out) as inner:
            assert (frames / "f.png").is_file() and inner != frames
        assert (frames / "f.png").is_file() and not inner.exists()
    assert list(tmp_path.iterdir()) == []


def test_a_videos_frames_are_picked_into_a_work_folder_beside_out(tmp_path, monkeypatch):
    import splat_framework.sfm as sfm
    from splat_framework.cli import process

    seen = []

    def pick(video, frames, folder):
        seen.append(Path(folder))
        raise DataError(f"{video}: stop")

    monkeypatch.setattr(sfm, "pick_video_frames", pick)
    with pytest.raises(DataError, match="stop"):
        process.main(process.VideoArgs(video=tmp_path / "v.mp4", out=tmp_path / "scene"))
    assert seen[0].parent.parent == tmp_path and seen[0].parent.name.startswith(".scene.work-")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.bad_input("a truncated JPEG given to `splat-process`", "exit 2, one line naming the photo (not a half-grey photo in the scene)")
def test_read_photo_refuses_a_truncated_jpeg_that_opencv_decodes_half_grey(tmp_path):
    from splat_framework.data.images import read_photo

    (p,) = noise_photos(tmp_path / "ph", 1, 64, 48)
    assert read_photo(p).shape == (48, 64, 3)
    truncate(p)
    assert cv2.imread(str(p)) is not None  # what splat-process used: a grey lower half, no error
    with pytest.raises(DataError, match=r"p0\.jpg: truncated JPEG"):
        read_photo(p)


def _work_folder_of_another_process(out: Path, stay: bool) -> tuple[Path, subprocess.Popen]:
    """A work folder of ``out`` made by a child process, which then exits without cleaning up
    (``stay``: keeps running, holding its lock)."""
    code = ("import os, sys, time; from pathlib import Path; from splat_framework.files.work_folder import make_work_folder; "
            f"print(make_work_folder(Path({str(out)!r})), flush=True); time.sleep(60 if {stay} else 0); os._exit(0)")
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=cli_env())
    work = Path(child.stdout.readline().strip())
    if not stay:
        child.wait()
    return work, child


@pytest.mark.bad_input("`splat-process` killed with kill -9", "its hidden work folder is removed by the next run (folders in use are kept)")
def test_stale_work_folders_are_removed_and_live_or_foreign_ones_kept(tmp_path):
    out = tmp_path / "scene"
    stale, _ = _work_folder_of_another_process(out, stay=False)
    live, sleeper = _work_folder_of_another_process(out, stay=True)
    try:
        mine = make_work_folder(out)  # this process's own, in use
        unlocked = tmp_path / ".scene.work-nolock"  # no lock file: not ours, or not yet locked
        unlocked.mkdir()
        other, _ = _work_folder_of_another_process(tmp_path / "other", stay=False)  # another output's
        (tmp_path / "keep").mkdir()
        (tmp_path / "keep" / "file").write_text("mine")
        (stale / "input").mkdir()
        (stale / "input" / "link").symlink_to(tmp_path / "keep")  # unlinked, never followed
        os.symlink(tmp_path / "keep", tmp_path / ".scene.work-link")
        assert remove_stale_work_folders(out) == [stale]
    finally:
        sleeper.kill()
        sleeper.wait()
    assert not stale.exists() and all(p.is_dir() for p in (live, mine, unlocked, other))
    assert (tmp_path / "keep" / "file").read_text() == "mine" and (tmp_path / ".scene.work-link").is_symlink()
    assert remove_stale_work_folders(out) == [live]  # its process is gone now
    remove_work_folder(mine)
    assert not mine.exists()


@pytest.mark.bad_input("a truncated JPEG given to `splat-process`", "exit 2, one line naming the photo (not a half-grey photo in the scene)")
@pytest.mark.bad_input("`splat-process` killed with kill -9", "its hidden work folder is removed by the next run (folders in use are kept)")
def test_a_killed_process_leaves_a_work_folder_that_the_next_run_removes_then_a_truncated_jpeg_is_refused(tmp_path):
    pytest.importorskip("pycolmap", reason='splat-process needs pycolmap (pip install "splat-framework[process]")')
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
        work = [p for p in tmp_path.glob(".scene.work-*") if (p / LOCK_NAME).is_file()]
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
        ([], ("missing a command", "images", "video")),
    ],
)
@pytest.mark.bad_input("bad arguments of splat-match, splat-scene, splat-process, splat-sweep (`--max-lines -5`, `--seed -1`, an unknown matcher, `--width -5`, `--views 0`, `--mapper nosuch`, ...)", "exit 2 at parse time, one line naming the field; nothing written")
def test_process_arguments_are_parsed_to_one_line(args, words):
    """tyro's refusals (an unknown mapper, a count that is not a number, an unknown subcommand)
    are one DataError line (cli.common.parse_cli), not a usage box."""
    from splat_framework.cli.common import parse_cli
    from splat_framework.cli.process import Args

    with pytest.raises((DataError, ArgumentsError)) as e:
        parse_cli(Args, prog="splat-process", args=args)
    message = str(e.value)
    assert "\n" not in message and all(w in message for w in words), message


@pytest.mark.bad_input("SIGTERM while photos are being posed (pycolmap loaded)", "exit 130, `interrupted`, no stack dump")
def test_sigterm_after_pycolmap_is_loaded_stops_like_ctrl_c():
    """Importing pycolmap installs glog's failure handler for SIGTERM (a stack dump, then death);
    load_pycolmap puts the CLI's handler back, so a SIGTERM while posing stops as Ctrl-C does."""
    import signal
    import subprocess
    import sys

    pytest.importorskip("pycolmap", reason='posing needs pycolmap (pip install "splat-framework[process]")')
    code = ("import time\nfrom splat_framework.cli.common import run_cli\nfrom splat_framework.sfm.colmap import load_pycolmap\n"
            "def main():\n    load_pycolmap()\n    print('ready', flush=True)\n    time.sleep(60)\nrun_cli(main)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and err.strip() == "interrupted", err[-2000:]


def _corrupt_body(path: Path) -> None:
    """Overwrite bytes in the middle of a JPEG's compressed data: libjpeg decodes it with garbage,
    printing only its own warning."""
    data = bytearray(path.read_bytes())
    middle = len(data) // 2
    for k in range(middle, middle + 40):
        data[k] = 0xFF if k % 7 == 0 else data[k] ^ 0x5A
    path.write_bytes(bytes(data))


@pytest.mark.bad_input("own photos: a JPEG with a corrupt body; a FIFO or a link to `/dev/zero` named `*.jpg`",
                       "exit 2, one line naming the photo and the decoder's complaint (libjpeg's own line not "
                       "printed); a special file: one warning line naming it, skipped, never opened")
def test_a_corrupt_jpeg_is_named_with_the_decoders_complaint_and_special_files_are_skipped_naming_them(tmp_path):
    photos = tmp_path / "photos"
    corrupt = noise_photos(photos, 3, 64, 48)[0]
    _corrupt_body(corrupt)
    os.mkfifo(photos / "fifo.jpg")  # opening it would wait for a writer forever
    (photos / "zero.jpg").symlink_to("/dev/zero")  # reading it would never end
    r = run_cli("process", "images", photos, "--out", tmp_path / "scene", code=2, max_lines=3, watch=[tmp_path],
                match=(corrupt.name, "corrupt JPEG (Corrupt JPEG data"))
    lines = r.message.splitlines()
    assert sorted(lines[:2]) == [f"warning: {photos / 'fifo.jpg'}: not a regular file (a FIFO); skipped",
                                 f"warning: {photos / 'zero.jpg'}: not a regular file (a device); skipped"], r.stderr
    assert lines[2].startswith("error: ") and sum("Corrupt JPEG data" in line for line in lines) == 1, r.stderr


BAD_MATCHERS = '''
import numpy as np

ENTRY_POINTS = {"splat_framework.photo_matchers": {"not-callable": "bad_matchers:NOT_CALLABLE",
                                                   "bad-shape": "bad_matchers:bad_shape"}}
NOT_CALLABLE = 3


def bad_shape(images, pairs=None):
    return {(0, 1): (np.zeros((5, 3)), np.zeros((5, 3)))}
'''


@pytest.mark.bad_input("a plugin's photo matcher that is not callable or returns matches of the wrong shape",
                       "exit 2, one line naming the matcher, its plugin and what is wrong")
def test_a_plugin_photo_matcher_that_is_not_callable_or_returns_the_wrong_shape_is_one_line(tmp_path):
    code = tmp_path / "code"
    code.mkdir()
    (code / "bad_matchers.py").write_text(BAD_MATCHERS)
    env = cli_env(PYTHONPATH=os.pathsep.join(p for p in (str(code), os.environ.get("PYTHONPATH")) if p),
                  SPLAT_PLUGINS="bad_matchers")
    photos = tmp_path / "photos"
    noise_photos(photos, 3, 64, 48)
    run_cli("process", "images", photos, "--out", tmp_path / "a", "--matcher", "not-callable", code=2, env=env,
            watch=[photos], match=("photo matcher 'not-callable' of SPLAT_PLUGINS module 'bad_matchers' "
                                   "(bad_matchers:NOT_CALLABLE) is not callable (it is of type int)"), timeout=600)
    run_cli("process", "images", photos, "--out", tmp_path / "b", "--matcher", "bad-shape", code=2, env=env, max_lines=2,
            watch=[photos], match=("photo matcher 'bad-shape' returned for (0, 1) points of shapes [[5, 3], [5, 3]], "
                                   "not two [M, 2]"), timeout=600)
