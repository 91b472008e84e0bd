"""LPIPS: the real loading paths, exercised with randomly initialised weights written in the test."""

import pytest
import torch

from roodi_toolkit.errors import ConfigError
from roodi_toolkit.io.lpips_weights import lpips_for_loss
from roodi_toolkit.evaluate.lpips import LPIPS, LPIPSUnavailable
from roodi_toolkit.io.lpips_weights import ALEXNET_CHECKPOINT, ENV_WEIGHTS, read_lpips, write_lpips


def random_upstream_pair(seed=0):
    """State dicts shaped like torchvision's AlexNet checkpoint and the lpips v0.1 alex.pth."""
    g = torch.Generator().manual_seed(seed)
    ref = LPIPS()
    alexnet = {k: torch.randn(v.shape, generator=g) * 0.05 for k, v in ref.state_dict().items()
               if k.startswith("features.")}
    alexnet["classifier.1.weight"] = torch.zeros(4, 4)  # the upstream file has a classifier too; it is ignored
    lin = {f"lin{i}.model.1.weight": torch.rand(ref.lins[i].weight.shape, generator=g) for i in range(5)}
    return lin, alexnet


def test_identical_images_have_zero_distance_and_noise_increases_it():
    net = LPIPS.from_state_dicts(*random_upstream_pair())
    g = torch.Generator().manual_seed(1)
    x = torch.rand(2, 3, 64, 64, generator=g)
    noisy = (x + 0.1 * torch.randn(x.shape, generator=g)).clamp(0, 1)
    very = (x + 0.4 * torch.randn(x.shape, generator=g)).clamp(0, 1)
    d0, d1, d2 = net(x, x), net(x, noisy), net(x, very)
    assert torch.all(d0.abs() < 1e-6)
    assert torch.all(d1 > 0) and torch.all(d2 > d1)


def test_gradients_flow_to_the_input_not_the_weights():
    net = LPIPS()
    x = torch.rand(1, 3, 48, 48, requires_grad=True)
    net(x, torch.rand(1, 3, 48, 48)).sum().backward()
    assert x.grad is not None and torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0
    assert all(p.grad is None for p in net.parameters())


def test_read_lpips_reads_combined_file_and_upstream_pair(tmp_path, monkeypatch):
    lin, alexnet = random_upstream_pair(3)
    reference = LPIPS.from_state_dicts(lin, alexnet)
    x, y = torch.rand(1, 3, 64, 64), torch.rand(1, 3, 64, 64)
    combined = write_lpips(reference, tmp_path / "lpips_alex.pt")
    monkeypatch.setenv(ENV_WEIGHTS, str(combined))
    assert torch.allclose(read_lpips()(x, y), reference(x, y))
    # the upstream pair from a torch hub cache and an lpips package folder
    monkeypatch.delenv(ENV_WEIGHTS)
    hub = tmp_path / "hub"
    (hub / "checkpoints").mkdir(parents=True)
    torch.save(alexnet, hub / "checkpoints" / ALEXNET_CHECKPOINT)
    pkg = tmp_path / "site" / "lpips"
    (pkg / "weights" / "v0.1").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    torch.save(lin, pkg / "weights" / "v0.1" / "alex.pth")
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(hub))
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    assert torch.allclose(read_lpips()(x, y), reference(x, y))


def test_missing_or_wrong_weights_say_what_is_missing(tmp_path, monkeypatch):
    monkeypatch.delenv(ENV_WEIGHTS, raising=False)
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "empty_hub"))
    with pytest.raises(LPIPSUnavailable, match="no local LPIPS weights; looked at"):
        read_lpips()
    with pytest.raises(LPIPSUnavailable, match="not found"):
        read_lpips(tmp_path / "nope.pt")
    torch.save({"features.0.weight": torch.zeros(1)}, tmp_path / "bad.pt")
    with pytest.raises(LPIPSUnavailable, match="incomplete"):
        read_lpips(tmp_path / "bad.pt")
    with pytest.raises(ValueError, match="32x32"):
        LPIPS()(torch.rand(1, 3, 16, 16), torch.rand(1, 3, 16, 16))


def test_lpips_for_loss_reads_what_the_perceptual_kind_needs(tmp_path, monkeypatch):
    """The fine-tuning's network as the run layer reads it: none for laplacian (whatever is here), the local weights
    for auto and lpips; without them none for auto, and lpips says where it looked."""
    monkeypatch.delenv(ENV_WEIGHTS, raising=False)
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "empty_hub"))
    assert lpips_for_loss("auto") is None and lpips_for_loss("laplacian") is None
    assert lpips_for_loss("auto", tmp_path / "missing.pt") is None
    with pytest.raises(ConfigError, match="perceptual loss 'lpips' unavailable: no local LPIPS weights; looked at"):
        lpips_for_loss("lpips")
    with pytest.raises(ConfigError, match="missing.pt: LPIPS weights file not found"):
        lpips_for_loss("lpips", tmp_path / "missing.pt")
    reference = LPIPS.from_state_dicts(*random_upstream_pair(5))
    weights = write_lpips(reference, tmp_path / "lpips.pt")
    assert lpips_for_loss("laplacian", weights) is None
    x, y = torch.rand(1, 3, 40, 40), torch.rand(1, 3, 40, 40)
    assert torch.allclose(lpips_for_loss("lpips", weights)(x, y), reference(x, y))
    monkeypatch.setenv(ENV_WEIGHTS, str(weights))
    assert torch.allclose(lpips_for_loss("auto")(x, y), reference(x, y))
