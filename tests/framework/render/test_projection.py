"""The projection compiled by torch.compile (training runs) against the eager one: the same
outputs and gradients for SH and plain colours, one graph whatever the number of Gaussians and
whatever the SH degree (3DGS raises it mid-run), and a render that is backpropagated twice."""

from __future__ import annotations

import shutil
import warnings

import pytest
import torch

import test_rasterizer as ref
from splat_framework.render import _kernels, _project, rasterize

pytestmark = pytest.mark.skipif(not (shutil.which("c++") or shutil.which("g++")),
                                reason="no C++ compiler: torch.compile cannot build CPU kernels here")


def _grads(n, seed, sh_k, degree=None, *, twice=False):
    width, height = 40, 30
    viewmat, K = ref.make_camera(width, height)
    params = [p.requires_grad_() for p in ref.random_scene(n, seed, dtype=torch.float32, sh_k=sh_k)]
    out = rasterize(*params, viewmat, K, width, height, sh_degree=degree)
    loss = out.rgb.square().sum() + 0.1 * out.depth.sum() + out.alpha.sum()
    grads = torch.autograd.grad(loss, params, retain_graph=twice)
    if twice:  # the same graph again: the compiled projection's backward must allow it
        again = torch.autograd.grad(loss, params)
        for a, b in zip(grads, again):
            torch.testing.assert_close(a, b)
    return [out.rgb.detach(), out.depth.detach(), out.meta["radii"]] + list(grads)


def test_compiled_projection_matches_eager(tmp_path, monkeypatch):
    from torch._dynamo.utils import counters

    # plain colours and SH, two sizes each; then each lower SH degree, of 16 or of only the bands it uses
    cases = [(50, 0, None), (80, 1, None), (60, 2, 16), (90, 3, 16), (60, 5, 16, 0), (70, 6, 16, 1), (40, 7, 9, 2),
             (50, 8, 4, 1)]
    eager = [_grads(*case) for case in cases]
    monkeypatch.delenv("SPLAT_COMPILE")
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path / "inductor"))
    monkeypatch.setenv("SPLAT_THREADS", str(torch.get_num_threads()))
    monkeypatch.setattr(_project, "_compiled_projection", _project._compiled_projection.__wrapped__)
    compiled_projection = _project._compiled_projection()  # this test's own, made afresh
    monkeypatch.setattr(_project, "_compiled_projection", lambda: compiled_projection)
    # the compositing stays eager: only the projection is compiled here
    monkeypatch.setattr("splat_framework.render.rasterizer.native_for", lambda device: None)
    monkeypatch.setattr("splat_framework.render._composite.get_kernels",
                        lambda: (_kernels.gathering_fwd(_kernels.fwd_round), _kernels.gathering_bwd(_kernels.bwd_round)))
    graphs = counters["stats"]["unique_graphs"]
    _kernels.set_compile(True)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            made = []  # graphs compiled so far, after each case
            for case, want in zip(cases, eager):
                for got, expected in zip(_grads(*case), want):
                    torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-5)
                made.append(counters["stats"]["unique_graphs"] - graphs)
            _grads(70, 4, 16, twice=True)
    finally:
        _kernels.set_compile(False)
    assert not [str(w.message) for w in caught if "could not compile" in str(w.message)]
    assert made[0] > 0  # the compiled projection really ran
    assert made[1] == made[0] and made[3] == made[2]  # another number of Gaussians: no new graph
    assert made[-1] == made[3]  # another SH degree, or fewer bands given: no new graph either
