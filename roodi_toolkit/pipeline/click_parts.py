"""Free-standing objects for the click segmenter (:mod:`roodi_toolkit.pipeline.click`): the Gaussians near a click
cut into connected pieces, and the piece the click points at taken whole when it ends inside a sphere round the click
(:func:`free_standing`), with the pieces that belong to it (:func:`with_parts`, :func:`whole`); and an object
standing on a level support (a person on the ground), free once the support's layer is left out
(:func:`support_layer`, :func:`standing_free`).
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
                  limit: float, region: np.ndarray | None = None, cut: np.ndarray | None = None
                  ) -> np.ndarray | None:
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
    through colour-weighted links instead; so does a piece that is most of the scene. The Gaussians ``cut`` ``[N]``
    (the layer of a support, :func:`support_layer`) are left out of the pieces.
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
        idx = np.flatnonzero((dist <= reach) & ~cut if cut is not None else dist <= reach)
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
    chosen = with_parts(s, pos, rgb, piece, main)
    out = np.zeros(len(scene), dtype=bool)
    out[idx[chosen]] = True
    return out


def pieces(pos: np.ndarray, spacing: float) -> np.ndarray:
    """Return the connected piece of each position ``[n]``: each linked to those of its 16 nearest within
    ``spacing`` times their median spacing (the ``part_spacing`` setting)."""
    near, nb = cKDTree(pos).query(pos, k=min(17, len(pos)))
    link = near[:, 1:] <= spacing * float(np.median(near[:, 1]))
    rows = np.repeat(np.arange(len(pos)), link.sum(axis=1))
    graph = sparse.coo_matrix((np.ones(len(rows)), (rows, nb[:, 1:][link])), shape=(len(pos),) * 2)
    return connected_components(graph, directed=False)[1]


def with_parts(settings: Any, pos: np.ndarray, rgb: np.ndarray, piece: np.ndarray, main: int) -> np.ndarray:
    """Return the piece ``main`` ``[n]`` bool with the pieces that are no larger and belong to it (:func:`is_part`
    of each; the body's trees built once: without a support's layer the ground leaves thousands of stones)."""
    s = settings
    body = piece == main
    sizes = np.bincount(piece)
    others = (sizes >= 3) & (sizes <= sizes[main])
    others[main] = False
    if not others.any():
        return body
    centre = pos[body].mean(axis=0)
    radius = float(np.linalg.norm(pos[body] - centre, axis=1).max())
    members = np.flatnonzero(others[piece])
    gap = cKDTree(pos[body]).query(pos[members], distance_upper_bound=s.part_gap * radius * (1 + 1e-9))[0]
    near = np.zeros(len(sizes), bool)
    near[piece[members[gap <= s.part_gap * radius]]] = True
    members = members[near[piece[members]]]
    if not len(members):
        return body
    close = cKDTree(rgb[body]).query(rgb[members])[0] <= s.part_colour
    share = np.bincount(piece[members], weights=close, minlength=len(sizes)) / np.maximum(sizes, 1)
    return body | (near & (share >= 0.5))[piece]


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


LAYER_TOLERANCE = 0.1
"""The support plane's RANSAC tolerance and its layer's thickness over the plane, as a share of the clicked region's
spread (the median distance of its points from their centre). The biker of benchmarks/RESULTS.md over the playbot's
rocky ground (90% of the ground within 0.017 of its plane): layers 0.02-0.08 thick all free him with 93-98% of his
Gaussians."""
LAYER_AROUND = 4.0
"""The support is looked for under the click within this many spreads of it horizontally (the local support: the
table under a mug, not the floor under the table)."""
LAYER_LEVEL = 0.95
"""The support's normal is within this cosine of the scene's up."""
LAYER_RIVALS = 0.5
"""Level planes holding at least this share of the best one's points are rivals; the highest below the click wins."""
LAYER_MAX = 0.5
"""The layer never reaches above this share of the piece's height over the plane (the 99th percentile of its
Gaussians' heights)."""
LAYER_MIN = 0.005
"""The layer is at least this share of the limit thick (the scene box's diagonal: a rough ground's stones under a
click whose region is small, a patch of a thigh)."""
LAYER_THICKER = (1, 2, 4, 8)
"""The support's layer is tried at these multiples of its first thickness (a rough ground's stones)."""
FOOT_SHARE = 0.1
"""A piece stands on the support when less than this share of it lies within two layer thicknesses over the layer
(the biker: 1-5%; with the ground round his boots that a thinner layer left, 10% and more)."""
SHAVE_RATE = 2.0
"""A piece found over a layer is found again over the next, thicker one; the thicker layer's piece is taken where
what the step shaved off, per unit of height, is more than this many times the thicker piece's Gaussians per unit of
its height, and lay near the layer: the step cut away the ground's stones that had joined the object's foot (a
standing person's piece per unit of height is about even), not a slice of the object. The biker from a click on his
head, over layers 0.022 / 0.044 / 0.087 thick: 556k / 116k Gaussians shaved per unit of height against his 98k."""
GROWTH_AGREES = 0.1
"""The colour-weighted growth is kept over the piece freed of its support where the two differ, off the layer, by
less than this share of the piece (both found the object); more, and the piece is the object (the biker: from clicks
on his chest the growth missed 8-16% of the piece and held 2-8% of its own Gaussians off the piece and the layer;
from his arm it held 4% of him)."""


def support_layer(means: np.ndarray, centre: np.ndarray, up: np.ndarray | None, spread: float, limit: float,
                  at_click: np.ndarray, seed: int = 0, hypotheses: int = 2000,
                  sample: int = 20000) -> tuple[np.ndarray, float] | None:
    """Return each Gaussian's height ``[N]`` over the level surface the clicked object stands on, and the thickness
    of that surface's layer to try first, or None.

    A person on the ground or a vase on a table touches its support, so its Gaussians and the support's form one
    connected piece and :func:`free_standing` finds nothing; without the support's layer it stands free. The support
    is the plane, within :data:`LAYER_LEVEL` of the scene's ``up`` ``[3]``, that RANSAC (tolerance
    :data:`LAYER_TOLERANCE` times the clicked region's ``spread``) finds holding the most of the Gaussians under the
    click's point ``centre`` ``[3]`` (within :data:`LAYER_AROUND` spreads of it horizontally and ``limit`` below it;
    the highest of its rivals, :data:`LAYER_RIVALS`), refitted by least squares on its points. Its layer is
    everything up to a thickness over the plane, first that tolerance or :data:`LAYER_MIN` of ``limit``
    (:func:`standing_free` thickens it). Unlike a fill's support in one view
    (:func:`~roodi_toolkit.pipeline.click_regions.support_plane`) it is found in 3D, so a click on a person's arm,
    whose fill never reaches the ground, finds it too. None without an up or a level plane under the click.
    """
    if up is None or not (at_click > 0).any() or not spread > 0:
        return None
    tol = LAYER_TOLERANCE * spread
    pos = np.asarray(means, np.float64)
    height = (pos - centre) @ up
    across = np.linalg.norm(pos - centre - height[:, None] * up, axis=1)
    under = np.flatnonzero((height < -tol) & (height > -limit) & (across <= LAYER_AROUND * spread))
    if len(under) < 3:
        return None
    rng = np.random.default_rng(seed)
    probe = pos[under[rng.choice(len(under), min(sample, len(under)), replace=False)]]
    triples = pos[under[rng.integers(0, len(under), (hypotheses, 3))]]  # [K, 3, 3]
    normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    length = np.linalg.norm(normals, axis=1)
    normals = normals / np.maximum(length, 1e-30)[:, None]
    normals *= np.where(normals @ up < 0, -1.0, 1.0)[:, None]
    offsets = np.einsum("kj,kj->k", normals, triples[:, 0])
    level = (length > 1e-30) & (normals @ up >= LAYER_LEVEL) & (offsets < normals @ centre - tol)
    if not level.any():
        return None
    normals, offsets = normals[level], offsets[level]
    held = (np.abs(probe @ normals.T - offsets) < tol).sum(axis=0)  # [K] probe points on each plane
    rivals = np.flatnonzero(held >= LAYER_RIVALS * held.max())
    best = rivals[np.argmax(offsets[rivals] - normals[rivals] @ centre)]  # the highest below the click
    on = under[np.abs(pos[under] @ normals[best] - offsets[best]) < tol]
    if len(on) < 3:
        return None
    for _ in range(3):  # refit on its points (least squares, facing up), then take them again
        mid = pos[on].mean(axis=0)
        normal = np.linalg.svd(pos[on] - mid, full_matrices=False)[2][-1]
        normal *= 1.0 if normal @ up >= 0 else -1.0
        on = under[np.abs((pos[under] - mid) @ normal) < tol]
        if len(on) < 3:
            return None
    over = (pos - mid) @ normal  # [N] height over the plane
    click_over = float((centre - mid) @ normal)
    if not click_over > tol:
        return None
    return over, max(tol, LAYER_MIN * limit)


def standing_free(settings: Any, scene: GaussianCloud, at_click: np.ndarray, centre: np.ndarray, radius0: float,
                  limit: float, region: np.ndarray, height: np.ndarray, thickness: float
                  ) -> tuple[np.ndarray, np.ndarray] | None:
    """Return the piece ``[N]`` bool that stands free on the support once its layer is left out, and that layer
    ``[N]`` bool, or None.

    The layer is every Gaussian up to a thickness over the support's plane (``height`` ``[N]`` over it, from
    :func:`support_layer`): ``thickness`` first, then each of :data:`LAYER_THICKER` times it, until
    :func:`free_standing` finds a piece (its arguments as there; the click's weight in the layer moved to what lies
    just over it, :func:`lifted`) that stands on the layer: less than :data:`FOOT_SHARE` of it within two
    thicknesses over the layer, and a layer under :data:`LAYER_MAX` of the piece's height. Over a thin layer a rough
    ground's stones join the piece round its foot, and so does the ground round an object lying on it (a donut on
    the ground); a thicker layer leaves them out. A piece that stands is tried over the next thickness too, and that
    one's piece taken while the step shaves off ground that had joined its foot (:func:`_shaved_ground`): the ground
    round the foot can be under a tenth of it. An object whose height is not many thicknesses (a mug in a room-sized
    scene, a donut lying on the ground) is left to the growth.
    """
    found = found_layer = None  # the piece standing on the layer, until a thicker layer shaves off its ground
    found_top = 0.0
    for times in LAYER_THICKER:
        top = times * thickness
        layer = height <= top
        anchor = lifted(scene.means, at_click, layer, top)
        if anchor is None:
            break  # the click is on the layer, nothing of an object over it (the support itself)
        piece = free_standing(settings, scene, anchor, centre, radius0, limit, region, cut=layer)
        if piece is not None and float(np.percentile(height[piece], 99)) < top / LAYER_MAX:
            break  # the layer reaches half the piece's height: no object standing, or cut through
        if piece is None or _near_layer(height[piece], top).mean() >= FOOT_SHARE:
            if found is None:
                continue
            break
        if found is not None and not _shaved_ground(height, found, found_top, piece, top):
            break
        found, found_layer, found_top = piece, layer, top
    return None if found is None else (found, found_layer)


def _near_layer(height: np.ndarray, top: float) -> np.ndarray:
    """Whether each height over the support's plane lies within two layer thicknesses over a layer ``top`` high (an
    object's foot, or the ground's stones joined to it)."""
    return height <= 3 * top


def lifted(means: np.ndarray, at_click: np.ndarray, layer: np.ndarray, top: float) -> np.ndarray | None:
    """Return the click's weights ``[N]`` with those of its Gaussians in the support's ``layer`` ``[N]`` bool moved
    to their nearest Gaussian over the layer, if one lies within its thickness ``top``, or None when most of the
    weight finds none.

    A click on a person's boot, a hand's width over the ground, points at Gaussians that a layer thick enough to
    leave out the ground's stones holds too: their weight goes to the boot just over the layer. A click on the
    ground itself, at the plane, has nothing within the layer's thickness over the layer."""
    inside = np.flatnonzero((at_click > 0) & layer)
    if not len(inside):
        return at_click
    total = float(at_click[at_click > 0].sum())
    lo, hi = means[inside].min(axis=0) - top, means[inside].max(axis=0) + top
    over = np.flatnonzero(~layer & np.all((means >= lo) & (means <= hi), axis=1))
    anchor = np.where(layer, 0.0, np.maximum(at_click, 0.0))
    if len(over):
        dist, near = cKDTree(means[over]).query(means[inside], distance_upper_bound=top)
        found = np.isfinite(dist)
        np.add.at(anchor, over[near[found]], at_click[inside[found]])
    if anchor.sum() <= 0.5 * total:
        return None
    return anchor


def _shaved_ground(height: np.ndarray, piece: np.ndarray, top: float, thicker: np.ndarray, thicker_top: float
                   ) -> bool:
    """Whether the piece over the layer ``thicker_top`` high, ``thicker`` ``[N]`` bool, lost the ground's stones
    that ``piece``, over ``top``, held round its foot (:data:`SHAVE_RATE`): what the step shaved off lay near the
    layer and was many more Gaussians per unit of height than the thicker piece holds."""
    lost = piece & ~thicker
    if not lost.any() or (thicker & ~piece).sum() > 0.1 * thicker.sum():
        return False  # the same piece, or another one
    if _near_layer(height[lost], thicker_top).mean() < 0.8:
        return False  # a part of the object came off, not its foot's ground
    extent = float(np.percentile(height[thicker], 99)) - thicker_top
    rate = lost.sum() / (thicker_top - top)
    return extent > 0 and rate > SHAVE_RATE * thicker.sum() / extent
