"""The segmenter plugin interface: a dataset and a prompt -> per-view masks of the target object(s).

A segmenter is a class registered under the entry-point group ``roodi_toolkit.segmenters``; the built-ins register in
this package's ``setup.cfg`` exactly as a third-party one does (``plugins/roodi-sam2`` registers ``sam2``)::

    [options.entry_points]
    roodi_toolkit.segmenters =
        files = roodi_toolkit.segmenters:FilesSegmenter
        click = roodi_toolkit.segmenters:ClickSegmenter

A segmenter subclasses :class:`Segmenter`: ``available()`` says whether it can run here, and
``segment(dataset, prompt, scene=...)`` returns :class:`ViewMasks`: one ``[H, W]`` integer map per view of the
dataset, either binary (0 = rest, 1 = the target) or instance ids (0 = background, 1..C-1 objects).

Built-ins:

- ``files`` (default): masks or instance-id maps from a folder of PNGs matched to the views by name, or the
  dataset's own masks (Blender frames with ``mask_path``, as the generated benchmark scenes have).
- ``click``: one or two clicks in one view, lifted to 3D through the trained scene's rendered depth, projected into the
  other views with a visibility test against their rendered depth, and refined per view by OpenCV GrabCut.
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

from .cameras import Camera
from .datasets import Dataset
from .errors import ConfigError, DatasetError, PluginError
from .gaussians import GaussianCloud
from .plugins import discover, instantiate
from .progress import ProgressFactory, null_progress

MASK_KINDS = ("binary", "instances")


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
        from .files import read_image

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


def _backproject(camera: Camera, pixels_rc: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Return world points ``[P, 3]`` of pixels ``[P, 2]`` (row, col) at z-depths ``[P]``."""
    K = camera.K
    u = pixels_rc[:, 1] + 0.5
    v = pixels_rc[:, 0] + 0.5
    cam = np.stack([(u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth, depth], axis=1)
    c2w = camera.camera_to_world
    return cam @ c2w[:3, :3].T + c2w[:3, 3]


@dataclass(frozen=True)
class ClickSettings:
    """Parameters of the ``click`` segmenter (ours; chosen on the generated benchmark scenes, see RESULTS.md).

    Attributes:
        depth_tolerance: neighbouring pixels belong to the same surface when their rendered depths differ by less
            than this fraction of the depth (the clicked region's flood fill).
        region_radius: the clicked region stays within this fraction of the scene box diagonal of the click's 3D
            point (keeps the flood fill from running along the ground).
        visibility_tolerance: a lifted point is visible in another view when its depth is at most the rendered depth
            times ``1 + visibility_tolerance``.
        min_alpha: pixels with rendered alpha below this have no usable depth.
        grabcut_iterations: GrabCut iterations per view.
        margin: the band around the projected region that GrabCut may still give to the object, as a fraction of
            the region's size (at least 2 pixels).
        min_pixels: a view where fewer lifted points are visible than this gets an empty mask.
        max_points: the lifted point set is subsampled to this many points.
        grow_radius: points lifted from the propagated views join the set only within this multiple of the clicked
            region's 3D radius from its centre (so the back of the object is reached and the ground is not).
    """

    depth_tolerance: float = 0.02
    region_radius: float = 0.15
    visibility_tolerance: float = 0.03
    min_alpha: float = 0.5
    grabcut_iterations: int = 5
    margin: float = 0.25
    min_pixels: int = 4
    max_points: int = 20000
    grow_radius: float = 1.6


class ClickSegmenter(Segmenter):
    """One or two clicks in one view, propagated through the trained scene's geometry and refined by GrabCut.

    In the clicked view the region is the flood fill of the rendered depth from the clicks (neighbouring depths
    within ``depth_tolerance``, within ``region_radius`` of the click in 3D) refined by GrabCut on the image. Its
    pixels are lifted to 3D with the rendered depth. The other views are visited in order of increasing angle from the
    clicked view (around the lifted points' centre); in each, the lifted points that are visible (their depth at most
    the rendered depth there) give a prior region, which GrabCut refines (sure object: the eroded prior; probable
    object: the prior; probable rest: a band around it; sure rest: the remainder). Each refined mask is lifted in turn
    (within ``grow_radius`` of the first region), so the back of the object is reached as the views go round.

    Args:
        renderer: renderer name for depth (default the built-in ``torch``).
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

    def _render(self, scene: GaussianCloud, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        from .renderers import render_cloud

        out = render_cloud(scene, camera, renderer=self.renderer)
        return out.depth[..., 0].numpy().astype(np.float64), out.alpha[..., 0].numpy().astype(np.float64)

    def segment(self, dataset: Dataset, prompt: SegmentPrompt, *, scene: Optional[GaussianCloud] = None,
                progress: ProgressFactory = null_progress) -> ViewMasks:
        """Return binary masks (1 = the clicked object) of every view.

        Raises:
            ConfigError: no scene, bad clicks, or a click on empty space (no rendered depth there).
        """
        import cv2

        if scene is None:
            raise ConfigError("the click segmenter needs the trained scene (its depth) to propagate the clicks")
        s = self.settings
        v0 = check_clicks(dataset, prompt.clicks)
        H, W = dataset.height, dataset.width
        names = dataset.names
        out = np.zeros((len(dataset), H, W), dtype=np.int64)
        cam0 = dataset.cameras[v0]
        depth0, alpha0 = self._render(scene, cam0)
        valid0 = (alpha0 >= s.min_alpha) & (depth0 > 0)
        seeds = [(min(int(c.y), H - 1), min(int(c.x), W - 1)) for c in prompt.clicks]
        for r, c in seeds:
            if not valid0[r, c]:
                raise ConfigError(f"the click at {c},{r} in {names[v0]} hits no surface of the scene model "
                                  f"(rendered alpha below {s.min_alpha}); click on the object")
        diag = float(np.linalg.norm(np.asarray(dataset.bounds[1]) - np.asarray(dataset.bounds[0])))
        all_rc = np.argwhere(valid0)
        pts_all = _backproject(cam0, all_rc, depth0[valid0])
        near_grid = np.zeros((H, W), bool)
        for r, c in seeds:
            p0 = _backproject(cam0, np.array([[r, c]]), depth0[[r], [c]])[0]
            near_grid[valid0] |= np.linalg.norm(pts_all - p0, axis=1) <= s.region_radius * diag
        region = _depth_flood_fill(depth0, valid0 & near_grid, seeds, s.depth_tolerance)
        for r, c in seeds:
            region[r, c] = True
        init = np.full((H, W), cv2.GC_BGD, np.uint8)
        init[_dilate(region, max(2, int(0.1 * math.sqrt(region.sum()))))] = cv2.GC_PR_BGD
        init[region] = cv2.GC_PR_FGD
        for r, c in seeds:
            init[max(0, r - 1):r + 2, max(0, c - 1):c + 2] = cv2.GC_FGD
        image0 = dataset.images[v0].numpy()
        mask0 = _grabcut(image0, init, s.grabcut_iterations, self.seed)
        mask0 = _component_at(_fill_holes(mask0), seeds) & valid0 | (init == cv2.GC_FGD)
        out[v0] = mask0
        rc = np.argwhere(mask0 & valid0)
        points = _backproject(cam0, rc, depth0[mask0 & valid0])
        centre = points.mean(axis=0)
        radius0 = max(float(np.linalg.norm(points - centre, axis=1).max()), 1e-6)
        rng = np.random.default_rng(self.seed)
        order = _views_by_angle(dataset.cameras, v0, centre)
        info: dict[str, Any] = {"clicked_view": names[v0], "prior_pixels": {}}
        with progress(total=len(order), desc="propagate clicks") as bar:
            for v in order:
                cam = dataset.cameras[v]
                depth, alpha = self._render(scene, cam)
                uv, z = cam.project(points)
                px = np.floor(uv).astype(np.int64)
                ok = (z > cam.near) & (px[:, 0] >= 0) & (px[:, 0] < W) & (px[:, 1] >= 0) & (px[:, 1] < H)
                px, z = px[ok], z[ok]
                dref = depth[px[:, 1], px[:, 0]]
                vis = (alpha[px[:, 1], px[:, 0]] >= s.min_alpha) & (z <= dref * (1 + s.visibility_tolerance))
                prior = np.zeros((H, W), bool)
                prior[px[vis, 1], px[vis, 0]] = True
                info["prior_pixels"][names[v]] = int(prior.sum())
                if prior.sum() < s.min_pixels:
                    bar.update(1)
                    continue
                prior = _fill_holes(_close(prior, 1))
                size = math.sqrt(prior.sum())
                band = max(2, int(round(s.margin * size)))
                init = np.full((H, W), cv2.GC_BGD, np.uint8)
                init[_dilate(prior, band)] = cv2.GC_PR_BGD
                init[prior] = cv2.GC_PR_FGD
                init[_erode(prior, max(1, band // 2))] = cv2.GC_FGD
                mask = _grabcut(dataset.images[v].numpy(), init, s.grabcut_iterations, self.seed)
                mask = _fill_holes(mask)
                out[v] = mask
                valid = mask & (alpha >= s.min_alpha) & (depth > 0)
                new = _backproject(cam, np.argwhere(valid), depth[valid])
                new = new[np.linalg.norm(new - centre, axis=1) <= s.grow_radius * radius0]
                points = np.concatenate([points, new])
                if len(points) > s.max_points:
                    points = points[rng.choice(len(points), s.max_points, replace=False)]
                bar.update(1)
        return ViewMasks(torch.from_numpy(out), names, "binary", 2, source=f"click in {names[v0]}", info=info)


def _views_by_angle(cameras: Sequence[Camera], v0: int, centre: np.ndarray) -> list[int]:
    """Return the view indices other than ``v0`` sorted by the angle between their and ``v0``'s direction to
    ``centre``."""
    def direction(cam: Camera) -> np.ndarray:
        d = cam.center - centre
        return d / max(float(np.linalg.norm(d)), 1e-12)

    d0 = direction(cameras[v0])
    others = [i for i in range(len(cameras)) if i != v0]
    return sorted(others, key=lambda i: -float(direction(cameras[i]) @ d0))


def _disk(radius: int) -> np.ndarray:
    r = max(int(radius), 0)
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    return (x * x + y * y) <= r * r


def _dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    from scipy import ndimage

    return ndimage.binary_dilation(mask, structure=_disk(radius)) if radius > 0 else mask.copy()


def _erode(mask: np.ndarray, radius: int) -> np.ndarray:
    from scipy import ndimage

    return ndimage.binary_erosion(mask, structure=_disk(radius)) if radius > 0 else mask.copy()


def _close(mask: np.ndarray, radius: int) -> np.ndarray:
    from scipy import ndimage

    return ndimage.binary_closing(mask, structure=_disk(radius)) if radius > 0 else mask.copy()


def mask_iou(pred: np.ndarray | torch.Tensor, true: np.ndarray | torch.Tensor) -> float:
    """Return the intersection over union of two boolean masks (1.0 when both are empty).

    Example:
        >>> mask_iou(np.array([1, 1, 0, 0], bool), np.array([1, 0, 0, 0], bool))
        0.5
    """
    p = np.asarray(pred, dtype=bool)
    t = np.asarray(true, dtype=bool)
    union = np.logical_or(p, t).sum()
    return 1.0 if union == 0 else float(np.logical_and(p, t).sum() / union)
