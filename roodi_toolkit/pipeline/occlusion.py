"""Occlusion reasoning (paper, Sec. 3.3): which parts of four object-centred views of the object are hidden by the scene.

Four cameras look at the object's centre from random directions around it on the upper hemisphere (w.r.t. the
scene's up axis), close enough that the object fills the frame. The object-only model and the full-scene model are
rendered from each; a pixel is *occluded* where the object has alpha and the scene's expected depth is nearer than the
object's by more than a tolerance (Eq. 5 of the paper, ``d_scene < d_object``). The occluded set is smoothed with a
17x17 morphological opening (kornia), which drops specks that reconstruction noise produces, and the inpainting mask
is the occluded set plus the background (object alpha low), so that the inpainter can also redraw the object's
outline and fill holes where the object was never seen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional, Sequence

import kornia
import numpy as np
import torch
from scipy.ndimage import binary_dilation, binary_erosion
from torch import Tensor

from ..cameras import Camera, horizontal_basis, intrinsics_from_fov, look_at
from ..errors import CloudError, ConfigError
from ..gaussians import GaussianCloud
from ..params import GaussianParams
from ..render.pictures import probability_grid
from ..render.renderer import Renderer, resolve_renderer
from ..settings import check_settings, documented, setting


@documented
@dataclass(frozen=True)
class OcclusionConfig:
    """Settings of occlusion reasoning. Sources: paper (4 views, 17x17 opening, background in the mask), ours (rest)."""

    # paper: 4, tiled 2x2 for the inpainter
    num_views: int = setting(4, "Object-centred views.", low=1, cli=False)
    # 512 gives SD-XL's 1024x1024 grid; a 2x2 grid of 4096 px views (8192 px a side) is more than any inpainter here
    # takes
    size: int = setting(256, "Side in pixels of the four object-centred views that are inpainted.", low=8, high=4096,
                        option="--view-size")
    fov_deg: float = setting(50.0, "Field of view of the views in degrees.", low=1, high=150, cli=False)
    margin: float = setting(1.05, "Camera distance over the distance at which the object's bounding sphere just "
                            "fills the view.", low=0, low_open=True, cli=False)
    elevation_deg: tuple[float, float] = setting((10.0, 60.0), "Range of the camera elevations above the horizon in "
                                                 "degrees (the upper hemisphere w.r.t. the scene's up).", cli=False)
    # expected depth blends surfaces at edges, and the object's own Gaussians are in the scene too
    depth_tolerance: float = setting(0.05, "The scene must be nearer than the object by this fraction of the "
                                     "object's radius to count as occluding.", low=0, cli=False)
    alpha_threshold: float = setting(0.5, "Object alpha at or above which a pixel shows the object (below: "
                                     "background).", low=0, high=1, low_open=True, high_open=True, cli=False)
    # paper: 17; must be odd (checked below)
    opening_size: int = setting(17, "Side of the square structuring element of the opening; odd.", low=1, cli=False)
    # a 17x17 opening at 512 px (a view of the 1024x1024 SD-XL grid) is 3x3 at 96 px
    opening_reference: int = setting(512, "View size the opening size refers to: the element is scaled by "
                                     "size / reference (0: never scaled).", low=0, cli=False)
    seed: int = setting(0, "Seed of the camera directions.", low=0, cli=False)

    def __post_init__(self) -> None:
        check_settings(self)
        lo, hi = self.elevation_deg
        if not -90.0 <= lo <= hi <= 90.0:
            raise ConfigError(f"elevation_deg must be lo,hi with -90 <= lo <= hi <= 90, got {lo}, {hi}")
        if self.opening_size % 2 == 0:
            raise ConfigError(f"opening_size must be odd, got {self.opening_size}")

    @property
    def effective_opening(self) -> int:
        """The odd side of the opening actually used at ``size``."""
        if not self.opening_reference:
            return self.opening_size
        k = max(1, round(self.opening_size * self.size / self.opening_reference))
        return k if k % 2 else k + 1


@dataclass
class OcclusionResult:
    """Renders and masks of the object-centred views.

    Attributes:
        cameras: the views.
        object_rgb: the object alone on the background colour. [V, H, W, 3]
        object_alpha: [V, H, W]
        object_depth: expected depth, 0 where nothing. [V, H, W]
        scene_rgb: the full scene. [V, H, W, 3]
        scene_depth: [V, H, W]
        occluded_raw: object present and scene nearer, before the opening. [V, H, W] bool
        occluded: after the opening. [V, H, W] bool
        mask: what the inpainter fills: ``occluded | object_alpha < alpha_threshold``. [V, H, W] bool
        centre: the object's centre. [3]
        radius: the object's radius.
    """

    cameras: list[Camera] = field(repr=False)
    object_rgb: Tensor = field(repr=False)
    object_alpha: Tensor = field(repr=False)
    object_depth: Tensor = field(repr=False)
    scene_rgb: Tensor = field(repr=False)
    scene_depth: Tensor = field(repr=False)
    occluded_raw: Tensor = field(repr=False)
    occluded: Tensor = field(repr=False)
    mask: Tensor = field(repr=False)
    centre: np.ndarray = field(repr=False)
    radius: float = 0.0


def object_extent(cloud: GaussianCloud, quantile: float = 0.98) -> tuple[np.ndarray, float]:
    """Return the centre ``[3]`` and radius of a Gaussian object, robust to a few stray Gaussians.

    The centre is the middle of the per-axis ``1 - quantile`` .. ``quantile`` range of the means; the radius is the
    ``quantile`` of the distances from it, plus three times the median Gaussian scale (their own extent).

    Example:
        >>> c = GaussianCloud.from_activated(np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]]) + 5,
        ...     scales=np.full((4, 3), 1e-4), opacities=np.full(4, 0.9), rgb=np.zeros((4, 3)))
        >>> centre, radius = object_extent(c, quantile=1.0)
        >>> centre.tolist(), round(radius, 3)
        ([5.0, 5.0, 5.0], 1.0)
    """
    if len(cloud) == 0:
        raise CloudError("the object model has no Gaussians; nothing to reason about")
    means = cloud.means.astype(np.float64)
    lo = np.quantile(means, 1 - quantile, axis=0)
    hi = np.quantile(means, quantile, axis=0)
    centre = (lo + hi) / 2
    dist = np.linalg.norm(means - centre, axis=1)
    radius = float(np.quantile(dist, quantile)) + 3.0 * float(np.median(cloud.scales.max(axis=1)))
    return centre, max(radius, 1e-6)


def up_from_cameras(cameras: Sequence[Camera]) -> np.ndarray:
    """Return the scene's up axis ``[3]`` estimated as the mean of the cameras' up directions (-y in OpenCV axes).

    Example:
        >>> cam = Camera(look_at([0, -3, 1], [0, 0, 0]), intrinsics_from_fov(1.0, 8, 8), 8, 8)
        >>> np.round(up_from_cameras([cam]), 2).tolist()
        [0.0, 0.32, 0.95]
    """
    ups = np.stack([-c.world_to_camera[1, :3] for c in cameras])
    up = ups.mean(axis=0)
    n = np.linalg.norm(up)
    if n < 1e-6:
        raise ConfigError("cannot estimate the up axis: the cameras' up directions cancel out; pass up explicitly")
    return up / n


def object_cameras(centre: Sequence[float], radius: float, config: OcclusionConfig = OcclusionConfig(), *,
                   up: Sequence[float] = (0.0, 0.0, 1.0)) -> list[Camera]:
    """Return ``config.num_views`` seeded cameras around the object looking at its centre, the object filling the frame.

    Azimuths are stratified (one random direction per equal sector, so the views surround the object); elevations
    are uniform in ``config.elevation_deg`` above the plane perpendicular to ``up``. The distance puts the bounding
    sphere of ``radius`` just inside the field of view, times ``config.margin``.

    Example:
        >>> cams = object_cameras([0, 0, 0], 1.0, OcclusionConfig(size=32))
        >>> len(cams), all(c.center[2] > 0 for c in cams)
        (4, True)
    """
    up_v, e1, e2 = horizontal_basis(up)
    rng = np.random.default_rng(config.seed)
    n = config.num_views
    fov = math.radians(config.fov_deg)
    dist = radius / math.sin(fov / 2) * config.margin
    K = intrinsics_from_fov(fov, config.size, config.size)
    offset = rng.uniform(0, 2 * math.pi)
    lo, hi = (math.sin(math.radians(e)) for e in config.elevation_deg)
    centre = np.asarray(centre, dtype=np.float64)
    cams = []
    for k in range(n):
        az = offset + 2 * math.pi * (k + rng.uniform(0.15, 0.85)) / n
        s = rng.uniform(lo, hi)  # uniform in sin(elevation): uniform over the band's area
        c = math.sqrt(max(0.0, 1 - s * s))
        d = c * (math.cos(az) * e1 + math.sin(az) * e2) + s * up_v
        eye = centre + dist * d
        cams.append(Camera(look_at(eye, centre, up_v), K, config.size, config.size,
                           near=max(1e-3, 0.01 * radius), far=1e4, name=f"view_{k}"))
    return cams


def morphological_opening(masks: Tensor, size: int) -> Tensor:
    """Return boolean masks ``[V, H, W]`` opened (eroded, then dilated) with a ``size`` x ``size`` square (kornia).

    Outside the image counts as unmasked for the erosion (kornia's geodesic border), so regions touching the border
    are not eroded from the border side.

    Example:
        >>> m = torch.zeros(1, 12, 12, dtype=torch.bool)
        >>> m[0, 2:9, 2:9] = True  # a 7x7 block survives a 5x5 opening
        >>> m[0, 10, 10] = True  # a speck does not
        >>> out = morphological_opening(m, 5)
        >>> int(out.sum()), bool(out[0, 10, 10])
        (49, False)
    """
    if size <= 1:
        return masks.clone()
    kernel = torch.ones(size, size)
    opened = kornia.morphology.opening(masks.float()[:, None], kernel)
    return opened[:, 0] > 0.5


def _render_stack(cloud: GaussianCloud, cameras: Sequence[Camera], background: Tensor, renderer: Renderer):
    params = GaussianParams.from_cloud(cloud)
    rgb, alpha, depth = [], [], []
    with torch.no_grad():
        for cam in cameras:
            out = renderer.render(params, cam, background=background)
            rgb.append(out.rgb.clamp(0, 1))
            alpha.append(out.alpha[..., 0])
            depth.append(out.depth[..., 0])
    return torch.stack(rgb), torch.stack(alpha), torch.stack(depth)


def occlusion_masks(object_cloud: GaussianCloud, scene_cloud: GaussianCloud, cameras: Sequence[Camera] | None = None,
                    config: OcclusionConfig = OcclusionConfig(), *, up: Sequence[float] = (0.0, 0.0, 1.0),
                    background: Sequence[float] = (1.0, 1.0, 1.0), renderer: Renderer | None = None,
                    frame: Optional[GaussianCloud] = None) -> OcclusionResult:
    """Return the object-centred renders and the occlusion / inpainting masks of an object in its scene.

    Args:
        object_cloud: the object's Gaussians alone.
        scene_cloud: the whole scene's Gaussians (the object's included).
        cameras: the views (default :func:`object_cameras` around the object).
        config: settings.
        up: the scene's up axis (for the default cameras).
        background: RGB behind the renders.
        renderer: draws the object and the scene (default: the built-in CPU renderer).
        frame: the Gaussians whose extent the views frame and whose bounding sphere the result holds (default
            ``object_cloud``; the refinement passes the object with its 3D completion, so that a part no training
            view saw is in the views too).
    """
    centre, radius = object_extent(object_cloud if frame is None else frame)
    if cameras is None:
        cameras = object_cameras(centre, radius, config, up=up)
    cameras = list(cameras)
    bg = torch.as_tensor(background, dtype=torch.float32)
    renderer = resolve_renderer(renderer)
    o_rgb, o_alpha, o_depth = _render_stack(object_cloud, cameras, bg, renderer)
    s_rgb, _, s_depth = _render_stack(scene_cloud, cameras, bg, renderer)
    present = o_alpha >= config.alpha_threshold
    scene_d = torch.where(s_depth > 0, s_depth, torch.full_like(s_depth, float("inf")))
    occluded_raw = present & (scene_d < o_depth - config.depth_tolerance * radius)
    occluded = morphological_opening(occluded_raw, config.effective_opening)
    mask = occluded | ~present
    return OcclusionResult(cameras, o_rgb, o_alpha, o_depth, s_rgb, s_depth, occluded_raw, occluded, mask,
                           centre, radius)


def mask_scores(predicted: Tensor | np.ndarray, truth: Tensor | np.ndarray) -> dict[str, float]:
    """Return precision, recall and IoU of a predicted boolean mask against the truth (NaN where undefined).

    Example:
        >>> mask_scores(np.array([1, 1, 0, 0], bool), np.array([1, 0, 1, 0], bool))
        {'precision': 0.5, 'recall': 0.5, 'iou': 0.3333333333333333, 'predicted': 2, 'true': 2}
    """
    p = np.asarray(predicted, dtype=bool)
    t = np.asarray(truth, dtype=bool)
    tp = int((p & t).sum())
    n_p, n_t, union = int(p.sum()), int(t.sum()), int((p | t).sum())
    nan = float("nan")
    return {"precision": tp / n_p if n_p else nan, "recall": tp / n_t if n_t else nan,
            "iou": tp / union if union else nan, "predicted": n_p, "true": n_t}


def outline(mask: np.ndarray | Tensor, width: int = 1) -> np.ndarray:
    """Return the pixels ``[H, W]`` (bool) on the inside edge of ``mask``, ``width`` pixels thick.

    Example:
        >>> m = np.zeros((5, 5), bool)
        >>> m[1:4, 1:4] = True
        >>> int(outline(m).sum())  # the 3x3 square's 8 border pixels
        8
    """
    m = np.asarray(mask, dtype=bool)
    return m & ~binary_erosion(m, iterations=max(1, width), border_value=0)


def outlined(image: np.ndarray | Tensor, regions: Sequence[tuple[np.ndarray | Tensor, Sequence[float]]], *,
             width: int = 1, tint: float = 0.25) -> np.ndarray:
    """Return ``image`` ``[H, W, 3]`` with each ``(mask [H, W], RGB)`` region tinted by ``tint`` and outlined.

    Example:
        >>> img = np.ones((6, 6, 3), np.float32)
        >>> m = np.zeros((6, 6), bool)
        >>> m[2:5, 2:5] = True
        >>> out = outlined(img, [(m, (1.0, 0.0, 0.0))])
        >>> out[2, 2].tolist(), out[0, 0].tolist()
        ([1.0, 0.0, 0.0], [1.0, 1.0, 1.0])
    """
    out = np.array(image, dtype=np.float32, copy=True)
    for mask, colour in regions:
        m = np.asarray(mask, dtype=bool)
        c = np.asarray(colour, dtype=np.float32)
        out[m] = (1 - tint) * out[m] + tint * c
        out[outline(m, width)] = c
    return out


#: outline colours of the fill pictures: what the fill changed (red) and what the scene hides (yellow)
FILLED_COLOUR = (1.0, 0.1, 0.1)
OCCLUDED_COLOUR = (1.0, 0.85, 0.0)


def fill_picture(before: Tensor, after: Tensor, filled: Tensor, occluded: Optional[Tensor] = None, *,
                 gap: int = 2, middle: Optional[Tensor] = None) -> np.ndarray:
    """Return a picture of views before (top row) and after (bottom row) the fill with the filled region outlined.

    Args:
        before: the object's renders before the fill. [V, H, W, 3]
        after: the same views after it (the inpainted views or the refined object's renders). [V, H, W, 3]
        filled: the region the fill added, outlined in red in both rows. [V, H, W] bool
        occluded: the region the scene hides, outlined in yellow (optional). [V, H, W] bool
        gap: white pixels between tiles.
        middle: a row drawn between the two, outlined alike (optional; e.g. the Gaussians a 3D completion added,
            alone). [V, H, W, 3]

    The regions are tinted in the top row and only outlined below it. Views smaller than 128 pixels are enlarged by
    a whole factor first.
    """
    # small views are enlarged (nearest neighbour) so that one-pixel outlines do not cover them
    scale = max(1, 128 // max(1, int(before.shape[1])))
    if scale > 1:
        before, after, filled = (t.repeat_interleave(scale, 1).repeat_interleave(scale, 2) for t in (before, after, filled))
        occluded = None if occluded is None else occluded.repeat_interleave(scale, 1).repeat_interleave(scale, 2)
        middle = None if middle is None else middle.repeat_interleave(scale, 1).repeat_interleave(scale, 2)
    rows = []
    for r, views in enumerate((before, after) if middle is None else (before, middle, after)):
        row = []
        for k in range(len(views)):
            regions = [(filled[k], FILLED_COLOUR)]
            if occluded is not None:
                regions.append((occluded[k], OCCLUDED_COLOUR))
            # tinted in the top row only: below, the fill's own colours are what the picture is for
            row.append(outlined(np.asarray(views[k]), regions, width=max(1, views.shape[1] // 128),
                                tint=0.25 if r == 0 else 0.0))
        rows.append(row)
    return probability_grid(rows, gap=gap)


def hidden_part_picture(whole: GaussianCloud, completion: GaussianCloud, occ: OcclusionResult, after: Tensor,
                        renderer: Renderer, background: Sequence[float], *, alpha_threshold: float = 0.5) -> np.ndarray:
    """Return the hidden part before and after in the refinement's views (:func:`fill_picture` with three rows): the
    object as selected (top), the Gaussians a 3D completion added, alone (middle), and the refined object (bottom);
    outlined in red, the pixels the object with its completion covers and the object alone did not (the part no
    training view saw), in yellow what the scene hides.

    Args:
        whole: the object with its completion, before fine-tuning.
        completion: the Gaussians the completion added.
        occ: the occlusion reasoning of the views (the object's renders before the completion).
        after: the refined object in the views. [V, H, W, 3]
        renderer: draws the views.
        background: RGB behind them.
        alpha_threshold: a pixel is covered at or above this alpha.
    """
    bg = torch.as_tensor(background, dtype=torch.float32)
    added, both = GaussianParams.from_cloud(completion), GaussianParams.from_cloud(whole)
    rgb, hidden = [], []
    with torch.no_grad():
        for k, cam in enumerate(occ.cameras):
            rgb.append(renderer.render(added, cam, background=bg).rgb.clamp(0, 1))
            covered = renderer.render(both, cam).alpha[..., 0] >= alpha_threshold
            hidden.append(covered & (occ.object_alpha[k] < alpha_threshold))
    return fill_picture(occ.object_rgb, after, torch.stack(hidden), occ.occluded, middle=torch.stack(rgb))


def seen_empty(points: np.ndarray, cameras: Sequence[Camera], object_masks: Tensor | np.ndarray,
               depths: Tensor | np.ndarray, tolerance: float, *, margin: int = 1) -> np.ndarray:
    """Return which points ``[N, 3]`` some view sees as empty space (bool ``[N]``): the point projects into the view
    more than ``margin`` pixels away from the object's mask there, and the view's surface at that pixel is farther
    than the point by more than ``tolerance`` (or there is none), so the view looks through where the point is.

    Args:
        points: world points. [N, 3]
        cameras: the views.
        object_masks: True on the object in each view. [V, H, W]
        depths: the scene's depth along each view's optical axis, 0 where nothing. [V, H, W]
        tolerance: depth slack (world units).
        margin: pixels around the object's mask that never count as empty (its outline is uncertain).

    Example:
        >>> cam = Camera(look_at([0, -3, 0], [0, 0, 0]), intrinsics_from_fov(1.0, 16, 16), 16, 16)
        >>> masks = np.zeros((1, 16, 16), bool)
        >>> masks[0, 6:10, 6:10] = True
        >>> depths = np.full((1, 16, 16), 5.0)  # a wall 2 behind the object's centre
        >>> seen_empty(np.array([[0.0, 0, 0], [0.8, 0, 0], [1.5, 3.0, 0]]), [cam], masks, depths, 0.1).tolist()
        [False, True, False]
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    masks = np.asarray(object_masks, dtype=bool)
    depths = np.asarray(depths, dtype=np.float64)
    empty = np.zeros(len(pts), dtype=bool)
    for k, cam in enumerate(cameras):
        uv, z = cam.project(pts)
        with np.errstate(invalid="ignore"):
            j, i = np.floor(uv[:, 0]), np.floor(uv[:, 1])
        ok = (z > 0) & (j >= 0) & (j < cam.width) & (i >= 0) & (i < cam.height)
        idx = np.flatnonzero(ok)
        ii, jj = i[idx].astype(int), j[idx].astype(int)
        near_object = binary_dilation(masks[k], iterations=margin) if margin > 0 else masks[k]
        d = depths[k][ii, jj]
        through = ~near_object[ii, jj] & ((d <= 0) | (d > z[idx] + tolerance))
        empty[idx[through]] = True
    return empty


def seen_through(points: np.ndarray, cameras: Sequence[Camera], object_masks: Tensor | np.ndarray,
                 scene: GaussianCloud | GaussianParams, tolerance: float, *, renderer: Renderer | None = None,
                 margin: int = 1, bins: int = 32, max_alpha: float = 0.5) -> np.ndarray:
    """Return which points ``[N, 3]`` some view sees through (bool ``[N]``): the point projects into the view more
    than ``margin`` pixels away from the object's mask there, and the scene's Gaussians in front of it (up to
    ``tolerance`` behind it) stop less than ``max_alpha`` of that pixel's light.

    :func:`seen_empty` compares the point with the view's expected depth, which blends every surface along the
    ray: behind a thin, half-transparent wall (a sleeve round a bottle, 8 mm thick, a few pixels wide) the blend
    lies beyond the wall, so the space the wall hides counts as seen through. Here each view is rendered once with
    the scene's Gaussians binned by their depth along the view (``bins`` bins over the points' depth range, the
    Gaussians nearer or farther in a bin of their own), composited as feature channels with the renderer's own
    weights, so that the alpha accumulated in front of every point is known to a bin; the whole bin holding the
    point's depth plus ``tolerance`` counts as in front (the safe side: less is seen through).

    Args:
        points: world points. [N, 3]
        cameras: the training views.
        object_masks: True on the object in each view. [V, H, W]
        scene: the whole scene's Gaussians (a cloud, or parameters to render as they are).
        tolerance: depth slack (world units).
        renderer: draws the views (default: the built-in CPU renderer).
        margin: pixels round the object's mask that never count as seen through (its outline is uncertain).
        bins: depth bins between the nearest and farthest point (each view).
        max_alpha: a view sees through a point when less than this much alpha lies in front of it.

    Example:
        >>> cam = Camera(look_at([0, -3, 0], [0, 0, 0]), intrinsics_from_fov(1.0, 16, 16), 16, 16)
        >>> masks = np.zeros((1, 16, 16), bool)
        >>> wall = GaussianCloud.from_activated(np.array([[0.0, -1.0, 0.0]]), scales=np.array([[2.0, 0.01, 2.0]]),
        ...                                     opacities=np.array([0.7]), rgb=np.zeros((1, 3)))
        >>> seen_through(np.array([[0.0, 0.0, 0.0], [0.0, -1.5, 0.0]]), [cam], masks, wall, 0.05).tolist()
        [False, True]
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    masks = np.asarray(object_masks, dtype=bool)
    through = np.zeros(len(pts), dtype=bool)
    if len(pts) == 0:
        return through
    renderer = resolve_renderer(renderer)
    params = GaussianParams.from_cloud(scene) if isinstance(scene, GaussianCloud) else scene
    means = params.means.detach().double().numpy()
    for k, cam in enumerate(cameras):
        uv, z = cam.project(pts)
        with np.errstate(invalid="ignore"):
            j, i = np.floor(uv[:, 0]), np.floor(uv[:, 1])
        ok = (z > 0) & (j >= 0) & (j < cam.width) & (i >= 0) & (i < cam.height) & ~through
        idx = np.flatnonzero(ok)
        if len(idx) == 0:
            continue
        ii, jj = i[idx].astype(int), j[idx].astype(int)
        near_object = binary_dilation(masks[k], iterations=margin) if margin > 0 else masks[k]
        free = ~near_object[ii, jj]
        idx, ii, jj = idx[free], ii[free], jj[free]
        if len(idx) == 0:
            continue
        reach = z[idx] + tolerance  # [M] how far each point's ray must get
        edges = np.linspace(reach.min(), reach.max(), bins + 1) if reach.max() > reach.min() \
            else np.array([reach.min(), reach.min() + max(tolerance, 1e-9)])
        zg = means @ cam.world_to_camera[2, :3] + cam.world_to_camera[2, 3]  # [G] camera depth of each Gaussian
        # bin 0: nearer than the nearest point's reach; bin b: up to edges[b]; the last: beyond the farthest
        labels = np.searchsorted(edges, zg, side="left")
        onehot = torch.zeros(len(zg), len(edges) + 1, dtype=params.means.dtype)
        onehot[torch.arange(len(zg)), torch.from_numpy(labels)] = 1.0
        with torch.no_grad():
            out = renderer.render(params.with_features(onehot), cam)
        cum = torch.cumsum(out.features, dim=-1).numpy()  # [H, W, B + 2] alpha accumulated up to each bin
        # the bin holding each point's reach, counted whole
        b = np.searchsorted(edges, reach, side="left")
        through[idx[cum[ii, jj, b] < max_alpha]] = True
    return through

