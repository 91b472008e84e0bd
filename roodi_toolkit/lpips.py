"""LPIPS (Zhang et al. 2018), AlexNet variant, in plain PyTorch: no torchvision, weights from local files only.

The network is the reference one (``lpips.LPIPS(net="alex")``, version 0.1): inputs in [0, 1] mapped to [-1, 1],
the scaling layer, AlexNet's five ReLU stages, unit-normalised channels, squared differences weighted by the learned
1x1 "lin" layers, spatial mean, sum over stages.

The network is built from state dicts (:meth:`LPIPS.from_state_dicts`, :meth:`LPIPS.from_combined`); the weight
files on this machine are found and read by :func:`roodi_toolkit.io.lpips_weights.read_lpips` (nothing downloads).
"""

from __future__ import annotations

from typing import Mapping

import torch
from torch import Tensor, nn

from .errors import EnvironmentProblemError, InputError

CHANNELS = (64, 192, 384, 256, 256)
_SLICES = ((0, 2), (2, 5), (5, 8), (8, 10), (10, 12))  # AlexNet feature indices ending at relu1..relu5


class LPIPSUnavailable(EnvironmentProblemError):
    """LPIPS weights are not available locally."""


class LPIPSInputError(InputError, ValueError):
    """Images LPIPS cannot compare; also a ValueError, as a torch module's bad-shape error is."""


def _alexnet_features() -> nn.Sequential:
    """Return AlexNet's convolutional trunk with torchvision's layer indices (so its state dict loads as is)."""
    return nn.Sequential(
        nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2), nn.ReLU(inplace=False),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(64, 192, kernel_size=5, padding=2), nn.ReLU(inplace=False),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(192, 384, kernel_size=3, padding=1), nn.ReLU(inplace=False),
        nn.Conv2d(384, 256, kernel_size=3, padding=1), nn.ReLU(inplace=False),
        nn.Conv2d(256, 256, kernel_size=3, padding=1), nn.ReLU(inplace=False),
        nn.MaxPool2d(kernel_size=3, stride=2),
    )


class LPIPS(nn.Module):
    """Learned perceptual distance between images (lower is more similar); frozen, differentiable in its inputs.

    Example:
        >>> torch.manual_seed(0) and None
        >>> net = LPIPS()  # random weights: for shapes only; real distances need real weights (io.lpips_weights)
        >>> x = torch.rand(2, 3, 64, 64)
        >>> d = net(x, x)
        >>> d.shape, bool(torch.all(d.abs() < 1e-6))
        (torch.Size([2]), True)
    """

    def __init__(self) -> None:
        super().__init__()
        self.features = _alexnet_features()
        self.lins = nn.ModuleList([nn.Conv2d(c, 1, kernel_size=1, bias=False) for c in CHANNELS])
        self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1))
        self.requires_grad_(False)
        self.eval()

    def _stages(self, x: Tensor) -> list[Tensor]:
        h = (x * 2.0 - 1.0 - self.shift) / self.scale
        out = []
        for start, stop in _SLICES:
            for layer in self.features[start:stop]:
                h = layer(h)
            out.append(h / (torch.sqrt(torch.sum(h * h, dim=1, keepdim=True)) + 1e-10))
        return out

    def forward(self, x: Tensor, y: Tensor) -> Tensor:
        """Return the LPIPS distance ``[B]`` between image batches ``[B, 3, H, W]`` in [0, 1] (H, W >= 32)."""
        if x.shape != y.shape or x.ndim != 4 or x.shape[1] != 3:
            raise LPIPSInputError(f"LPIPS needs two [B, 3, H, W] batches of one shape, got {list(x.shape)} and "
                                  f"{list(y.shape)}")
        if min(x.shape[-2:]) < 32:
            raise LPIPSInputError(f"LPIPS needs images of at least 32x32 pixels, got {list(x.shape[-2:])}")
        total = x.new_zeros(x.shape[0])
        for lin, fx, fy in zip(self.lins, self._stages(x), self._stages(y)):
            total = total + lin((fx - fy) ** 2).mean(dim=(1, 2, 3))
        return total

    # ------------------------------------------------------------------------------------------------ loading
    @classmethod
    def from_state_dicts(cls, lin: Mapping[str, Tensor], alexnet: Mapping[str, Tensor]) -> "LPIPS":
        """Return LPIPS from the upstream pair: the lpips ``alex.pth`` and torchvision's AlexNet state dict."""
        net = cls()
        state = {k: v for k, v in alexnet.items() if k.startswith("features.")}
        for i in range(len(CHANNELS)):
            key = f"lin{i}.model.1.weight"
            if key not in lin:
                raise LPIPSUnavailable(f"LPIPS lin weights lack {key!r}; expected the lpips v0.1 alex.pth")
            state[f"lins.{i}.weight"] = lin[key]
        net._load(state, "the lpips/AlexNet pair")
        return net

    @classmethod
    def from_combined(cls, state: Mapping[str, Tensor], source: str = "state dict") -> "LPIPS":
        """Return LPIPS from one state dict of this module (``features.*``, ``lins.*``)."""
        net = cls()
        net._load(dict(state), source)
        return net

    def _load(self, state: dict[str, Tensor], source: str) -> None:
        state = {**state, "shift": self.shift, "scale": self.scale}
        expected = set(self.state_dict())
        missing, unexpected = expected - set(state), set(state) - expected
        if missing:
            raise LPIPSUnavailable(f"{source}: LPIPS weights incomplete, missing {sorted(missing)[:4]}")
        try:
            self.load_state_dict({k: state[k] for k in expected})
        except RuntimeError as exc:
            raise LPIPSUnavailable(f"{source}: LPIPS weights do not fit the AlexNet variant "
                                   f"({' '.join(str(exc).split())[:160]})") from None
        del unexpected
