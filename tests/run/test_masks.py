"""Mask folders in a run: read for the files segmenter only, and handed to it in memory."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

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


def test_the_masks_are_read_at_the_working_size(tmp_path):
    """Distillation segments views scaled down to its pixel budget: the folder is read at that size (centre samples of
    each block, as the working dataset's own masks), not held at full size beside it."""
    ds = SimpleNamespace(names=["a"], width=8, height=6, masks=None)
    folder = tmp_path / "masks"
    folder.mkdir()
    full = np.arange(48, dtype=np.uint8).reshape(6, 8)
    write_image(full, folder / "a.png")
    options = options_with_masks("files", None, SegmentPrompt(mask_dir=folder), ds, max_pixels=12)  # 4x3: 1/2
    np.testing.assert_array_equal(options["masks"]["a"], full[1::2, 1::2])
    assert options_with_masks("files", None, SegmentPrompt(mask_dir=folder), ds)["masks"]["a"].shape == (6, 8)


def test_a_folder_of_the_datasets_masks_gives_the_working_datasets_masks(tmp_path):
    """What distillation segments from ``--masks`` is what it takes from the dataset's own masks at its working
    resolution (the folder holds them at full size)."""
    from roodi_toolkit.pipeline.resolution import working_dataset

    from ..object_scene import object_dataset

    ds, _, _ = object_dataset()
    folder = tmp_path / "masks"
    folder.mkdir()
    for name, m in zip(ds.names, ds.masks.numpy()):
        write_image(m.astype(np.uint8), folder / f"{name}.png")
    work, factor = working_dataset(ds, 16 * 16)
    options = options_with_masks("files", None, SegmentPrompt(mask_dir=folder), ds, max_pixels=16 * 16)
    masks = get_segmenter("files", **options).segment(work, SegmentPrompt(mask_dir=folder))
    assert factor == 2 and masks.kind == "instances" and torch.equal(masks.masks, work.masks)
    assert torch.equal(folder_masks(folder, ds).masks, ds.masks)


def test_folder_masks_reads_instance_ids(tmp_path):
    masks = folder_masks(_folder(tmp_path, values=(0, 2)), _dataset())
    assert masks.kind == "instances" and masks.present_ids() == [2] and masks.source.endswith("masks")


def test_a_distillations_masks_keep_each_view_where_train_and_test_share_names(tmp_path):
    """A Blender set's ``train/r_0`` and ``test/r_0`` are both ``r_0``: the distillation writes each view's mask under
    a stem of its own, and the extraction reads every view its own mask back (the test views' masks overwrote the
    training views' of the same name, and occlusion and fine-tuning took them for the training views)."""
    from roodi_toolkit.io.files import file_stems
    from roodi_toolkit.run.distill import save_distilled
    from roodi_toolkit.io.ply import write_ply
    from roodi_toolkit.pipeline.distill import DistilledScene, ObjectClassifier, with_features
    from roodi_toolkit.pipeline.segment import ViewMasks

    from ..conftest import make_cloud

    names = ["r_0", "r_1", "r_0", "r_1"]  # train, then test
    ds = SimpleNamespace(names=names, width=4, height=3, masks=None)
    masks = torch.zeros(4, 3, 4, dtype=torch.uint8)
    for i in range(4):
        masks[i, i % 3, i] = 1
    cloud = make_cloud(5)
    ply = tmp_path / "scene.ply"
    write_ply(cloud, ply)
    distilled = DistilledScene(with_features(cloud, np.zeros((5, 2), np.float32)),
                               ObjectClassifier(torch.zeros(2, 2), torch.zeros(2)),
                               ViewMasks(masks, names, "binary", 2), None, {})
    save_distilled(tmp_path / "dist", distilled, ply)
    assert sorted(p.name for p in (tmp_path / "dist" / "object_masks").iterdir()) == [
        f"{s}.png" for s in sorted(file_stems(names))]
    back = folder_masks(tmp_path / "dist" / "object_masks", ds)
    assert torch.equal(back.masks, masks)
    # a folder written before (one file per name) is refused with what to do, not read with the wrong masks
    for stem in set(file_stems(names)) - set(names):
        (tmp_path / "dist" / "object_masks" / f"{stem}.png").unlink()
    with pytest.raises(DatasetError, match="older roodi-toolkit.*distil again"):
        folder_masks(tmp_path / "dist" / "object_masks", ds)
