"""splat-render: camera-path videos (frames, size, motion, cameras aimed at the scene) and test-view PNGs."""

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

pytestmark = pytest.mark.slow




def render_cli(monkeypatch, *argv):
    from splat_framework.cli.render import entrypoint

    monkeypatch.setattr(sys, "argv", ["splat-render", *map(str, argv)])
    entrypoint()


def read_video(path: Path) -> list[np.ndarray]:
    import cv2

    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    cap.release()
    return frames


def test_spiral_video(run_dir, tmp_path, monkeypatch):
    out = tmp_path / "spiral.mp4"
    render_cli(monkeypatch, run_dir, "--path", "spiral", "--frames", 8, "--out", out, "--depth")
    frames = read_video(out)
    assert len(frames) == 8
    assert all(f.shape == (48, 64, 3) for f in frames)
    for a, b in zip(frames, frames[1:]):
        assert np.abs(a.astype(int) - b.astype(int)).mean() > 1.0  # the camera moves
    depth = read_video(tmp_path / "spiral_depth.mp4")
    assert len(depth) == 8 and depth[0].shape == (48, 64, 3)
    from splat_framework.export.video import h264_available

    if h264_available():  # browser-playable: H.264 in yuv420p
        import av

        for name in ("spiral.mp4", "spiral_depth.mp4"):
            with av.open(str(tmp_path / name)) as c:
                ctx = c.streams.video[0].codec_context
                assert (ctx.name, ctx.format.name) == ("h264", "yuv420p")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["spiral.mp4", "spiral_depth.mp4"]  # no temp files


def test_auto_path_is_spiral_for_forward_scenes(run_dir, monkeypatch):
    render_cli(monkeypatch, run_dir, "--path", "auto", "--frames", 3)
    assert len(read_video(run_dir / "spiral.mp4")) == 3
    (run_dir / "spiral.mp4").unlink()


def test_spiral_cameras_look_at_the_scene(run_dir):
    from splat_framework.cameras import Camera
    from splat_framework.cli.render import camera_path
    from splat_framework.engine.run import load_run
    from splat_framework.pipeline.scene import background_for

    config, dm, model = load_run(run_dir)
    kind, cams = camera_path("spiral", dm, 8)
    assert kind == "spiral" and len(cams) == 8
    # geometry: the true surface (training depth maps lifted to 3D) lands inside every path frame
    pts = []
    for cam, batch in dm.train_views():
        d = batch["depth"][..., 0]
        ys, xs = torch.nonzero(d > 0, as_tuple=True)
        uv = torch.stack([xs + 0.5, ys + 0.5], -1).double()
        pts.append(cam.unproject_depth(uv, d[ys, xs].double()))
    pts = torch.cat(pts)
    for cam in cams:
        uv, z = cam.project(pts)
        inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        assert inside.double().mean() > 0.6
    # rendering: the trained Gaussians cover most of every frame ...
    bg = background_for(dm.scene, "cpu")
    with torch.no_grad():
        for cam in cams:
            assert (model.get_outputs(cam, bg).alpha > 0.5).float().mean() > 0.8
        # ... unlike a camera turned around (so the check above means something)
        c = cams[0]
        flip = torch.diag(torch.tensor([-1.0, 1.0, -1.0, 1.0], dtype=c.world_to_cam.dtype))
        back = Camera(c.K, flip @ c.world_to_cam, c.width, c.height, c.near, c.far)
        assert (model.get_outputs(back, bg).alpha > 0.5).float().mean() < 0.2


def test_test_views_write_pngs(run_dir, tmp_path, monkeypatch):
    import cv2

    from splat_framework.files.output_paths import MARKER

    out = tmp_path / "pngs"
    render_cli(monkeypatch, run_dir, "--path", "test", "--out", out)
    names = sorted(p.name for p in out.iterdir())
    expected = [MARKER, *(f"image{i:03d}_{k}.png" for i in (0, 8, 16) for k in ("render", "depth"))]
    assert names == sorted(expected)  # the marker: splat-render wrote this folder (and may replace it)
    assert cv2.imread(str(out / "image000_render.png")).shape == (48, 64, 3)


def test_bad_arguments_exit_2(run_dir, tmp_path, monkeypatch, capsys):
    for argv in ([tmp_path / "nope", "--path", "spiral"], [run_dir, "--path", "spiral", "--frames", 0]):
        with pytest.raises(SystemExit) as e:
            render_cli(monkeypatch, *argv)
        assert e.value.code == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("error:") and "\n" not in err


@pytest.mark.bad_input("`splat-render`, `splat-eval` or `splat-export` on a mistyped run folder, or on a file",
                       "exit 2, one line: no such run folder (or not a folder); nothing written")
def test_a_mistyped_run_folder_is_no_such_run_folder(tmp_path):
    from cli_harness import run_cli

    missing = tmp_path / "outputs" / "fren"
    run_cli("render", missing, code=2, match=f"error: {missing}: no such run folder", watch=[tmp_path])
    run_cli("eval", missing, code=2, match=f"error: {missing}: no such run folder", watch=[tmp_path])
    (tmp_path / "afile").write_text("x")
    run_cli("export", tmp_path / "afile", "--out", tmp_path / "x.ply", code=2,
            match="not a run folder (a file, not a folder)", watch=[tmp_path])
