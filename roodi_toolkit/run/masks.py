"""Mask folders in a run: the folder a user names for the ``files`` segmenter (``--masks DIR``), read
(:func:`roodi_toolkit.io.masks.read_mask_folder`, which names the file at fault) and handed to the segmenter in memory
(:class:`roodi_toolkit.pipeline.segment.FilesSegmenter`'s ``masks`` option), and a distillation's ``object_masks/``,
read back as the masks it was distilled from."""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path
from typing import Any

from ..errors import DatasetError
from ..io.dataset import Dataset
from ..io.files import file_stems
from ..io.masks import read_mask_folder
from ..pipeline.resolution import working_factor
from ..pipeline.segment import SegmentPrompt, ViewMasks, given_masks
from ..progress import ProgressFactory, null_progress


def options_with_masks(segmenter: str, options: dict[str, Any] | None, prompt: SegmentPrompt, dataset: Dataset,
                       *, max_pixels: int | None = None, progress: ProgressFactory = null_progress) -> dict[str, Any]:
    """Return the segmenter's options, with the masks of the prompt's folder read for the ``files`` segmenter (the
    masks of ``dataset``'s views); other segmenters, and ``files`` without a folder, get ``options`` as they are.

    ``max_pixels``: the pixel budget of the mask stages (``DistillConfig.max_pixels``): the masks are read at the
    working size the segmenter sees (:func:`roodi_toolkit.pipeline.resolution.working_factor`), not held at full size
    beside it; None: the dataset's size.

    Raises:
        DatasetError: no such folder, missing files (listed), colour or mis-sized masks (the file named).
    """
    options = dict(options or {})
    if segmenter != "files" or prompt.mask_dir is None:
        return options
    f = 1 if max_pixels is None else working_factor(dataset.width, dataset.height, max_pixels)
    size = (dataset.width // f, dataset.height // f)
    masks = read_mask_folder(prompt.mask_dir, dataset.names, size, progress=progress)
    return {**options, "masks": masks, "source": str(prompt.mask_dir)}


def folder_masks(folder: str | os.PathLike, dataset: Dataset, *,
                 progress: ProgressFactory = null_progress) -> ViewMasks:
    """Return the masks of a distillation's ``object_masks/`` (binary or instance ids) at ``dataset``'s size: one PNG
    a view, named by :func:`roodi_toolkit.io.files.file_stems` of the views' names as the distillation wrote them
    (unique where a name repeats, as a Blender set's train and test ``r_0`` do).

    Raises:
        DatasetError: no such folder, missing files (listed), colour or mis-sized masks (the file named).
    """
    stems = file_stems(dataset.names)
    repeated = {n for n, count in Counter(dataset.names).items() if count > 1}
    older = [s for s, n in zip(stems, dataset.names) if n in repeated and s != n
             and not (Path(folder) / f"{s}.png").is_file()]
    if older and Path(folder).is_dir():  # written before a repeated view name had a file of its own
        raise DatasetError(f"{folder}: no mask for {len(older)} views whose names repeat ({older[0]}, ...): it was "
                           "written by an older roodi-toolkit, whose masks of repeated names overwrote each other; "
                           "distil again (--overwrite)")
    masks = read_mask_folder(folder, stems, (dataset.width, dataset.height), progress=progress)
    return given_masks(masks, dataset, str(folder), keys=stems)
