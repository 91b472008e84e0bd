"""The shared real data through the loaders: the statue's COLMAP capture (23 undistorted JPEGs of 7 heights) and the
NeRF-synthetic lego (RGBA). Skipped, with the reason, when ../shared/data is absent."""

from __future__ import annotations

import numpy as np
import pytest

from roodi_toolkit.io.colmap import read_colmap_model
from roodi_toolkit.io.dataset import load_cameras, load_dataset, to_loaded_pixel

from .test_formats import DATA

STATUE, LEGO = DATA / "statue", DATA / "lego"


@pytest.mark.skipif(not STATUE.is_dir(), reason=f"{STATUE} not found (the shared real data)")
def test_the_statue_loads_cropped_to_its_smallest_height():
    model = read_colmap_model(STATUE / "sparse" / "0")
    heights = sorted({c.height for c in model.cameras.values()})
    assert len(model.images) == 23 and heights[0] == 656 and heights[-1] == 662
    ds = load_dataset(STATUE, 4)
    assert ds.images.shape == (23, 164, 250, 3) and ds.test_indices == [0, 8, 16]
    assert ds.metadata["crop"]["size"] == [1000, 656]
    # every camera keeps its own intrinsics: the principal points differ by the crop offsets
    by_name = {img.name.rsplit(".", 1)[0]: model.cameras[img.camera_id] for img in model.images.values()}
    for cam in ds.cameras:
        ref = by_name[cam.name]
        y0 = (ref.height - 656) // 2
        np.testing.assert_allclose(cam.K[1, 2], (ref.params[3] - y0) / 4, rtol=1e-9)
        np.testing.assert_allclose(cam.K[0, 0], ref.params[0] / 4, rtol=1e-9)
    # cameras alone keep the photos' own sizes; a click in the photo's pixels lands in the loaded image
    cams = load_cameras(STATUE)
    assert sorted({c.height for c in cams}) == heights
    tall = next(c for c in cams if c.height == 662)
    assert to_loaded_pixel(ds, tall.name, 500.0, 331.0) == (125.0, 82.0)


@pytest.mark.skipif(not LEGO.is_dir(), reason=f"{LEGO} not found (the shared real data)")
def test_lego_loads_with_alpha_at_a_reduced_size():
    ds = load_dataset(LEGO, 8)
    assert ds.images.shape == (100, 100, 100, 3) and ds.alphas is not None and ds.alphas.shape == (100, 100, 100)
    assert ds.metadata["source_pixels"]["r_0"] == {"size": [800, 800], "scale": [0.125, 0.125], "offset": [0.0, 0.0]}
