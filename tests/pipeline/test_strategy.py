import math

import numpy as np
import pytest
import torch

from roodi_toolkit.pipeline.strategy import (MCMCStrategy, compute_relocation, grow, inject_position_noise, noise_gate,
                                    relocate_dead)


def reference_relocation(o, s, n):
    """Equation 9 of 3DGS-MCMC written as the paper's double sum."""
    new_o = 1 - (1 - o) ** (1 / n)
    denom = sum(math.comb(i - 1, k) * (-1) ** k * new_o ** (k + 1) / math.sqrt(k + 1)
                for i in range(1, n + 1) for k in range(i))
    return new_o, o / denom * s


@pytest.mark.parametrize("n", [1, 2, 3, 7, 20])
def test_relocation_matches_the_double_sum(n):
    o = torch.tensor([0.05, 0.3, 0.7, 0.95], dtype=torch.float64)
    s = torch.rand(4, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) + 0.1
    new_o, new_s = compute_relocation(o, s, torch.full((4,), n))
    for i in range(4):
        ro, rs = reference_relocation(float(o[i]), s[i].numpy(), n)
        assert float(new_o[i]) == pytest.approx(ro, rel=1e-10)
        np.testing.assert_allclose(new_s[i].numpy(), rs, rtol=1e-8)


@pytest.mark.parametrize("o,n", [(0.2, 2), (0.6, 3), (0.9, 5), (0.99, 8)])
def test_copies_render_like_the_original(o, n):
    """N composited copies give the original opacity at the centre and the same integrated opacity along a line."""
    new_o, new_s = compute_relocation(torch.tensor([o], dtype=torch.float64), torch.ones(1, 3, dtype=torch.float64),
                                      torch.tensor([n]))
    a, s_new = float(new_o[0]), float(new_s[0, 0])
    assert 1 - (1 - a) ** n == pytest.approx(o, rel=1e-12)  # rendered opacity at the centre
    x = np.linspace(-12, 12, 200001)
    original = o * np.exp(-0.5 * x ** 2)
    composited = 1 - (1 - a * np.exp(-0.5 * (x / s_new) ** 2)) ** n
    assert np.trapezoid(composited, x) == pytest.approx(np.trapezoid(original, x), rel=1e-6)


def make_params(n=200, seed=0):
    g = torch.Generator().manual_seed(seed)
    params = {
        "means": torch.randn(n, 3, generator=g),
        "quats_wxyz": torch.randn(n, 4, generator=g),
        "log_scales": torch.randn(n, 3, generator=g) - 3,
        "opacity_logits": torch.randn(n, generator=g),
        "sh_dc": torch.randn(n, 3, generator=g),
        "sh_rest": torch.randn(n, 3, 3, generator=g),
    }
    params = {k: torch.nn.Parameter(v) for k, v in params.items()}
    optimizers = {k: torch.optim.Adam([p], lr=1e-3) for k, p in params.items()}
    loss = sum((p ** 2).sum() for p in params.values())
    loss.backward()
    for opt in optimizers.values():
        opt.step()
    return params, optimizers


def test_relocate_moves_dead_onto_live_and_resets_their_optimizer_state():
    params, opts = make_params()
    with torch.no_grad():
        params["opacity_logits"][:20] = -10.0  # dead
    before = {k: v.detach().clone() for k, v in params.items()}
    moved = relocate_dead(params, opts, 0.005, torch.Generator().manual_seed(1))
    assert moved == 20
    assert len(params["means"]) == 200
    o = torch.sigmoid(params["opacity_logits"])
    assert (o[:20] > 0.005).all()
    # each dead slot now sits exactly on a live Gaussian's centre
    same = (params["means"][:20, None, :] == before["means"][None, 20:, :]).all(dim=2)
    assert same.any(dim=1).all()
    # optimizer state follows the new Parameter objects and is zero where touched
    st = opts["means"].state[params["means"]]
    assert torch.all(st["exp_avg"][:20] == 0)
    assert opts["means"].param_groups[0]["params"][0] is params["means"]


def test_grow_adds_five_percent_up_to_the_cap():
    params, opts = make_params(200)
    assert grow(params, opts, cap_max=1000, grow_rate=0.05, min_opacity=0.005) == 10
    assert len(params["means"]) == 210 and len(params["sh_rest"]) == 210
    assert opts["log_scales"].state[params["log_scales"]]["exp_avg"].shape == (210, 3)
    assert grow(params, opts, cap_max=215, grow_rate=0.05, min_opacity=0.005) == 5
    assert grow(params, opts, cap_max=215, grow_rate=0.05, min_opacity=0.005) == 0
    # training continues with the edited parameters
    loss = sum((p ** 2).sum() for p in params.values())
    loss.backward()
    for opt in opts.values():
        opt.step()


def test_growth_preserves_rendered_opacity_of_split_gaussians():
    params, opts = make_params(50)
    o_before = torch.sigmoid(params["opacity_logits"]).detach().clone()
    g = torch.Generator().manual_seed(3)
    grow(params, opts, cap_max=1000, grow_rate=1.0, min_opacity=0.0, generator=g)
    o_after = torch.sigmoid(params["opacity_logits"]).detach()
    # group each original with its copies by identical means: 1 - prod(1 - o_copies) = o_original
    means = params["means"].detach()
    for i in range(50):
        same = (means == means[i]).all(dim=1)
        combined = 1 - torch.prod(1 - o_after[same])
        assert float(combined) == pytest.approx(float(o_before[i]), rel=1e-4, abs=1e-6)


def test_noise_gate_spares_opaque_gaussians():
    gate = noise_gate(torch.tensor([0.001, 0.5, 0.999]))
    assert gate[0] > 0.5 and gate[2] < 1e-9 and gate[1] < 1e-10
    params, _ = make_params(100)
    with torch.no_grad():
        params["opacity_logits"][:50] = 10.0  # opaque: must not move
        params["opacity_logits"][50:] = -10.0  # transparent: moves
    before = params["means"].detach().clone()
    inject_position_noise(params, 1e3, torch.Generator().manual_seed(0))
    moved = (params["means"].detach() - before).norm(dim=1)
    assert moved[:50].max() < 1e-6 and moved[50:].min() > 0


def test_strategy_schedule_and_validation():
    s = MCMCStrategy()
    assert s.is_refine_step(600) and not s.is_refine_step(500) and not s.is_refine_step(650)
    assert not s.is_refine_step(25_000)
    with pytest.raises(Exception, match="cap_max"):
        MCMCStrategy(cap_max=0)
    params, _ = make_params(10)
    with torch.no_grad():
        reg = s.regularization(params)
        expected = 0.01 * torch.sigmoid(params["opacity_logits"]).mean() + 0.01 * torch.exp(params["log_scales"]).mean()
    assert float(reg) == pytest.approx(float(expected))
