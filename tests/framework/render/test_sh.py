"""Spherical harmonics: constants, ordering/signs (3DGS convention), orthonormality, grads."""

from __future__ import annotations

import math

import pytest
import torch

from splat_framework.render import eval_sh, rgb_to_sh, sh_to_color, sh_to_rgb
from splat_framework.render.sh import SH_C0, num_sh_bases

PI = math.pi


def standard_real_sh(d: torch.Tensor) -> torch.Tensor:
    """[M, 16] real SH (textbook Cartesian forms, positive normalisation) in 3DGS order."""
    x, y, z = d.unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    return torch.stack(
        [
            0.5 * math.sqrt(1 / PI) * torch.ones_like(x),
            math.sqrt(3 / (4 * PI)) * y,
            math.sqrt(3 / (4 * PI)) * z,
            math.sqrt(3 / (4 * PI)) * x,
            0.5 * math.sqrt(15 / PI) * x * y,
            0.5 * math.sqrt(15 / PI) * y * z,
            0.25 * math.sqrt(5 / PI) * (2 * zz - xx - yy),
            0.5 * math.sqrt(15 / PI) * x * z,
            0.25 * math.sqrt(15 / PI) * (xx - yy),
            0.25 * math.sqrt(35 / (2 * PI)) * y * (3 * xx - yy),
            0.5 * math.sqrt(105 / PI) * x * y * z,
            0.25 * math.sqrt(21 / (2 * PI)) * y * (4 * zz - xx - yy),
            0.25 * math.sqrt(7 / PI) * z * (2 * zz - 3 * xx - 3 * yy),
            0.25 * math.sqrt(21 / (2 * PI)) * x * (4 * zz - xx - yy),
            0.25 * math.sqrt(105 / PI) * z * (xx - yy),
            0.25 * math.sqrt(35 / (2 * PI)) * x * (xx - 3 * yy),
        ],
        dim=-1,
    )


# sign convention of the 3DGS reference (Condon-Shortley style alternation)
SIGNS_3DGS = torch.tensor(
    [1.0, -1, 1, -1, 1, -1, 1, -1, 1, -1, 1, -1, 1, -1, 1, -1], dtype=torch.float64
)


def basis_values(degree: int, d: torch.Tensor) -> torch.Tensor:
    """[M, (degree+1)^2] values of each basis function via one-hot coefficients."""
    k = num_sh_bases(degree)
    # identity coefficients: "channel" j carries basis function j (eval_sh is linear
    # and treats the last axis as independent channels)
    coeffs = torch.eye(k, dtype=d.dtype).expand(d.shape[0], k, k)
    return eval_sh(degree, coeffs, d)


def fibonacci_sphere(m: int) -> torch.Tensor:
    i = torch.arange(m, dtype=torch.float64) + 0.5
    z = 1 - 2 * i / m
    r = torch.sqrt(1 - z * z)
    phi = i * PI * (3 - math.sqrt(5))
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)


def test_constants_and_signs_match_textbook_real_sh():
    g = torch.Generator().manual_seed(0)
    d = torch.randn(200, 3, generator=g, dtype=torch.float64)
    d = d / d.norm(dim=-1, keepdim=True)
    got = basis_values(3, d)
    want = standard_real_sh(d) * SIGNS_3DGS
    torch.testing.assert_close(got, want, atol=1e-12, rtol=1e-10)
    assert abs(SH_C0 - 0.5 * math.sqrt(1 / PI)) < 1e-15


def test_orthonormal_on_sphere():
    d = fibonacci_sphere(20_000)
    y = basis_values(3, d)
    gram = y.T @ y * (4 * PI / d.shape[0])
    torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), atol=2e-3, rtol=0)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_degree_truncation_and_shapes(degree):
    g = torch.Generator().manual_seed(degree)
    n = 7
    coeffs = torch.randn(n, 16, 3, generator=g)
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    k = num_sh_bases(degree)
    out = eval_sh(degree, coeffs, d)
    assert out.shape == (n, 3)
    cut = coeffs.clone()
    cut[:, k:] = 123.0  # ignored
    torch.testing.assert_close(eval_sh(degree, cut, d), out)
    torch.testing.assert_close(eval_sh(degree, coeffs[:, :k], d), out)
    # linear in the coefficients, per channel, with the basis values
    basis = basis_values(degree, d.double())
    torch.testing.assert_close(out.double(), torch.einsum("nk,nkc->nc", basis, coeffs[:, :k].double()),
                               atol=1e-5, rtol=1e-5)


def test_degree_zero_is_constant_colour():
    rgb = torch.tensor([[0.1, 0.5, 0.9]])
    dc = rgb_to_sh(rgb)
    coeffs = torch.zeros(1, 16, 3)
    coeffs[:, 0] = dc
    for d in torch.eye(3):
        torch.testing.assert_close(sh_to_color(0, coeffs, d[None]), rgb)
        torch.testing.assert_close(sh_to_color(3, coeffs, d[None]), rgb)
    torch.testing.assert_close(sh_to_rgb(dc), rgb)


def test_color_clamped_at_zero_with_zero_grad():
    coeffs = torch.zeros(2, 1, 3, dtype=torch.float64)
    coeffs[0, 0] = -5.0  # colour = 0.5 - 5 * C0 < 0 -> clamped
    coeffs[1, 0] = 0.3
    coeffs.requires_grad_()
    d = torch.tensor([[0.0, 0.0, 1.0]] * 2, dtype=torch.float64)
    col = sh_to_color(0, coeffs, d)
    assert (col[0] == 0).all() and (col[1] > 0.5).all()
    col.sum().backward()
    assert (coeffs.grad[0] == 0).all()
    torch.testing.assert_close(coeffs.grad[1, 0], torch.full((3,), SH_C0, dtype=torch.float64))


def test_gradcheck_coeffs_and_dirs():
    g = torch.Generator().manual_seed(3)
    coeffs = torch.randn(4, 16, 3, generator=g, dtype=torch.float64, requires_grad=True)
    d = torch.nn.functional.normalize(torch.randn(4, 3, generator=g, dtype=torch.float64), dim=-1)
    d.requires_grad_()
    assert torch.autograd.gradcheck(lambda c, v: eval_sh(3, c, v), (coeffs, d))


def test_invalid_arguments():
    with pytest.raises(ValueError):
        eval_sh(4, torch.zeros(1, 25, 3), torch.zeros(1, 3))
    with pytest.raises(ValueError):
        eval_sh(2, torch.zeros(1, 4, 3), torch.zeros(1, 3))
