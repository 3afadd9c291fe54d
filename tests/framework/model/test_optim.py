"""The shared Adam: fused where the device has it, and a loaded state keeps this process's choice."""

from __future__ import annotations

import copy

import torch

from splat_framework.model.optim import adam


def _trained(opt: torch.optim.Optimizer, p: torch.Tensor, steps: int) -> None:
    for k in range(steps):
        p.grad = torch.full_like(p, 0.1 * (k + 1)).sin()
        opt.step()


def test_adam_updates_as_the_plain_adam_does():
    a = torch.linspace(-1, 1, 12).reshape(4, 3).requires_grad_()
    b = a.detach().clone().requires_grad_()
    _trained(adam([{"params": [a]}], lr=0.01), a, 5)
    _trained(torch.optim.Adam([{"params": [b]}], lr=0.01, eps=1e-15), b, 5)
    torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)


def test_a_saved_state_is_loaded_with_this_processes_flags():
    p = torch.zeros(5, requires_grad=True)
    opt = adam([{"params": [p]}], lr=0.01)
    _trained(opt, p, 2)
    saved = copy.deepcopy(opt.state_dict())  # state_dict() holds the live moments
    for group in saved["param_groups"]:  # as written by an optimiser that chose otherwise
        group["fused"] = not opt.defaults["fused"]
    q = p.detach().clone().requires_grad_()
    other = adam([{"params": [q]}], lr=0.01)
    other.load_state_dict(saved)
    assert [g["fused"] for g in other.param_groups] == [opt.defaults["fused"]]
    _trained(opt, p, 1)
    _trained(other, q, 1)
    torch.testing.assert_close(p, q)


def test_adam_is_fused_on_cpu_where_torch_has_a_fused_cpu_adam():
    fused_on_cpu = tuple(int(x) for x in torch.__version__.split("+")[0].split(".")[:2]) >= (2, 4)
    assert adam([{"params": [torch.zeros(2, requires_grad=True)]}], lr=0.1).defaults["fused"] is (True if fused_on_cpu else None)
