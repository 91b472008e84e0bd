"""Hand-drawn polygon masks (``polygons.json``: ``{"polygons": {VIEW: [[x, y], ...]}}``, in the photos' own pixels),
read for :func:`roodi_toolkit.evaluate.polygons.polygon_masks`, which rasterises them at a loaded dataset's size."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import DatasetError
from .files import read_json


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
