"""The perceptual loss of fine-tuning against the inpainted views (paper, Sec. 3.3).

LPIPS (Zhang et al. 2018), as in the paper, when the caller hands in the network (the run layer reads its weights
with :func:`roodi_toolkit.io.lpips_weights.lpips_for_loss`: ``lpips_weights``, ``$ROODI_LPIPS_WEIGHTS`` or the
upstream files in the local caches; nothing is downloaded). Otherwise a Laplacian-pyramid L1 ("Lap1", Bojanowski et
al. 2018, proposed as a weight-free perceptual proxy): L1 between band-pass levels of the two images, each level
weighted equally, so that edges and texture at every scale count as much as flat colour. It needs no weights and is
not D-SSIM.
"""

from __future__ import annotations

import math
from typing import Optional

import kornia
import torch
from torch import Tensor

from ..errors import ConfigError

__all__ = ["LaplacianLoss", "LPIPSLoss", "perceptual_loss"]


class LaplacianLoss(torch.nn.Module):
    """Return the mean over pyramid levels of the L1 between Laplacian-pyramid bands of two images.

    Args:
        levels: band-pass levels (the last one is the low-pass residual).

    Example:
        >>> a = torch.rand(32, 32, 3, generator=torch.Generator().manual_seed(0))
        >>> loss = LaplacianLoss()
        >>> float(loss(a, a)), float(loss(a, a.mean() * torch.ones_like(a))) > 0.05
        (0.0, True)
    """

    name = "laplacian"

    def __init__(self, levels: int = 4) -> None:
        super().__init__()
        self.levels = levels

    def forward(self, a: Tensor, b: Tensor) -> Tensor:
        x = torch.stack([a, b]).permute(0, 3, 1, 2)
        levels = max(1, min(self.levels, int(math.log2(max(2, min(x.shape[-2:])))) - 2))
        pyr = kornia.geometry.transform.build_laplacian_pyramid(x, levels)
        return torch.stack([(p[0] - p[1]).abs().mean() for p in pyr]).mean()


class LPIPSLoss(torch.nn.Module):
    """Return LPIPS between two ``[H, W, 3]`` images in [0, 1].

    Args:
        model: the LPIPS network (:class:`roodi_toolkit.lpips.LPIPS` with its weights), taking two ``[B, 3, H, W]``
            batches and returning ``[B]`` distances.
    """

    name = "lpips"

    def __init__(self, model: torch.nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, a: Tensor, b: Tensor) -> Tensor:
        return self.model(a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None]).mean()


def perceptual_loss(kind: str = "auto", lpips: Optional[torch.nn.Module] = None) -> torch.nn.Module:
    """Return the perceptual loss module to use: LPIPS with the network given (``kind`` ``"auto"`` or ``"lpips"``),
    else the Laplacian one.

    Args:
        kind: ``"auto"`` (LPIPS when ``lpips`` is given), ``"lpips"`` (required) or ``"laplacian"``.
        lpips: the LPIPS network, as :func:`roodi_toolkit.io.lpips_weights.lpips_for_loss` reads it for ``kind``.

    Raises:
        ConfigError: ``kind="lpips"`` without a network.
    """
    if kind == "laplacian":
        return LaplacianLoss()
    if lpips is not None:
        return LPIPSLoss(lpips)
    if kind == "lpips":
        raise ConfigError("perceptual loss 'lpips' needs the LPIPS network: read its local weights with "
                          "roodi_toolkit.io.lpips_weights.lpips_for_loss and pass it as lpips=")
    return LaplacianLoss()
