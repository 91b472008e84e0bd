"""Pixel regions of the click segmenter's clicked view (:mod:`roodi_toolkit.pipeline.click`): a depth flood fill from
the clicks, OpenCV's GrabCut, hole filling, the components at the clicks and disc dilation, each on ``[H, W]`` masks.
"""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np
from scipy import ndimage


def _grabcut(image: np.ndarray, init: np.ndarray, iterations: int, seed: int) -> np.ndarray:
    """Return the foreground ``[H, W]`` bool of OpenCV GrabCut started from ``init`` (cv2.GC_* labels).

    Falls back to the probable/sure foreground of ``init`` when GrabCut cannot model one of the two sides (it needs
    pixels of both).
    """
    fg = (init == cv2.GC_FGD) | (init == cv2.GC_PR_FGD)
    if fg.all() or not fg.any():
        return fg
    img8 = (np.clip(image, 0, 1) * 255 + 0.5).astype(np.uint8)[..., ::-1].copy()  # OpenCV wants BGR
    mask = init.astype(np.uint8).copy()
    bgd = np.zeros((1, 65), np.float64)
    fgd = np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(seed)
    try:
        cv2.grabCut(img8, mask, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    except cv2.error:
        return fg
    return (mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD)


def _depth_flood_fill(depth: np.ndarray, allowed: np.ndarray, seeds: Sequence[tuple[int, int]],
                      tolerance: float) -> np.ndarray:
    """Return the pixels reached from ``seeds`` (row, col) through 4-neighbours whose depths differ by less than
    ``tolerance`` relative, within ``allowed``."""
    logd = np.log(np.where(allowed, np.maximum(depth, 1e-12), 1.0)).astype(np.float32)
    H, W = depth.shape
    region = np.zeros((H, W), bool)
    for r, c in seeds:
        if region[r, c] or not allowed[r, c]:
            continue
        block = np.ones((H + 2, W + 2), np.uint8)
        block[1:-1, 1:-1] = ~allowed  # floodFill does not enter non-zero mask pixels
        diff = float(np.log1p(tolerance))
        cv2.floodFill(logd.copy(), block, (int(c), int(r)), 0.0, diff, diff,
                      4 | cv2.FLOODFILL_MASK_ONLY | (2 << 8))
        region |= (block[1:-1, 1:-1] == 2)
    return region


def _fill_holes(mask: np.ndarray) -> np.ndarray:
    return ndimage.binary_fill_holes(mask)


def _component_at(mask: np.ndarray, seeds: Sequence[tuple[int, int]]) -> np.ndarray:
    """Return the union of the 8-connected components of ``mask`` that contain a seed ``(row, col)``."""
    labels, _ = ndimage.label(mask, structure=np.ones((3, 3), bool))
    ids = {int(labels[r, c]) for r, c in seeds if labels[r, c] > 0}
    return np.isin(labels, list(ids)) if ids else np.zeros_like(mask)


def _disk(radius: int) -> np.ndarray:
    r = max(int(radius), 0)
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    return (x * x + y * y) <= r * r


def _dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    return ndimage.binary_dilation(mask, structure=_disk(radius)) if radius > 0 else mask.copy()
