"""The working resolution of the mask stages: reduced views, masks brought back to full size, distillation on them."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from roodi_toolkit.errors import ConfigError
from roodi_toolkit.evaluate.metrics import alpha_iou
from roodi_toolkit.params import GaussianParams
from roodi_toolkit.pipeline.distill import DistillConfig, distill_scene
from roodi_toolkit.masks import full_size_masks, mask_from_array
from roodi_toolkit.pipeline.resolution import working_dataset, working_factor
from roodi_toolkit.pipeline.select import select_object
from roodi_toolkit.render.renderer import NumbaRenderer

from ..object_scene import object_dataset


@pytest.fixture(scope="module")
def scene():
    return object_dataset()


def test_factor_is_the_smallest_that_fits():
    assert working_factor(64, 48, 64 * 48) == 1
    assert working_factor(64, 48, 64 * 48 - 1) == 2
    assert working_factor(1001, 751, 512 * 512) == 2 and (1001 // 2) * (751 // 2) <= 512 * 512
    assert working_factor(3000, 2000, 512 * 512) == 5
    with pytest.raises(ConfigError):
        working_factor(10, 10, 0)


def test_reduced_views_are_the_block_means_of_the_full_views(scene):
    ds, cloud, _ = scene
    work, f = working_dataset(ds, (ds.width * ds.height) // 4)
    assert f == 2 and (work.width, work.height) == (ds.width // 2, ds.height // 2) and len(work) == len(ds)
    full = ds.images[0][: work.height * 2, : work.width * 2]
    torch.testing.assert_close(work.images[0], full.reshape(work.height, 2, work.width, 2, 3).mean((1, 3)))
    assert torch.equal(work.masks[0], ds.masks[0][1::2, 1::2][: work.height, : work.width])
    # the reduced camera puts every point at half the full camera's pixel coordinates (pixel centres at +0.5) ...
    full_px, _ = ds.cameras[3].project(cloud.means.astype(np.float64))
    half_px, _ = work.cameras[3].project(cloud.means.astype(np.float64))
    np.testing.assert_allclose(half_px, full_px / 2, rtol=0, atol=1e-9)
    # ... so its render is about the block mean of the full render (a 32 px view: its edges blur differently)
    params = GaussianParams.from_cloud(cloud)
    a = NumbaRenderer().render(params, ds.cameras[3]).alpha[..., 0][: work.height * 2, : work.width * 2]
    b = NumbaRenderer().render(params, work.cameras[3]).alpha[..., 0]
    pooled = a.reshape(work.height, 2, work.width, 2).mean((1, 3))
    assert (pooled - b).abs().mean() < 0.05 and ((pooled > 0.5) == (b > 0.5)).float().mean() > 0.95
    assert working_dataset(ds, ds.width * ds.height) == (ds, 1)


def test_masks_come_back_to_full_size():
    rng = np.random.default_rng(0)
    small = rng.integers(0, 3, (2, 5, 7))
    up = full_size_masks(small, 15, 11)  # 7 * 2 + 1 columns, 5 * 2 + 1 rows: the dropped strip repeats the edge
    assert up.shape == (2, 11, 15)
    assert np.array_equal(up[:, :10:2, :14:2], small) and np.array_equal(up[:, 10, :14:2], small[:, 4])
    assert full_size_masks(up, 15, 11) is up
    with pytest.raises(ConfigError):
        full_size_masks(small, 20, 11)
    assert np.array_equal(mask_from_array(small[0].astype(np.uint8), (15, 11), "m.png"), up[0])


def test_distillation_at_half_size_selects_what_full_size_selects(scene):
    """The record says the working size; the selection made on half-size views matches the full-size one."""
    ds, cloud, ids = scene
    config = DistillConfig(iterations=150)
    full = distill_scene(cloud, ds, config=config)
    half = distill_scene(cloud, ds, config=DistillConfig(iterations=150, max_pixels=(ds.width * ds.height) // 4))
    assert full.summary["working_downscale"] == 1 and half.summary["working_downscale"] == 2
    assert half.summary["working_size"] == [ds.width // 2, ds.height // 2]
    assert tuple(half.masks.masks.shape[1:]) == (ds.height // 2, ds.width // 2)
    for object_id in (1, 2):  # what the object looks like, from every view at full size, is the same
        a = select_object(full.cloud, full.classifier, object_id, prune=False).selected
        b = select_object(half.cloud, half.classifier, object_id, prune=False).selected
        truth = (ds.masks == object_id).float()
        ref = np.mean(alpha_iou(full.cloud.select(a), ds.cameras, truth))
        assert ref > 0.6 and np.mean(alpha_iou(half.cloud.select(b), ds.cameras, truth)) > ref - 0.02
