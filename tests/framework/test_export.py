"""PLY export in the 3DGS reference layout: header, channel order, round trip through the rasterizer, CLI."""

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from splat_framework.errors import DataError
from splat_framework.export.ply import export_ply, gaussians_for_export, load_ply, ply_property_names, write_ply
from splat_framework.model.gaussians import GaussianModel
from splat_framework.render import rasterize

# What the 3DGS reference (GaussianModel.construct_list_of_attributes) writes for SH degree 3.
REFERENCE_NAMES = (
    ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    + [f"f_rest_{i}" for i in range(45)]
    + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
)




def read_header(path: Path) -> tuple[list[str], int]:
    """(header lines without comments, byte offset of the data)."""
    lines = []
    with open(path, "rb") as f:
        while True:
            line = f.readline().decode("ascii").rstrip("\n")
            if not line.startswith("comment "):
                lines.append(line)
            if line == "end_header":
                return lines, f.tell()


def random_gaussians(n=7, k1=15, seed=0):
    g = torch.Generator().manual_seed(seed)
    return {
        "means": torch.randn(n, 3, generator=g),
        "quats": torch.randn(n, 4, generator=g),
        "scales": torch.randn(n, 3, generator=g),
        "opacities": torch.randn(n, generator=g),
        "sh0": torch.randn(n, 1, 3, generator=g),
        "shN": torch.randn(n, k1, 3, generator=g),
    }


def test_header_matches_the_reference(tmp_path):
    g = random_gaussians()
    path = write_ply(tmp_path / "g.ply", g)
    lines, offset = read_header(path)
    assert lines[:3] == ["ply", "format binary_little_endian 1.0", "element vertex 7"]
    props = lines[3:-1]
    assert all(p.startswith("property float ") for p in props)
    assert [p.split()[-1] for p in props] == REFERENCE_NAMES == ply_property_names(15)
    assert path.stat().st_size == offset + 7 * len(REFERENCE_NAMES) * 4
    assert path.read_bytes().split(b"\n")[2] == b"comment written by splat-export"  # how splat-export knows its files
    assert not list(tmp_path.glob(".*tmp"))  # atomic write left nothing behind


def test_values_and_channel_major_sh_order(tmp_path):
    g = random_gaussians(n=5, k1=8)  # SH degree 2
    path = write_ply(tmp_path / "g.ply", g)
    lines, offset = read_header(path)
    names = [p.split()[-1] for p in lines[3:-1]]
    raw = np.frombuffer(path.read_bytes()[offset:], dtype=np.dtype([(n, "<f4") for n in names]))
    for c in range(3):
        for k in range(8):
            np.testing.assert_array_equal(raw[f"f_rest_{c * 8 + k}"], g["shN"][:, k, c].numpy())
        np.testing.assert_array_equal(raw[f"f_dc_{c}"], g["sh0"][:, 0, c].numpy())
    np.testing.assert_array_equal(raw["rot_0"], g["quats"][:, 0].numpy())  # w first
    np.testing.assert_array_equal(raw["opacity"], g["opacities"].numpy())  # logit, as stored
    for n in ("nx", "ny", "nz"):
        assert (raw[n] == 0).all()
    back = load_ply(path)
    for k, v in g.items():
        assert back[k].shape == v.shape and torch.equal(back[k], v), k


def test_degree_zero_has_no_f_rest(tmp_path):
    g = random_gaussians(n=3, k1=0)
    path = write_ply(tmp_path / "g.ply", g)
    lines, _ = read_header(path)
    assert not any("f_rest" in line for line in lines)
    assert load_ply(path)["shN"].shape == (3, 0, 3)


def test_a_model_with_no_gaussians_writes_an_empty_ply(tmp_path):
    # a run whose pruning removed every Gaussian still writes its point_cloud.ply (0 vertices, the full layout)
    path = write_ply(tmp_path / "g.ply", random_gaussians(n=0, k1=15))
    assert "element vertex 0" in read_header(path)[0]
    assert load_ply(path)["shN"].shape == (0, 15, 3)


class _RayModel:
    """Stand-in for a ray-based model: true positions differ from params['means'], extra keys present."""

    def __init__(self):
        self.params = random_gaussians(n=4) | {
            "z": torch.ones(4), "ray_o": torch.zeros(4, 3), "ray_d": torch.ones(4, 3),
            "is_ray": torch.ones(4), "is_match": torch.ones(4),
        }

    def positions(self):
        return self.params["ray_o"] + self.params["z"][:, None] * self.params["ray_d"]

    export_gaussians = GaussianModel.export_gaussians  # the base's: positions() and the standard keys


def test_ray_models_export_true_positions_and_no_extra_keys(tmp_path):
    model = _RayModel()
    path = export_ply(model, tmp_path / "r.ply")
    lines, _ = read_header(path)
    assert [p.split()[-1] for p in lines[3:-1]] == REFERENCE_NAMES
    assert torch.equal(load_ply(path)["means"], torch.ones(4, 3))


def test_bad_files_raise_data_error(tmp_path):
    path = write_ply(tmp_path / "g.ply", random_gaussians())
    data = path.read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-10])
    with pytest.raises(DataError, match="truncated"):
        load_ply(tmp_path / "cut.ply")
    (tmp_path / "txt.ply").write_text("hello\n")
    with pytest.raises(DataError, match="not a PLY"):
        load_ply(tmp_path / "txt.ply")
    with pytest.raises(DataError, match="cannot open"):
        load_ply(tmp_path / "missing.ply")


def test_round_trip_renders_identically(run_dir, tmp_path, monkeypatch):
    from splat_framework.cli.export import entrypoint
    from splat_framework.engine.run import load_run
    from splat_framework.pipeline.scene import background_for

    out = tmp_path / "out.ply"
    monkeypatch.setattr(sys, "argv", ["splat-export", str(run_dir), "--out", str(out)])
    entrypoint()
    lines, _ = read_header(out)
    assert [p.split()[-1] for p in lines[3:-1]] == REFERENCE_NAMES

    config, dm, model = load_run(run_dir)
    back = load_ply(out)
    ref = gaussians_for_export(model)
    assert back.keys() == ref.keys()
    for k in ref:
        assert torch.equal(back[k], ref[k]), k

    bg = background_for(dm.scene, "cpu")
    cam, _ = dm.eval_views()[0]
    d = model.active_sh_degree
    with torch.no_grad():
        expect = model.get_outputs(cam, bg)
        got = rasterize(
            back["means"], back["quats"], torch.exp(back["scales"]), torch.sigmoid(back["opacities"]),
            torch.cat([back["sh0"], back["shN"]], 1)[:, : (d + 1) ** 2],
            cam.world_to_cam.float(), cam.K.float(), cam.width, cam.height,
            sh_degree=d, background=bg, near_plane=0.01, depth_mode=config.model.depth_mode,
        )
    assert d == 3  # the run reached full SH degree, so f_rest matters
    assert (got.rgb - expect.rgb).abs().max() < 1e-5
    assert (got.depth - expect.depth).abs().max() < 1e-5
    assert (got.alpha - expect.alpha).abs().max() < 1e-5


@pytest.mark.bad_input("`splat-scene --out FILE`, `splat-export --out DIR`, `--data some/dir/..`", "exit 2 with one line; run folders never leave `outputs/`")
def test_default_output_and_bad_run_dir(run_dir, tmp_path, monkeypatch, capsys):
    # the default output lands in the run folder; work on a copy so the shared run stays untouched
    import shutil

    from splat_framework.cli.export import ExportArgs, main

    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy, ignore=shutil.ignore_patterns("renders"))
    assert main(ExportArgs(copy)) == [copy / "point_cloud.ply"]
    assert load_ply(copy / "point_cloud.ply")["means"].shape[0] > 0

    from splat_framework.cli.export import entrypoint

    monkeypatch.setattr(sys, "argv", ["splat-export", str(tmp_path / "nope")])
    with pytest.raises(SystemExit) as e:
        entrypoint()
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: {tmp_path / 'nope'}: no such run folder"
    # --out naming an existing folder: exit 2, one line, nothing written
    (tmp_path / "a_dir").mkdir()
    monkeypatch.setattr(sys, "argv", ["splat-export", str(copy), "--out", str(tmp_path / "a_dir")])
    with pytest.raises(SystemExit) as e:
        entrypoint()
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "a_dir" in err and "is a folder" in err and "\n" not in err
    assert not any((tmp_path / "a_dir").iterdir())


def test_loading_a_run_checks_every_row_but_composites_nothing(run_dir, monkeypatch):
    """Loading a run (export, render, view, eval) renders once to check the parameters fit the
    rasterizer, from a camera every Gaussian is behind: every row is projected and none composited
    (a camera inside fern's 106k Gaussians composited for 51 s before each export)."""
    from splat_framework.engine.run import load_trained_model
    from splat_framework.render import rasterizer

    real, seen = rasterizer.composite, []

    def spy(means2d, conics, opacities, rgb, depths, background, fp, *rest):
        seen.append((means2d.shape[0], int(fp.hit.sum())))
        return real(means2d, conics, opacities, rgb, depths, background, fp, *rest)

    monkeypatch.setattr(rasterizer, "composite", spy)
    _, model = load_trained_model(run_dir, "cpu")
    assert seen == [(model.num_gaussians, 0)] and model.num_gaussians > 1000
