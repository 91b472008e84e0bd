"""Mask folders: read by view name into arrays at the views' size; the folder or file at fault named."""

from __future__ import annotations

import numpy as np
import pytest

from roodi_toolkit.errors import DatasetError
from roodi_toolkit.io.files import write_image
from roodi_toolkit.io.masks import read_mask_folder

NAMES = ["r_000", "r_001", "r_002"]
SIZE = (8, 6)  # width, height


def _ids(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 3, size=(SIZE[1], SIZE[0])).astype(np.uint8)


def test_masks_are_read_by_view_name_at_the_views_size(tmp_path):
    folder = tmp_path / "masks"
    folder.mkdir()
    write_image(_ids(0), folder / "r_000.PNG")  # either case of the extension
    write_image(np.kron(_ids(1), np.ones((2, 2), np.uint8)), folder / "r_001.png")  # twice the size: centre samples
    write_image(np.repeat(_ids(2)[..., None], 3, axis=2), folder / "r_002.png")  # grey stored as colour
    write_image(np.zeros((2, 2), np.uint8), folder / "unrelated.png")
    masks = read_mask_folder(folder, NAMES, SIZE)
    assert list(masks) == NAMES
    for i, name in enumerate(NAMES):
        np.testing.assert_array_equal(masks[name], _ids(i))
        assert masks[name].dtype == np.uint8
        assert masks[name].base is None  # its own copy, not a view keeping the whole image read
    half = tmp_path / "half"  # as the mask stages write them: the size divided by an integer, each pixel repeated
    half.mkdir()
    small = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000  # 16-bit ids stay 16-bit
    for name in NAMES:
        write_image(small, half / f"{name}.png")
    masks = read_mask_folder(half, NAMES, SIZE)
    assert masks["r_000"].dtype == np.uint16
    np.testing.assert_array_equal(masks["r_000"], np.kron(small, np.ones((2, 2), np.uint16)))


def test_the_folder_or_file_at_fault_is_named(tmp_path):
    with pytest.raises(DatasetError, match="missing: mask folder not found"):
        read_mask_folder(tmp_path / "missing", NAMES, SIZE)
    folder = tmp_path / "m"
    folder.mkdir()
    write_image(_ids(0), folder / "r_000.png")
    with pytest.raises(DatasetError, match=f"{folder}: no mask for 2 of 3 views: r_001.png, r_002.png; masks are "
                                           "matched to views by name"):
        read_mask_folder(folder, NAMES, SIZE)
    many = [f"v{i}" for i in range(8)]
    with pytest.raises(DatasetError, match="no mask for 8 of 8 views: v0.png, v1.png, v2.png, v3.png, v4.png and 3 "
                                           "more"):
        read_mask_folder(folder, many, SIZE)
    write_image(np.zeros((5, 8), np.uint8), folder / "r_001.png")
    write_image(_ids(2), folder / "r_002.png")
    with pytest.raises(DatasetError, match="r_001.png: mask is 8x5 but its view is 8x6"):
        read_mask_folder(folder, NAMES, SIZE)
    colour = np.zeros((6, 8, 3), np.uint8)
    colour[..., 0] = 255
    write_image(colour, folder / "r_001.png")
    with pytest.raises(DatasetError, match="r_001.png: mask is a colour image"):
        read_mask_folder(folder, NAMES, SIZE)
