"""The native CPU kernels (render/native/*.cpp) against the brute-force reference of
test_rasterizer: forward, gradients, float64 gradcheck, early termination, clamped alphas; their
binning against the torch binning; and how they are chosen, built and given up on."""

from __future__ import annotations

import os
import shutil
import warnings
from pathlib import Path

import pytest
import test_rasterizer as ref
import torch

from splat_framework.render import RenderSettings, _native, backend, rasterizer


@pytest.fixture
def native(native_module, monkeypatch):
    """Every rasterize() of the test composites with the native kernels."""
    monkeypatch.setattr(backend, "native_for", lambda device, settings: native_module if device.type == "cpu" else None)
    monkeypatch.setattr(backend, "choose", lambda device, settings: "native" if device.type == "cpu" else "torch")
    return native_module


@pytest.mark.parametrize("seed", [0, 1])
def test_native_matches_bruteforce_float64(native, seed):
    ref._compare(40, seed, 37, 29, torch.float64)


def test_native_matches_bruteforce_small_tiles_many_chunks(native):
    # termination across depth chunks: each chunk starts from the transmittance the last one left
    ref._compare(60, 3, 33, 26, torch.float64, tile_size=8, block=4, chunk_pairs=16)


def test_native_matches_bruteforce_float32(native):
    # float32 uses the kernels' own exp (range reduction and a polynomial)
    ref._compare(40, 5, 37, 29, torch.float32, grad_rtol=2e-3)


@pytest.mark.parametrize("deg", [0, 3])
def test_native_matches_bruteforce_sh(native, deg):
    ref._compare(30, 10 + deg, 27, 21, torch.float64, sh_k=16, sh_degree=deg)


@pytest.mark.slow  # the brute-force reference on a large scene
def test_native_absgrad_matches_bruteforce(native):
    ref.check_absgrad()


def test_native_off_centre_tiles_and_settings(native):
    ref.test_non_square_off_centre_principal_point()
    ref.test_tile_and_block_settings_agree()


def test_native_early_termination_and_clamped_alpha(native):
    ref.test_early_termination_dense_opaque_scene()
    ref.test_clamped_alpha_opacity_one()


def test_native_gradcheck(native):
    ref.test_gradcheck_tiny_scene()


def test_native_gradients_are_the_same_bits_every_time_on_several_threads(native):
    # each thread adds its own tiles' pairs in a fixed order: no run-to-run rounding differences
    # (an exact resume replays the same steps), however the threads happen to be scheduled
    width, height = 96, 64
    viewmat, K = ref.make_camera(width, height)
    params = [p.requires_grad_() for p in ref.random_scene(400, 9, dtype=torch.float32)]
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        grads = []
        for _ in range(4):
            out = rasterizer.rasterize(*params, viewmat, K, width, height)
            grads.append(torch.autograd.grad((out.rgb.square().sum() + out.depth.sum()), params))
    finally:
        torch.set_num_threads(before)
    assert any(g.abs().sum() > 0 for g in grads[0])
    for other in grads[1:]:
        for a, b in zip(grads[0], other):
            assert torch.equal(a, b)


def test_native_float32_exp_is_accurate(native):
    # one Gaussian per pixel grid: the rendered alpha is o exp(-q/2) itself, from the kernels' exp
    width, height = 16, 16
    viewmat, K = ref.make_camera(width, height, dtype=torch.float32)
    params = ref.random_scene(1, 0, dtype=torch.float32, spread=0.0, scale=(0.0, 0.0))
    out = rasterizer._rasterize(*params, viewmat, K, width, height, sh_degree=None, background=None,
                                near_plane=0.01, far_plane=1e10, depth_mode="accumulated", eps2d=0.3,
                                tile_size=8, block=None, chunk_pairs=None, settings=RenderSettings(), absgrad=False)
    p64 = [p.double() for p in params]
    _, _, alpha = ref.reference_render(*p64, viewmat.double(), K.double(), width, height)
    assert alpha.max() > 0.1
    torch.testing.assert_close(out.alpha.double(), alpha, atol=2e-7, rtol=2e-6)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_native_depth_order_is_torchs_stable_argsort(native_module, dtype):
    # depths with ties (equal depths keep their input order), a wide range, negatives, -0 and +0
    gen = torch.Generator().manual_seed(3)
    keys = torch.cat([torch.rand(50_000, generator=gen, dtype=dtype) * 40 + 0.01,
                      torch.randint(0, 50, (20_000,), generator=gen).to(dtype) / 8,
                      torch.logspace(-30, 30, 1000, dtype=dtype), -torch.rand(500, generator=gen, dtype=dtype),
                      torch.tensor([0.0, -0.0, 0.0, -0.0, 1e-40], dtype=dtype)])  # 1e-40: a float32 denormal
    keys = keys[torch.randperm(keys.numel(), generator=gen)]
    order = native_module.stable_order(keys)
    assert order.dtype == torch.int64
    assert torch.equal(order, torch.argsort(keys, stable=True))
    # depths within one octave share their top digits: those passes are skipped, the order is the same
    near = 5 + torch.rand(3000, generator=gen, dtype=dtype)
    assert torch.equal(native_module.stable_order(near), torch.argsort(near, stable=True))
    assert native_module.stable_order(torch.empty(0, dtype=dtype)).numel() == 0
    with pytest.raises(RuntimeError, match="float32 or float64"):
        native_module.stable_order(torch.arange(4))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_native_footprints_are_the_torch_ones(native_module, dtype):
    # the same visible Gaussians in the same depth order (ties in depth, invalid ones, ones off
    # each side of the image, extents at whole pixels) and the same rectangles and rows
    from splat_framework.render import _composite as comp

    gen = torch.Generator().manual_seed(5)
    n, width, height = 20_000, 130, 90
    means2d = torch.rand(n, 2, generator=gen, dtype=dtype) * torch.tensor([width * 1.4, height * 1.4], dtype=dtype)
    means2d -= torch.tensor([width * 0.2, height * 0.2], dtype=dtype)
    means2d[:200] = means2d[:200].round() + 0.5  # centres on pixel centres, extents at whole pixels
    ext_x = torch.rand(n, generator=gen, dtype=dtype) * 12
    ext_y = torch.rand(n, generator=gen, dtype=dtype) * 12
    ext_x[:100], ext_y[100:200] = 1.0, 2.0
    ok = torch.rand(n, generator=gen) > 0.1
    depths = torch.randint(1, 400, (n,), generator=gen).to(dtype) / 16  # many ties
    cov2d = torch.rand(n, 3, generator=gen, dtype=dtype)
    qmax = torch.rand(n, generator=gen, dtype=dtype) * 11
    grid = comp.TileGrid(tile=8, ntx=17, nty=12, width=width, height=height)
    want = comp.tile_footprints(means2d, ext_x, ext_y, ok, depths, cov2d, qmax, grid)
    got = comp.tile_footprints(means2d, ext_x, ext_y, ok, depths, cov2d, qmax, grid, native=native_module)
    assert 1000 < want.ids.numel() < n
    for name in ("ids", "tx0", "tx1", "ty0", "ty1", "ell", "hit"):
        a, b = getattr(want, name), getattr(got, name)
        assert a.dtype == b.dtype and torch.equal(a, b), name
    none = comp.tile_footprints(means2d, ext_x, ext_y, torch.zeros_like(ok), depths, cov2d, qmax, grid,
                                native=native_module)
    assert none.ids.numel() == 0 and none.ell.shape == (0, 6) and not bool(none.hit.any())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_native_binning_gives_the_torch_binnings_pairs_in_the_same_order(native, dtype):
    # the same chunks, the same (tile, Gaussian) pairs sorted by (tile, depth), with and without
    # finished tiles, for chunks that start at the first Gaussian and further on
    from splat_framework.render import _composite as comp
    from splat_framework.render._project import footprint, project_and_shade

    width, height = 90, 70
    viewmat, K = ref.make_camera(width, height, dtype=dtype)
    means, quats, scales, opac, colors = ref.random_scene(600, 4, dtype=dtype)
    means2d, _, cov2d, depths, valid, _ = project_and_shade(means, quats, scales, colors, viewmat, K, width, height,
                                                            0.01, 1e10, 0.3, None)
    ext_x, ext_y, ok, qmax = footprint(cov2d, opac, valid)
    grid = comp.TileGrid(tile=8, ntx=12, nty=9, width=width, height=height)
    fp = comp.tile_footprints(means2d, ext_x, ext_y, ok, depths, cov2d, qmax, grid)
    done = torch.rand(grid.n_tiles, generator=torch.Generator().manual_seed(1)) < 0.4
    checked = 0
    for chunk_pairs in (64, 700, 100_000):
        for tile_done, pos in ((torch.zeros_like(done), 0), (done, 0), (done, 150)):
            first = not bool(tile_done.any())
            expected, next_pos = comp._torch_chunk(fp, grid, chunk_pairs, tile_done, pos, first)
            gid, count, offset, native_next = native.bin_chunk(fp.ids, fp.tx0, fp.tx1, fp.ty0, fp.ty1, fp.ell,
                                                               tile_done, pos, chunk_pairs, grid.tile, grid.ntx,
                                                               grid.nty, grid.width, grid.height)
            assert native_next == next_pos
            if expected is None:
                assert gid.numel() == 0
                continue
            assert expected[0].numel() >= gid.numel()  # the whole first chunk: the pairs, then unused room
            for a, b in zip((expected[0][: gid.numel()], *expected[1:]), (gid, count, offset)):
                assert torch.equal(a, b)
            assert not bool(count[tile_done].any())  # finished tiles get no pair
            checked += gid.numel()
    assert checked > 5000


def test_native_binning_on_two_threads_gives_the_same_pairs_call_after_call(native):
    # chunks big enough to be listed in two slices (over 16,384 pairs), binned again and again
    # with the lists kept from call to call (larger, smaller, larger): the torch binning's pairs
    from splat_framework.render import _composite as comp
    from splat_framework.render._project import footprint, project_and_shade

    width, height = 200, 150
    viewmat, K = ref.make_camera(width, height)
    means, quats, scales, opac, colors = ref.random_scene(6000, 4, dtype=torch.float32)
    means2d, _, cov2d, depths, valid, _ = project_and_shade(means, quats, scales, colors, viewmat, K, width, height,
                                                            0.01, 1e10, 0.3, None)
    ext_x, ext_y, ok, qmax = footprint(cov2d, opac, valid)
    grid = comp.TileGrid(tile=8, ntx=25, nty=19, width=width, height=height)
    fp = comp.tile_footprints(means2d, ext_x, ext_y, ok, depths, cov2d, qmax, grid)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        sizes = []
        for chunk_pairs, pos in ((60_000, 0), (20_000, 500), (60_000, 0), (3_000, 2000)):
            tile_done = torch.zeros(grid.n_tiles, dtype=torch.bool)
            expected, next_pos = comp._torch_chunk(fp, grid, chunk_pairs, tile_done, pos, pos == 0)
            gid, count, offset, native_next = native.bin_chunk(fp.ids, fp.tx0, fp.tx1, fp.ty0, fp.ty1, fp.ell,
                                                               tile_done, pos, chunk_pairs, grid.tile, grid.ntx,
                                                               grid.nty, grid.width, grid.height)
            assert native_next == next_pos
            assert expected[0].numel() >= gid.numel()  # the whole first chunk: the pairs, then unused room
            for a, b in zip((expected[0][: gid.numel()], *expected[1:]), (gid, count, offset)):
                assert torch.equal(a, b)
            sizes.append(gid.numel())
    finally:
        torch.set_num_threads(before)
    assert max(sizes) > 16_384 and min(sizes) < 16_384  # two slices and one


def test_native_kernels_are_chosen_for_cpu_renders_while_compiling(native_module, monkeypatch):
    monkeypatch.setattr(_native, "native_kernels", lambda cache_dir=None: native_module)
    compiled = RenderSettings(compile=True)
    assert backend.native_for(torch.device("cpu"), compiled) is native_module
    assert backend.kernels_for(torch.device("cpu"), compiled).composite is native_module
    assert backend.native_for(torch.device("meta"), compiled) is None  # another device: the torch kernels
    assert backend.native_for(torch.device("cpu"), RenderSettings()) is None  # eager: the torch kernels


def test_a_failed_build_warns_once_and_falls_back(monkeypatch, tmp_path):
    from torch.utils import cpp_extension

    calls = []

    def broken(**kwargs):
        calls.append(kwargs)
        raise RuntimeError("Ninja is required to load C++ extensions\nmore detail")

    monkeypatch.setattr(cpp_extension, "load", broken)
    monkeypatch.setattr(_native, "_STATE", {"module": None, "failed": False})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert _native.native_kernels(tmp_path) is None
        assert _native.native_kernels(tmp_path) is None  # not tried again in this process
    assert len(calls) == 1
    messages = [str(w.message) for w in caught]
    assert messages == ["could not build the native rasterizer kernels (RuntimeError: Ninja is required to load "
                        "C++ extensions); using the torch ones"]
    compiled = RenderSettings(compile=True, cache_dir=tmp_path)
    assert backend.native_for(torch.device("cpu"), compiled) is None  # renders take the torch.compile kernels
    assert backend.kernels_for(torch.device("cpu"), compiled) is None


def _recording_load(monkeypatch, build):
    """cpp_extension.load replaced by one that records whether torch's build lock was in the folder
    (torch's builder would wait on it forever) and then fails (the test builds nothing)."""
    from torch.utils import cpp_extension

    seen = []

    def fake_load(**kwargs):
        seen.append((build / "lock").exists())
        raise RuntimeError("not building in a test")

    monkeypatch.setattr(cpp_extension, "load", fake_load)
    monkeypatch.setattr(_native, "_STATE", {"module": None, "failed": False})
    return seen


def test_a_build_lock_left_by_a_killed_build_is_removed_however_young(tmp_path, monkeypatch, capsys):
    # a build killed a minute ago leaves torch's "lock" file: the next run used to wait on it
    # (42 minutes once, until an age limit of 10 minutes that it checked only before waiting)
    build = _native._build_dir(tmp_path)
    build.mkdir(parents=True)
    (build / "lock").touch()
    seen = _recording_load(monkeypatch, build)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _native.native_kernels(tmp_path)
    assert seen == [False]
    assert "removed a build lock left by a build that did not finish" in capsys.readouterr().err


def test_a_process_waits_for_a_live_builder_and_goes_on_when_it_dies(tmp_path, monkeypatch, capsys):
    import subprocess
    import sys
    import threading

    build = _native._build_dir(tmp_path)
    build.mkdir(parents=True)
    guard = build.parent / f"{build.name}.building"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time, filelock; l = filelock.FileLock(sys.argv[1]); l.acquire(); "
         "(open(sys.argv[2], 'w').close(), time.sleep(60))", str(guard), str(tmp_path / "held")])
    try:
        for _ in range(200):
            if (tmp_path / "held").exists():
                break
            holder.poll()
            assert holder.returncode is None
            threading.Event().wait(0.05)
        (build / "lock").touch()  # the holder's build is running: its lock is not touched while it lives
        killer = threading.Timer(1.0, holder.kill)  # the build is killed mid-way
        killer.start()
        seen = _recording_load(monkeypatch, build)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _native.native_kernels(tmp_path)
        assert holder.poll() is not None  # it waited until the holder was gone
        assert seen == [False]
        err = capsys.readouterr().err
        assert f"note: another process is building the native rasterizer kernels; waiting for it ({guard})" in err
    finally:
        holder.kill()
        holder.wait()


def test_a_built_library_is_loaded_as_it_is_whatever_the_build_tools_state(native_module, tmp_path):
    """A later process imports the checked library without asking ninja: with the build's
    ``.ninja_deps`` cut short (a build killed while writing it), ninja rebuilt it in every process
    (60-75 s a run), and without any compiler at all it still loads."""
    import subprocess
    import sys

    built = Path(native_module.__file__).parent
    cache = tmp_path / "cache"
    build = _native._build_dir(cache)
    shutil.copytree(built, build)  # the same key: the same sources, flags, torch and CPU
    (build / ".ninja_deps").write_bytes(b"# ninjadeps\n\x04\x00\x00\x00cut")
    stamp = (build / "splat_native.so").stat().st_mtime_ns
    code = ("import sys, warnings; warnings.simplefilter('error'); from pathlib import Path; "
            "from torch.utils import cpp_extension; from splat_framework.render import _native; "
            "cpp_extension.load = None; "  # any call to the builder fails
            "m = _native.native_kernels(Path(sys.argv[1])); print(Path(m.__file__).name, hasattr(m, 'composite_forward'))")
    env = dict(os.environ, PATH="/nowhere")  # no compiler, no ninja
    out = subprocess.run([sys.executable, "-c", code, str(cache)], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["splat_native.so", "True"]
    assert (build / "splat_native.so").stat().st_mtime_ns == stamp


def test_the_ninja_package_goes_on_path_only_where_no_ninja_is_found(monkeypatch):
    import os

    ninja = pytest.importorskip("ninja")
    monkeypatch.setenv("PATH", "/nowhere")
    monkeypatch.setattr(shutil, "which", lambda name: None)  # e.g. a venv's tools run without activating it
    _native._ninja_on_path()
    assert os.environ["PATH"].split(os.pathsep) == [ninja.BIN_DIR, "/nowhere"]
    monkeypatch.setenv("PATH", "/nowhere")
    monkeypatch.setattr(shutil, "which", lambda name: "/usr/bin/ninja")
    _native._ninja_on_path()
    assert os.environ["PATH"] == "/nowhere"  # a ninja on PATH is left alone


def test_build_folder_is_keyed_by_source_flags_and_cpu(tmp_path, monkeypatch):
    a = _native._build_dir(tmp_path)
    assert a.parent == tmp_path / "native"
    monkeypatch.setattr(torch.backends.cpu, "get_cpu_capability", lambda: "SOMETHING-ELSE")
    assert _native._build_dir(tmp_path) != a  # a cache shared with another CPU never loads this build
    monkeypatch.undo()
    monkeypatch.setattr(_native, "_compiler", lambda: "/usr/bin/g++-99 g++ 99")
    other = _native._build_dir(tmp_path)
    assert other != a and other.name.rsplit("-", 1)[0] == a.name.rsplit("-", 1)[0]  # another compiler builds its own
    assert _native._build_dir(None) is None


def test_native_gradients_are_the_same_bits_for_any_thread_count(native):
    # under SPLAT_THREADS=auto the count follows the machine's load: the sums of the backward are
    # ordered by gradient slots (one per core), not by threads, so a seed trains the same alone or
    # beside other work
    width, height = 96, 64
    viewmat, K = ref.make_camera(width, height)
    params = [p.requires_grad_() for p in ref.random_scene(400, 9, dtype=torch.float32)]
    before = torch.get_num_threads()
    grads = []
    try:
        for threads in (1, 2, 3):
            torch.set_num_threads(threads)
            out = rasterizer.rasterize(*params, viewmat, K, width, height)
            grads.append(torch.autograd.grad((out.rgb.square().sum() + out.depth.sum()), params))
    finally:
        torch.set_num_threads(before)
    for other in grads[1:]:
        for a, b in zip(grads[0], other):
            assert torch.equal(a, b)


def test_two_checkouts_sharing_a_cache_build_from_the_same_staged_sources(tmp_path, monkeypatch):
    """The build rules name ``build/src/module.cpp`` whichever checkout (package folder) builds:
    a second checkout (a worktree, another environment) with the same sources loads the library
    its neighbour built instead of rebuilding it (and a process loading it meanwhile no longer
    finds it missing and falls back to the torch kernels)."""
    from torch.utils import cpp_extension

    build = tmp_path / "cache" / "native" / "kernels-x"
    build.mkdir(parents=True)
    staged = []
    for checkout in ("one", "two"):
        folder = tmp_path / checkout / "native"
        shutil.copytree(_native._FOLDER, folder)
        monkeypatch.setattr(_native, "_FOLDER", folder)
        staged.append(_native._staged_sources(build))
        if checkout == "one":
            stamps = {p.name: p.stat().st_mtime_ns for p in (build / "src").iterdir()}
    assert staged[0] == staged[1] == build / "src" / "module.cpp"
    assert {p.name: p.stat().st_mtime_ns for p in (build / "src").iterdir()} == stamps  # same bytes: untouched
    (build / "src" / "composite.cpp").write_text("// edited in the cache\n")
    _native._staged_sources(build)  # what is compiled is always the package's own sources
    assert (build / "src" / "composite.cpp").read_bytes() == (_native._FOLDER / "composite.cpp").read_bytes()
    assert not list((build / "src").glob(".*"))  # no temporary file left behind

    seen = []

    def fake_load(**kwargs):
        seen.append(kwargs)
        raise RuntimeError("not building in a test")

    monkeypatch.setattr(cpp_extension, "load", fake_load)
    monkeypatch.setattr(_native, "_STATE", {"module": None, "failed": False})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _native.native_kernels(tmp_path / "cache")
    assert seen and seen[0]["sources"] == [str(_native._build_dir(tmp_path / "cache") / "src" / "module.cpp")]
