"""Posed-image datasets: format detection and the loaders behind one call, :func:`load_dataset`.

Every loader returns the same type: images as float32 tensors in [0, 1], cameras in the internal OpenCV convention
(:class:`~roodi_toolkit.cameras.Camera`), the train/test split, scene bounds and the background colour, plus what the
format offers besides (alpha, per-pixel instance ids, depth, sparse points).

The formats live in their own modules: :mod:`roodi_toolkit.io.blender` (Blender / NeRF-synthetic ``transforms_*.json``,
also what :mod:`roodi_toolkit.synth.scene` writes), :mod:`roodi_toolkit.io.nerfstudio` (nerfstudio's and instant-ngp's
``transforms.json``) and :mod:`roodi_toolkit.io.colmap` (``sparse/0`` models). :func:`load_dataset` and
:func:`load_cameras` detect the format and call the right one. The :class:`Dataset` type and the helpers the loaders
share live in :mod:`roodi_toolkit.io.dataset_core`, below the loaders, and are importable from here as well.

Example:
    >>> detect_format("no/such/folder")
    Traceback (most recent call last):
    ...
    roodi_toolkit.errors.DatasetError: no/such/folder: dataset not found
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

from ..cameras import Camera
from ..errors import DatasetError
from ..progress import ProgressFactory, null_progress
from .blender import load_blender, load_blender_cameras
from .colmap import load_colmap, load_colmap_cameras
# the Dataset type and the loaders' shared helpers, importable from here as before
from .dataset_core import (LLFF_HOLD, MAX_CROP_FRACTION, SPLITS, Dataset, _check_background,  # noqa: F401
                           _check_downscale, _crop_camera, _Crop, _downscaled_size, _find_colmap_sparse,
                           _is_colmap_model_dir, _plan_crop, _source_pixels, estimate_bounds, split_views,
                           to_loaded_pixel)
from .nerfstudio import NERFSTUDIO_FILE, is_nerfstudio_file, load_nerfstudio, load_nerfstudio_cameras
from .other_models import is_inria_cameras_file, load_inria_cameras
# the photo decoding (photos.py), importable from here as before
from .photos import _image_size, _read_depth, _read_mask, _ViewStack  # noqa: F401

__all__ = [
    "Dataset",
    "SPLITS",
    "detect_format",
    "load_dataset",
    "load_cameras",
    "estimate_bounds",
    "to_loaded_pixel",
]

# ----------------------------------------------------------------------------------------------------- detection


def detect_format(path: str | os.PathLike) -> str:
    """Return ``"blender"``, ``"nerfstudio"`` or ``"colmap"`` for a dataset folder (or a transforms JSON file).

    A folder with ``transforms_train/val/test.json`` is Blender; one with ``transforms.json`` is nerfstudio (also
    instant-ngp's captures); one with ``sparse/0`` is COLMAP. A JSON file named ``transforms_<split>.json`` is Blender,
    any other JSON file nerfstudio.

    Raises:
        DatasetError: the path is missing or holds none of the formats.
    """
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"{p}: dataset not found")
    if p.is_file():
        if p.suffix.lower() == ".json":
            return "nerfstudio" if is_nerfstudio_file(p) else "blender"
        raise DatasetError(f"{p}: not a dataset; give a folder with transforms.json, transforms_*.json or sparse/0, "
                           "or a transforms JSON file")
    if any((p / f"transforms_{s}.json").is_file() for s in SPLITS):
        return "blender"
    if (p / NERFSTUDIO_FILE).is_file():
        return "nerfstudio"
    if _find_colmap_sparse(p) is not None:
        return "colmap"
    raise DatasetError(f"{p}: no dataset found: expected transforms.json (nerfstudio, instant-ngp), "
                       "transforms_train/val/test.json (Blender) or sparse/0/cameras.bin|txt (COLMAP)")


def load_dataset(path: str | os.PathLike, downscale: float = 1, *, background: Sequence[float] | None = None,
                 splits: Sequence[str] | None = None, test_every: int = LLFF_HOLD,
                 progress: ProgressFactory = null_progress) -> Dataset:
    """Return the dataset at ``path``, detecting its format (:func:`detect_format`).

    Args:
        path: a dataset folder or a transforms JSON file.
        downscale: divide the image resolution by this factor (>= 1; images area-averaged, masks nearest).
        background: RGB in [0, 1] to composite transparent pixels on; defaults to the dataset's (``background`` key
            of a generated scene), else white for Blender and black for COLMAP.
        splits: Blender only: which of train/val/test to read (default all present).
        test_every: COLMAP, and nerfstudio without split lists: every ``test_every``-th image in name order is a test
            view (0: all train).
        progress: progress factory.

    Raises:
        DatasetError: the dataset is missing, malformed or inconsistent.
    """
    fmt = detect_format(path)
    if fmt == "blender":
        return load_blender(path, downscale, background=background, splits=splits, progress=progress)
    if fmt == "nerfstudio":
        return load_nerfstudio(path, downscale, background=background, test_every=test_every, progress=progress)
    return load_colmap(path, downscale, background=background, test_every=test_every, progress=progress)


def load_cameras(path: str | os.PathLike, *, splits: Sequence[str] | None = None) -> list[Camera]:
    """Return the cameras of a dataset without reading its images (sizes come from the files' metadata).

    Args:
        path: a dataset folder, a transforms JSON file, a COLMAP model folder (``sparse/0``), or an Inria model's
            ``cameras.json``.
        splits: Blender only: which splits to include, in this order (default train, val, test as present).
    """
    p = Path(path)
    if p.is_dir() and _is_colmap_model_dir(p):
        return load_colmap_cameras(p)
    if p.is_file() and p.name == "cameras.json":
        if is_inria_cameras_file(p):
            return load_inria_cameras(p)
    fmt = detect_format(p)
    if fmt == "blender":
        return load_blender_cameras(p, splits)
    if fmt == "nerfstudio":
        return load_nerfstudio_cameras(p)
    return load_colmap_cameras(_find_colmap_sparse(p))


