"""The working resolution of the mask stages: segmentation and distillation see views scaled down to a pixel budget.

A selection is a set of Gaussians: it needs masks that say which Gaussians are the object, not photo-sharp masks.
Segmenting and distilling a 1000 px capture at full size costs four times the rendering of the half-size views for
the same selection (``benchmarks/RESULTS.md``, "Working resolution of the mask stages"), so these stages work on the
dataset scaled down by the smallest integer factor that brings each view under ``max_pixels``; the stages after them
(occlusion, inpainting, fine-tuning) use the full-size photos, and masks are brought back to full size by repeating
each pixel (:func:`roodi_toolkit.masks.full_size_masks`).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ..cameras import Camera
from ..errors import ConfigError
from ..io.dataset import Dataset


def working_factor(width: int, height: int, max_pixels: int) -> int:
    """Return the smallest integer factor that brings a ``width`` x ``height`` view to at most ``max_pixels``.

    Example:
        >>> working_factor(800, 800, 512 * 512), working_factor(1000, 750, 512 * 512), working_factor(200, 200, 10**6)
        (2, 2, 1)
    """
    if max_pixels < 1:
        raise ConfigError(f"max_pixels must be positive, got {max_pixels}")
    f = max(1, math.ceil(math.sqrt(width * height / max_pixels)))
    while (width // f) * (height // f) > max_pixels:
        f += 1
    return f


def _reduced_camera(cam: Camera, f: int, width: int, height: int) -> Camera:
    K = cam.K.copy()
    K[:2] /= f  # pixel j' covers original pixels f j' .. f j' + f - 1, so centres map as x' = x / f
    return Camera(cam.world_to_camera, K, width, height, cam.near, cam.far, cam.name)


def working_dataset(dataset: Dataset, max_pixels: int) -> tuple[Dataset, int]:
    """Return the dataset scaled down by :func:`working_factor` (the same object when the factor is 1) and the factor.

    Images (and alphas, depths) are averaged over ``f`` x ``f`` blocks, instance masks take each block's centre
    sample; the last ``width % f`` columns and ``height % f`` rows are dropped.
    """
    f = working_factor(dataset.width, dataset.height, max_pixels)
    if f == 1:
        return dataset, 1
    h, w = dataset.height // f, dataset.width // f

    def pool(t: torch.Tensor | None, channels_last: bool) -> torch.Tensor | None:
        if t is None:
            return None
        x = t[:, :h * f, :w * f]
        x = x.permute(0, 3, 1, 2) if channels_last else x[:, None]
        y = F.avg_pool2d(x.float(), f)
        return y.permute(0, 2, 3, 1).contiguous() if channels_last else y[:, 0].contiguous()

    masks = None if dataset.masks is None else dataset.masks[:, f // 2::f, f // 2::f][:, :h, :w].contiguous()
    cameras = [_reduced_camera(c, f, w, h) for c in dataset.cameras]
    meta = {**dataset.metadata, "working_downscale": f}
    return Dataset(pool(dataset.images, True), cameras, list(dataset.splits), dataset.background, dataset.bounds,
                   pool(dataset.alphas, False), masks, pool(dataset.depths, False), dataset.points,
                   dataset.point_colors, dataset.root, dataset.format, meta), f
