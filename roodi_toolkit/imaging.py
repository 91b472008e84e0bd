"""Image comparisons shared by training, the pipeline and evaluation: PSNR, SSIM and the IoU of two masks.

One home for each, so the figures a training run logs and the ones ``roodi-toolkit evaluate`` reports are computed the
same way. Images are channels-last ``[H, W, C]`` in [0, 1], as numpy arrays or torch tensors.

Example:
    >>> import numpy as np
    >>> round(psnr(np.zeros((4, 4, 3)), np.full((4, 4, 3), 0.1)), 6)
    20.0
    >>> mask_iou(np.array([1, 1, 0, 0], bool), np.array([1, 0, 0, 0], bool))
    0.5
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import kornia
import numpy as np
import torch
from torch import Tensor

__all__ = ["psnr", "ssim", "mask_iou"]


def _float64(x: Any) -> np.ndarray:
    if isinstance(x, Tensor):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def psnr(a: np.ndarray | Tensor, b: np.ndarray | Tensor) -> float:
    """Return the PSNR in dB of two images in [0, 1] (inf when identical), computed in float64.

    Args:
        a: an image, any shape. [H, W, C]
        b: the reference, the same shape. [H, W, C]
    """
    mse = float(np.mean((_float64(a) - _float64(b)) ** 2))
    return float("inf") if mse == 0 else -10.0 * math.log10(mse)


def ssim(a: np.ndarray | Tensor, b: np.ndarray | Tensor, window: int = 11) -> Tensor:
    """Return the mean SSIM of two images (``kornia.metrics.ssim``, Gaussian window), differentiable for tensors.

    The window is shrunk to the image's short side (kept odd) for crops smaller than it. Arrays are compared in
    float32; tensors in their own dtype.

    Args:
        a: an image in [0, 1]. [H, W, C]
        b: the reference, the same shape. [H, W, C]
        window: the Gaussian window's side (3DGS: 11).

    Example:
        >>> x = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(0))
        >>> float(ssim(x, x))
        1.0
    """
    x = a if isinstance(a, Tensor) else torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32)
    y = b if isinstance(b, Tensor) else torch.as_tensor(np.ascontiguousarray(b), dtype=torch.float32)
    win = min(window, min(x.shape[:2]))
    win = win if win % 2 == 1 else win - 1
    return kornia.metrics.ssim(x.permute(2, 0, 1)[None], y.permute(2, 0, 1)[None], max(win, 1)).mean()


def mask_iou(pred: np.ndarray | Tensor, true: np.ndarray | Tensor) -> float:
    """Return the intersection over union of two boolean masks of one shape (1.0 when both are empty)."""
    p = np.asarray(pred, dtype=bool)
    t = np.asarray(true, dtype=bool)
    union = np.logical_or(p, t).sum()
    return 1.0 if union == 0 else float(np.logical_and(p, t).sum() / union)


def class_map_ious(pred: np.ndarray, true: np.ndarray, ids: Sequence[int] | None = None) -> dict[int, float]:
    """Return the IoU per id of two ``[H, W]`` class maps (default ids: the non-zero ids in ``true``).

    Example:
        >>> class_map_ious(np.array([[0, 1], [1, 2]]), np.array([[0, 1], [2, 2]]))
        {1: 0.5, 2: 0.5}
    """
    ids = sorted(int(i) for i in np.unique(true) if i != 0) if ids is None else list(ids)
    return {i: mask_iou(pred == i, true == i) for i in ids}
