"""Pictures made from renders: class maps in distinct colours, probability heat maps, and grids of tiles.

Pure array functions (no file I/O); the stages that write pictures hand their results to :mod:`roodi_toolkit.io.files`.
They live beside the renderer rather than in :mod:`roodi_toolkit.viz` because pipeline stages (distillation,
selection) make pictures too, and the pipeline may not import from viz, which depends on it.
"""

from __future__ import annotations

import colorsys
from typing import Any, Sequence

import numpy as np

from ..errors import ConfigError


def colorize_ids(ids: np.ndarray) -> np.ndarray:
    """Return ``[H, W, 3]`` float colours of a class map: 0 black, others distinct hues (golden-angle spaced)."""
    ids = np.asarray(ids)
    top = int(ids.max()) if ids.size else 0
    palette = np.zeros((top + 1, 3), np.float32)
    for i in range(1, top + 1):
        palette[i] = colorsys.hsv_to_rgb((i * 0.618034) % 1.0, 0.75, 0.95)
    return palette[ids]


def probability_grid(rows: Sequence[Sequence[np.ndarray]], gap: int = 2) -> np.ndarray:
    """Return one ``[H', W', 3]`` image of equally sized ``[H, W, 3]`` tiles laid out row by row on white."""
    if not rows or not rows[0]:
        raise ConfigError("a picture needs at least one tile")
    H, W = rows[0][0].shape[:2]
    cols = max(len(r) for r in rows)
    out = np.ones((len(rows) * (H + gap) - gap, cols * (W + gap) - gap, 3), np.float32)
    for r, row in enumerate(rows):
        for c, tile in enumerate(row):
            t = np.asarray(tile, np.float32)
            if t.ndim == 2:
                t = np.repeat(t[..., None], 3, axis=2)
            out[r * (H + gap):r * (H + gap) + H, c * (W + gap):c * (W + gap) + W] = t
    return out


def colour_map(name: str) -> Any:
    """Return matplotlib's colour map ``name`` (a function of values in [0, 1] to RGBA ``[..., 4]``)."""
    from matplotlib import colormaps  # lazy: matplotlib takes 1-2 s to import; only pictures need its colour maps

    return colormaps[name]


def heat(prob: np.ndarray) -> np.ndarray:
    """Return ``[H, W, 3]`` viridis colours of probabilities ``[H, W]`` in [0, 1]."""
    return colour_map("viridis")(np.clip(prob, 0, 1))[..., :3].astype(np.float32)
