"""Mask folders in a run: read for the files segmenter only, and handed to it in memory."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from roodi_toolkit.errors import DatasetError
from roodi_toolkit.io.files import write_image
from roodi_toolkit.pipeline.segment import SegmentPrompt, get_segmenter
from roodi_toolkit.run.masks import folder_masks, options_with_masks

NAMES = ["a", "b"]


def _dataset():
    return SimpleNamespace(names=NAMES, width=4, height=3, masks=None)


def _folder(tmp_path, values=(0, 255)):
    folder = tmp_path / "masks"
    folder.mkdir()
    for i, name in enumerate(NAMES):
        m = np.full((3, 4), values[0], np.uint8)
        m[i, :2] = values[1]
        write_image(m, folder / f"{name}.png")
    return folder


def test_the_files_segmenter_gets_the_folder_read(tmp_path):
    ds, folder = _dataset(), _folder(tmp_path)
    options = options_with_masks("files", {"keep": 1}, SegmentPrompt(mask_dir=folder), ds)
    assert options["keep"] == 1 and options["source"] == str(folder) and list(options["masks"]) == NAMES
    masks = get_segmenter("files", masks=options["masks"]).segment(ds, SegmentPrompt(mask_dir=folder))
    assert masks.kind == "binary" and masks.masks[1, 1, :2].tolist() == [1, 1] and int(masks.masks.sum()) == 4
    # no folder, or another segmenter: nothing is read (a folder that is not there is no error for them)
    missing = SegmentPrompt(mask_dir=tmp_path / "missing")
    assert options_with_masks("click", {"r": 2}, missing, ds) == {"r": 2}
    assert options_with_masks("files", None, SegmentPrompt(), ds) == {}
    with pytest.raises(DatasetError, match="missing: mask folder not found"):
        options_with_masks("files", None, missing, ds)


def test_folder_masks_reads_instance_ids(tmp_path):
    masks = folder_masks(_folder(tmp_path, values=(0, 2)), _dataset())
    assert masks.kind == "instances" and masks.present_ids() == [2] and masks.source.endswith("masks")
