"""The segmenter plugin interface: a dataset and a prompt -> per-view masks of the target object(s).

A segmenter is a class registered under the entry-point group ``roodi_toolkit.segmenters``; the built-ins register in
this package's ``setup.cfg`` exactly as a third-party one does (``plugins/roodi-sam2`` registers ``sam2``)::

    [options.entry_points]
    roodi_toolkit.segmenters =
        files = roodi_toolkit.pipeline.segment:FilesSegmenter
        click = roodi_toolkit.pipeline.segment:ClickSegmenter

A segmenter subclasses :class:`Segmenter`: ``available()`` says whether it can run here, and
``segment(dataset, prompt, scene=...)`` returns :class:`ViewMasks`: one ``[H, W]`` integer map per view of the
dataset, either binary (0 = rest, 1 = the target) or instance ids (0 = background, 1..C-1 objects).

Built-ins:

- ``files`` (default): masks or instance-id maps from a folder of PNGs matched to the views by name, or the
  dataset's own masks (Blender frames with ``mask_path``, as the generated benchmark scenes have).
- ``click``: one or two clicks in one view; the clicked surface's Gaussians (by their compositing weights there) are
  grown through a 3D neighbour graph of the trained scene's Gaussians, and every view's mask is where the selected
  Gaussians give most of the rendered alpha (see :class:`ClickSegmenter`).
"""

from __future__ import annotations

import math
import re
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np
import torch

from ..cameras import Camera
from ..io.dataset import Dataset
from ..errors import ConfigError, DatasetError, PluginError, RoodiError
from ..gaussians import GaussianCloud
from ..plugins import discover, instantiate
from ..progress import ProgressFactory, null_progress

MASK_KINDS = ("binary", "instances")


class SegmentationError(RoodiError):
    """A segmenter ran but found no object (for example a click that selects nothing)."""


# ------------------------------------------------------------------------------------------------------ prompt


@dataclass(frozen=True)
class Click:
    """A positive click on the target: pixel ``(x, y)`` (x right, y down; pixel centres at +0.5) in view ``view``.

    ``view`` is a view name (the image's file stem, e.g. ``r_003``) or a view index as text.
    """

    view: str
    x: float
    y: float

    @classmethod
    def parse(cls, text: str) -> "Click":
        """Return the click written as ``VIEW:x,y`` (e.g. ``r_003:41,57``).

        Example:
            >>> Click.parse("r_003:41,57.5")
            Click(view='r_003', x=41.0, y=57.5)
        """
        m = re.fullmatch(r"\s*(.+?)\s*:\s*([-+0-9.eE]+)\s*,\s*([-+0-9.eE]+)\s*", str(text))
        if not m:
            raise ConfigError(f"cannot read click {text!r}; expected VIEW:x,y such as r_003:41,57")
        try:
            x, y = float(m.group(2)), float(m.group(3))
        except ValueError:
            raise ConfigError(f"cannot read click {text!r}; x and y must be numbers") from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ConfigError(f"click {text!r}: x and y must be finite")
        return cls(m.group(1), x, y)


@dataclass(frozen=True)
class SegmentPrompt:
    """What the user gives a segmenter.

    Attributes:
        clicks: positive clicks on the target, all in one view (``click``, ``sam2``).
        mask_dir: a folder of mask PNGs named like the views (``files``); None: the dataset's own masks.
    """

    clicks: tuple[Click, ...] = ()
    mask_dir: Optional[Path] = None


@dataclass
class ViewMasks:
    """Per-view masks, one for every view of the dataset, in dataset order.

    Attributes:
        masks: class id per pixel, 0 = background / rest. [N, H, W] int64
        names: the views' names. [N]
        kind: ``"binary"`` (ids 0 and 1, 1 = the target) or ``"instances"`` (ids 0..C-1).
        num_classes: C, at least 2 (distillation's classifier size).
        source: where the masks came from (for reports).
    """

    masks: torch.Tensor
    names: list[str]
    kind: str
    num_classes: int
    source: str = ""
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.masks.ndim != 3 or self.masks.shape[0] != len(self.names):
            raise PluginError(f"masks must be [N, H, W] with N = {len(self.names)} views, got "
                              f"{list(self.masks.shape)}")
        if self.kind not in MASK_KINDS:
            raise PluginError(f"mask kind must be one of {MASK_KINDS}, got {self.kind!r}")
        self.masks = self.masks.to(torch.int64)
        if len(self.masks) and int(self.masks.min()) < 0:
            raise PluginError("mask ids must be non-negative")
        top = int(self.masks.max()) if self.masks.numel() else 0
        if self.kind == "binary" and top > 1:
            raise PluginError(f"binary masks must hold 0 and 1 only, found id {top}")
        self.num_classes = max(int(self.num_classes), top + 1, 2)

    def __len__(self) -> int:
        return len(self.names)

    def present_ids(self) -> list[int]:
        """Return the non-zero ids that occur in at least one view."""
        return [int(i) for i in torch.unique(self.masks).tolist() if i != 0]


# ------------------------------------------------------------------------------------------------------ interface


class Segmenter(ABC):
    """Base class of segmenter plugins. Subclasses take their options as keyword arguments of ``__init__``.

    Attributes:
        name: the registered name.
        needs_scene: True if ``segment`` needs the trained scene (its geometry), as ``click`` does.
    """

    name: str = ""
    needs_scene: bool = False

    @classmethod
    def available(cls) -> tuple[bool, str]:
        """Return (True, "") if this segmenter can run on this machine, else (False, why not and what to do)."""
        return True, ""

    @abstractmethod
    def segment(self, dataset: Dataset, prompt: SegmentPrompt, *, scene: Optional[GaussianCloud] = None,
                progress: ProgressFactory = null_progress) -> ViewMasks:
        """Return one mask per view of ``dataset`` for the target(s) described by ``prompt``.

        Args:
            dataset: the posed images (all of its views get a mask).
            prompt: clicks and/or a mask folder.
            scene: the trained scene model, for segmenters that use its geometry.
            progress: progress factory.
        """


def segmenter_names() -> list[str]:
    """Return the names of the registered segmenters (loaded or not)."""
    return [spec.name for spec in discover("segmenters")]


def get_segmenter(name: str = "files", **options: Any) -> Segmenter:
    """Return an instance of the segmenter registered as ``name``, built with ``options``.

    Raises:
        PluginError: unknown name, failed import, not a :class:`Segmenter`, or not available here (the message says
            why and how to install what is missing).
    """
    return instantiate("segmenters", name, Segmenter, **options)


def view_index(dataset: Dataset, view: str) -> int:
    """Return the index of the view named ``view`` (or given as an index) in ``dataset``.

    Raises:
        ConfigError: no such view (the message lists a few names).
    """
    names = dataset.names
    if view in names:
        return names.index(view)
    if re.fullmatch(r"\d+", view) and int(view) < len(names):
        return int(view)
    shown = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
    raise ConfigError(f"no view named {view!r}; the dataset's views are {shown} (or give an index 0..{len(names) - 1})")


def check_clicks(dataset: Dataset, clicks: Sequence[Click], max_clicks: int = 2) -> int:
    """Return the index of the view the clicks are in, after checking they are 1..max_clicks, in one view, on screen.

    Raises:
        ConfigError: no click, too many, in several views, or outside the image.
    """
    if not clicks:
        raise ConfigError("this segmenter needs a click on the target: --click VIEW:x,y (e.g. r_000:48,40)")
    if len(clicks) > max_clicks:
        raise ConfigError(f"give at most {max_clicks} clicks, got {len(clicks)}")
    views = {view_index(dataset, c.view) for c in clicks}
    if len(views) != 1:
        raise ConfigError("all clicks must be in the same view")
    for c in clicks:
        if not (0 <= c.x < dataset.width and 0 <= c.y < dataset.height):
            raise ConfigError(f"click {c.view}:{c.x:g},{c.y:g} is outside the {dataset.width}x{dataset.height} image")
    return views.pop()


# ------------------------------------------------------------------------------------------------------ files


def _mask_file(folder: Path, name: str) -> Optional[Path]:
    for ext in (".png", ".PNG"):
        p = folder / f"{name}{ext}"
        if p.is_file():
            return p
    return None


def mask_from_array(arr: np.ndarray, size: tuple[int, int], where: str) -> np.ndarray:
    """Return ``[H, W]`` int64 ids from a mask image, resized (nearest) when it is a larger copy of the view.

    Args:
        arr: the image: ``[h, w]`` ids (8 or 16 bit) or ``[h, w, 3|4]`` grey stored as colour.
        size: the view's ``(width, height)``.
        where: the file, for messages.

    Raises:
        DatasetError: colour masks, or a size that is not the view's (or an exact multiple of it, as when the
            dataset is loaded downscaled).
    """
    a = np.asarray(arr)
    if a.ndim == 3:
        rgb = a[..., :3]
        if not (np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2])):
            raise DatasetError(f"{where}: mask is a colour image; expected 8- or 16-bit grey instance ids "
                               "(0 = background) or a black-and-white binary mask")
        a = rgb[..., 0]
    a = a.astype(np.int64)
    w, h = size
    if a.shape != (h, w):
        fy, fx = a.shape[0] / h, a.shape[1] / w
        if not (a.shape[0] > h and abs(fx - fy) < 1e-6 and abs(fx - round(fx)) < 1e-6 and a.shape[1] % w == 0):
            raise DatasetError(f"{where}: mask is {a.shape[1]}x{a.shape[0]} but its view is {w}x{h}; masks must "
                               "have the view's size (or an exact multiple of it)")
        f = int(round(fx))
        a = a[f // 2::f, f // 2::f]  # nearest: the sample at the centre of each block
    return a


class FilesSegmenter(Segmenter):
    """Masks read from files: a folder of PNGs named like the views, or the dataset's own masks.

    A folder's masks may be binary (0 and 255, or 0 and 1: the target is 1) or instance ids (any other values,
    0 = background). Without a folder the dataset's masks are used (``mask_path`` in Blender transforms).

    Args:
        mask_dir: default folder when the prompt gives none.
    """

    name = "files"

    def __init__(self, mask_dir: str | Path | None = None) -> None:
        self.mask_dir = None if mask_dir is None else Path(mask_dir)

    def segment(self, dataset: Dataset, prompt: SegmentPrompt = SegmentPrompt(), *,
                scene: Optional[GaussianCloud] = None, progress: ProgressFactory = null_progress) -> ViewMasks:
        """Return the masks of every view from the folder (or the dataset's own masks).

        Raises:
            DatasetError: no folder and no dataset masks, missing files (listed), colour or mis-sized masks.
        """
        folder = prompt.mask_dir if prompt.mask_dir is not None else self.mask_dir
        if folder is None:
            if dataset.masks is None:
                raise DatasetError("the dataset has no masks (its transforms frames have no mask_path); give a "
                                   "folder of mask PNGs named like the views, or use --segmenter click")
            masks = dataset.masks.clone()
            return ViewMasks(masks, dataset.names, "instances", int(masks.max()) + 1, source="dataset masks")
        from ..io.files import read_image

        folder = Path(folder)
        if not folder.is_dir():
            raise DatasetError(f"{folder}: mask folder not found")
        names = dataset.names
        paths = {n: _mask_file(folder, n) for n in names}
        missing = [n for n, p in paths.items() if p is None]
        if missing:
            shown = ", ".join(f"{n}.png" for n in missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5
                                                                 else "")
            raise DatasetError(f"{folder}: no mask for {len(missing)} of {len(names)} views: {shown}; masks are "
                               "matched to views by name (the image's file stem)")
        out = np.zeros((len(names), dataset.height, dataset.width), dtype=np.int64)
        with progress(total=len(names), desc="read masks") as bar:
            for i, n in enumerate(names):
                p = paths[n]
                out[i] = mask_from_array(read_image(p), (dataset.width, dataset.height), str(p))
                bar.update(1)
        values = np.unique(out)
        if set(values.tolist()) <= {0, 255}:
            out = (out == 255).astype(np.int64)
            kind = "binary"
        elif set(values.tolist()) <= {0, 1}:
            kind = "binary"
        else:
            kind = "instances"
        return ViewMasks(torch.from_numpy(out), names, kind, int(out.max()) + 1, source=str(folder))


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
            point (keeps the flood fill from running along the ground).
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
    region_radius: float = 0.15
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


def _view_weights(tensors: dict[str, torch.Tensor], camera: Camera) -> Any:
    """Return the sparse ``[H*W, N]`` scipy CSR matrix of the Gaussians' alpha-compositing weights in ``camera``
    (rows: pixels in row-major order): :func:`roodi_toolkit.pipeline.distill.compositing_weights` in scipy's form, for the
    column slicing and sums the propagation needs."""
    from scipy import sparse

    from .distill import compositing_weights

    w = compositing_weights(tensors, camera)
    return sparse.csr_matrix((w.values().numpy(), w.col_indices().numpy(), w.crow_indices().numpy()), shape=w.shape)


class ClickSegmenter(Segmenter):
    """One or two clicks in one view, grown into a set of the scene's Gaussians and rendered into every view.

    1. Clicked view: the region is a flood fill from the clicks over the depth of each pixel's largest-weight
       Gaussian (sharp at object edges, unlike the blended expected depth), within ``region_radius`` of the click in
       3D. Its tolerance grows from ``depth_tolerance_min`` by ``depth_tolerance_step`` and stops before the step
       where the area jumps by more than ``leak_ratio`` (the fill has leaked through a contact); GrabCut on the image
       then refines it.
    2. Seeds: with the view's per-pixel compositing weights (``rasterizer.compositing_pairs``), a Gaussian whose
       weight lies mostly inside the region seeds the object; one whose weight lies mostly in the band around the
       region seeds the rest.
    3. 3D growth: the Gaussians within ``grow_radius`` times the region's 3D radius are linked to their
       ``neighbours`` nearest Gaussians, links weakened across colour edges (``colour_sigma``). Each Gaussian's label
       is the smooth solution of this graph (a sparse linear solve, as in random-walker segmentation) with the
       seeds held at 1 and 0, the Gaussians beyond the radius at 0, and a weak pull of the others towards the label
       of the nearest seed colour; labels above ``threshold`` form the selection. This reaches the object's hidden
       back, which no pixel of the clicked view shows.
    4. Masks: in every view a pixel is the object when more than ``threshold`` of its alpha comes from the selected
       Gaussians (occlusion is the full scene's compositing). ``vote_rounds`` times, the selection is re-estimated as
       the Gaussians whose weight over all views falls mostly inside the masks, and the masks are rendered again.

    Args:
        renderer: accepted for compatibility and unused: the compositing weights come from the built-in rasterizer
            (:func:`roodi_toolkit.render.rasterizer.compositing_pairs`), whatever renderer trained the scene.
        seed: OpenCV's random seed (GrabCut's GMM initialisation).
        **settings: fields of :class:`ClickSettings`.
    """

    name = "click"
    needs_scene = True

    def __init__(self, renderer: str = "torch", seed: int = 0, **settings: Any) -> None:
        self.renderer = renderer
        self.seed = seed
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
        from .distill import _frozen_tensors

        tensors = _frozen_tensors(scene)
        cam0 = dataset.cameras[v0]
        w0 = _view_weights(tensors, cam0)
        seeds = [(min(int(c.y), H - 1), min(int(c.x), W - 1)) for c in prompt.clicks]
        mask0, band0 = self._clicked_region(dataset, v0, scene, w0, seeds)
        inside = np.asarray(w0.T @ mask0.reshape(-1).astype(np.float64)).ravel()
        around = np.asarray(w0.T @ band0.reshape(-1).astype(np.float64)).ravel()
        total = np.asarray(w0.sum(axis=0)).ravel()
        seen = total >= s.min_weight
        fg = seen & (inside >= s.seed_fraction * total)
        bg = seen & (around >= s.seed_fraction * total)
        depth0 = self._depth(w0, scene, cam0).reshape(H, W)
        rc = np.argwhere(mask0 & (depth0 > 0))
        points = cam0.backproject(rc, depth0[mask0 & (depth0 > 0)])
        centre = points.mean(axis=0)
        radius0 = max(float(np.linalg.norm(points - centre, axis=1).max()), 1e-6)
        labels = self._grow(scene, fg, bg, centre, s.grow_radius * radius0)
        selected = labels > s.threshold
        candidates = np.linalg.norm(scene.means - centre, axis=1) <= s.grow_radius * radius0
        info: dict[str, Any] = {"clicked_view": names[v0], "seed_gaussians": int(fg.sum()),
                                "grown_gaussians": int(selected.sum())}
        weights = []
        with progress(total=len(dataset), desc="render the selection") as bar:
            for v in range(len(dataset)):
                w = w0 if v == v0 else _view_weights(tensors, dataset.cameras[v])
                alpha = np.asarray(w.sum(axis=1)).ravel()
                weights.append((w[:, candidates].tocsr(), alpha))
                bar.update(1)
        cand_index = np.flatnonzero(candidates)
        sel = selected[cand_index].astype(np.float64)
        for _ in range(max(int(s.vote_rounds), 0) + 1):
            masks = [(wc @ sel > s.threshold * np.maximum(alpha, 1e-12)) & (alpha >= 1.0 / 255.0)
                     for wc, alpha in weights]
            if _ == s.vote_rounds:
                break
            inw = np.zeros(len(cand_index))
            tot = np.zeros(len(cand_index))
            for (wc, _alpha), m in zip(weights, masks):
                inw += wc.T @ m.astype(np.float64)
                tot += np.asarray(wc.sum(axis=0)).ravel()
            voted = tot >= s.min_weight
            sel = np.where(voted, inw > s.threshold * tot, sel > 0).astype(np.float64)
        info["selected_gaussians"] = int(sel.sum())
        if not masks[v0].any():
            raise SegmentationError(
                f"the click in {names[v0]} selected no Gaussians of the scene model ({int(fg.sum())} seeds, "
                f"{int(selected.sum())} after growing, none left after the multi-view vote): click nearer the middle "
                "of the object, add a second click, or give masks with the files segmenter")
        out = np.stack([m.reshape(H, W) for m in masks]).astype(np.int64)
        return ViewMasks(torch.from_numpy(out), names, "binary", 2, source=f"click in {names[v0]}", info=info)

    @staticmethod
    def _depth(weights: Any, scene: GaussianCloud, camera: Camera) -> np.ndarray:
        """Return the rendered expected depth ``[H*W]`` (0 where nothing is hit) from compositing weights."""
        z = scene.means @ camera.world_to_camera[2, :3] + camera.world_to_camera[2, 3]
        alpha = np.asarray(weights.sum(axis=1)).ravel()
        return np.where(alpha > 1e-10, (weights @ z) / np.maximum(alpha, 1e-10), 0.0)

    @staticmethod
    def _surface_depth(weights: Any, scene: GaussianCloud, camera: Camera) -> np.ndarray:
        """Return the depth ``[H*W]`` of each pixel's largest-weight Gaussian (0 where nothing is hit): unlike the
        expected depth it does not blend across object edges, so a flood fill stops there."""
        z = scene.means @ camera.world_to_camera[2, :3] + camera.world_to_camera[2, 3]
        top = np.asarray(weights.argmax(axis=1)).ravel()
        hit = np.asarray(weights.max(axis=1).todense()).ravel() > 0
        return np.where(hit, z[top], 0.0)

    def _clicked_region(self, dataset: Dataset, v0: int, scene: GaussianCloud, w0: Any,
                        seeds: Sequence[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
        """Return the clicked view's object region and the band of rest around it, both ``[H, W]`` bool."""
        import cv2

        s = self.settings
        H, W = dataset.height, dataset.width
        cam0 = dataset.cameras[v0]
        alpha0 = np.asarray(w0.sum(axis=1)).ravel().reshape(H, W)
        depth0 = self._surface_depth(w0, scene, cam0).reshape(H, W)
        valid0 = (alpha0 >= s.min_alpha) & (depth0 > 0)
        for r, c in seeds:
            if not valid0[r, c]:
                raise ConfigError(f"the click at {c},{r} in {dataset.names[v0]} hits no surface of the scene model "
                                  f"(rendered alpha below {s.min_alpha}); click on the object")
        diag = float(np.linalg.norm(np.asarray(dataset.bounds[1]) - np.asarray(dataset.bounds[0])))
        pts_all = cam0.backproject(np.argwhere(valid0), depth0[valid0])
        near_grid = np.zeros((H, W), bool)
        for r, c in seeds:
            p0 = cam0.backproject(np.array([[r, c]]), depth0[[r], [c]])[0]
            near_grid[valid0] |= np.linalg.norm(pts_all - p0, axis=1) <= s.region_radius * diag
        # the fill's tolerance grows step by step and stops before the step where the region suddenly grows
        # several-fold: it has leaked through a contact onto the ground or a neighbour
        tol = s.depth_tolerance_min
        region = _depth_flood_fill(depth0, valid0 & near_grid, seeds, tol)
        while tol * s.depth_tolerance_step <= s.depth_tolerance_max * (1 + 1e-9):
            tol *= s.depth_tolerance_step
            grown = _depth_flood_fill(depth0, valid0 & near_grid, seeds, tol)
            if region.sum() >= s.leak_min_pixels and grown.sum() > s.leak_ratio * region.sum():
                break
            region = grown
        for r, c in seeds:
            region[r, c] = True
        init = np.full((H, W), cv2.GC_BGD, np.uint8)
        init[_dilate(region, max(2, int(0.1 * math.sqrt(region.sum()))))] = cv2.GC_PR_BGD
        init[region] = cv2.GC_PR_FGD
        for r, c in seeds:
            init[max(0, r - 1):r + 2, max(0, c - 1):c + 2] = cv2.GC_FGD
        mask0 = _grabcut(dataset.images[v0].numpy(), init, s.grabcut_iterations, self.seed)
        mask0 = _component_at(_fill_holes(mask0), seeds) & valid0 | (init == cv2.GC_FGD)
        if mask0.sum() < s.grabcut_min_keep * region.sum():
            mask0 = region
        band = _dilate(mask0, max(2, int(round(0.25 * math.sqrt(mask0.sum()))))) & ~mask0
        return mask0, band

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
