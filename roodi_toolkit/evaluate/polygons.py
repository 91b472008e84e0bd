"""Masks drawn as polygons in the photos' own pixels, rasterised at a loaded dataset's resolution.

Real captures come without masks; a few hand-drawn polygons on held-out photos (``tests/data/statue_masks``) are what
an extraction of a real object is scored against. The polygons are given in the photo's pixels (what an image
viewer shows), and the loaded dataset may be downscaled and cropped to a common size, so each vertex goes through
the same mapping a click does (:func:`roodi_toolkit.io.dataset.to_loaded_pixel`); vertices on the photo's border
(where a polygon closes along an edge the object runs out of) are mapped without the click's range check.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from ..errors import ConfigError, DatasetError
from ..io.dataset import Dataset, to_loaded_pixel
from ..io.files import read_json

SUPERSAMPLE = 4
"""Each loaded pixel is covered by SUPERSAMPLE^2 samples; it is inside when at least half of them are."""


def read_polygons(path: str | Path) -> dict[str, list[list[float]]]:
    """Return the polygons ``{view name: [[x, y], ...]}`` of a ``polygons.json`` (``{"polygons": {...}}``).

    Raises:
        DatasetError: unreadable, or a polygon with fewer than 3 finite vertices.
    """
    record = read_json(path, "polygon masks")
    polys = record.get("polygons") if isinstance(record, dict) else None
    if not isinstance(polys, dict) or not polys:
        raise DatasetError(f"{path}: expected {{\"polygons\": {{VIEW: [[x, y], ...]}}}}")
    out = {}
    for name, pts in polys.items():
        arr = np.asarray(pts, dtype=np.float64) if isinstance(pts, list) else np.zeros((0, 2))
        if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) < 3 or not np.isfinite(arr).all():
            raise DatasetError(f"{path}: the polygon of {name!r} must be at least 3 finite [x, y] vertices")
        out[str(name)] = arr.tolist()
    return out


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


def polygon_masks(dataset: Dataset, path: str | Path) -> dict[str, np.ndarray]:
    """Return ``{view name: [H, W] bool}`` for every polygon of ``path`` (a ``polygons.json``)."""
    return {name: polygon_mask(dataset, name, pts) for name, pts in read_polygons(path).items()}
