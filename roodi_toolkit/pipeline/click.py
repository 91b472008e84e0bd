"""The ``click`` segmenter: clicks in one view -> the clicked object's Gaussians -> masks of every view.

See :class:`ClickSegmenter` for the method; the interface it implements is :mod:`roodi_toolkit.pipeline.segment`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Optional, Sequence

import numpy as np
import torch

from ..cameras import Camera
from ..errors import ConfigError
from ..gaussians import GaussianCloud
from ..io.dataset import Dataset
from ..params import GaussianParams
from ..progress import ProgressFactory, null_progress
from ..render import fast
from ..render.renderer import Renderer, resolve_renderer
from .segment import SegmentationError, Segmenter, SegmentPrompt, ViewMasks, check_clicks


# ------------------------------------------------------------------------------------------------------ click


def _grabcut(image: np.ndarray, init: np.ndarray, iterations: int, seed: int) -> np.ndarray:
    """Return the foreground ``[H, W]`` bool of OpenCV GrabCut started from ``init`` (cv2.GC_* labels).

    Falls back to the probable/sure foreground of ``init`` when GrabCut cannot model one of the two sides (it needs
    pixels of both).
    """
    import cv2

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
    import cv2

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


def _fill_holes(mask: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    return ndimage.binary_fill_holes(mask)


def _component_at(mask: np.ndarray, seeds: Sequence[tuple[int, int]]) -> np.ndarray:
    """Return the union of the 8-connected components of ``mask`` that contain a seed ``(row, col)``."""
    from scipy import ndimage

    labels, _ = ndimage.label(mask, structure=np.ones((3, 3), bool))
    ids = {int(labels[r, c]) for r, c in seeds if labels[r, c] > 0}
    return np.isin(labels, list(ids)) if ids else np.zeros_like(mask)


SCENE_REGION_RADIUS = 0.15
"""``region_radius`` for datasets without sparse points (their box holds the whole scene)."""
CAPTURE_REGION_RADIUS = 0.5
"""``region_radius`` for captures with SfM points (their box is what SfM reconstructed)."""


@dataclass(frozen=True)
class ClickSettings:
    """Parameters of the ``click`` segmenter (ours; chosen on the generated benchmark scenes, see RESULTS.md).

    Attributes:
        depth_tolerance_min: in the clicked view, neighbouring pixels belong to the same surface when their depths
            (of each pixel's largest-weight Gaussian) differ by less than a tolerance, as a fraction of the depth (the
            clicked region's flood fill); the tolerance starts at this value ...
        depth_tolerance_max: ... and is multiplied by ``depth_tolerance_step`` up to at most this value ...
        depth_tolerance_step: ... per step,
        leak_ratio: stopping before the step that multiplies the region's area by more than this (a leak through a
            contact onto the ground or a neighbouring object) ...
        leak_min_pixels: ... once the region has at least this many pixels.
        region_radius: the clicked region stays within this fraction of the scene box diagonal of the click's 3D
            point (keeps the flood fill from running along the ground). None: 0.15 for a dataset without sparse
            points, whose box holds the whole scene (a generated room; chosen there), and 0.5 for a capture with
            SfM points, whose box is that of what SfM reconstructed, in an object-centred capture mostly the object
            itself (the statue: 0.15 stops the fill on the crown's band, alpha IoU 0.08; 0.5 and 1.0 give the same
            0.72, the leak check stopping the fill first).
        min_alpha: pixels with rendered alpha below this have no usable depth, and a click there is refused.
        grabcut_iterations: GrabCut iterations on the clicked view's region.
        grabcut_min_keep: GrabCut refines the depth fill's region; when it keeps less than this fraction of it (a
            small, flat-coloured or reflective object whose colours it cannot tell from the background's), the depth
            fill's region is used as it is.
        seed_fraction: a Gaussian seeds the object (or the rest) when at least this fraction of its compositing
            weight in the clicked view falls inside the clicked region (or inside the band around it).
        min_weight: Gaussians whose summed compositing weight in the clicked view is below this are no seeds.
        grow_radius: only Gaussians whose centres lie within this multiple of the clicked region's 3D radius (around
            its centre) can join the object; those beyond are fixed to the rest (so the ground is not followed).
        neighbours: each Gaussian is linked to this many nearest Gaussians (by centre) in the 3D growth graph.
        colour_sigma: link strength falls as ``exp(-dist2 / (2 colour_sigma^2))`` of the two Gaussians' DC colours
            (RGB 0..1), so growth stops at colour edges.
        colour_weight: strength of each unseeded Gaussian's pull towards the label of the nearest seed colour,
            relative to one link.
        threshold: a pixel is in a view's mask when more than this fraction of its rendered alpha comes from the
            selected Gaussians; a Gaussian is selected when its smoothed label exceeds it.
        vote_rounds: rounds of the multi-view vote: each Gaussian is re-selected when more than ``threshold`` of its
            compositing weight over all views falls inside the masks, and the masks are rendered again.
    """

    depth_tolerance_min: float = 0.004
    depth_tolerance_max: float = 0.03
    depth_tolerance_step: float = 1.25
    leak_ratio: float = 2.0
    leak_min_pixels: int = 20
    region_radius: Optional[float] = None
    min_alpha: float = 0.5
    grabcut_iterations: int = 5
    grabcut_min_keep: float = 0.5
    seed_fraction: float = 0.5
    min_weight: float = 1.0
    grow_radius: float = 1.2
    neighbours: int = 10
    colour_sigma: float = 0.1
    colour_weight: float = 0.1
    threshold: float = 0.5
    vote_rounds: int = 2


def _weight_sums(renderer: Renderer, params: GaussianParams, camera: Camera,
                 images: np.ndarray) -> tuple[np.ndarray, Any]:
    """Return, per Gaussian, the sum over the view's pixels of its compositing weight times each image ``[N, K]``,
    and the rendering.

    This is the gradient of ``sum(features_image * images)`` with respect to per-Gaussian features, so any
    differentiable renderer gives it, at the cost of one rendering and one backward pass, without listing the
    (pixel, Gaussian) weights (gigabytes for a real scene at 1000 px).

    Args:
        renderer: draws the features.
        params: the scene's Gaussians (no gradients).
        camera: the view.
        images: the per-pixel factors. [H, W, K]
    """
    feats = torch.zeros(len(params), images.shape[-1], dtype=params.dtype, requires_grad=True)
    out = renderer.render(params.with_features(feats), camera)
    (out.features * torch.as_tensor(images, dtype=params.dtype)).sum().backward()
    return feats.grad.numpy(), out


class ClickSegmenter(Segmenter):
    """Clicks in one view, grown into a set of the scene's Gaussians and rendered into every view.

    1. Clicked view: the region is a flood fill from the clicks over the depth of each pixel's largest-weight
       Gaussian (sharp at object edges, unlike the blended expected depth), within ``region_radius`` of the click in
       3D. Its tolerance grows from ``depth_tolerance_min`` by ``depth_tolerance_step`` and stops before the step
       where the area jumps by more than ``leak_ratio`` (the fill has leaked through a contact); GrabCut on the image
       then refines it. A negative click's surface (its own fill at the smallest tolerance) is closed to the fill,
       is sure background for GrabCut and joins the band of rest below.
    2. Seeds: a Gaussian whose compositing weight in the clicked view lies mostly inside the region seeds the
       object; one whose weight lies mostly in the band around the region seeds the rest.
    3. 3D growth: the Gaussians within ``grow_radius`` times the region's 3D radius are linked to their
       ``neighbours`` nearest Gaussians, links weakened across colour edges (``colour_sigma``). Each Gaussian's label
       is the smooth solution of this graph (a sparse linear solve, as in random-walker segmentation) with the
       seeds held at 1 and 0, the Gaussians beyond the radius at 0, and a weak pull of the others towards the label
       of the nearest seed colour; labels above ``threshold`` form the selection. This reaches the object's hidden
       back, which no pixel of the clicked view shows.
    4. Masks: in every view a pixel is the object when more than ``threshold`` of its alpha comes from the selected
       Gaussians (occlusion is the full scene's compositing). ``vote_rounds`` times, the selection is re-estimated as
       the Gaussians whose weight over all views falls mostly inside the masks, and the masks are rendered again.

    Every per-Gaussian sum of weights over pixels is one rendering of features and its backward pass (the gradient
    of the feature image times the pixel factors), so the cost of a view is that of a rendering and the memory does
    not grow with the number of (pixel, Gaussian) pairs; the masks are made at the dataset's resolution (pass a
    downscaled dataset for a cheaper, coarser segmentation). The clicked view's largest-weight Gaussian per pixel
    comes from the built-in compiled kernels.

    Args:
        renderer: renders the feature images and their gradients (an instance, a registered name, or None for the
            default).
        seed: OpenCV's random seed (GrabCut's GMM initialisation).
        **settings: fields of :class:`ClickSettings`.
    """

    name = "click"
    needs_scene = True

    def __init__(self, renderer: Renderer | str | None = None, seed: int = 0, **settings: Any) -> None:
        self.renderer = resolve_renderer(renderer)
        self.seed = seed
        types = {f.name: float if f.default is None else type(f.default) for f in fields(ClickSettings)}
        for key, value in settings.items():  # options from the command line arrive as text
            if key in types and isinstance(value, str):
                try:
                    settings[key] = types[key](value)
                except ValueError:
                    raise ConfigError(f"click segmenter option {key}={value!r}: expected a "
                                      f"{types[key].__name__}") from None
        try:
            self.settings = ClickSettings(**settings)
        except TypeError as exc:
            raise ConfigError(f"click segmenter: {exc}") from None

    @classmethod
    def available(cls) -> tuple[bool, str]:
        try:
            import cv2  # noqa: F401
        except ImportError:
            return False, "OpenCV is missing: pip install opencv-python-headless"
        return True, ""

    def segment(self, dataset: Dataset, prompt: SegmentPrompt, *, scene: Optional[GaussianCloud] = None,
                progress: ProgressFactory = null_progress) -> ViewMasks:
        """Return binary masks (1 = the clicked object) of every view.

        Raises:
            ConfigError: no scene, bad clicks, or a click on empty space (no rendered depth there).
            SegmentationError: the click selected nothing (the clicked view's mask came out empty).
        """
        if scene is None:
            raise ConfigError("the click segmenter needs the trained scene (its depth) to propagate the clicks")
        s = self.settings
        v0 = check_clicks(dataset, prompt.clicks)
        H, W = dataset.height, dataset.width
        names = dataset.names
        params = GaussianParams.from_cloud(scene, sh_degree=0)
        cam0 = dataset.cameras[v0]
        seeds = [(min(int(c.y), H - 1), min(int(c.x), W - 1)) for c in prompt.clicks if c.positive]
        not_seeds = [(min(int(c.y), H - 1), min(int(c.x), W - 1)) for c in prompt.clicks if not c.positive]
        mask0, band0 = self._clicked_region(dataset, v0, scene, seeds, not_seeds)
        sums, out0 = _weight_sums(self.renderer, params, cam0,
                                  np.stack([mask0, band0, np.ones_like(mask0)], -1).astype(np.float32))
        inside, around, total = sums.T
        seen = total >= s.min_weight
        fg = seen & (inside >= s.seed_fraction * total)
        bg = seen & (around >= s.seed_fraction * total)
        depth0 = out0.depth[..., 0].detach().numpy()
        rc = np.argwhere(mask0 & (depth0 > 0))
        points = cam0.backproject(rc, depth0[mask0 & (depth0 > 0)])
        centre = points.mean(axis=0)
        radius0 = max(float(np.linalg.norm(points - centre, axis=1).max()), 1e-6)
        labels = self._grow(scene, fg, bg, centre, s.grow_radius * radius0)
        selected = labels > s.threshold
        candidates = np.linalg.norm(scene.means - centre, axis=1) <= s.grow_radius * radius0
        info: dict[str, Any] = {"clicked_view": names[v0], "seed_gaussians": int(fg.sum()),
                                "grown_gaussians": int(selected.sum())}
        sel = (selected & candidates).astype(np.float32)
        masks = np.zeros((len(dataset), H, W), np.uint8)
        rounds = max(int(s.vote_rounds), 0)
        with progress(total=len(dataset) * (rounds + 1), desc="render the selection") as bar:
            for r in range(rounds + 1):
                vote = r < rounds
                inw = np.zeros(len(scene))
                tot = np.zeros(len(scene))
                for v in range(len(dataset)):
                    feats = torch.zeros(len(scene), 2, dtype=params.dtype)
                    feats[:, 0] = torch.from_numpy(sel)
                    feats.requires_grad_(vote)
                    with torch.set_grad_enabled(vote):
                        out = self.renderer.render(params.with_features(feats), dataset.cameras[v])
                    alpha = out.alpha[..., 0].detach().numpy()
                    share = out.features[..., 0].detach().numpy()
                    m = (share > s.threshold * np.maximum(alpha, 1e-12)) & (alpha >= 1.0 / 255.0)
                    masks[v] = m
                    if vote:  # per Gaussian: its weight inside the mask (channel 0) and in all (channel 1)
                        grads = torch.from_numpy(np.stack([m, np.ones_like(m)], -1).astype(np.float32))
                        (out.features * grads.to(params.dtype)).sum().backward()
                        inw += feats.grad[:, 0].numpy()
                        tot += feats.grad[:, 1].numpy()
                    bar.update(1)
                if vote:
                    voted = tot >= s.min_weight
                    sel = (np.where(voted, inw > s.threshold * tot, sel > 0) & candidates).astype(np.float32)
        info["selected_gaussians"] = int(sel.sum())
        if not masks[v0].any():
            raise SegmentationError(
                f"the click in {names[v0]} selected no Gaussians of the scene model ({int(fg.sum())} seeds, "
                f"{int(selected.sum())} after growing, none left after the multi-view vote): click nearer the middle "
                "of the object, add a second click, or give masks with the files segmenter")
        return ViewMasks(torch.from_numpy(masks), names, "binary", 2, source=f"click in {names[v0]}", info=info)

    def _clicked_region(self, dataset: Dataset, v0: int, scene: GaussianCloud, seeds: Sequence[tuple[int, int]],
                        not_seeds: Sequence[tuple[int, int]] = ()) -> tuple[np.ndarray, np.ndarray]:
        """Return the clicked view's object region and the rest around it (a band, and the surfaces of the negative
        clicks ``not_seeds``), both ``[H, W]`` bool."""
        import cv2

        s = self.settings
        H, W = dataset.height, dataset.width
        cam0 = dataset.cameras[v0]
        view = fast.make_view(cam0.world_to_camera, cam0.K, W, H, near=cam0.near, far=cam0.far)
        f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
        top, alpha0, z = fast.surface_ids(f32(scene.means), f32(scene.quats_wxyz), f32(scene.log_scales),
                                          f32(scene.opacity_logits), view)
        # the depth of each pixel's largest-weight Gaussian: unlike the expected depth it does not blend across
        # object edges, so a flood fill stops there
        depth0 = np.where(top >= 0, z[np.maximum(top, 0)], 0.0)
        valid0 = (alpha0 >= s.min_alpha) & (depth0 > 0)
        for (r, c), what in [(rc, "click") for rc in seeds] + [(rc, "negative click") for rc in not_seeds]:
            if not valid0[r, c]:
                raise ConfigError(f"the {what} at {c},{r} in {dataset.names[v0]} hits no surface of the scene model "
                                  f"(rendered alpha below {s.min_alpha}); click on "
                                  + ("the object" if what == "click" else "a surface"))
        diag = float(np.linalg.norm(np.asarray(dataset.bounds[1]) - np.asarray(dataset.bounds[0])))
        reach = s.region_radius if s.region_radius is not None else (
            CAPTURE_REGION_RADIUS if dataset.points is not None else SCENE_REGION_RADIUS)
        pts_all = cam0.backproject(np.argwhere(valid0), depth0[valid0])
        near_grid = np.zeros((H, W), bool)
        for r, c in seeds:
            p0 = cam0.backproject(np.array([[r, c]]), depth0[[r], [c]])[0]
            near_grid[valid0] |= np.linalg.norm(pts_all - p0, axis=1) <= reach * diag
        # the fill's tolerance grows step by step and stops before the step where the region suddenly grows
        # several-fold: it has leaked through a contact onto the ground or a neighbour
        region, not_region = self._competing_fill(depth0, valid0 & near_grid, valid0, seeds, not_seeds)
        for r, c in seeds:
            region[r, c] = True
        init = np.full((H, W), cv2.GC_BGD, np.uint8)
        init[_dilate(region, max(2, int(0.1 * math.sqrt(region.sum()))))] = cv2.GC_PR_BGD
        init[region] = cv2.GC_PR_FGD
        init[not_region] = cv2.GC_BGD
        for r, c in seeds:
            init[max(0, r - 1):r + 2, max(0, c - 1):c + 2] = cv2.GC_FGD
        mask0 = _grabcut(dataset.images[v0].numpy(), init, s.grabcut_iterations, self.seed)
        mask0 = _component_at(_fill_holes(mask0) & ~not_region, seeds) & valid0 | (init == cv2.GC_FGD)
        if mask0.sum() < s.grabcut_min_keep * region.sum():
            mask0 = region
        band = _dilate(mask0, max(2, int(round(0.25 * math.sqrt(mask0.sum()))))) & ~mask0 | not_region
        return mask0, band

    def _competing_fill(self, depth: np.ndarray, allowed: np.ndarray, not_allowed: np.ndarray,
                        seeds: Sequence[tuple[int, int]],
                        not_seeds: Sequence[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
        """Return the clicked surface ``[H, W]`` and the negative clicks' surface ``[H, W]`` (empty without them).

        Both are flood fills over ``depth`` whose tolerance grows from ``depth_tolerance_min`` step by step; the
        object's fill stops before the step where its area jumps by more than ``leak_ratio`` (it has leaked through
        a contact). With negative clicks the two fills compete, as seeded region growing does: neither may enter
        what the other holds, and pixels both reach at the same step go to neither, so the rest (the table under
        the object) is claimed at a small tolerance before the object's fill would leak into it.
        """
        s = self.settings
        tol = s.depth_tolerance_min
        none = np.zeros(depth.shape, bool)
        region = _depth_flood_fill(depth, allowed, seeds, tol)
        not_region = _depth_flood_fill(depth, not_allowed & ~region, not_seeds, tol) if not_seeds else none
        leaked = False
        while tol * s.depth_tolerance_step <= s.depth_tolerance_max * (1 + 1e-9):
            tol *= s.depth_tolerance_step
            if not leaked:
                grown = _depth_flood_fill(depth, allowed & ~not_region, seeds, tol)
                leaked = region.sum() >= s.leak_min_pixels and grown.sum() > s.leak_ratio * region.sum()
            elif not not_seeds:
                break
            not_grown = _depth_flood_fill(depth, not_allowed & ~region, not_seeds, tol) if not_seeds else none
            if not leaked:
                both = grown & not_grown
                region = grown & ~both
                not_grown = not_grown & ~both
            not_region = not_grown & ~region
        for r, c in not_seeds:
            not_region[r, c] = True
        return region, not_region

    def _grow(self, scene: GaussianCloud, fg: np.ndarray, bg: np.ndarray, centre: np.ndarray,
              radius: float) -> np.ndarray:
        """Return each Gaussian's object label in 0..1 ``[N]``: the seeds grown through the 3D neighbour graph."""
        from scipy import sparse
        from scipy.spatial import cKDTree
        from scipy.sparse.linalg import spsolve

        s = self.settings
        n = len(scene)
        dist = np.linalg.norm(scene.means - centre, axis=1)
        # the graph holds a shell beyond the radius, held at 0, so the growth feels the rest around the object
        idx = np.flatnonzero(dist <= 1.5 * radius)
        labels = np.zeros(n)
        labels[fg] = 1.0
        if len(idx) < 2:
            return labels
        pos = scene.means[idx]
        rgb = np.clip(scene.rgb[idx], 0, 1)
        k = min(s.neighbours, len(idx) - 1)
        _, nb = cKDTree(pos).query(pos, k=k + 1)
        i = np.repeat(np.arange(len(idx)), k)
        j = nb[:, 1:].reshape(-1)
        dc2 = ((rgb[i] - rgb[j]) ** 2).sum(1)
        w = np.exp(-dc2 / (2 * s.colour_sigma ** 2))
        A = sparse.coo_matrix((w, (i, j)), shape=(len(idx), len(idx))).tocsr()
        A = A.maximum(A.T)
        f, b = fg[idx], bg[idx] & ~fg[idx]
        outside = dist[idx] > radius
        fixed = f | b | outside
        target = np.where(f, 1.0, 0.0)
        prior = np.zeros(len(idx))
        if f.any() and (b | outside).any():
            d_fg, _ = cKDTree(rgb[f]).query(rgb)
            d_bg, _ = cKDTree(rgb[b | outside]).query(rgb)
            prior = d_bg / np.maximum(d_fg + d_bg, 1e-12)
        free = ~fixed
        if not free.any():
            labels[idx] = target
            return labels
        L = sparse.diags(np.asarray(A.sum(axis=1)).ravel()) - A
        Lff = L[free][:, free] + sparse.diags(np.full(int(free.sum()), s.colour_weight))
        rhs = -(L[free][:, fixed] @ target[fixed]) + s.colour_weight * prior[free]
        x = np.atleast_1d(spsolve(Lff.tocsc(), rhs))
        out = target.copy()
        out[free] = x
        labels[idx] = out
        return labels


def _disk(radius: int) -> np.ndarray:
    r = max(int(radius), 0)
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    return (x * x + y * y) <= r * r


def _dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    from scipy import ndimage

    return ndimage.binary_dilation(mask, structure=_disk(radius)) if radius > 0 else mask.copy()


