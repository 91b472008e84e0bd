"""Pixel regions of the click segmenter's clicked view (:mod:`roodi_toolkit.pipeline.click`): a depth flood fill from
the clicks, OpenCV's GrabCut, hole filling, the components at the clicks and disc dilation, each on ``[H, W]`` masks;
and what the segmenter decides from the points and labels behind them: the support a fill leaked onto
(:func:`support_plane`, :func:`off_support`, with the scene's up, :func:`scene_up`), whether the fill's reach cut the
object (:func:`cut_by_reach`, :func:`level_at`), whether a step of the fill leaked (:func:`fill_leaked`), where the 3D
growth's labels are cut (:func:`label_cut`) and whether a negative click points at a free-standing piece
(:func:`clicked_off`).
"""

from __future__ import annotations

from typing import Any, Sequence

import cv2
import numpy as np
from scipy import ndimage

from ..errors import ConfigError
from ..render.upright import cameras_up


def _grabcut(image: np.ndarray, init: np.ndarray, iterations: int, seed: int) -> np.ndarray:
    """Return the foreground ``[H, W]`` bool of OpenCV GrabCut started from ``init`` (cv2.GC_* labels).

    Falls back to the probable/sure foreground of ``init`` when GrabCut cannot model one of the two sides (it needs
    pixels of both).
    """
    fg = (init == cv2.GC_FGD) | (init == cv2.GC_PR_FGD)
    if fg.all() or not fg.any():
        return fg
    img8 = (np.clip(image, 0, 1) * 255 + 0.5).astype(np.uint8)[..., ::-1].copy()  # OpenCV wants BGR
    mask = init.astype(np.uint8).copy()
    bgd = np.zeros((1, 65), np.float64)
    fgd = np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(seed)
    try:
        cv2.grabCut(img8, mask, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    except cv2.error:
        return fg
    return (mask == cv2.GC_FGD) | (mask == cv2.GC_PR_FGD)


def _depth_flood_fill(depth: np.ndarray, allowed: np.ndarray, seeds: Sequence[tuple[int, int]],
                      tolerance: float) -> np.ndarray:
    """Return the pixels reached from ``seeds`` (row, col) through 4-neighbours whose depths differ by less than
    ``tolerance`` relative, within ``allowed``."""
    logd = np.log(np.where(allowed, np.maximum(depth, 1e-12), 1.0)).astype(np.float32)
    H, W = depth.shape
    region = np.zeros((H, W), bool)
    for r, c in seeds:
        if region[r, c] or not allowed[r, c]:
            continue
        block = np.ones((H + 2, W + 2), np.uint8)
        block[1:-1, 1:-1] = ~allowed  # floodFill does not enter non-zero mask pixels
        diff = float(np.log1p(tolerance))
        cv2.floodFill(logd.copy(), block, (int(c), int(r)), 0.0, diff, diff,
                      4 | cv2.FLOODFILL_MASK_ONLY | (2 << 8))
        region |= (block[1:-1, 1:-1] == 2)
    return region


LEAK_MIN_GAUSSIANS = 4
"""The fill's leak check applies once its region shows at least this many Gaussians (distinct depths) ..."""
LEAK_MIN_SHARE = 0.001
"""... and holds at least this share of the image's pixels (160 at 400 x 400)."""


def fill_leaked(region: np.ndarray, grown: np.ndarray, depth: np.ndarray, min_pixels: int, ratio: float) -> bool:
    """Whether the next step of a depth fill, ``grown`` ``[H, W]`` from ``region`` ``[H, W]``, has leaked: it
    multiplies the area by more than ``ratio``, from a region of at least ``min_pixels`` and
    :data:`LEAK_MIN_SHARE` of the image that shows at least :data:`LEAK_MIN_GAUSSIANS` Gaussians.

    ``depth`` is each pixel's largest-weight Gaussian's depth, constant over its footprint: a click on a trained
    splat's surface seen at an angle (a man's black leather: flat ellipses a few hundredths of a unit across, steps
    of 1-1.5% of the depth between them) fills the clicked Gaussian's footprint alone at the smallest tolerances, a
    plateau of one depth that the next step leaves for the whole surface (23 pixels, then 8,696). That is not a leak:
    a surface is the footprints of several Gaussians. Nor is the step from a strip along a steep edge onto the surface
    behind it (a click at the edge of the man's back: 79 pixels, then 6,649): a region under 0.1% of the image is
    too small to tell a leak from the object's own surface (the price: an object that small, 13 x 13 pixels at the
    working size of 400 x 400, fills on over what it touches)."""
    n = int(region.sum())
    if n < max(min_pixels, LEAK_MIN_SHARE * region.size) or grown.sum() <= ratio * n:
        return False
    return len(np.unique(depth[region])) >= LEAK_MIN_GAUSSIANS


def click_sides(depth: np.ndarray, area: np.ndarray, seeds: Sequence[tuple[int, int]],
                not_seeds: Sequence[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """Return the pixels of ``area`` ``[H, W]`` nearer the clicks ``seeds`` and nearer the negative clicks
    ``not_seeds`` (two ``[H, W]`` masks, the watershed line in neither): a watershed from the clicks (OpenCV's: it
    floods in the order of the largest channel step between neighbouring pixels) over the surface's orientation
    and depth, the two slopes of the log depth as a normal's x and y and the log depth itself, each in 8 bits. A
    crease (an object's foot on the ground, two look-alikes that touch) turns the orientation, an occluding edge
    steps the depth, so the floods meet there; the depth fills' own measure, the depth step alone, does not tell a
    crease from a smooth surface."""
    logd = np.log(np.maximum(depth, 1e-12)).astype(np.float32)
    lo, hi = float(logd[area].min()), float(logd[area].max())
    smooth = cv2.GaussianBlur(np.where(area, logd, np.float32(np.median(logd[area]))), (0, 0), 1.0)
    gy, gx = np.gradient(smooth)
    scale = float(max(depth.shape))  # slopes per pixel, as seen by a focal length of the image's size
    norm = np.sqrt(1.0 + (scale * gx) ** 2 + (scale * gy) ** 2)
    channels = [(-scale * gx / norm + 1.0) * 127.5, (-scale * gy / norm + 1.0) * 127.5,
                (logd - lo) / max(hi - lo, 1e-12) * 255.0]
    image = cv2.merge([np.clip(np.round(np.where(area, c, 0.0)), 0, 255).astype(np.uint8) for c in channels])
    markers = np.full(depth.shape, -1, np.int32)  # -1: a barrier the flood does not cross
    markers[area] = 0
    for (r, c), side in [(rc, 2) for rc in not_seeds] + [(rc, 1) for rc in seeds]:
        markers[r, c] = side
    cv2.watershed(image, markers)
    return markers == 1, markers == 2


def _fill_holes(mask: np.ndarray) -> np.ndarray:
    return ndimage.binary_fill_holes(mask)


def _component_at(mask: np.ndarray, seeds: Sequence[tuple[int, int]]) -> np.ndarray:
    """Return the union of the 8-connected components of ``mask`` that contain a seed ``(row, col)``."""
    labels, _ = ndimage.label(mask, structure=np.ones((3, 3), bool))
    ids = {int(labels[r, c]) for r, c in seeds if labels[r, c] > 0}
    return np.isin(labels, list(ids)) if ids else np.zeros_like(mask)


def _disk(radius: int) -> np.ndarray:
    r = max(int(radius), 0)
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    return (x * x + y * y) <= r * r


def _dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    return ndimage.binary_dilation(mask, structure=_disk(radius)) if radius > 0 else mask.copy()


SUPPORT_SHARE = 0.3
"""A plane holding at least this share of the clicked region's points can be the support its fill leaked onto ..."""
SUPPORT_AT_LIMIT = 0.5
"""... when it also holds at least this share of the region's points where the fill met its 3D reach (a leak runs
on along the support until the reach stops it; an object's own flat face ends at its edges first) ..."""
SUPPORT_TOLERANCE = 0.02
"""... its points being those within this fraction of the region's 3D radius of it ..."""
SUPPORT_CLEARANCE = 3.0
"""... and the clicks at least this many tolerances off it (a click on the plane itself asks for the support)."""
SUPPORT_LEVEL = 0.9
"""Without a fill that met its reach, a plane is the support when the scene's up is known and it is level (its
normal within acos(0.9), 26 degrees, of up), the clicks lie above it by :data:`SUPPORT_CLEARANCE` tolerances ..."""
SUPPORT_SPREAD = 0.5
"""... and it holds at least this share of the region's points within twice the tolerance (the fill ran over the
ground round the object more than over the object: a level face of the object itself, a chair's seat under a click
on its back, holds less of a region that stopped at the object's edges) ..."""
SUPPORT_BELOW = 0.05
"""... unless at most this share of the region lies under it: what stands on a support is above it (a person on the
ground, clicked on a leg, makes a region of legs and some ground; a chair's legs are under its seat)."""


def support_plane(points: np.ndarray, clicks: np.ndarray, at_limit: np.ndarray, up: np.ndarray | None = None,
                  seed: int = 0, hypotheses: int = 256,
                  sample: int = 4096) -> tuple[np.ndarray, np.ndarray, np.ndarray, float] | None:
    """Return the surface the clicked region's fill leaked onto, as (its points ``[P]`` bool, a point on the plane
    ``[3]``, its unit normal ``[3]``, its tolerance), or None.

    A depth fill from a click on an object resting on a table, the ground or a shelf runs from the object onto its
    support where they meet (the depth is continuous along the contact), and on over the support until the 3D reach
    stops it. As in tabletop segmentation (a dominant plane, then what stands on it), a RANSAC plane is fitted to the
    region's points ``[P, 3]``: it is the support when it holds :data:`SUPPORT_SHARE` of them and
    :data:`SUPPORT_AT_LIMIT` of those where the fill met its reach (``at_limit`` ``[P]`` bool), and the clicks
    ``[C, 3]`` lie :data:`SUPPORT_CLEARANCE` tolerances off it. A fill need not meet its reach to have leaked: from a
    click at a donut's side it runs over the ground in front of it to the ground's own edge. So with the scene's up
    ``[3]`` known (the cameras' mean up) a level plane that the clicks stand above, holding :data:`SUPPORT_SPREAD`
    of the region, or with at most :data:`SUPPORT_BELOW` of the region under it, is the support too
    (:data:`SUPPORT_LEVEL`).
    """
    if len(points) < 3 or not (at_limit.any() or up is not None):
        return None
    pts = np.asarray(points, np.float64)
    tol = SUPPORT_TOLERANCE * float(np.linalg.norm(pts - pts.mean(axis=0), axis=1).max())
    if not tol > 0:
        return None
    rng = np.random.default_rng(seed)
    probe = pts[rng.choice(len(pts), min(sample, len(pts)), replace=False)]
    triples = pts[rng.integers(0, len(pts), (hypotheses, 3))]  # [K, 3, 3]
    normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    length = np.linalg.norm(normals, axis=1)
    keep = length > 1e-12
    if not keep.any():
        return None
    normals = normals[keep] / length[keep, None]
    offsets = np.einsum("kj,kj->k", normals, triples[keep, 0])
    support = (np.abs(probe @ normals.T - offsets) < tol).sum(axis=0)  # [K] inliers among the probe points
    best = int(np.argmax(support))
    on = np.abs(pts @ normals[best] - offsets[best]) < tol
    if on.sum() < 3:
        return None
    # refit on the inliers (least squares: the smallest principal direction), then take its points again
    inl = pts[on]
    mid = inl.mean(axis=0)
    normal = np.linalg.svd(inl - mid, full_matrices=False)[2][-1]
    height = (pts - mid) @ normal
    on = np.abs(height) < tol
    clicks_height = (np.asarray(clicks, np.float64) - mid) @ normal
    if on.mean() < SUPPORT_SHARE or np.abs(clicks_height).min() < SUPPORT_CLEARANCE * tol:
        return None
    if at_limit.any() and on[at_limit].mean() >= SUPPORT_AT_LIMIT:
        return on, mid, normal, tol
    if up is None or abs(float(normal @ up)) < SUPPORT_LEVEL:
        return None
    sign = np.sign(float(normal @ up))
    if (clicks_height * sign).min() < SUPPORT_CLEARANCE * tol:  # the clicks must stand above it
        return None
    if (np.abs(height) < 2 * tol).mean() < SUPPORT_SPREAD and (height * sign < -tol).mean() > SUPPORT_BELOW:
        return None
    return on, mid, normal, tol


def off_support(cam0: Any, depth0: np.ndarray, region: np.ndarray, beyond: np.ndarray,
                seeds: Sequence[tuple[int, int]], up: np.ndarray | None = None,
                surface: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Return ``region`` ``[H, W]`` without the support its fill leaked onto (:func:`support_plane`: the table or
    ground under the clicked object, up to the fill's 3D reach, ``beyond`` ``[H, W]`` being the pixels past it, or
    level under the clicks when the scene's ``up`` ``[3]`` is known), kept where it joins the clicks (``region``
    itself when it did not leak), and the pixels of ``surface`` ``[H, W]`` (default: the region) on that plane."""
    rc = np.argwhere(region)
    clicks = cam0.backproject(np.array(seeds), depth0[tuple(np.array(seeds).T)])
    plane = support_plane(cam0.backproject(rc, depth0[region]), clicks, _dilate(beyond, 1)[region], up)
    surface = region if surface is None else surface
    if plane is None:
        return region, np.zeros_like(region)
    on, mid, normal, tol = plane
    off = region.copy()
    off[tuple(rc[on].T)] = False
    kept = _component_at(off, seeds)
    flat = np.zeros_like(region)
    at = np.argwhere(surface & (depth0 > 0))
    flat[tuple(at.T)] = np.abs((cam0.backproject(at, depth0[tuple(at.T)]) - mid) @ normal) < tol
    return (kept if kept.any() else region), flat


REACH_CUT = 0.1
"""A fill was cut by its reach when at least this many of its pixels per pixel of its region's square root (its
width) border the pixels past the reach on one surface with them."""


def cut_by_reach(depth: np.ndarray, region: np.ndarray, beyond: np.ndarray, tolerance: float) -> bool:
    """Whether the clicked ``region`` ``[H, W]`` goes on past the fill's 3D reach: :data:`REACH_CUT` of its width
    in pixels have a 4-neighbour in ``beyond`` ``[H, W]`` (valid pixels past the reach, off the support) whose depth
    differs by less than ``tolerance`` (relative), the fill's largest: the reach, not an edge, stopped it there."""
    if not region.any():
        return False
    logd = np.log(np.maximum(depth, 1e-12))
    step = np.log1p(tolerance)
    cut = np.zeros_like(region)
    for axis in (0, 1):
        for shift in (1, -1):
            other = np.roll(beyond, shift, axis) & (np.abs(logd - np.roll(logd, shift, axis)) < step)
            edge = np.ones_like(region)  # np.roll wraps round: the image's first/last row or column has no neighbour
            index = [slice(None)] * 2
            index[axis] = 0 if shift == 1 else -1
            edge[tuple(index)] = False
            cut |= region & other & edge
    return bool(cut.sum() >= REACH_CUT * np.sqrt(region.sum()))


def level_at(cam0: Any, depth: np.ndarray, valid: np.ndarray, rc: tuple[int, int], up: np.ndarray | None,
             radius: int = 3) -> bool:
    """Whether the surface at pixel ``rc`` (row, col) is level: the plane through its neighbours' points (the
    ``2 radius + 1`` square's valid pixels of ``depth`` ``[H, W]``) has its normal within :data:`SUPPORT_LEVEL` of
    ``up``; a click on the ground or a table top, not on what stands on it."""
    if up is None:
        return False
    r, c = rc
    patch = np.argwhere(valid[max(r - radius, 0):r + radius + 1, max(c - radius, 0):c + radius + 1])
    if len(patch) < 6:
        return False
    patch += [max(r - radius, 0), max(c - radius, 0)]
    pts = cam0.backproject(patch, depth[tuple(patch.T)])
    normal = np.linalg.svd(pts - pts.mean(axis=0), full_matrices=False)[2][-1]
    return abs(float(normal @ up)) >= SUPPORT_LEVEL


LABEL_CUT_MIN = 0.15
"""The growth's labels are never cut below this (the rest's own labels reach 0.1 next to the object)."""
LABEL_REST = 0.05
"""A label under this is the rest's, set apart from the object ..."""
LABEL_REST_SHARE = 0.55
"""... and the labels are cut below ``threshold`` only when this share of those under LABEL_CUT_MIN are under it: the
rest is set apart from the object (the donut on dark ground: 93-96%; a man standing on the ground, where the ground
round his boots falls off over 0.05-0.15: 66%); where it is not (the statue on white paper, a sparse model whose
labels spread over 0-0.5 across the whole scene: 44%), a lower cut would take the paper and the floor."""


def label_cut(labels: np.ndarray, threshold: float) -> float:
    """Return the label above which a grown Gaussian is selected: Otsu's split of ``labels`` ``[n]`` (those within
    the growth's reach, the ones above ``threshold`` taken as ``threshold``) into two groups, at least
    :data:`LABEL_CUT_MIN` and at most ``threshold``, where the rest sits near 0 (:data:`LABEL_REST_SHARE`); else
    ``threshold``.

    The growth holds the seeds of the rest, the Gaussians past its reach and a pull towards the nearest seed colour
    at 0, so its labels are not balanced around 0.5: on the donut resting on the playbot's ground, clicked where only
    its icing shows, the ground near it comes out below 0.05 and the donut's unseen tan underside at 0.2-0.5,
    joined to the icing across a colour edge (benchmarks/RESULTS.md, "A click anywhere on a resting object")."""
    if len(labels) < 2 or not threshold > LABEL_CUT_MIN:
        return threshold
    # labels above the threshold are selected anyway: as one level, they do not pull the split up into the object
    levels = np.round(np.clip(labels / threshold, 0.0, 1.0) * 255.0).astype(np.uint8).reshape(-1, 1)
    otsu, _ = cv2.threshold(levels, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    cut = min(threshold, max(LABEL_CUT_MIN, (float(otsu) + 0.5) / 255.0 * threshold))
    below = labels[labels < LABEL_CUT_MIN]
    if not len(below) or (below < LABEL_REST).mean() < LABEL_REST_SHARE:
        return threshold  # the rest does not sit near 0: labels fall off smoothly into colours like the object's
    return cut


def scene_up(dataset: Any) -> np.ndarray | None:
    """The dataset's up direction ``[3]`` (its cameras' mean up: photographers hold cameras upright), or None when
    the cameras share none."""
    try:
        return cameras_up(dataset.cameras)
    except ConfigError:
        return None


NEGATIVE_SHARE = 0.1
"""A free-standing piece holding more than this share of the compositing weight under the negative clicks is no
free-standing object (:func:`clicked_off`): the user says a part of it is not the object, so the growth from the
seeds decides. A negative click on the ground under a floating object leaves the object free-standing."""


def clicked_off(piece: np.ndarray, at_not: np.ndarray) -> bool:
    """Whether the free-standing ``piece`` ``[N]`` bool holds more than :data:`NEGATIVE_SHARE` of the compositing
    weight under the negative clicks ``at_not`` ``[N]``: the user said a part of it is not the object."""
    return bool(at_not[piece].sum() > NEGATIVE_SHARE * at_not.sum())
