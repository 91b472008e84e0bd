"""Masks drawn as polygons in the photos' own pixels, rasterised at a loaded dataset's resolution.

Real captures come without masks; a few hand-drawn polygons on held-out photos (``tests/data/statue_masks``) are what
an extraction of a real object is scored against. The polygons are given in the photo's pixels (what an image
viewer shows), and the loaded dataset may be downscaled and cropped to a common size, so each vertex goes through
the same mapping a click does (:func:`roodi_toolkit.io.dataset.to_loaded_pixel`); vertices on the photo's border
(where a polygon closes along an edge the object runs out of) are mapped without the click's range check. The file
is read by :func:`roodi_toolkit.io.polygons.read_polygons`.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
from PIL import Image, ImageDraw

from ..errors import ConfigError, DatasetError
from ..io.dataset import Dataset, to_loaded_pixel

SUPERSAMPLE = 4
"""Each loaded pixel is covered by SUPERSAMPLE^2 samples; it is inside when at least half of them are."""


def _loaded_vertex(dataset: Dataset, view: str, x: float, y: float) -> tuple[float, float]:
    """Return the loaded image's position of photo pixel ``(x, y)``; border vertices are not refused."""
    m = dataset.metadata.get("source_pixels", {}).get(view)
    if m is not None and "undistort" not in m:
        (ax, ay), (bx, by) = m["scale"], m["offset"]
        return x * ax - bx, y * ay - by
    try:
        return to_loaded_pixel(dataset, view, x, y)
    except ConfigError:  # outside the photo or in a cropped border: the affine part is all a polygon needs
        (ax, ay), (bx, by) = (m["scale"], m["offset"]) if m is not None else ((1.0, 1.0), (0.0, 0.0))
        return x * ax - bx, y * ay - by


def polygon_mask(dataset: Dataset, view: str, polygon: Any) -> np.ndarray:
    """Return the ``[H, W]`` bool mask of ``polygon`` (photo pixels of view ``view``) at the dataset's resolution."""
    if view not in dataset.names:
        raise ConfigError(f"the polygon's view {view!r} is not in the dataset")
    pts = [_loaded_vertex(dataset, view, float(x), float(y)) for x, y in polygon]
    s = SUPERSAMPLE
    canvas = Image.new("L", (dataset.width * s, dataset.height * s), 0)
    ImageDraw.Draw(canvas).polygon([(x * s, y * s) for x, y in pts], fill=1)
    big = np.asarray(canvas, dtype=np.float32)
    cover = big.reshape(dataset.height, s, dataset.width, s).mean(axis=(1, 3))
    return cover >= 0.5


def polygon_masks(dataset: Dataset, polygons: Mapping[str, Sequence[Sequence[float]]]) -> dict[str, np.ndarray]:
    """Return ``{view name: [H, W] bool}`` for every polygon of ``polygons`` (``{view name: [[x, y], ...]}``, as
    :func:`roodi_toolkit.io.polygons.read_polygons` reads a ``polygons.json``)."""
    return {name: polygon_mask(dataset, name, pts) for name, pts in polygons.items()}
