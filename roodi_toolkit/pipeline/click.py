"""The ``click`` segmenter: clicks in one view -> the clicked object's Gaussians -> masks of every view.

See :class:`ClickSegmenter` for the method; the interface it implements is :mod:`roodi_toolkit.pipeline.segment`. The
pixel operations on the clicked view (flood fill, GrabCut, holes, components) are in
:mod:`roodi_toolkit.pipeline.click_regions`; the free-standing test (connected pieces of Gaussians) in
:mod:`roodi_toolkit.pipeline.click_parts`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional, Sequence

import cv2
import numpy as np
import torch
from scipy import sparse
from scipy.sparse.linalg import cg, spsolve
from scipy.spatial import cKDTree

from ..cameras import spread_cameras
from ..errors import ConfigError
from ..gaussians import GaussianCloud
from ..io.dataset import Dataset
from ..params import GaussianParams
from ..progress import ProgressFactory, null_progress
from ..render import fast
from ..render.renderer import Renderer, render_features, resolve_renderer
from ..settings import check_settings, config_from_text, documented, setting
from .click_parts import GROWTH_AGREES, free_standing, standing_free, support_layer
from .click_regions import (LEAK_MIN_GAUSSIANS, LEAK_MIN_SHARE, _component_at, _depth_flood_fill, _dilate,
                            _fill_holes, _grabcut, click_sides, clicked_off, cut_by_reach, fill_leaked, label_cut,
                            level_at, off_support, scene_up)
from .segment import SegmentationError, Segmenter, SegmentPrompt, ViewMasks, check_clicks


# ------------------------------------------------------------------------------------------------------ click


GROW_RTOL = 1e-8
"""The growth's labels are solved by conjugate gradients to this relative residual (labels within about 1e-6 of the
direct solution)."""


def solve_labels(system: sparse.csr_matrix, rhs: np.ndarray) -> np.ndarray:
    """Return the solution of the growth's system ``[n, n]`` (the graph Laplacian's free block plus the colour pull
    on its diagonal: symmetric positive definite) for ``rhs`` ``[n]``.

    Conjugate gradients with the diagonal as preconditioner: the colour pull keeps the system well conditioned, so
    a few hundred sparse products solve it. SuperLU's direct solve, used before, fills in the factor of a graph
    Laplacian: 69 s and most of the click's 5.2 GB peak for the biker's 621,138 unknowns, where this takes 4 s
    (136 products; labels within 3e-7). The direct solve stays as the fallback where it does not converge."""
    diagonal = system.diagonal()
    x, info = cg(system, rhs, rtol=GROW_RTOL, maxiter=max(1000, 10 * int(np.sqrt(len(rhs)))),
                 M=sparse.diags(1.0 / np.maximum(diagonal, 1e-12)))
    return np.atleast_1d(x if info == 0 else spsolve(system.tocsc(), rhs))


SCENE_REGION_RADIUS = 0.15
"""``region_radius`` for datasets without sparse points (their box holds the whole scene)."""
CAPTURE_REGION_RADIUS = 0.5
"""``region_radius`` for captures with SfM points (their box is what SfM reconstructed)."""
CLICK_PATCH = 2
"""The pixels within this many of a click (a 5x5 patch) are the ones it points at."""


@documented(given="--segmenter-option {name}=VALUE")
@dataclass(frozen=True)
class ClickSettings:
    """Parameters of the ``click`` segmenter (ours; chosen on the generated benchmark scenes, see RESULTS.md). The
    command line gives them as ``--segmenter-option NAME=VALUE`` (``extract``, ``distill``), read and checked by
    :func:`roodi_toolkit.settings.config_from_text`."""

    # the clicked region is a flood fill over the depth of each pixel's largest-weight Gaussian; its tolerance grows
    # from depth_tolerance_min by depth_tolerance_step up to depth_tolerance_max, stopping before a step that leaks
    depth_tolerance_min: float = setting(0.004, "The clicked region's flood fill joins neighbouring pixels whose "
                                                "depths differ by less than a tolerance, a fraction of the depth; "
                                                "the tolerance starts at this value.", low=0, low_open=True)
    depth_tolerance_max: float = setting(0.03, "The fill's largest depth tolerance.", low=0, low_open=True)
    depth_tolerance_step: float = setting(1.25, "The fill's tolerance is multiplied by this per step.", low=1,
                                          low_open=True)
    leak_ratio: float = setting(2.0, "The fill stops before the step that multiplies the region's area by more "
                                     "than this (a leak through a contact onto the ground or another object).",
                                low=1)
    leak_min_pixels: int = setting(20, "The fill's leak check waits for a region of this many pixels, "
                                       f"{LEAK_MIN_SHARE:.1%} of the image and {LEAK_MIN_GAUSSIANS} Gaussians.", low=0)
    # None: 0.15 for a dataset without sparse points, whose box holds the whole scene (a generated room; chosen
    # there), and 0.5 for a capture with SfM points, whose box is that of what SfM reconstructed, in an
    # object-centred capture mostly the object itself (the statue: 0.15 stops the fill on the crown's band, alpha
    # IoU 0.08; 0.5 and 1.0 give the same 0.72, the leak check stopping the fill first)
    region_radius: Optional[float] = setting(None, "The clicked region stays within this fraction of the scene box "
                                                   "diagonal of the click's 3D point (None: 0.15 without sparse "
                                                   "points, 0.5 for a capture with SfM points).", low=0,
                                             low_open=True)
    reach_doublings: int = setting(3, "Where that reach cuts the object across a smooth surface (a tall object), the "
                                      "fill goes on from its region twice as far, up to this many times.", low=0)
    min_alpha: float = setting(0.5, "Pixels with rendered alpha below this have no usable depth; a click there is "
                                    "refused.", low=0, high=1)
    grabcut_iterations: int = setting(5, "GrabCut iterations on the clicked view's region.", low=1)
    grabcut_min_keep: float = setting(0.5, "When GrabCut keeps less than this fraction of the depth fill's region "
                                           "(a small, flat-coloured or reflective object), the fill's region is "
                                           "used as it is.", low=0, high=1)
    seed_fraction: float = setting(0.5, "A Gaussian seeds the object (or the rest) when at least this fraction of "
                                        "its compositing weight in the clicked view falls inside the clicked region "
                                        "(or the band around it).", low=0, high=1)
    min_weight: float = setting(1.0, "Gaussians whose summed compositing weight in the clicked view is below this "
                                     "are no seeds.", low=0)
    grow_radius: float = setting(1.2, "Only Gaussians within this multiple of the clicked region's 3D radius can "
                                      "join the object (so the ground is not followed).", low=0, low_open=True)
    neighbours: int = setting(10, "Each Gaussian is linked to this many nearest Gaussians in the 3D growth graph.",
                              low=1)
    colour_sigma: float = setting(0.1, "Link strength falls as exp(-dist2 / (2 colour_sigma^2)) of the two "
                                       "Gaussians' DC colours (RGB 0..1): growth stops at colour edges.", low=0,
                                  low_open=True)
    colour_weight: float = setting(0.1, "Pull of each unseeded Gaussian towards the label of the nearest seed "
                                        "colour, relative to one link.", low=0)
    threshold: float = setting(0.5, "A pixel is in a view's mask when more than this fraction of its alpha comes "
                                    "from the selected Gaussians; a Gaussian is selected when its label exceeds "
                                    "it.", low=0, high=1)
    label_split: bool = setting(True, "Select the grown Gaussians whose label exceeds the split of the labels "
                                      "within the growth's reach into two groups (Otsu's threshold) where it is "
                                      "lower than threshold: the rest sits near 0, and an object whose hidden side "
                                      "is joined to its seen side across a colour edge reaches 0.2-0.5.")
    vote_rounds: int = setting(2, "Rounds of the multi-view vote: each Gaussian re-selected when more than "
                                  "threshold of its weight over the voting views falls inside their masks.", low=0)
    vote_views: int = setting(32, "The vote looks at this many views spread evenly over the dataset (and the "
                                  "clicked one).", low=1)
    # part_*: chosen on the PlayCanvas playbot (its robot's hands float 0.2 body radii from it, its ground slab 0.03
    # below it); benchmarks/RESULTS.md, "Extraction at scale"
    part_spacing: float = setting(5.0, "Gaussians within this multiple of the median spacing near the click are one "
                                       "piece (0: never look for a free-standing object).", low=0)
    part_share: float = setting(0.5, "A piece holding more than this share of the scene's Gaussians is no "
                                     "free-standing object (the ground).", low=0, high=1)
    part_gap: float = setting(0.3, "A free-standing piece takes the pieces within this multiple of its radius that "
                                   "are no larger and mostly (half their Gaussians) near its colours.", low=0)
    part_colour: float = setting(0.15, "The RGB distance within which a piece's Gaussians are near a free-standing "
                                       "piece's colours (part_gap).", low=0)

    def __post_init__(self) -> None:
        check_settings(self)


class ClickSegmenter(Segmenter):
    """Clicks in one view, grown into a set of the scene's Gaussians and rendered into every view.

    1. Clicked view: the region is a flood fill from the clicks over the depth of each pixel's largest-weight
       Gaussian (sharp at object edges, unlike the blended expected depth), within ``region_radius`` of the click in
       3D. Its tolerance grows from ``depth_tolerance_min`` by ``depth_tolerance_step`` and stops before the step
       where the area jumps by more than ``leak_ratio`` (the fill has leaked through a contact). A fill that ran on
       over the object's support up to that reach, with no jump (a donut on the ground: the depth is continuous along
       the contact), loses the support's plane (:func:`~roodi_toolkit.pipeline.click_regions.support_plane`, as in
       tabletop segmentation); so does a fill that ran over a level plane under the clicks (the scene's up is the
       cameras' mean up) to the plane's own edge, or that holds less of the fill but nothing under it (a person on
       the ground clicked on a leg). A fill the reach cut (a tall object) fills again twice as far, off the support
       (``reach_doublings``, :func:`~roodi_toolkit.pipeline.click_regions.cut_by_reach`). GrabCut on the image then
       refines it. A negative click's surface (its own fill, growing step by step with the object's;
       pixels both reach at one step go to the click nearer across the surface's creases) is closed to the fill, is
       sure background for GrabCut and joins the band of rest below; a free-standing piece that holds what a
       negative click points at is not taken whole.
    2. Seeds: a Gaussian whose compositing weight in the clicked view lies mostly inside the region seeds the
       object; one whose weight lies mostly in the band around the region seeds the rest.
    3. 3D growth: the Gaussians within ``grow_radius`` times the region's 3D radius are linked to their
       ``neighbours`` nearest Gaussians, links weakened across colour edges (``colour_sigma``). Each Gaussian's label
       is the smooth solution of this graph (a sparse linear solve, as in random-walker segmentation) with the
       seeds held at 1 and 0, the Gaussians beyond the radius at 0, and a weak pull of the others towards the label
       of the nearest seed colour; labels above ``threshold``, or above the split of the labels within the radius
       into two groups where that is lower (``label_split``), form the selection. This reaches the object's hidden
       back, which no pixel of the clicked view shows. An object standing on a level support (a person on the
       ground) stands free without the support's layer (:func:`~roodi_toolkit.pipeline.click_parts.support_layer`):
       where the growth differs from that free piece, off the support's layer, by ``GROWTH_AGREES`` of it or more
       (it stopped on the person's own torso behind a clicked arm), the piece is the selection.
    4. Masks: in every view a pixel is the object when more than ``threshold`` of its alpha comes from the selected
       Gaussians (occlusion is the full scene's compositing). ``vote_rounds`` times, the selection is re-estimated as
       the Gaussians whose weight over ``vote_views`` views falls mostly inside their masks; then the masks of
       every view are rendered.

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
        # options from the command line arrive as text (--segmenter-option region_radius=0.5)
        self.settings = config_from_text(ClickSettings, settings, "click segmenter option")

    @classmethod
    def available(cls) -> tuple[bool, str]:
        return True, ""  # OpenCV, all it needs, is imported with this module

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
        fg, bg, at_click, at_not, depth0 = self._seed_gaussians(scene, params, cam0, mask0, band0, seeds, not_seeds)
        rc = np.argwhere(mask0 & (depth0 > 0))
        points = cam0.backproject(rc, depth0[mask0 & (depth0 > 0)])
        centre = points.mean(axis=0)
        radius0 = max(float(np.linalg.norm(points - centre, axis=1).max()), 1e-6)
        info: dict[str, Any] = {"clicked_view": names[v0], "seed_gaussians": int(fg.sum())}
        diag = float(np.linalg.norm(np.asarray(dataset.bounds[1]) - np.asarray(dataset.bounds[0])))
        # what the click points at: its pixels' Gaussians that belong to the clicked region (a click at the object's
        # edge has the ground behind it in its pixels too)
        pointed = np.maximum(np.where(fg, at_click, 0.0), 0.0)
        pointed = pointed if pointed.any() else np.maximum(at_click, 0.0)
        parts = self._parts(scene, pointed, centre, radius0, diag, region=fg)
        parts = None if parts is not None and clicked_off(parts, at_not) else parts
        if parts is not None:  # a free-standing object: its connected pieces, whatever their colours
            selected = candidates = parts
            info["free_standing"] = True
        else:  # an object that touches the rest: grown from the seeds, stopping at colour edges
            labels = self._grow(scene, fg, bg, centre, s.grow_radius * radius0)
            candidates = np.linalg.norm(scene.means - centre, axis=1) <= s.grow_radius * radius0
            cut = label_cut(labels[candidates], s.threshold) if s.label_split else s.threshold
            selected = labels > cut
            info["free_standing"] = False
            info["label_cut"] = round(float(cut), 4)
            # standing on a level support (a person on the ground): free without the support's layer; that piece
            # replaces a growth that differs from it, off the layer (stopped on the person's own torso behind a
            # clicked arm, or held Gaussians off the piece). A region of fewer seeds than LEAK_MIN_GAUSSIANS gives
            # no scale for the support's layer.
            spread = float(np.median(np.linalg.norm(points - centre, axis=1)))
            support = support_layer(scene.means, centre, scene_up(dataset), spread, diag, pointed) \
                if fg.sum() >= LEAK_MIN_GAUSSIANS else None
            free = None if support is None else standing_free(s, scene, pointed, centre, radius0, diag, fg, *support)
            if free is not None:
                piece, layer = free
                if not clicked_off(piece, at_not) and \
                        (piece ^ (selected & ~layer)).sum() >= GROWTH_AGREES * piece.sum():
                    info.update(free_standing=True, support_layer=int(layer.sum()), grown_first=int(selected.sum()))
                    selected = candidates = piece
        info["grown_gaussians"] = int(selected.sum())
        masks, sel = self._vote_and_render(dataset, params, (selected & candidates).astype(np.float32), candidates,
                                           v0, progress)
        info["selected_gaussians"] = int(sel.sum())
        if not masks[v0].any():
            raise SegmentationError(
                f"the click in {names[v0]} selected no Gaussians of the scene model ({int(fg.sum())} seeds, "
                f"{int(selected.sum())} after growing, none left after the multi-view vote): click nearer the middle "
                "of the object, add a second click, or give masks with the files segmenter")
        return ViewMasks(torch.from_numpy(masks), names, "binary", 2, source=f"click in {names[v0]}", info=info)

    def _seed_gaussians(self, scene: GaussianCloud, params: GaussianParams, cam0: Any, mask0: np.ndarray,
                        band0: np.ndarray, seeds: Sequence[tuple[int, int]],
                        not_seeds: Sequence[tuple[int, int]] = ()) -> tuple[np.ndarray, ...]:
        """Return the seeds of the object and of the rest ``[N]`` bool (most of a Gaussian's weight in the clicked
        view inside the region, or in the band round it), each Gaussian's weight under the clicks and under the
        negative clicks ``[N]``, and the clicked view's expected depth ``[H, W]`` (0 where nothing is rendered)."""
        s = self.settings
        # per Gaussian, the sum over the pixels of its compositing weight times the region, the band and 1 is the
        # gradient of the rendered feature image times those pixel factors: one rendering and its backward, for any
        # differentiable renderer, without listing (pixel, Gaussian) weights (gigabytes at 1000 px). The last
        # feature but one, each Gaussian's camera-space depth, composites the expected depth (its gradient is the
        # weight whatever the feature's value: its pixel factor is the negative clicks' pixels).
        z = scene.means @ cam0.world_to_camera[2, :3] + cam0.world_to_camera[2, 3]
        feats = torch.zeros(len(scene), 5, dtype=params.dtype)
        feats[:, 3] = torch.as_tensor(z, dtype=params.dtype)
        feats.requires_grad_()
        rendered, alpha = render_features(self.renderer, params, feats, cam0)
        # the last factor: the pixels under the clicks themselves, whose Gaussians are what the user pointed at
        def patches(points: Sequence[tuple[int, int]]) -> np.ndarray:
            at = np.zeros_like(mask0)
            for r, c in points:
                at[max(r - CLICK_PATCH, 0):r + CLICK_PATCH + 1, max(c - CLICK_PATCH, 0):c + CLICK_PATCH + 1] = True
            return at

        pixel_factors = np.stack([mask0, band0, np.ones_like(mask0), patches(not_seeds), patches(seeds)], -1)
        (rendered * torch.as_tensor(pixel_factors, dtype=params.dtype)).sum().backward()
        inside, around, total, at_not, at_click = feats.grad.numpy().T
        seen = total >= s.min_weight
        fg = seen & (inside >= s.seed_fraction * total)
        bg = seen & (around >= s.seed_fraction * total)
        a0 = alpha[..., 0].detach().numpy()
        depth0 = np.where(a0 > 1e-10, rendered[..., 3].detach().numpy() / np.maximum(a0, 1e-10), 0.0)
        return fg, bg, at_click, at_not, depth0

    def _vote_and_render(self, dataset: Dataset, params: GaussianParams, sel: np.ndarray, candidates: np.ndarray,
                         v0: int, progress: ProgressFactory) -> tuple[np.ndarray, np.ndarray]:
        """Return the masks of every view ``[V, H, W]`` uint8 and the final selection ``[N]``: ``vote_rounds`` times
        the selection ``sel`` (among the ``candidates``) becomes the Gaussians whose weight over the voting views
        lies mostly inside their masks, then every view's mask is rendered."""
        s = self.settings
        n = len(sel)
        masks = np.zeros((len(dataset), dataset.height, dataset.width), np.uint8)
        rounds = max(int(s.vote_rounds), 0)
        # the vote is a statistic over views: a few dozen spread round the scene (by pose, not by index: a capture's
        # photos need not be in order) decide it as well as hundreds
        voters = sorted(set(spread_cameras(dataset.cameras, s.vote_views)) | {v0})
        with progress(total=rounds * len(voters) + len(dataset), desc="render the selection") as bar:
            for r in range(rounds + 1):
                vote = r < rounds
                inw = np.zeros(n)
                tot = np.zeros(n)
                for v in voters if vote else range(len(dataset)):
                    feats = torch.zeros(n, 2, dtype=params.dtype)
                    feats[:, 0] = torch.from_numpy(sel)
                    feats.requires_grad_(vote)
                    with torch.set_grad_enabled(vote):
                        rendered, alpha_t = render_features(self.renderer, params, feats, dataset.cameras[v])
                    alpha = alpha_t[..., 0].detach().numpy()
                    share = rendered[..., 0].detach().numpy()
                    m = (share > s.threshold * np.maximum(alpha, 1e-12)) & (alpha >= 1.0 / 255.0)
                    masks[v] = m
                    if vote:  # per Gaussian: its weight inside the mask (channel 0) and in all (channel 1)
                        grads = torch.from_numpy(np.stack([m, np.ones_like(m)], -1).astype(np.float32))
                        (rendered * grads.to(params.dtype)).sum().backward()
                        inw += feats.grad[:, 0].numpy()
                        tot += feats.grad[:, 1].numpy()
                    bar.update(1)
                if vote:
                    voted = tot >= s.min_weight
                    sel = (np.where(voted, inw > s.threshold * tot, sel > 0) & candidates).astype(np.float32)
        return masks, sel

    def _clicked_region(self, dataset: Dataset, v0: int, scene: GaussianCloud, seeds: Sequence[tuple[int, int]],
                        not_seeds: Sequence[tuple[int, int]] = ()) -> tuple[np.ndarray, np.ndarray]:
        """Return the clicked view's object region and the rest around it (a band, and the surfaces of the negative
        clicks ``not_seeds``), both ``[H, W]`` bool."""
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
        dist = np.full((H, W), np.inf)
        for r, c in seeds:
            p0 = cam0.backproject(np.array([[r, c]]), depth0[[r], [c]])[0]
            dist[valid0] = np.minimum(dist[valid0], np.linalg.norm(pts_all - p0, axis=1))
        up, radius, flat, starts, previous = scene_up(dataset), reach * diag, np.zeros((H, W), bool), list(seeds), None
        # a tall object goes on past the reach: twice as far, off the support (not from a click on a level surface)
        doublings = 0 if any(level_at(cam0, depth0, valid0, rc, up) for rc in seeds) else s.reach_doublings
        for doubling in range(doublings + 1):
            near_grid = dist <= radius  # the fill (its tolerance raised until the region leaks) within the reach
            region, not_region = self._competing_fill(depth0, valid0 & near_grid & ~flat, valid0, starts, not_seeds)
            region, plane = off_support(cam0, depth0, region, valid0 & ~near_grid, seeds, up, valid0)
            if previous is not None and region.sum() > s.leak_ratio * previous[0].sum():
                region, not_region = previous  # twice as far it ran on over a surface: the last reach holds
                break
            flat |= plane
            if doubling == doublings or radius >= diag or not cut_by_reach(depth0, region, valid0 & ~near_grid & ~flat,
                                                                           s.depth_tolerance_max):
                break
            radius *= 2.0
            starts = list(seeds) + [tuple(rc) for rc in np.argwhere(region)]
            previous = region, not_region
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
        what the other holds, so the rest (the table under the object) is claimed at a small tolerance before the
        object's fill would leak into it. Pixels both reach at one step go to the side whose clicks are nearer
        across the surface (:func:`click_sides`: a watershed that meets at creases and occluding edges), and while
        the object's fill is stuck at its click (fewer than ``leak_min_pixels``: a click on an object's steep edge
        has no neighbour within the first tolerances), the negative clicks' fill does not enter the click's side.
        Before, such pixels went to neither and a stuck fill lost the object to the negative click's fill: a click
        at a resting object's edge with a negative click on the ground round it failed, and a negative click on a
        look-alike touching the object was lost in the object's first fill.
        """
        s = self.settings
        tol = s.depth_tolerance_min
        none = np.zeros(depth.shape, bool)
        mine, theirs = click_sides(depth, allowed | not_allowed, seeds, not_seeds) if not_seeds else (none, none)

        def split(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            both = a & b
            return a & ~(both & ~mine), b & ~(both & ~theirs)

        def rest_allowed() -> np.ndarray:  # while the object's fill is stuck at its click (a click on a steep
            # edge), the negative clicks do not take what lies on the click's side of the creases
            return not_allowed & ~mine if region.sum() < s.leak_min_pixels else not_allowed

        region = _depth_flood_fill(depth, allowed, seeds, tol)
        not_region = _depth_flood_fill(depth, rest_allowed(), not_seeds, tol) if not_seeds else none
        region, not_region = split(region, not_region)
        leaked = False
        while tol * s.depth_tolerance_step <= s.depth_tolerance_max * (1 + 1e-9):
            tol *= s.depth_tolerance_step
            if not leaked:
                grown = _depth_flood_fill(depth, allowed & ~not_region, seeds, tol)
                leaked = fill_leaked(region, grown, depth, s.leak_min_pixels, s.leak_ratio)
            elif not not_seeds:
                break
            not_grown = _depth_flood_fill(depth, rest_allowed() & ~region, not_seeds, tol) if not_seeds else none
            if not leaked:
                region, not_grown = split(grown, not_grown)
            not_region = not_grown & ~region
        for r, c in not_seeds:
            not_region[r, c] = True
        return region, not_region


    def _parts(self, scene: GaussianCloud, at_click: np.ndarray, centre: np.ndarray, radius0: float,
               limit: float, region: np.ndarray | None = None) -> np.ndarray | None:
        """:func:`~roodi_toolkit.pipeline.click_parts.free_standing` with this segmenter's settings."""
        return free_standing(self.settings, scene, at_click, centre, radius0, limit, region)

    def _grow(self, scene: GaussianCloud, fg: np.ndarray, bg: np.ndarray, centre: np.ndarray,
              radius: float) -> np.ndarray:
        """Return each Gaussian's object label in 0..1 ``[N]``: the seeds grown through the 3D neighbour graph."""
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
        x = solve_labels(Lff.tocsr(), rhs)
        out = target.copy()
        out[free] = x
        labels[idx] = out
        return labels
