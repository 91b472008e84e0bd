"""The overview picture of a generated scene: a grid of training views with each target outlined in its own colour.

Example:
    >>> import numpy as np
    >>> m = np.zeros((5, 5), bool); m[1:4, 1:4] = True
    >>> int(_outline(m).sum())
    21
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import ConfigError

__all__ = ["overview_image"]

_OUTLINE_COLORS = [(1.0, 0.1, 0.1), (0.1, 0.9, 0.2), (0.15, 0.4, 1.0), (1.0, 0.85, 0.0)]


def _outline(mask: np.ndarray) -> np.ndarray:
    """Return the pixels of ``mask`` that touch a pixel outside it (4-neighbourhood), thickened by one pixel."""
    m = np.pad(mask, 1)
    inner = m[1:-1, 1:-1] & m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2] & m[1:-1, 2:]
    edge = mask & ~inner
    e = np.pad(edge, 1)
    return e[1:-1, 1:-1] | e[:-2, 1:-1] | e[2:, 1:-1] | e[1:-1, :-2] | e[1:-1, 2:]


def overview_image(images: Sequence[np.ndarray], masks: Sequence[np.ndarray], target_ids: Sequence[int], *,
                   columns: int = 4, max_views: int = 12, target_thumbnails: Sequence[np.ndarray] = ()) -> np.ndarray:
    """Return an ``[H', W', 3]`` float32 grid of views with each target's visible outline in its own colour.

    Args:
        images: ``[H, W, 3]`` float views.
        masks: ``[H, W]`` instance ids of the views.
        target_ids: ids to outline (colours: red, green, blue, yellow in this order).
        columns: views per row.
        max_views: views shown, evenly picked.
        target_thumbnails: optional ``[H, W, 3]`` images of each target alone, shown in a last row framed in the
            target's colour.
    """
    if not images:
        raise ConfigError("overview needs at least one view")
    idx = np.unique(np.linspace(0, len(images) - 1, min(max_views, len(images))).round().astype(int))
    H, W = images[0].shape[:2]
    tiles = []
    for i in idx:
        tile = np.asarray(images[i], dtype=np.float32).copy()
        for k, tid in enumerate(target_ids):
            tile[_outline(np.asarray(masks[i]) == tid)] = _OUTLINE_COLORS[k % len(_OUTLINE_COLORS)]
        tiles.append(tile)
    for k, thumb in enumerate(target_thumbnails):
        tile = np.asarray(thumb, dtype=np.float32).copy()
        frame = np.zeros((H, W), dtype=bool)
        frame[:2], frame[-2:], frame[:, :2], frame[:, -2:] = True, True, True, True
        tile[frame] = _OUTLINE_COLORS[k % len(_OUTLINE_COLORS)]
        if k == 0:
            while len(tiles) % columns:
                tiles.append(np.ones((H, W, 3), np.float32))
        tiles.append(tile)
    while len(tiles) % columns:
        tiles.append(np.ones((H, W, 3), np.float32))
    gap = 2
    rows = len(tiles) // columns
    out = np.ones((rows * H + (rows - 1) * gap, columns * W + (columns - 1) * gap, 3), np.float32)
    for j, tile in enumerate(tiles):
        r, c = divmod(j, columns)
        out[r * (H + gap):r * (H + gap) + H, c * (W + gap):c * (W + gap) + W] = tile
    return out
