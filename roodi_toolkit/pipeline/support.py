"""The surface an object stands on, and the object completed down to it where no training view saw it.

A part hidden on every side (a bottle's lower half in a sleeve, a pot in a box, a ball in a bowl) has no seen mirror
image (:mod:`roodi_toolkit.pipeline.symmetry`). Objects stand on something, so :func:`support_height` finds the floor
or table top under the object among the scene's Gaussians around it, and :func:`shell_to_support` builds a closed
wall of new, opaque Gaussians from the object's lowest seen band straight down to it: the band's outline round its
centre, tiled with flat Gaussians at least a training-view pixel apart (:func:`pixel_size`), kept inside the scene's
other Gaussians round the hidden part (:func:`other_gaussians`: what hides it bounds it). Fine-tuning moves and
recolours Gaussians but makes none, so the hidden part has Gaussians only if a completion adds them. Where the object
is too few pixels wide for a wall, copies of its lowest band (:func:`extrude_to_support`) stand in.
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ..cameras import Camera, horizontal_basis
from ..gaussians import SH_C0, GaussianCloud, logit


def _spacing(means: np.ndarray) -> float:
    d, _ = cKDTree(means).query(means, k=2)
    return float(np.median(d[:, 1]))



SUPPORT_RADIUS = 3.0
"""support_height looks for the support among the scene's Gaussians within this many object radii (horizontally)."""
SUPPORT_REACH = 4.0
"""...and at most this many times the seen part's height (or radius, if larger) under its lowest point: a wrap may
hide two thirds of an object or more, so the seen part can be a third of its height (the top leaves of a plant whose
pot a sleeve hides; with twice, 2 of the 48 occluded benchmark targets found a sleeve's rim instead of the floor)."""


def support_height(object_cloud: GaussianCloud, scene_cloud: GaussianCloud, up: Sequence[float], *,
                   bins: int = 64) -> Optional[float]:
    """Return the height (along ``up``) of the surface the object stands on, or None when there is none below it.

    The scene's Gaussians within :data:`SUPPORT_RADIUS` object radii of the object's vertical axis and below its
    lowest point are binned by height; a support (floor, table top) is a dense, level layer, so it is the fullest
    bin's centre. Where the object stands in a wrap, the support right under it was never seen, but the floor around
    the wrap was, at the same height.

    Example:
        >>> rng = np.random.default_rng(0)
        >>> floor = np.c_[rng.uniform(-2, 2, (2000, 2)), rng.normal(0, 0.005, 2000)]
        >>> obj = np.c_[rng.normal(0, 0.1, (300, 2)), rng.uniform(0.6, 1.0, 300)]
        >>> make = lambda p: GaussianCloud.from_activated(p, scales=np.full((len(p), 3), 0.02),
        ...                                             opacities=np.full(len(p), 0.9), rgb=np.full((len(p), 3), 0.5))
        >>> abs(support_height(make(obj), make(np.r_[floor, obj]), [0, 0, 1])) < 0.01
        True
    """
    u, h_obj, lowest, height = _vertical_extent(object_cloud, up)
    obj = object_cloud.means.astype(np.float64)
    scene = scene_cloud.means.astype(np.float64)
    h_scene = scene @ u
    centre = obj.mean(axis=0)
    flat = lambda p: (p - centre) - np.outer((p - centre) @ u, u)  # noqa: E731
    radius = float(np.quantile(np.linalg.norm(flat(obj), axis=1), 0.9))
    # under the object's lowest point by more than 5% of its height: not the object's own lowest Gaussians
    near = ((np.linalg.norm(flat(scene), axis=1) <= SUPPORT_RADIUS * max(radius, 1e-9))
            & (h_scene < lowest - 0.05 * height))
    if near.sum() < 8:
        return None
    below = h_scene[near]
    below = below[below > lowest - SUPPORT_REACH * max(height, radius)]  # a support, not the bottom of the world
    if len(below) < 8:
        return None
    counts, edges = np.histogram(below, bins=bins)
    k = int(np.argmax(counts))
    return float(0.5 * (edges[k] + edges[k + 1]))


def extrude_to_support(cloud: GaussianCloud, up: Sequence[float], support: float, *, band: float = 0.1,
                       step: Optional[float] = None, reach: float = 2.0, mean_colour: bool = True,
                       cap_scales: bool = True) -> GaussianCloud:
    """Return copies of the object's lowest band carried straight down to the support (an empty cloud if none).

    A part that every training view had hidden (a bottle in a sleeve, a pot in a box) most often continues the
    lowest part that was seen: the Gaussians within ``band`` of the object's height above its lowest point (a slab)
    are copied downwards every ``step`` (default: the slab's thickness, so that the copies tile the gap at the
    object's own density) until they reach ``support``. Callers drop the
    copies a training view sees through (``FillContext.seen_empty``): where a view saw empty space under the
    object, the object does not go on.

    What is below the band was never seen, so the copies are the safest guess rather than the band repeated:

    - the object ends at the surface it stands on: a copy whose Gaussian reaches through it (``reach`` standard
      deviations along ``up``) is dropped;
    - ``mean_colour``: the copies take the band's opacity-weighted mean base colour (no view-dependent bands).
      Under squared error the mean is the best single guess of a colour that was never seen; repeating each band
      Gaussian repeats its blotches and highlights down the whole hidden part;
    - ``cap_scales``: no axis of a copy is longer than the median of the object's Gaussians' largest axes, so that
      one large band Gaussian does not spread its copies beyond the band's outline.

    Measured on the occluded presets before fine-tuning (the selected object with its copies against the true
    object-alone test views, box PSNR, 16 targets per seed, ``benchmarks/bench_extrusion.py``): seeds 0 / 1, the
    band repeated as it is 14.75 / 14.19 dB, with the three rules 15.35 / 14.67 dB; full ROODI after fine-tuning
    14.76 / 14.25 -> 15.48 / 14.71 dB (``benchmarks/RESULTS.md``, "Occluded scenes").
    """
    u, h, lowest, height = _vertical_extent(cloud, up)
    means = cloud.means.astype(np.float64)
    gap = lowest - float(support)
    layer = np.flatnonzero(h <= lowest + band * height)
    if gap <= 0 or height <= 0 or len(layer) == 0:
        return cloud.select(np.zeros(len(cloud), dtype=bool))
    step = max(band * height, _spacing(means)) if step is None else float(step)
    count = int(np.ceil(gap / max(step, 1e-9)))
    if count > 200:  # a support far below (or a tiny spacing): step so that at most 200 copies are made
        step, count = gap / 200.0, 200
    source = cloud.select(layer)
    if cap_scales:
        cap = np.median(np.asarray(cloud.log_scales, np.float64).max(axis=1))
        source = source.with_fields(log_scales=np.minimum(source.log_scales, cap).astype(source.log_scales.dtype))
    if mean_colour:
        w = source.opacities.astype(np.float64)
        w = w / w.sum() if w.sum() > 0 else np.full(len(source), 1.0 / len(source))
        dc = np.tensordot(w, source.sh_dc.astype(np.float64), axes=1)
        source = source.with_fields(sh_dc=np.broadcast_to(dc, source.sh_dc.shape).astype(source.sh_dc.dtype).copy(),
                                    sh_rest=np.zeros_like(source.sh_rest))
    # every copy of a band Gaussian has its standard deviation along up, sqrt(u^T Sigma u): computed once
    spread = np.sqrt(np.maximum(np.einsum("i,nij,j->n", u, source.covariances().astype(np.float64), u), 0.0))
    copies = []
    for k in range(1, count + 1):
        c = source.copy()
        c.means = (c.means.astype(np.float64) - k * step * u).astype(c.means.dtype)
        copies.append(c.select(c.means.astype(np.float64) @ u - reach * spread >= float(support)))
    return GaussianCloud.concatenate(copies)


def _circular_fill(values: np.ndarray) -> np.ndarray:
    """Return ``values`` ``[K, ...]`` of K sectors round a circle with the NaN sectors linearly interpolated
    between their nearest filled neighbours on either side (all NaN stays all NaN)."""
    k = len(values)
    flat = values.reshape(k, -1)
    ok = ~np.isnan(flat[:, 0])
    if ok.all() or not ok.any():
        return values.copy()
    idx = np.flatnonzero(ok)
    pos = np.concatenate([idx - k, idx, idx + k])  # the filled sectors, repeated once either side of the circle
    out = np.stack([np.interp(np.arange(k), pos, np.tile(flat[idx, c], 3)) for c in range(flat.shape[1])], axis=1)
    return out.reshape(values.shape)


def _ring_centre(xy: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Return the centre ``[2]`` of the circle best fitting points ``[N, 2]`` (weighted algebraic fit: unlike their
    centroid, it does not move towards where the points are denser), or their centroid when the fit is degenerate
    or lands outside their extent."""
    centroid = (weights[:, None] * xy).sum(0) / weights.sum()
    sw = np.sqrt(weights)[:, None]
    a = np.c_[2 * xy, np.ones(len(xy))] * sw
    b = (xy ** 2).sum(1)[:, None] * sw
    sol, _, rank, _ = np.linalg.lstsq(a, b, rcond=None)
    centre = sol[:2, 0]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    if rank < 3 or not np.all((centre >= lo) & (centre <= hi)):
        return centroid
    return centre


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][min(int(np.searchsorted(cum, 0.5 * cum[-1])), len(order) - 1)])


MIN_BAND = 6
"""shell_to_support takes at least this many of the object's lowest Gaussians as its band."""


def _sectors(xy: np.ndarray, centre: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Return the sector of each point ``[M, 2]`` among ``k`` equal angles round ``centre`` ``[M]``, and its distance
    from the centre ``[M]``."""
    edges = 2 * np.pi / k
    d = xy - centre
    return np.floor((np.arctan2(d[:, 1], d[:, 0]) % (2 * np.pi)) / edges).astype(int) % k, np.linalg.norm(d, axis=1)


def _outline_radii(sector: np.ndarray, distance: np.ndarray, weights: np.ndarray, k: int) -> np.ndarray:
    """Return the outline's distance from the centre in each of ``k`` sectors ``[k]``: the weighted median of its
    points', sectors without any interpolated from their neighbours, a little smoothed round the outline."""
    radius = np.full(k, np.nan)
    for s in range(k):
        in_s = sector == s
        if in_s.any():
            radius[s] = _weighted_median(distance[in_s], weights[in_s])
    radius = _circular_fill(radius)
    return (np.roll(radius, 1) + 2 * radius + np.roll(radius, -1)) / 4


def _sector_colours(rgb: np.ndarray, weights: np.ndarray, sector: np.ndarray, k: int) -> np.ndarray:
    """Return each sector's colour ``[k, 3]``: the weighted median colour of its points (``rgb`` ``[M, 3]``), shrunk
    towards the median of all of them where a sector has few points."""
    overall = np.array([_weighted_median(rgb[:, c], weights) for c in range(3)])
    colours = np.tile(overall, (k, 1))
    for s in range(k):
        in_s = sector == s
        if in_s.any():
            own = np.array([_weighted_median(rgb[in_s, c], weights[in_s]) for c in range(3)])
            t = in_s.sum() / (in_s.sum() + 4.0)
            colours[s] = t * own + (1 - t) * overall
    return colours


def _wall_orientations(ring: np.ndarray, radial: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the quaternion ``[A, 4]`` wxyz of a Gaussian lying in the wall at each point of the ``ring`` ``[A, 3]``
    (its frame: along the outline, up, across it) and the wall's normal there ``[A, 3]`` (across the outline,
    outwards like ``radial``)."""
    tangent = np.roll(ring, -1, axis=0) - np.roll(ring, 1, axis=0)
    tangent -= np.outer(tangent @ u, u)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    normal = np.cross(tangent, u)
    normal *= np.sign(np.sum(normal * radial, axis=1, keepdims=True) + 1e-12)
    tangent = np.cross(u, normal)  # right-handed frame (tangent, up, normal)
    frames = np.stack([tangent, np.broadcast_to(u, tangent.shape), normal], axis=2)  # [A, 3, 3], columns
    xyzw = Rotation.from_matrix(frames).as_quat()
    return np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1), normal


def shell_to_support(cloud: GaussianCloud, up: Sequence[float], support: float, *, band: float = 0.1,
                     colour_band: float = 0.5, sectors: Optional[int] = None, around: int = 40,
                     opacity: float = 0.9, overlap: float = 0.7, thickness: float = 0.2,
                     max_rows: int = 200, min_spacing: float = 0.0, min_around: int = 3,
                     obstacles: Optional[np.ndarray] = None) -> GaussianCloud:
    """Return a closed wall of new Gaussians from the object's lowest seen band straight down to the support (an
    empty cloud if there is no gap).

    What a wrap hid below the lowest part that was seen most often continues that part (a bottle's body under its
    shoulders, a pot's wall, a box's sides). The band (the Gaussians within ``band`` of the object's height above its
    lowest point, at least its :data:`MIN_BAND` lowest) gives the cross-section: round its centre, in ``sectors`` equal angles (default: one per four band
    Gaussians, 6 to 48), the opacity-weighted median distance of the band's Gaussians from the centre, sectors
    without any interpolated from their neighbours. The wall is that outline carried down to ``support`` and tiled
    with flat Gaussians, ``around`` of them round the outline and rows as far apart as they are wide, each lying in
    the wall (``thickness`` of its spacing across it), ``overlap`` of its spacing wide along it so that neighbours
    overlap and the wall renders opaque, with ``opacity`` and no view-dependent colour. Its colour per sector is the
    opacity-weighted median base colour of the Gaussians within ``colour_band`` of the height above the lowest point
    (thicker than the band: the lowest Gaussians blend with the gap and the wrap), pulled towards the median of all
    sectors where a sector holds few Gaussians.

    Unlike copies of the band Gaussians (:func:`extrude_to_support`), which keep the trained model's sparse,
    semi-transparent layout, the wall has no gaps. Callers drop what a training view sees through
    (``FillContext.seen_empty``), as for every completion.

    Args:
        cloud: the object (after the mirror, if one was added). Its columns are kept: the new Gaussians are
            made from its Gaussians (extra columns copied from the nearest band Gaussian).
        up: the scene's up axis. [3]
        support: the height along ``up`` of the surface the object stands on.
        min_spacing: the Gaussians are at least this far apart, fewer than ``around`` where the outline is short
            (the refinement passes a training-view pixel: a splat much smaller than a pixel is widened to about half
            a pixel, so many tiny opaque ones render a wall wider than its outline).
        min_around: no wall (an empty cloud) when fewer than this many Gaussians at ``min_spacing`` go round the
            outline: the object is too few pixels wide in the views for a wall to be drawn.
        obstacles: positions ``[M, 3]`` of the scene's other Gaussians: the wall stays inside what lies round
            the hidden part (:func:`_inside_obstacles`; a ball in a bowl is narrower near the floor).
    """
    u, h, lowest, height = _vertical_extent(cloud, up)
    gap = lowest - float(support)
    layer = np.flatnonzero(h <= lowest + band * height)
    if len(layer) < MIN_BAND:  # a small object (a few pixels in the views): its lowest Gaussians, whatever the band
        layer = np.argsort(h, kind="stable")[:MIN_BAND]
    if gap <= 0 or height <= 0 or len(layer) < 3:
        return cloud.select(np.zeros(len(cloud), dtype=bool))
    _, e1, e2 = horizontal_basis(u)
    means = cloud.means.astype(np.float64)
    w_all = np.maximum(cloud.opacities.astype(np.float64), 1e-3)
    xy = np.stack([means @ e1, means @ e2], axis=1)  # [N, 2]
    w = w_all[layer]
    centre = _ring_centre(xy[layer], w)
    k = int(np.clip(len(layer) // 4, 6, 48)) if sectors is None else int(sectors)
    edges = 2 * np.pi / k
    radius = _outline_radii(*_sectors(xy[layer], centre, k), w, k)
    # colour: the thicker slab, per sector, shrunk towards the median of all of it where a sector has few Gaussians
    slab = np.flatnonzero(h <= lowest + colour_band * height)
    colours = _sector_colours(np.clip(cloud.rgb[slab].astype(np.float64), 0, 1), w_all[slab],
                              _sectors(xy[slab], centre, k)[0], k)
    # the samples: ``around`` angles, rows evenly from just under the band down to the support
    perimeter = float(np.sum(np.hypot(radius * edges, np.diff(np.r_[radius, radius[:1]]))))
    around = int(min(around, np.floor(perimeter / max(min_spacing, 1e-12))))
    if around < max(3, min_around):
        return cloud.select(np.zeros(len(cloud), dtype=bool))
    spacing = perimeter / around
    rows = int(min(max_rows, max(1, np.ceil(gap / max(spacing, 1e-9)))))
    step = gap / rows
    theta = (np.arange(around) + 0.5) * 2 * np.pi / around
    pos = theta / edges - 0.5  # sector-centre coordinates: linear interpolation of the radius round the circle
    i0 = np.floor(pos).astype(int)
    f = pos - i0
    r_at = (1 - f) * radius[i0 % k] + f * radius[(i0 + 1) % k]
    c_at = (1 - f[:, None]) * colours[i0 % k] + f[:, None] * colours[(i0 + 1) % k]
    radial = np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2  # [A, 3]
    ring = (centre[0] * e1 + centre[1] * e2) + r_at[:, None] * radial  # [A, 3] at height 0
    heights = float(support) + (np.arange(rows) + 0.5) * step  # [R]
    r_rows = np.tile(r_at, (rows, 1))  # [R, A]
    if obstacles is not None and len(obstacles):
        r_rows = _inside_obstacles(r_rows, np.asarray(obstacles, np.float64), centre, e1, e2, u, float(support),
                                   step, lowest, 0.5 * min(spacing, step))
    keep = r_rows.ravel() > 0
    centre3 = centre[0] * e1 + centre[1] * e2
    pts = (centre3 + r_rows[..., None] * radial[None] + heights[:, None, None] * u).reshape(-1, 3)  # [R * A, 3]
    wxyz, normal = _wall_orientations(ring, radial, u)
    quats = np.tile(wxyz, (rows, 1))
    along = max(spacing, 1e-9)
    scales = np.tile([overlap * along, overlap * step, thickness * min(along, step)], (len(pts), 1))
    # each new Gaussian takes its columns (SH degree, extras) from the nearest band Gaussian
    _, nearest = cKDTree(xy[layer] - centre).query((ring - (centre[0] * e1 + centre[1] * e2)) @ np.stack([e1, e2], 1))
    out = cloud.select(np.tile(layer[nearest], rows))
    colour = np.tile(c_at, (rows, 1))
    out = out.with_fields(
        means=pts.astype(out.means.dtype), quats_wxyz=quats.astype(out.quats_wxyz.dtype),
        log_scales=np.log(np.maximum(scales, 1e-12)).astype(out.log_scales.dtype),
        opacity_logits=np.full(len(pts), logit(opacity), dtype=out.opacity_logits.dtype),
        sh_dc=((colour - 0.5) / SH_C0).astype(out.sh_dc.dtype), sh_rest=np.zeros_like(out.sh_rest),
        normals=None if out.normals is None else np.tile(normal, (rows, 1)).astype(out.normals.dtype))
    return out.select(keep)


def _inside_obstacles(r_rows: np.ndarray, obstacles: np.ndarray, centre: np.ndarray, e1: np.ndarray,
                      e2: np.ndarray, u: np.ndarray, support: float, step: float, lowest: float,
                      clearance: float) -> np.ndarray:
    """Return the wall's radii ``[R, A]`` (rows from the support up, angles round the centre) pulled in to
    ``clearance`` inside the nearest obstacle Gaussian of their row and angle (and the neighbouring ones); 0 where
    that would leave less than a third of the radius (the sample is dropped).

    Obstacles are the scene's other Gaussians: below the object's lowest seen point and above the support's
    layer, what lies round the hidden part is what hides it (a sleeve, a bowl), and the object is inside it.
    Only obstacles between half the wall's radius and the wall count: one nearer the axis is under the object
    (the floor, a stand), not round it.
    """
    rows, around = r_rows.shape
    h = obstacles @ u
    d = obstacles - np.outer(h, u)
    x, y = d @ e1 - centre[0], d @ e2 - centre[1]
    rho = np.hypot(x, y)
    j = np.floor((h - support) / step).astype(int)
    i = np.floor((np.arctan2(y, x) % (2 * np.pi)) / (2 * np.pi / around)).astype(int) % around
    ok = (h > support + step) & (h < lowest) & (j >= 0) & (j < rows)
    near = np.full((rows, around), np.inf)
    ok &= rho >= 0.5 * r_rows[np.clip(j, 0, rows - 1), i]
    np.minimum.at(near, (j[ok], i[ok]), rho[ok])
    # the nearest obstacle of each sample's row and angle and their neighbours (angles wrap round)
    spread = near.copy()
    for dj in (-1, 0, 1):
        for di in (-1, 0, 1):
            shifted = np.roll(near, di, axis=1)
            if dj:
                shifted = np.roll(shifted, dj, axis=0)
                shifted[0 if dj > 0 else -1] = np.inf
            spread = np.minimum(spread, shifted)
    clamped = np.minimum(r_rows, spread - clearance)
    return np.where(clamped >= r_rows / 3, clamped, 0.0)


def _vertical_extent(cloud: GaussianCloud, up: Sequence[float]) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Return the unit up axis, the heights of the cloud's centres along it, its lowest point (the 2% quantile:
    a stray Gaussian is not the bottom) and its height above that point; :func:`support_height` and
    :func:`extrude_to_support` measure the object alike."""
    u = np.asarray(up, np.float64)
    u = u / np.linalg.norm(u)
    h = cloud.means.astype(np.float64) @ u
    lowest = float(np.quantile(h, 0.02))
    return u, h, lowest, float(h.max() - lowest)


def other_gaussians(scene_cloud: GaussianCloud, object_cloud: GaussianCloud, *,
                    min_opacity: float = 0.3) -> np.ndarray:
    """Return the centres ``[M, 3]`` of the scene's Gaussians of at least ``min_opacity`` that are not the object's
    (the object was selected from the scene: its Gaussians are the scene's at the same places)."""
    means = scene_cloud.means.astype(np.float64)
    keep = scene_cloud.opacities >= min_opacity
    if len(object_cloud):
        d, _ = cKDTree(object_cloud.means.astype(np.float64)).query(means, distance_upper_bound=1e-6)
        keep &= ~np.isfinite(d)
    return means[keep]


def pixel_size(cameras: Sequence[Camera], point: Sequence[float]) -> Optional[float]:
    """Return the median over ``cameras`` of the width in world units of one pixel at ``point`` (its depth over the
    focal length), or None when no camera has it in front.

    Example:
        >>> import math
        >>> from roodi_toolkit.cameras import intrinsics_from_fov, look_at
        >>> cam = Camera(look_at([0, -2, 0], [0, 0, 0]), intrinsics_from_fov(math.radians(90), 100, 100), 100, 100)
        >>> round(pixel_size([cam], [0, 0, 0]), 3)  # 2 from the camera, a 90 degree view 100 pixels wide
        0.04
    """
    widths = []
    for cam in cameras:
        _, z = cam.project(np.asarray(point, dtype=np.float64)[None])
        if z[0] > 0:
            widths.append(float(z[0]) / float(cam.K[0, 0]))
    return float(np.median(widths)) if widths else None
