"""Host syncs: what a training step would make the host wait for on CUDA, counted on the CPU.

On a GPU a step is fastest when the host queues kernels ahead of the device and never reads a
device value back (issue 81). :mod:`splat_framework.testing.host_syncs` counts the reads and the
value-sized operations a piece of code asks for, whatever its device, so these tests hold the
training step to its budget on machines without a GPU: one read a step in the trainer (whether the
step was finite), none in the strategy's statistics or SCGaussian's losses (and one in a render's
binning on the Triton path: render/test_triton.py).
"""

from __future__ import annotations

import pytest
import torch

from splat_framework.testing import Trainer, apply_overrides, get_method
from splat_framework.testing.host_syncs import count_host_syncs

RENDER_FILES = ("_composite.py", "_kernels.py", "rasterizer.py", "_project.py")


def test_the_counter_sees_each_kind_of_host_read_and_names_its_place():
    x = torch.arange(6.0)
    mask = x > 2
    with count_host_syncs() as syncs:
        bool(x.sum() > 0), float(x[0]), int(x[1]), x.sum().item(), x.tolist(), x.cpu()
        torch.nonzero(mask), x[mask], torch.where(mask), torch.unique(x), torch.repeat_interleave(mask.long())
    assert syncs.total() == 11, syncs.report()
    assert all(place.startswith("test_host_syncs.py:") for _, place in syncs.by_place())
    with count_host_syncs() as none:  # the device-side forms
        torch.where(mask, x, 0.0), x[torch.tensor([0, 2])], x.to(torch.float64), mask.any(), x.cumsum(0)
        torch.repeat_interleave(torch.arange(3), torch.tensor([1, 2, 0]), output_size=3)
        x.new_zeros(6).scatter_add_(0, torch.tensor([0, 0, 5]), torch.ones(3))
    assert none.total() == 0, none.report()


@pytest.fixture(scope="module")
def scg_trainer(tmp_path_factory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SPLAT_CACHE", str(tmp_path_factory.getbasetemp() / "splatcache"))
        mp.delenv("SPLAT_COMPILE", raising=False)
        mp.delenv("SPLAT_RASTERIZER", raising=False)
        cfg = apply_overrides(get_method("scgaussian").default_config(), {
            "data": "synthetic/forward-tiny", "output": str(tmp_path_factory.mktemp("syncs") / "run"), "steps": 16,
            "progress": False, "compile": False, "rasterizer": "torch"})
        trainer = Trainer(cfg)
        for step in range(6):  # the first steps choose and keep each view's partners (a read each, once)
            trainer.train_step(step)
        yield trainer


def test_a_scgaussian_step_reads_the_device_once_outside_the_render(scg_trainer):
    """Densification statistics, L_rg, the multi-view term, the coarse-to-full switch, the loss log:
    none of them reads a device value; the step's one read is its finiteness verdict."""
    trainer = scg_trainer
    steps = range(6, 12)  # the coarse steps and the multi-view term end at 8; densification statistics every step
    assert trainer.densifies
    with count_host_syncs() as syncs:
        outs = [trainer.train_step(s) for s in steps]
    assert all(out is not None and {"rg", "photometric"} <= set(out[0]) for out in outs)
    assert any("multiview" in out[0] for out in outs) and any("multiview" not in out[0] for out in outs)
    outside = {k: n for k, n in syncs.by_place().items() if k[1].split(":")[0] not in RENDER_FILES}
    epoch_draws = sum(n for (op, place), n in outside.items() if place.startswith("datamanager.py:") and op == "tolist")
    assert epoch_draws <= len(steps) // 3 + 1  # the view order: a CPU generator's, a host tensor on CUDA too
    outside = {k: n for k, n in outside.items() if not k[1].startswith("datamanager.py:")}
    assert list(outside.values()) == [len(steps)] and next(iter(outside))[1].startswith("numerics.py:"), syncs.report()
    losses, train_psnr = outs[-1]  # left on the device, read when shown
    assert all(torch.is_tensor(v) and v.dim() == 0 for v in losses.values()) and torch.is_tensor(train_psnr)
    assert float(losses["loss"]) == pytest.approx(sum(float(v) for k, v in losses.items() if k != "loss"), rel=1e-5)
