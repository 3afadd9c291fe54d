"""The Triton compositing kernels (render/_triton.py), tested without a GPU: Triton's interpreter
(``TRITON_INTERPRET=1``) runs the same kernels on CPU tensors, against the brute-force reference of
test_rasterizer and the eager torch kernels, forward and every gradient, in float32 and float64;
and every kernel is compiled ahead of time for Ampere (sm_80) and Hopper (sm_90). Also the
``RenderSettings.rasterizer`` switch: what each choice runs where, and how a choice that cannot run fails."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from types import SimpleNamespace

import pytest
import test_rasterizer as ref
import torch

from splat_framework.errors import DataError
from splat_framework.render import RenderSettings, _triton, backend, rasterizer

triton = pytest.importorskip("triton", reason="triton is not installed (the test extra pins it)")


TRITON = RenderSettings(rasterizer="triton")


@pytest.fixture
def interpreted(monkeypatch):
    """Every rasterize() of the test without ``settings`` composites with the Triton kernels, run by the
    interpreter (conftest.py turns it on before triton is imported)."""
    assert _triton.language_interpreted(), "triton was imported before conftest.py set TRITON_INTERPRET=1"
    monkeypatch.setenv("TRITON_INTERPRET", "1")
    monkeypatch.setattr(rasterizer, "_DEFAULT_SETTINGS", TRITON)
    assert backend.kernels_for(torch.device("cpu"), TRITON).name == "triton"


def _render_and_grads(params, viewmat, K, width, height, weights, **kw):
    out = rasterizer.rasterize(*params, viewmat, K, width, height, **kw)
    wr, wd, wa = weights
    loss = (out.rgb * wr).sum() + 0.1 * (out.depth * wd).sum() + (out.alpha * wa).sum()
    return out, torch.autograd.grad(loss, params)


@pytest.mark.parametrize("seed", [0, 1])
def test_triton_matches_bruteforce_float32(interpreted, seed):
    ref._compare(40, 5 + seed, 37, 29, torch.float32, grad_rtol=2e-3, tile_size=8)


@pytest.mark.slow  # Triton's interpreter on more than a tiny scene
def test_triton_matches_bruteforce_float64_many_chunks(interpreted):
    # termination across depth chunks: each chunk's launch starts from the transmittance the last left
    ref._compare(60, 3, 33, 26, torch.float64, tile_size=8, chunk_pairs=16)


def test_triton_matches_bruteforce_sh_and_off_centre(interpreted):
    ref._compare(30, 13, 27, 21, torch.float64, sh_k=16, sh_degree=3, tile_size=8)
    ref._compare(40, 7, 41, 17, torch.float64, cx=14.0, cy=11.5, tile_size=8)


def test_triton_tile_16_and_a_tile_that_is_no_power_of_two(interpreted):
    ref._compare(40, 2, 37, 29, torch.float64, tile_size=16)
    ref._compare(40, 4, 37, 29, torch.float64, tile_size=6)  # 36 pixels in a 64-lane block


@pytest.mark.slow  # Triton's interpreter on more than a tiny scene
def test_triton_early_termination_opaque_scene_and_clamped_alpha(interpreted):
    ref.test_early_termination_dense_opaque_scene()
    ref.test_clamped_alpha_opacity_one()


@pytest.mark.slow  # Triton's interpreter on more than a tiny scene
def test_triton_absgrad_and_gradcheck(interpreted):
    ref.check_absgrad()
    ref.test_gradcheck_tiny_scene()


def test_triton_off_image_empty_tiles_and_no_gaussians(interpreted):
    ref.test_culling_near_far_behind_offscreen()  # behind, beyond far, off the image: empty tiles
    ref.test_zero_gaussians_returns_background()
    ref.test_all_culled_and_inference_mode()
    ref.test_huge_gaussian_covers_image_and_stays_finite()


def test_triton_ties_in_depth_match_the_torch_kernels(interpreted, monkeypatch):
    # Gaussians at exactly the same depths (pairs in input order), fully opaque ones among them
    width, height = 40, 32
    viewmat, K = ref.make_camera(width, height, dtype=torch.float32)
    means, quats, scales, opac, colors = ref.random_scene(90, 31, dtype=torch.float32, spread=0.8)
    means[:, 2] = torch.round(means[:, 2] * 2) / 2  # nine depth values shared by ten Gaussians each
    opac[::7] = 1.0
    params = [p.requires_grad_() for p in (means, quats, scales, opac, colors)]
    weights = ref._loss_weights(height, width, 2, torch.float32)
    out_t, g_t = _render_and_grads(params, viewmat, K, width, height, weights, tile_size=8)
    out_e, g_e = _render_and_grads(params, viewmat, K, width, height, weights, tile_size=8,
                                   settings=RenderSettings(rasterizer="torch"))
    assert out_e.alpha.max() > 0.9 and (out_e.alpha < 0.01).any()  # opaque parts and empty ones
    for a, b in ((out_t.rgb, out_e.rgb), (out_t.depth, out_e.depth), (out_t.alpha, out_e.alpha)):
        assert (a - b).abs().max() <= 1e-4
    for name, a, b in zip(["means", "quats", "scales", "opacities", "colors"], g_t, g_e):
        assert (a - b).abs().max() <= 1e-3 * b.abs().max(), name
    assert torch.equal(out_t.meta["visible"], out_e.meta["visible"])
    assert torch.equal(out_t.meta["radii"], out_e.meta["radii"])


def test_a_triton_render_reads_the_device_once(interpreted):
    """The Triton path's forward and backward read the host once (what a CUDA render waits for): the
    visible Gaussians' count with their rectangles' tile rows and tiles. The one depth chunk bins into
    room for that many tiles (the unused room sorted last, counted in no tile), every tile goes to
    the kernels (no list of the tiles with pairs), the tile counts are a scatter (bincount reads its
    largest id)."""
    from splat_framework.testing.host_syncs import count_host_syncs

    width, height = 40, 32
    viewmat, K = ref.make_camera(width, height, dtype=torch.float32)
    params = [p.requires_grad_() for p in ref.random_scene(60, 5, dtype=torch.float32, spread=0.8)]
    weights = ref._loss_weights(height, width, 2, torch.float32)
    with count_host_syncs() as syncs:
        out, grads = _render_and_grads(params, viewmat, K, width, height, weights, tile_size=8)
    assert (out.alpha < 0.01).any() and grads[0].abs().sum() > 0  # empty tiles among the rest
    assert syncs.total() == 1 and next(iter(syncs.by_place()))[1].startswith("_composite.py:"), syncs.report()


_AOT = """
from splat_framework.render._triton import compile_for
for capability, tile in ((80, 8), (90, 8), (90, 16)):
    built = compile_for(capability, tile)
    assert set(built) == {"forward0", "backward0", "backward1"}, built
    for name, kernel in built.items():
        assert f".target sm_{capability}" in kernel.asm["ptx"], (capability, name)
        assert len(kernel.asm["cubin"]) > 1000, (capability, name)
        print(capability, tile, name, len(kernel.asm["cubin"]))
"""


def test_every_kernel_compiles_ahead_of_time_for_ampere_and_hopper(tmp_path):
    # in a process of its own: this one imported triton for the interpreter
    env = {k: v for k, v in os.environ.items() if k != "TRITON_INTERPRET"}
    env["TRITON_CACHE_DIR"] = str(tmp_path / "triton-cache")
    proc = subprocess.run([sys.executable, "-c", _AOT], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert len(proc.stdout.splitlines()) == 9, proc.stdout


def test_compile_for_refuses_in_an_interpreting_process():
    with pytest.raises(RuntimeError, match="without TRITON_INTERPRET=1"):
        _triton.compile_for(80)


def test_the_switch_on_a_cpu(monkeypatch):
    cpu = torch.device("cpu")
    monkeypatch.delenv("TRITON_INTERPRET", raising=False)
    assert backend.choose(cpu, RenderSettings(compile=True)) == "native"  # auto: unchanged on a CPU
    named_torch = RenderSettings(rasterizer="torch", compile=True)
    assert backend.choose(cpu, named_torch) == "torch" and backend.kernels_for(cpu, named_torch) is None
    assert backend.native_for(cpu, named_torch) is None  # projection and loss in torch too
    with pytest.raises(DataError, match=r"^rasterizer triton: the Triton kernels run on CUDA tensors"):
        backend.choose(cpu, RenderSettings(rasterizer="triton", compile=True))
    monkeypatch.setenv("TRITON_INTERPRET", "1")
    assert backend.choose(cpu, RenderSettings(rasterizer="triton", compile=True)) == "triton"
    # named: runs even where kernels are not compiled
    assert backend.choose(cpu, RenderSettings(rasterizer="native")) == "native"
    assert backend.choose(cpu, RenderSettings()) == "torch"  # auto, eager torch (tests, --no-compile)


def test_the_settings_are_made_once_from_the_flags_and_the_environment(tmp_path):
    """--rasterizer other than auto wins over SPLAT_RASTERIZER; SPLAT_COMPILE wins over --compile; a bad
    name is one line."""
    def made(rasterizer="auto", compile=True, **env):
        return RenderSettings.from_config(SimpleNamespace(rasterizer=rasterizer, compile=compile), env=env,
                                          cache_dir=tmp_path)

    assert made("torch", SPLAT_RASTERIZER="native").rasterizer == "torch"
    assert made(SPLAT_RASTERIZER="native").rasterizer == "native"
    assert made().rasterizer == "auto" and made().compile and made().cache_dir == tmp_path
    assert not made(SPLAT_COMPILE="0").compile
    assert made(compile=False, SPLAT_COMPILE="1").compile
    with pytest.raises(DataError, match="SPLAT_RASTERIZER='cuda': expected auto, native, triton or torch"):
        made(SPLAT_RASTERIZER="cuda")
    with pytest.raises(DataError, match="--rasterizer 'gsplat'"):
        RenderSettings(rasterizer="gsplat")


def test_auto_on_cuda_takes_triton_and_falls_back_in_one_line_without_it(monkeypatch):
    cuda = torch.device("cuda")
    compiled = RenderSettings(compile=True)
    assert backend.choose(cuda, compiled) == "triton"
    monkeypatch.setattr(_triton, "available", lambda: "triton cannot be imported (ImportError: no module)")
    monkeypatch.setattr(backend, "_WARNED", set())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert backend.choose(cuda, compiled) == "torch"
        assert backend.choose(cuda, compiled) == "torch"
    assert [str(w.message) for w in caught] == [
        "triton cannot be imported (ImportError: no module): rendering with the torch kernels"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert backend.choose(cuda, RenderSettings(rasterizer="native", compile=True)) == "torch"
    assert "rasterizer native: the native kernels run on CPU tensors" in str(caught[-1].message)


def test_a_cpu_launch_without_the_interpreter_refuses_in_one_line(monkeypatch):
    kernels = _triton.TritonKernels(interpret=False)
    table = torch.zeros(2, 11)
    with pytest.raises(RuntimeError, match="the Triton rasterizer runs CUDA tensors"):
        kernels.composite_forward(table, *(torch.zeros(1, dtype=torch.int64),) * 4, torch.zeros(1, 2),
                                  torch.ones(1, 64), torch.zeros(1, 5, 64), 8)


def test_splat_train_with_triton_on_a_cpu_is_exit_2_and_one_line(tmp_path):
    env = dict(os.environ, SPLAT_RASTERIZER="triton", SPLAT_CACHE=str(tmp_path / "cache"))
    env.pop("TRITON_INTERPRET", None)
    proc = subprocess.run([sys.executable, "-m", "splat_framework.cli.train", "3dgs", "--data", "synthetic/forward",
                           "--steps", "2", "--output", str(tmp_path / "run"), "--no-progress"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert lines[-1].startswith("error: rasterizer triton: the Triton kernels run on CUDA tensors"), proc.stderr
    assert "Traceback" not in proc.stderr
