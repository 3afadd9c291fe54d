"""The MCMC strategy's relocation rule (eq. 9 of Kheradmand et al. 2024)."""

import torch
from splat_example_plugin.mcmc import split_opacity_scale


def test_a_split_keeps_what_a_gaussian_renders():
    """One copy changes nothing; c copies composite to the old opacity and are smaller."""
    o = torch.tensor([0.3, 0.9, 0.5, 0.05])
    s = torch.log(torch.full((4, 3), 0.2))
    c = torch.tensor([1, 2, 5, 51])
    o_new, s_new = split_opacity_scale(o, s, c)
    assert torch.allclose(o_new[0], o[0]) and torch.allclose(s_new[0], s[0])
    assert torch.allclose(1 - (1 - o_new) ** c.float(), o, atol=1e-6)
    assert (s_new[1:] < s[1:]).all() and torch.isfinite(s_new).all()
