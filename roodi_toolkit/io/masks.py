"""Mask folders: PNGs named like the views (``<view>.png``), read into arrays keyed by view name.

What a user gives the ``files`` segmenter with ``--masks DIR`` and what a distillation writes (``object_masks/``).
The run layer reads the folder here, where a missing file, a colour image or a mask of the wrong size is named, and
hands the arrays to the segmenter (:class:`roodi_toolkit.pipeline.segment.FilesSegmenter`), which opens no file.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from ..errors import DatasetError
from ..masks import mask_from_array
from ..progress import ProgressFactory, null_progress
from .files import read_image

__all__ = ["mask_file", "read_mask_folder"]


def mask_file(folder: Path, name: str) -> Optional[Path]:
    """Return the mask file of the view ``name`` in ``folder`` (``<name>.png`` or ``<name>.PNG``), or None."""
    for ext in (".png", ".PNG"):
        p = folder / f"{name}{ext}"
        if p.is_file():
            return p
    return None


def read_mask_folder(folder: str | os.PathLike, names: Sequence[str], size: tuple[int, int], *,
                     progress: ProgressFactory = null_progress) -> dict[str, np.ndarray]:
    """Return the mask of every view in ``names`` from ``folder``, keyed by view name: ``[H, W]`` ids at the views'
    ``size`` in the file's integer type (uint8, or uint16 for 16-bit masks).

    A mask stored at an exact multiple of the view's size (a dataset loaded downscaled) takes the centre sample of
    each block; one at the size divided by an integer (as the mask stages write them) repeats each pixel
    (:func:`roodi_toolkit.masks.mask_from_array`).

    Args:
        folder: the folder of ``<view>.png`` files; other files in it are ignored.
        names: the views' names (the images' file stems).
        size: the views' ``(width, height)``.
        progress: progress factory.

    Raises:
        DatasetError: no such folder, missing files (listed, with how views are matched), colour or mis-sized masks
            (the file named).
        InputError: a file that cannot be read as an image.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DatasetError(f"{folder}: mask folder not found")
    paths = {n: mask_file(folder, n) for n in names}
    missing = [n for n, p in paths.items() if p is None]
    if missing:
        shown = ", ".join(f"{n}.png" for n in missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5
                                                             else "")
        raise DatasetError(f"{folder}: no mask for {len(missing)} of {len(names)} views: {shown}; masks are "
                           "matched to views by name (the image's file stem)")
    masks = {}
    with progress(total=len(names), desc="read masks") as bar:
        for n in names:
            p = paths[n]
            # its own compact copy: a view into the image read (one channel, or a sample of each block) kept all of it
            masks[n] = np.ascontiguousarray(mask_from_array(read_image(p), size, str(p)))
            bar.update(1)
    return masks
