"""The compiled parts of a training step against their plain references: kornia's SSIM (value and gradient), the
MCMC position noise's covariance product, and a whole step against the unfused, uncompiled one."""

import pytest
import torch

import roodi_toolkit.pipeline.train as train_module
from roodi_toolkit.imaging import ssim as kornia_ssim
from roodi_toolkit.io.dataset import load_dataset
from roodi_toolkit.pipeline import train_kernels
from roodi_toolkit.pipeline.strategy import MCMCStrategy, covariance_noise_reference
from roodi_toolkit.pipeline.train import TrainConfig, Trainer


@pytest.mark.parametrize("shape, window", [((40, 52, 3), 11), ((9, 30, 3), 11), ((16, 16, 2), 7), ((12, 5, 1), 11)])
def test_ssim_kernel_matches_kornia_value_and_gradient(shape, window):
    g = torch.Generator().manual_seed(sum(shape))
    truth = torch.rand(shape, generator=g)
    render = (0.6 * truth + 0.4 * torch.rand(shape, generator=g)).requires_grad_()
    ours = train_kernels.ssim(render, truth, window)
    (grad,) = torch.autograd.grad(ours, render)
    reference = kornia_ssim(render, truth, window)  # also shrinks the window to the short side
    (ref_grad,) = torch.autograd.grad(reference, render)
    assert ours.dtype == torch.float32
    torch.testing.assert_close(ours, reference, atol=2e-6, rtol=0)
    torch.testing.assert_close(grad, ref_grad, atol=1e-8, rtol=1e-4)


def test_ssim_kernel_gradcheck_and_identity():
    g = torch.Generator().manual_seed(1)
    x = torch.rand(7, 9, 2, dtype=torch.float64, generator=g, requires_grad=True)
    y = torch.rand(7, 9, 2, dtype=torch.float64, generator=g)
    assert torch.autograd.gradcheck(lambda a: train_kernels.ssim(a, y, 5), (x,))
    assert float(train_kernels.ssim(y, y)) == pytest.approx(1.0, abs=1e-9)
    with pytest.raises(ValueError, match="reference"):
        train_kernels.ssim(y, x)


def test_covariance_noise_matches_the_torch_reference():
    g = torch.Generator().manual_seed(2)
    n = 1000
    quats = torch.randn(n, 4, generator=g) * torch.rand(n, 1, generator=g) * 3  # unnormalised, any length
    log_scales = torch.randn(n, 3, generator=g) - 3
    vectors = torch.randn(n, 3, generator=g)
    ours = train_kernels.covariance_noise(quats, log_scales, vectors)
    reference = covariance_noise_reference(quats, log_scales, vectors)
    assert ours.dtype == torch.float32 and ours.shape == (n, 3)
    torch.testing.assert_close(ours, reference, atol=1e-6, rtol=1e-5)


def test_a_training_step_matches_the_reference_step(tiny_kitchen, monkeypatch):
    """Fused Adam, the compiled SSIM and noise against unfused Adam, kornia and the torch covariances: the same
    parameters after steps that include relocation and growth."""
    ds = load_dataset(tiny_kitchen)
    config = TrainConfig(iterations=12, init_num_points=500, eval_every=0, sh_degree_interval=4,
                         strategy=MCMCStrategy(cap_max=700, refine_start_iter=4, refine_every=5))
    fast = Trainer(ds, config)
    reference = Trainer(ds, config)
    reference._make_optimizers(fused=False)
    for _ in range(12):
        fast.train_step()
    monkeypatch.setattr(train_module, "ssim_loss", kornia_ssim)
    monkeypatch.setattr(train_kernels, "covariance_noise", covariance_noise_reference)
    for _ in range(12):
        reference.train_step()
    assert fast.num_gaussians == reference.num_gaussians > 500
    for name in fast.params.keys():
        torch.testing.assert_close(fast.params[name], reference.params[name], atol=1e-4, rtol=1e-4)
