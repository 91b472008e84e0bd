"""Free-standing objects for the click segmenter (:mod:`roodi_toolkit.pipeline.click`): the Gaussians near a click
cut into connected pieces, and the piece the click points at taken whole when it ends inside a sphere round the click
(:func:`free_standing`), with the pieces that belong to it (:func:`is_part`, :func:`whole`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..gaussians import GaussianCloud

MAX_PART_GAUSSIANS = 4_000_000
"""Above this many Gaussians near the click the free-standing test is skipped (its neighbour graph would not fit)."""
PART_LOOKOUT = 8.0
"""A free piece looks this many times as far as the sphere it was found in for a larger free piece it is part of."""
REGION_SHARE = 0.1
"""The share of the clicked region's Gaussians a piece must hold to be what the click points at (a speck of a real
capture in front of the object, under the clicked pixel, holds less)."""


def free_standing(settings: Any, scene: GaussianCloud, at_click: np.ndarray, centre: np.ndarray, radius0: float,
                  limit: float, region: np.ndarray | None = None) -> np.ndarray | None:
    """Return the Gaussians ``[N]`` bool of a free-standing object, or None when the clicked one touches more.

    The Gaussians within a sphere around the click are cut into connected pieces (each linked to those of its
    16 nearest within ``part_spacing`` times the median spacing). The sphere starts at twice the clicked
    region's 3D radius and doubles, up to ``limit``, until the piece the click points at ends inside it (the
    piece with the most compositing weight ``at_click`` ``[N]`` under the clicked pixels, among the pieces that
    hold at least :data:`REGION_SHARE` of the clicked region's Gaussians ``region`` ``[N]``: the clicked region
    may spill onto what the object stands on, the pixel under the click does not, and a speck in front of the
    object on a real capture is under the click too, but holds little of the region): then it
    stands free (a robot over a ground slab, a vase with a gap under it; a click on its eye finds the whole
    body) and is the object, with the pieces near it (a gap under ``part_gap`` of its radius) that are no larger
    and mostly of its colours (the robot's floating hands). A free piece that is itself such a part of a larger
    one (a click on a floating hand) hands the object to that one, the sphere growing until it too ends inside:
    a click anywhere on the object selects what a click on its body does. A piece that still reaches the sphere
    at ``limit`` (a statue on its table: the piece is the table and the room) gives None, and the seeds are grown
    through colour-weighted links instead; so does a piece that is most of the scene.
    """
    s = settings
    if not (at_click > 0).any() or s.part_spacing <= 0:
        return None
    dist = np.linalg.norm(scene.means - centre, axis=1)
    reach = max(2.0 * radius0, 1e-9)
    anchor = at_click  # [N] weights: the piece with the most is the object (a larger piece it belongs to later)
    found = None  # the last free piece: the object unless a larger free piece takes it as a part
    adopt_until = limit  # how far to look for that larger piece (set when a free piece is found)
    while True:
        idx = np.flatnonzero(dist <= reach)
        if len(idx) > MAX_PART_GAUSSIANS:
            break
        if len(idx) >= 3 and (anchor[idx] > 0).any():
            pos = scene.means[idx].astype(np.float64)
            rgb = np.clip(scene.rgb[idx], 0, 1)
            piece = pieces(pos, s.part_spacing)
            weight = np.bincount(piece, weights=anchor[idx], minlength=piece.max() + 1)
            if region is not None and anchor is at_click:  # a speck under the click is no object
                held = np.bincount(piece, weights=region[idx].astype(np.float64), minlength=piece.max() + 1)
                eligible = held >= REGION_SHARE * held.sum()
                if not eligible.any():
                    # no piece holds a share of the clicked region: the Gaussians here do not form pieces an
                    # object is made of (a sparse or noisy model), so none stands free; grow the seeds instead
                    return None
                weight[~eligible] = 0.0
                if not weight.any():  # the click's own pixels show only specks: the region's largest piece
                    weight = np.where(eligible, held, 0.0)
            main = int(np.argmax(weight))
            ends = np.zeros(piece.max() + 1)
            np.maximum.at(ends, piece, dist[idx])
            if ends[main] < 0.8 * reach:  # the piece ends inside the sphere: it stands free
                if (piece == main).sum() > s.part_share * len(scene):
                    break  # it is most of the scene (the ground, a lone object): nothing stands free
                if found is None:
                    adopt_until = min(limit, PART_LOOKOUT * reach)
                found = (idx, pos, rgb, piece, main)
                larger = whole(s, pos, rgb, piece, main, ends < 0.8 * reach)
                if larger != main:
                    # the free piece is a part of a larger free one (a floating hand of its robot): that one is
                    # the object, so a click anywhere on it selects what a click on its body does
                    anchor = np.zeros(len(scene))
                    anchor[idx[piece == larger]] = 1.0
                    adopt_until = min(limit, PART_LOOKOUT * reach)
                    continue
        if reach >= limit or (found is not None and reach >= adopt_until):
            break  # it runs on as far as we look (it touches the rest), or what stands free was found
        reach = min(2.0 * reach, limit)
    if found is None:
        return None
    idx, pos, rgb, piece, main = found
    inside = piece == main
    sizes = np.bincount(piece)
    chosen = inside.copy()
    for other in np.flatnonzero((sizes >= 3) & (sizes <= sizes[main])):
        if other != main and is_part(s, pos, rgb, piece == other, inside):
            chosen |= piece == other
    out = np.zeros(len(scene), dtype=bool)
    out[idx[chosen]] = True
    return out

def pieces(pos: np.ndarray, spacing: float) -> np.ndarray:
    """Return the connected piece of each position ``[n]``: each linked to those of its 16 nearest within
    ``part_spacing`` times their median spacing."""
    near, nb = cKDTree(pos).query(pos, k=min(17, len(pos)))
    link = near[:, 1:] <= spacing * float(np.median(near[:, 1]))
    rows = np.repeat(np.arange(len(pos)), link.sum(axis=1))
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, nb[:, 1:][link])), shape=(len(pos),) * 2)
    return connected_components(graph, directed=False)[1]

def is_part(settings: Any, pos: np.ndarray, rgb: np.ndarray, part: np.ndarray, body: np.ndarray) -> bool:
    """Whether the Gaussians ``part`` belong to the object ``body`` (both ``[n]`` bool): nearer to it than
    ``part_gap`` of its radius and mostly (half their Gaussians) within ``part_colour`` of its colours."""
    s = settings
    centre = pos[body].mean(axis=0)
    radius = float(np.linalg.norm(pos[body] - centre, axis=1).max())
    if float(cKDTree(pos[body]).query(pos[part])[0].min()) > s.part_gap * radius:
        return False
    return bool(np.mean(cKDTree(rgb[body]).query(rgb[part])[0] <= s.part_colour) >= 0.5)

def whole(settings: Any, pos: np.ndarray, rgb: np.ndarray, piece: np.ndarray, main: int, free: np.ndarray
          ) -> int:
    """Return the smallest piece larger than ``main`` and standing free (``free[piece]``) that would take ``main``
    as one of its parts and is of one object with it, else ``main``. One object: their median colours within
    twice ``part_colour`` (a robot and its floating hand, orange and orange), or ``main`` inside the larger
    piece's box along its own axes (the robot's black eye in its head); not the dark ground slab under the robot,
    which has the robot's dark joints among its colours and holds the robot above its box."""
    sizes = np.bincount(piece)
    members = piece == main
    colour = np.median(rgb[members], axis=0)
    centre = pos[members].mean(axis=0)
    for other in np.argsort(sizes, kind="stable"):
        if sizes[other] <= sizes[main] or not free[other]:
            continue
        body = piece == other
        same = np.linalg.norm(np.median(rgb[body], axis=0) - colour) <= 2 * settings.part_colour
        if (same or inside_box(pos[body], centre)) and is_part(settings, pos, rgb, members, body):
            return int(other)
    return main


def inside_box(points: np.ndarray, point: np.ndarray) -> bool:
    """Whether ``point`` ``[3]`` lies in the box of ``points`` ``[n, 3]`` along their principal axes."""
    sample = points[:: max(1, len(points) // 20000)]
    centre = sample.mean(axis=0)
    _, _, axes = np.linalg.svd(sample - centre, full_matrices=False)
    coords = (sample - centre) @ axes.T
    p = (point - centre) @ axes.T
    return bool(np.all((p >= coords.min(axis=0)) & (p <= coords.max(axis=0))))
