"""One output-path guard for every command that writes (issue 40): nothing of the user's is replaced.

Each test runs the command in a subprocess (tests/cli_harness.py) and watches the
surrounding folder: a refused command changes nothing there.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from cli_harness import run_cli
from splat_framework.errors import DataError
from splat_framework.files.output_paths import (
    MARKER,
    PLY_COMMENT,
    RENDER_FOLDER,
    SCENE_FOLDER,
    VIDEO_FILE,
    check_output,
    run_inputs,
)

TINY_SCENE = ("--width", 16, "--height", 12, "--views", 3)


def user_folder(path: Path, **files: str) -> Path:
    """A folder of the user's holding ``files`` (name -> text)."""
    path.mkdir(parents=True)
    for name, text in files.items():
        (path / name).write_text(text)
    return path


@pytest.fixture
def dataset(tmp_path) -> Path:
    """A tiny forward-facing dataset the user owns (LLFF layout, not written by splat-scene)."""
    from support import make_llff

    root = tmp_path / "my-dataset"
    make_llff(root, n=4, w=16, h=12)
    return root


# ------------------------------------------------------------------ splat-process


@pytest.mark.bad_input("an output that is, holds or lies inside the input (`splat-process images DIR --out DIR`, `splat-train --output DATA/run`, `splat-match --out DATA`)", "exit 2, one line; the input is untouched, with or without `--overwrite`")
def test_process_refuses_the_photo_folder_as_its_output(tmp_path):
    from support import write_png

    photos = user_folder(tmp_path / "photos")
    for i in range(3):
        write_png(photos / f"IMG_{i}.png", 16, 12, seed=i)
    run_cli("process", "images", photos, "--out", photos, "--overwrite", "--matcher", "sift",
            code=2, match="is the input", watch=[tmp_path])
    run_cli("process", "images", photos, "--out", photos / "scene", "--overwrite", "--matcher", "sift",
            code=2, match="inside the input", watch=[tmp_path])


def test_train_with_a_data_that_names_nothing_leaves_the_output_alone_even_with_overwrite(tmp_path):
    run = _fake_run(tmp_path / "run")
    run_cli("train", "3dgs", "--data", tmp_path / "no-such-data", "--output", run, "--overwrite",
            code=2, match="no-such-data: no such dataset folder", watch=[tmp_path])  # nothing changed
    assert (run / "checkpoints" / "step-0000010.ckpt").read_bytes() == b"old run"


@pytest.mark.bad_input("an existing folder or file that the command did not write (a dataset for `splat-scene --out`, a user's folder for `--output`/`--out`, someone's PLY or video)", "exit 2, one line; never replaced, `--overwrite` or not")
def test_process_overwrite_refuses_a_folder_it_did_not_write(tmp_path):
    from support import write_png

    photos = user_folder(tmp_path / "photos")
    for i in range(3):
        write_png(photos / f"IMG_{i}.png", 16, 12, seed=i)
    mine = user_folder(tmp_path / "mine", **{"notes.txt": "keep"})
    run_cli("process", "images", photos, "--out", mine, "--overwrite", "--matcher", "sift",
            code=2, match="not a scene folder written by splat-process", watch=[tmp_path])


# ------------------------------------------------------------------ splat-scene


@pytest.mark.bad_input("an existing folder or file that the command did not write (a dataset for `splat-scene --out`, a user's folder for `--output`/`--out`, someone's PLY or video)", "exit 2, one line; never replaced, `--overwrite` or not")
def test_scene_refuses_an_existing_dataset(dataset, tmp_path):
    run_cli("scene", "forward", "--out", dataset, *TINY_SCENE,
            code=2, match="not a scene folder written by splat-scene", watch=[tmp_path])


@pytest.mark.bad_input("an output that the same command wrote before", "exit 2 asking for `--overwrite`; with it, only what the command wrote is removed (the user's other files stay; symlinks are unlinked, never followed)")
def test_scene_replaces_its_own_folder_only_with_overwrite_and_keeps_the_rest(tmp_path):
    out = tmp_path / "scene"
    run_cli("scene", "forward", "--out", out, *TINY_SCENE, code=0, watch=[tmp_path], allowed=[out])
    assert (out / MARKER).is_file() and (out / "poses_bounds.npy").is_file()
    with pytest.raises(DataError, match="--overwrite"):  # the same check as the CLI's, in-process
        check_output(out, SCENE_FOLDER)
    (out / "notes.txt").write_text("mine")
    before = (out / "poses_bounds.npy").read_bytes()
    run_cli("scene", "forward", "--out", out, *TINY_SCENE, "--seed", 1, "--overwrite", code=0,
            watch=[tmp_path], allowed=[out])
    assert (out / "notes.txt").read_text() == "mine" and (out / "poses_bounds.npy").read_bytes() != before


# ------------------------------------------------------------------ splat-train


def _fake_run(folder: Path) -> Path:
    """A run folder as splat-train leaves it: a signed config.json, metrics, checkpoints."""
    from splat_framework.config import save_config
    from splat_framework.registry import get_method

    (folder / "checkpoints").mkdir(parents=True)
    save_config(get_method("3dgs").default_config(), folder / "config.json")
    (folder / "metrics.json").write_text("{}")
    (folder / "checkpoints" / "step-0000010.ckpt").write_bytes(b"old run")
    return folder


@pytest.mark.bad_input("an output that the same command wrote before", "exit 2 asking for `--overwrite`; with it, only what the command wrote is removed (the user's other files stay; symlinks are unlinked, never followed)")
def test_train_overwrite_unlinks_a_checkpoints_symlink_and_never_follows_it(tmp_path):
    other = _fake_run(tmp_path / "other-run")
    run = _fake_run(tmp_path / "run")
    shutil.rmtree(run / "checkpoints")
    os.symlink(other / "checkpoints", run / "checkpoints")
    # a folder that is no dataset: found after the output is cleared (a --data that names nothing
    # is refused before, leaving the output alone)
    (tmp_path / "not-a-dataset").mkdir()
    run_cli("train", "3dgs", "--data", tmp_path / "not-a-dataset", "--output", run, "--overwrite",
            code=2, match="not-a-dataset: empty folder", watch=[tmp_path], allowed=[run])
    assert not os.path.lexists(run / "checkpoints") and not (run / "config.json").exists()
    assert (other / "checkpoints" / "step-0000010.ckpt").read_bytes() == b"old run"


@pytest.mark.bad_input("an existing folder or file that the command did not write (a dataset for `splat-scene --out`, a user's folder for `--output`/`--out`, someone's PLY or video)", "exit 2, one line; never replaced, `--overwrite` or not")
def test_train_overwrite_refuses_a_folder_that_is_not_a_run(tmp_path):
    folder = user_folder(tmp_path / "results", **{"config.json": '{"mine": 1}', "metrics.json": '{"psnr": 30}'})
    (tmp_path / "not-a-dataset").mkdir()  # the output is checked before the data is read
    run_cli("train", "3dgs", "--data", tmp_path / "not-a-dataset", "--output", folder, "--overwrite",
            code=2, match="not a run folder written by splat-train", watch=[tmp_path])


@pytest.mark.bad_input("an output that is, holds or lies inside the input (`splat-process images DIR --out DIR`, `splat-train --output DATA/run`, `splat-match --out DATA`)", "exit 2, one line; the input is untouched, with or without `--overwrite`")
def test_train_refuses_an_output_inside_its_data(dataset, tmp_path):
    run_cli("train", "3dgs", "--data", dataset, "--output", dataset / "run", "--steps", 1,
            code=2, match="inside the input", watch=[tmp_path])


# ------------------------------------------------------------------ splat-export


@pytest.mark.bad_input("an output path that is a FIFO or a device node, lies below a file, or is in a folder that cannot be written", "exit 2 (1 when not writable), one line; nothing opened or renamed over it")
def test_export_refuses_a_fifo_and_a_device_node(run_dir, tmp_path):
    fifo = tmp_path / "pipe.ply"
    os.mkfifo(fifo)
    run_cli("export", run_dir, "--out", fifo, "--overwrite", code=2, match="FIFO", watch=[tmp_path])
    device = tmp_path / "null.ply"
    os.symlink("/dev/null", device)  # /dev/null itself stays out of reach of a failing test
    run_cli("export", run_dir, "--out", device, "--overwrite", code=2, match="device node", watch=[tmp_path])


@pytest.mark.bad_input("an existing folder or file that the command did not write (a dataset for `splat-scene --out`, a user's folder for `--output`/`--out`, someone's PLY or video)", "exit 2, one line; never replaced, `--overwrite` or not")
def test_export_never_replaces_a_file_it_did_not_write(run_dir, tmp_path):
    theirs = tmp_path / "scan.ply"
    theirs.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nend_header\n")
    run_cli("export", run_dir, "--out", theirs, "--overwrite", code=2, match="not a PLY file written by splat-export",
            watch=[tmp_path])


@pytest.mark.bad_input("an output that the same command wrote before", "exit 2 asking for `--overwrite`; with it, only what the command wrote is removed (the user's other files stay; symlinks are unlinked, never followed)")
def test_export_replaces_its_own_ply_only_with_overwrite(run_dir, tmp_path):
    ply = tmp_path / "out.ply"
    run_cli("export", run_dir, "--out", ply, code=0, watch=[tmp_path], allowed=[ply])
    assert PLY_COMMENT.encode() in ply.read_bytes().split(b"end_header")[0]
    run_cli("export", run_dir, "--out", ply, code=2, match="--overwrite", watch=[tmp_path])
    run_cli("export", run_dir, "--out", ply, "--overwrite", code=0, watch=[tmp_path], allowed=[ply])


@pytest.mark.bad_input("an output path that is a FIFO or a device node, lies below a file, or is in a folder that cannot be written", "exit 2 (1 when not writable), one line; nothing opened or renamed over it")
def test_export_path_below_a_file_and_an_unwritable_folder(run_dir, tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    run_cli("export", run_dir, "--out", tmp_path / "notes.txt" / "out.ply", code=2, match="is not a folder",
            watch=[tmp_path])
    locked = Path("/proc/sys")  # not writable even by root
    if os.access(locked, os.W_OK):
        pytest.skip("/proc/sys is writable here")
    run_cli("export", run_dir, "--out", locked / "out.ply", code=1, match="cannot write", watch=[tmp_path])


# ------------------------------------------------------------------ splat-render


@pytest.mark.bad_input("an existing folder or file that the command did not write (a dataset for `splat-scene --out`, a user's folder for `--output`/`--out`, someone's PLY or video)", "exit 2, one line; never replaced, `--overwrite` or not")
def test_render_refuses_a_folder_or_video_of_the_user(run_dir, tmp_path):
    photos = user_folder(tmp_path / "holiday", **{"IMG_0001_render.png": "not a render"})
    run_cli("render", run_dir, "--out", photos, "--overwrite", code=2,
            match="not a render folder written by splat-render", watch=[tmp_path])
    video = tmp_path / "wedding.mp4"
    video.write_bytes(b"\0\0\0\x18ftypmp42")
    run_cli("render", run_dir, "--path", "spiral", "--frames", 2, "--out", video, "--overwrite",
            code=2, match="not a video written by splat-render", watch=[tmp_path])


@pytest.mark.bad_input("an output that the same command wrote before", "exit 2 asking for `--overwrite`; with it, only what the command wrote is removed (the user's other files stay; symlinks are unlinked, never followed)")
def test_render_refreshes_its_own_folder_with_overwrite_keeping_other_files(run_dir, tmp_path):
    out = tmp_path / "renders"
    run_cli("render", run_dir, "--out", out, code=0, watch=[tmp_path], allowed=[out])
    assert json.loads((out / MARKER).read_text())["written_by"] == "splat-render"
    with pytest.raises(DataError, match="--overwrite"):
        check_output(out, RENDER_FOLDER)
    (out / "notes.txt").write_text("mine")
    (out / "old_view_render.png").write_bytes(b"a render of a view that no longer exists")
    run_cli("render", run_dir, "--out", out, "--overwrite", code=0, watch=[tmp_path], allowed=[out])
    assert (out / "notes.txt").read_text() == "mine" and not (out / "old_view_render.png").exists()


# ------------------------------------------------------------------ an input run's layout and its dataset (issue 60)


def _dataset_of(run: Path) -> Path:
    """The dataset folder that the run's config.json records."""
    return Path(json.loads((run / "config.json").read_text())["config"]["resolved_data"]["path"])


@pytest.mark.bad_input("`splat-export --out` or `splat-render --out` inside an input run's checkpoints/renders or inside the dataset folder", "exit 2, one line naming the path; nothing written")
def test_export_refuses_a_ply_inside_the_runs_checkpoints(run_dir, tmp_path):
    target = run_dir / "checkpoints" / "new.ply"
    r = run_cli("export", run_dir, "--out", target, code=2, watch=[run_dir, tmp_path])
    assert r.message == (f"error: {target}: --out is inside the run folder's checkpoints/ (managed by splat-train); "
                         f"choose a separate PLY file")
    os.symlink(run_dir / "checkpoints", tmp_path / "link")  # compared resolved: links followed, `..` removed
    for sneaky in (tmp_path / "link" / "new.ply", run_dir / "no-such" / ".." / "checkpoints" / "new.ply"):
        run_cli("export", run_dir, "--out", sneaky, "--overwrite", code=2,
                match="is inside the run folder's checkpoints/", watch=[run_dir, tmp_path])


@pytest.mark.bad_input("`splat-export --out` or `splat-render --out` inside an input run's checkpoints/renders or inside the dataset folder", "exit 2, one line naming the path; nothing written")
def test_render_refuses_an_output_inside_the_runs_dataset_folder(run_dir, tmp_path):
    data = _dataset_of(run_dir)
    target = data / "my-renders"
    r = run_cli("render", run_dir, "--out", target, code=2, watch=[data, run_dir])
    assert r.message == (f"error: {target}: --out is inside the run's dataset folder {data.resolve()}; "
                         f"choose a separate render folder")
    run_cli("render", run_dir, "--out", data, "--overwrite", code=2, match="is the run's dataset folder",
            watch=[data, run_dir])
    run_cli("render", run_dir, "--path", "spiral", "--frames", 2, "--out", data / "images" / "spiral.mp4",
            code=2, match="is inside the run's dataset folder", watch=[data, run_dir])


@pytest.mark.bad_input("`splat-export --out` or `splat-render --out` inside an input run's checkpoints/renders or inside the dataset folder", "exit 2, one line naming the path; nothing written")
def test_render_never_writes_a_video_over_the_runs_own_files(run_dir):
    """A video in a run folder is recognised as splat-render's, but not in place of config.json."""
    config = run_dir / "config.json"
    run_cli("render", run_dir, "--path", "spiral", "--frames", 2, "--out", config, "--overwrite", code=2,
            match=f"{config}: --out is the run folder's config.json (managed by splat-train)", watch=[run_dir])


def test_a_runs_default_outputs_stay_the_commands_own(run_dir):
    """The defaults inside the run stay the commands' own (RUN/renders, RUN/point_cloud.ply, RUN/spiral.mp4);
    no other output may be or lie inside an entry of the run's layout."""
    from splat_framework.files.output_paths import PLY_FILE

    inputs = run_inputs(run_dir)
    check_output(run_dir / "renders", RENDER_FOLDER, overwrite=True, inputs=inputs)
    check_output(run_dir / "point_cloud.ply", PLY_FILE, overwrite=True, inputs=inputs)
    check_output(run_dir / "spiral.mp4", VIDEO_FILE, overwrite=True, inputs=inputs)
    with pytest.raises(DataError, match="is the run folder's point_cloud.ply"):  # splat-export's, not a video's
        check_output(run_dir / "point_cloud.ply", VIDEO_FILE, overwrite=True, inputs=inputs)
    with pytest.raises(DataError, match="is inside the run folder's renders"):
        check_output(run_dir / "renders" / "mine", RENDER_FOLDER, inputs=inputs)
    with pytest.raises(DataError, match="holds the run folder's config.json"):
        check_output(run_dir.parent, RENDER_FOLDER, inputs=inputs)


@pytest.mark.bad_input("an output that is, holds or lies inside the input (`splat-process images DIR --out DIR`, `splat-train --output DATA/run`, `splat-match --out DATA`)", "exit 2, one line; the input is untouched, with or without `--overwrite`")
def test_train_refuses_an_output_inside_a_dataset_named_under_splat_data(dataset, tmp_path):
    elsewhere = user_folder(tmp_path / "elsewhere")  # the current folder: --data is found under $SPLAT_DATA
    run_cli("train", "3dgs", "--data", dataset.name, "--output", dataset / "run", "--steps", 1,
            code=2, match="inside the input", watch=[tmp_path], cwd=elsewhere,
            env={**os.environ, "SPLAT_DATA": str(dataset.parent)})


# ------------------------------------------------------------------ splat-match and splat-sweep


@pytest.mark.bad_input("an output that is, holds or lies inside the input (`splat-process images DIR --out DIR`, `splat-train --output DATA/run`, `splat-match --out DATA`)", "exit 2, one line; the input is untouched, with or without `--overwrite`")
def test_match_output_is_a_file_or_the_data(dataset, tmp_path):
    target = tmp_path / "matches.txt"
    target.write_text("mine")
    for out, says in ((target, "is not a folder"), (dataset, "is the input")):
        r = run_cli("match", "--data", dataset, "--out", out, code=2, watch=[tmp_path])
        assert says in r.stdout + r.stderr and len((r.stdout + r.stderr).strip().splitlines()) == 1


@pytest.mark.bad_input("an existing folder or file that the command did not write (a dataset for `splat-scene --out`, a user's folder for `--output`/`--out`, someone's PLY or video)", "exit 2, one line; never replaced, `--overwrite` or not")
def test_sweep_refuses_a_folder_that_is_not_a_sweep(tmp_path):
    folder = user_folder(tmp_path / "paper", **{"results.md": "my table"})
    run_cli("sweep", "--methods", "3dgs", "--data", tmp_path / "no-such-data", "--steps", 1, "--no-live",
            "--out", folder, code=2, match="not a sweep folder written by splat-sweep", watch=[tmp_path])


@pytest.mark.bad_input("an output that the same command wrote before", "exit 2 asking for `--overwrite`; with it, only what the command wrote is removed (the user's other files stay; symlinks are unlinked, never followed)")
def test_clearing_an_output_unlinks_links_inside_and_keeps_the_users_files(tmp_path):
    """--overwrite's removal (the same function for every command) never descends into a symlink."""
    from splat_framework.files.output_paths import RUN_FOLDER, clear_output

    elsewhere = user_folder(tmp_path / "elsewhere", **{"precious.png": "x", "a_render.png": "y"})
    run = _fake_run(tmp_path / "run")
    (run / "renders").mkdir()
    os.symlink(elsewhere, run / "renders" / "linked")  # a link inside a folder that is removed
    os.symlink(elsewhere / "a_render.png", run / "spiral.mp4")  # a link in place of a file we write
    (run / "notes.txt").write_text("mine")
    clear_output(run, RUN_FOLDER)
    assert sorted(p.name for p in run.iterdir()) == ["notes.txt"]
    assert sorted(p.name for p in elsewhere.iterdir()) == ["a_render.png", "precious.png"]


@pytest.mark.parametrize("umask", [0o022, 0o002, 0o077])
def test_written_results_follow_the_umask_and_private_folders_stay_private(tmp_path, umask, monkeypatch):
    """A run's results (config.json, metrics.json, renders, the PLY: every file written through
    atomic_write_bytes) get the mode ``open`` gives under the user's umask, not a temporary file's
    0600; inside a private folder (a cache's, 0700) they stay 0600."""
    import os
    import stat

    from splat_framework.runtime.io import atomic_write_bytes, atomic_write_json

    (tmp_path / "run").mkdir(mode=0o755)
    os.chmod(tmp_path / "run", 0o755)
    (tmp_path / "cache").mkdir()
    os.chmod(tmp_path / "cache", 0o700)
    from splat_framework.runtime import io

    old = os.umask(umask)
    monkeypatch.setattr(io, "_UMASK", {})  # the process's umask is read once: this one, set just now
    try:
        atomic_write_json(tmp_path / "run" / "metrics.json", {"a": 1})
        atomic_write_bytes(tmp_path / "run" / "model.ply", b"ply")
        atomic_write_bytes(tmp_path / "cache" / "entry.bin", b"x")
    finally:
        os.umask(old)
    for name in ("metrics.json", "model.ply"):
        assert stat.S_IMODE((tmp_path / "run" / name).stat().st_mode) == 0o666 & ~umask, name
    assert stat.S_IMODE((tmp_path / "cache" / "entry.bin").stat().st_mode) == 0o600
