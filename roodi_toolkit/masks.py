"""Instance masks at a view's size: a mask image brought to its view (:func:`mask_from_array`) and masks of a
working resolution brought back to full size (:func:`full_size_masks`).

Shared by the reader of mask folders (:func:`roodi_toolkit.io.masks.read_mask_folder`, which names the file at fault)
and the ``files`` segmenter (:class:`roodi_toolkit.pipeline.segment.FilesSegmenter`, which takes the masks in memory
and brings them to the working resolution of the mask stages, :mod:`roodi_toolkit.pipeline.resolution`).
"""

from __future__ import annotations

import numpy as np

from .errors import ConfigError, DatasetError

__all__ = ["full_size_masks", "mask_from_array"]


def full_size_masks(masks: np.ndarray, width: int, height: int) -> np.ndarray:
    """Return ``[N, H, W]`` masks of a working resolution brought to ``width`` x ``height`` by repeating each pixel
    (and the last row and column into the strip the reduction dropped); masks already that size are returned.

    Example:
        >>> full_size_masks(np.array([[[1, 2]]]), 5, 2)
        array([[[1, 1, 2, 2, 2],
                [1, 1, 2, 2, 2]]])
    """
    n, h, w = masks.shape
    if (h, w) == (height, width):
        return masks
    f = width // w
    if f < 1 or width // f != w or height // f != h:
        raise ConfigError(f"masks of {w}x{h} are no integer reduction of {width}x{height}")
    up = np.repeat(np.repeat(masks, f, axis=1), f, axis=2)
    return np.pad(up, ((0, 0), (0, height - h * f), (0, width - w * f)), mode="edge")


def mask_from_array(arr: np.ndarray, size: tuple[int, int], where: str) -> np.ndarray:
    """Return ``[H, W]`` ids from a mask image (in the image's integer type), resized (nearest) when it is a larger
    copy of the view or an integer reduction of it.

    Args:
        arr: the image: ``[h, w]`` ids (8 or 16 bit) or ``[h, w, 3|4]`` grey stored as colour.
        size: the view's ``(width, height)``.
        where: the mask, for messages (its file).

    Raises:
        DatasetError: colour masks, or a size that is not the view's (nor an exact multiple of it, as when the
            dataset is loaded downscaled, nor its size divided by an integer, as the mask stages write them).

    Example:
        >>> mask_from_array(np.kron(np.array([[0, 3]], np.uint8), np.ones((2, 2), np.uint8)), (2, 1), "m.png")
        array([[0, 3]], dtype=uint8)
    """
    a = np.asarray(arr)
    if a.ndim == 3:
        rgb = a[..., :3]
        if not (np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2])):
            raise DatasetError(f"{where}: mask is a colour image; expected 8- or 16-bit grey instance ids "
                               "(0 = background) or a black-and-white binary mask")
        a = rgb[..., 0]
    w, h = size
    f = w // max(a.shape[1], 1)
    if a.shape[1] < w and f >= 1 and (w // f, h // f) == (a.shape[1], a.shape[0]):
        # made at a working resolution (pipeline/resolution.py): each pixel stands for an f x f block
        return full_size_masks(a[None], w, h)[0]
    if a.shape != (h, w):
        fy, fx = a.shape[0] / h, a.shape[1] / w
        if not (a.shape[0] > h and abs(fx - fy) < 1e-6 and abs(fx - round(fx)) < 1e-6 and a.shape[1] % w == 0):
            raise DatasetError(f"{where}: mask is {a.shape[1]}x{a.shape[0]} but its view is {w}x{h}; masks must "
                               "have the view's size (or an exact multiple of it)")
        f = int(round(fx))
        a = a[f // 2::f, f // 2::f]  # nearest: the sample at the centre of each block
    return a
