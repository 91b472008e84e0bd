"""Spherical harmonics: orthonormal bases, the 3DGS sign convention, the +0.5 / clamp colour rule, gradients."""

from __future__ import annotations

import math

import pytest
import torch

from roodi_toolkit.errors import ConfigError
from roodi_toolkit.sh import SH_C0, SH_C1, eval_sh_colors, num_sh_bases, sh_bases


def _uniform_dirs(n: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    d = torch.randn(n, 3, generator=g, dtype=torch.float64)
    return d / d.norm(dim=1, keepdim=True)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_bases_are_orthonormal_on_the_sphere(degree):
    dirs = _uniform_dirs(400_000)
    Y = sh_bases(degree, dirs)  # [n, K]
    gram = 4.0 * math.pi * (Y.T @ Y) / len(dirs)  # Monte Carlo of the integral of Y_i Y_j over the sphere
    torch.testing.assert_close(gram, torch.eye(num_sh_bases(degree), dtype=torch.float64), atol=0.02, rtol=0)


def test_degree_one_follows_3dgs_signs():
    # 3DGS: C0 sh0 - C1 y sh1 + C1 z sh2 - C1 x sh3
    d = torch.tensor([[0.6, 0.0, 0.8], [0.0, 1.0, 0.0]], dtype=torch.float64)
    torch.testing.assert_close(sh_bases(1, d), torch.tensor([[SH_C0, 0.0, SH_C1 * 0.8, -SH_C1 * 0.6],
                                                             [SH_C0, -SH_C1, 0.0, 0.0]], dtype=torch.float64))


def test_colors_add_half_and_clamp_at_zero_and_truncate_degree():
    sh = torch.zeros(2, 4, 3, dtype=torch.float64)
    sh[0, 0] = torch.tensor([1.0, -10.0, 0.0])
    sh[1, 3] = 1.0  # x basis
    dirs = torch.tensor([[0.0, 0.0, 2.0], [-3.0, 0.0, 0.0]], dtype=torch.float64)  # not unit: normalised inside
    rgb = eval_sh_colors(sh, dirs)
    torch.testing.assert_close(rgb[0], torch.tensor([0.5 + SH_C0, 0.0, 0.5], dtype=torch.float64))
    torch.testing.assert_close(rgb[1], torch.full((3,), 0.5 + SH_C1, dtype=torch.float64))
    torch.testing.assert_close(eval_sh_colors(sh, dirs, degree=0)[1], torch.full((3,), 0.5, dtype=torch.float64))


def test_colors_gradcheck():
    g = torch.Generator().manual_seed(3)
    sh = (0.2 * torch.randn(5, 16, 3, generator=g, dtype=torch.float64)).requires_grad_()
    dirs = torch.randn(5, 3, generator=g, dtype=torch.float64).requires_grad_()
    assert torch.autograd.gradcheck(lambda s, d: eval_sh_colors(s, d), (sh, dirs))


def test_errors():
    with pytest.raises(ConfigError, match="degree"):
        num_sh_bases(4)
    with pytest.raises(ConfigError, match=r"\[N, K, 3\]"):
        eval_sh_colors(torch.zeros(2, 4), torch.zeros(2, 3))
    with pytest.raises(ConfigError, match="5 SH coefficients"):
        eval_sh_colors(torch.zeros(2, 5, 3), torch.zeros(2, 3))
    with pytest.raises(ConfigError, match="needs more"):
        eval_sh_colors(torch.zeros(2, 4, 3), torch.ones(2, 3), degree=2)
