"""Polygon masks in the photos' own pixels, rasterised at a loaded dataset's resolution (the statue's held-out
masks, tests/data/statue_masks)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from roodi_toolkit.errors import ConfigError, DatasetError
from roodi_toolkit.evaluate.polygons import polygon_mask, polygon_masks
from roodi_toolkit.io.polygons import read_polygons
from roodi_toolkit.io.dataset import load_dataset

from ..io.test_formats import DATA
from ..paths import TEST_DATA

POLYGONS = TEST_DATA / "statue_masks" / "polygons.json"


@pytest.fixture(scope="module")
def half(tmp_path_factory):
    from ..object_scene import write_object_scene

    data, _, _ = write_object_scene(tmp_path_factory.mktemp("scene"), size=64)
    return load_dataset(data, 2)


def test_a_square_lands_on_the_loaded_pixels(half):
    view = half.names[0]
    mask = polygon_mask(half, view, [[8, 8], [56, 8], [56, 56], [8, 56]])  # 64 px photo -> 32 px loaded
    expected = np.zeros((32, 32), bool)
    expected[4:28, 4:28] = True
    assert np.array_equal(mask, expected)
    # a polygon closing along the photo's border is not refused as a click there would be
    edge = polygon_mask(half, view, [[0, 32], [64, 32], [64, 64], [0, 64]])
    assert edge[16:].all() and not edge[:16].any()


def test_bad_polygons(half, tmp_path):
    with pytest.raises(ConfigError, match="not in the dataset"):
        polygon_mask(half, "nope", [[0, 0], [1, 0], [1, 1]])
    bad = tmp_path / "p.json"
    bad.write_text(json.dumps({"polygons": {"r_000": [[0, 0], [1, 1]]}}))
    with pytest.raises(DatasetError, match="at least 3 finite"):
        read_polygons(bad)
    bad.write_text("[]")
    with pytest.raises(DatasetError, match="expected"):
        read_polygons(bad)


@pytest.mark.skipif(not (DATA / "statue").is_dir(), reason=f"{DATA / 'statue'} not found (the shared real data)")
def test_the_statue_masks_cover_the_statue_in_the_held_out_views():
    ds = load_dataset(DATA / "statue", 4)
    masks = polygon_masks(ds, read_polygons(POLYGONS))
    assert sorted(masks) == [ds.names[i] for i in ds.test_indices]  # the three held-out photos
    for name, m in masks.items():
        assert m.shape == (164, 250)
        assert 0.15 < m.mean() < 0.45, (name, m.mean())  # the statue fills the lower middle of each photo
        assert m[-1, 125] and not m[5, 5] and not m[5, -5]  # runs out of the bottom; background in the corners
