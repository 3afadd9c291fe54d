"""Render settings as a value (:class:`RenderSettings`): two backends rendering in one process, and a
backend proving itself against the torch reference before a run uses it (render/proving.py)."""

from __future__ import annotations

import json
import warnings

import pytest
import test_rasterizer as ref
import torch

from splat_framework.render import RenderSettings, backend, prepare_kernels, proving, rasterize

CPU = torch.device("cpu")


def _render_and_grads(settings, params, viewmat, K, width, height):
    out = rasterize(*params, viewmat, K, width, height, settings=settings)
    loss = (out.rgb * 0.7).sum() + 0.1 * out.depth.sum() + out.alpha.square().sum()
    return [out.rgb, out.depth, out.alpha, *torch.autograd.grad(loss, params)]


def test_two_backends_render_in_one_process_and_agree_with_the_reference(native_module, monkeypatch, tmp_path):
    """A viewer on the torch kernels and a trainer on the native ones, their renders interleaved in one
    process: each takes its own kernels and both give the brute-force reference's image and gradients."""
    calls = []
    real = native_module.composite_forward
    monkeypatch.setattr(native_module, "composite_forward", lambda *args: calls.append(1) or real(*args))
    viewer = RenderSettings(rasterizer="torch")
    trainer = RenderSettings(rasterizer="native", compile=True, cache_dir=tmp_path)
    assert backend.kernels_for(CPU, viewer) is None and backend.kernels_for(CPU, trainer).name == "native"
    width, height, dtype = 37, 29, torch.float64
    viewmat, K = ref.make_camera(width, height, dtype=dtype)
    params = [p.requires_grad_() for p in ref.random_scene(40, 3, dtype=dtype)]
    rgb, depth, alpha = ref.reference_render(*params, viewmat, K, width, height)
    assert alpha.max() > 0.5, "nothing rendered: the test is vacuous"
    want = [rgb, depth, alpha, *torch.autograd.grad((rgb * 0.7).sum() + 0.1 * depth.sum() + alpha.square().sum(),
                                                    params)]
    for settings, native_calls in ((trainer, True), (viewer, False), (trainer, True), (viewer, False)):
        before = len(calls)
        got = _render_and_grads(settings, params, viewmat, K, width, height)
        assert (len(calls) > before) == native_calls
        for name, a, b in zip(["rgb", "depth", "alpha", "means", "quats", "scales", "opacities", "colors"], got, want):
            err = float((a - b).detach().abs().max() / b.detach().abs().max().clamp_min(1e-3))
            assert err < 1e-6, f"{settings.rasterizer}: {name} off by {err:.3g}"


def test_a_backend_that_agrees_is_kept_and_its_verdict_written_once(native_module, tmp_path, monkeypatch):
    settings = RenderSettings(compile=True, cache_dir=tmp_path)  # auto: native on a CPU
    monkeypatch.setattr(proving, "_VERDICTS", {})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert prepare_kernels(CPU, settings) == settings
    (kept,) = (tmp_path / "proofs").glob("native-*.json")
    assert json.loads(kept.read_text())["differences"] == ""
    assert prepare_kernels(CPU, RenderSettings()) == RenderSettings()  # eager torch: nothing to prove


@pytest.mark.parametrize("fault", ["forward", "backward"])
def test_a_backend_that_disagrees_is_refused_in_one_line_and_the_run_takes_torch(native_module, tmp_path, monkeypatch,
                                                                                 fault):
    """A planted fault in the native kernels (an offset in the image, or scaled gradients): the backend is
    refused with one line naming what differs, renders take the torch kernels, and the verdict, kept in
    the cache folder, refuses it in a later process without rendering again."""
    if fault == "forward":
        real = native_module.composite_forward

        def planted(*args):
            n_incl = real(*args)
            args[7].add_(0.05)  # out [T, F, P]
            return n_incl

        monkeypatch.setattr(native_module, "composite_forward", planted)
    else:
        real_backward = native_module.composite_backward

        def planted(*args):
            real_backward(*args)
            args[10].mul_(1.5)  # the gradient tables

        monkeypatch.setattr(native_module, "composite_backward", planted)
    monkeypatch.setattr(proving, "_VERDICTS", {})
    settings = RenderSettings(compile=True, cache_dir=tmp_path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        used = prepare_kernels(CPU, settings)
    assert used == settings.replace(rasterizer="torch")
    assert backend.backend_name(CPU, used) == "torch (compiled)"
    (message,) = [str(w.message) for w in caught]
    assert message.startswith("rasterizer native: refused, it disagrees with the torch reference on cpu ")
    assert message.endswith("; rendering with the torch kernels") and "\n" not in message
    if fault == "forward":
        assert "image: off by up to" in message
    else:
        assert "image" not in message and "grad of means: off by up to" in message
    (kept,) = (tmp_path / "proofs").glob("native-*.json")
    assert json.loads(kept.read_text())["differences"]
    # a later process: the kept verdict, nothing rendered
    monkeypatch.setattr(proving, "_VERDICTS", {})
    monkeypatch.setattr(proving, "differences", lambda device, settings: pytest.fail("proved again"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert prepare_kernels(CPU, settings).rasterizer == "torch"
    assert [str(w.message) for w in caught] == [message]


def test_a_verdict_is_keyed_by_backend_version_and_device(monkeypatch):
    key = proving._version_key("native", CPU)
    assert proving._version_key("triton", CPU) != key
    monkeypatch.setattr(torch, "__version__", "0.0-other")
    assert proving._version_key("native", CPU) != key
    monkeypatch.undo()
    monkeypatch.setattr(torch.backends.cpu, "get_cpu_capability", lambda: "SOMETHING-ELSE")
    assert proving._version_key("native", CPU) != key


def test_an_edited_verdict_is_not_trusted_and_the_backend_is_proved_again(native_module, tmp_path, monkeypatch):
    """The kept verdict is loaded only when this user's signed manifest vouches for it: a verdict file
    edited to say "agrees" (or to refuse) is ignored and the kernels are proved again."""
    settings = RenderSettings(compile=True, cache_dir=tmp_path)
    monkeypatch.setattr(proving, "_VERDICTS", {})
    monkeypatch.setattr(proving, "differences", lambda device, settings: "image: off by up to 1")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert prepare_kernels(CPU, settings).rasterizer == "torch"
    (kept,) = (tmp_path / "proofs").glob("native-*.json")
    kept.write_text(json.dumps({"backend": "native", "differences": ""}))  # edited: no checksum, not the manifest's
    proved = []
    monkeypatch.setattr(proving, "_VERDICTS", {})
    monkeypatch.setattr(proving, "differences", lambda device, settings: proved.append(1) or "")
    assert prepare_kernels(CPU, settings) == settings and proved == [1]
