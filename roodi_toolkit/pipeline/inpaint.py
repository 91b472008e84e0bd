"""The inpainter plugin interface, the 2x2 grid the four views travel in, and the built-in classical inpainter.

An inpainter is a class registered under the entry-point group ``roodi_toolkit.inpainters``; the built-in ``opencv``
inpainter (:class:`OpenCVInpainter`, this package's ``setup.cfg``) registers exactly as a third-party one does, e.g.
the ``sdxl`` diffusion inpainter in ``plugins/roodi-sdxl``::

    [options.entry_points]
    roodi_toolkit.inpainters =
        opencv = roodi_toolkit.pipeline.inpaint:OpenCVInpainter

An inpainter class subclasses :class:`Inpainter` and implements :meth:`Inpainter.fill`; callers use
:meth:`Inpainter.inpaint`, which checks shapes and value ranges, calls ``fill`` and composites the result so that
pixels outside the mask come back exactly as they went in, whatever the backend did to them.

Following the paper (after NeRFiller), the four object-centred views are inpainted together, as one 2x2 grid
(:func:`inpaint_views`), so that the inpainter sees all of them at once and fills them consistently.

3D-aware inpainters (e.g. ``symmetry``, :mod:`roodi_toolkit.pipeline.symmetry`) set ``uses_context = True`` and then
get a fourth argument, a :class:`FillContext` (the object's Gaussians, the views' cameras, the renderer, the
occlusion reasoning) or None when the caller has none (they must still fill, e.g. with a 2D fallback). Inpainters
that do not set it are called with three arguments exactly as before, so existing plugins keep working unchanged.
A 3D-aware inpainter may also propose Gaussians to add to the object (:attr:`FillContext.proposed`), which
:func:`roodi_toolkit.pipeline.finetune.refine_object` adds before fine-tuning. One that completes the object in 3D
before any view is drawn implements :meth:`Inpainter.complete`: the refinement then frames its four views around the
object with its completion (a hidden lower half would otherwise fall outside views framed on the seen part) and hands
the completion back in :attr:`FillContext.completion`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Optional, Sequence

import cv2
import numpy as np
import torch
from torch import Tensor

from ..errors import ConfigError, PluginError
from ..plugins import discover, instantiate

if TYPE_CHECKING:
    from ..cameras import Camera
    from ..gaussians import GaussianCloud
    from ..render.renderer import Renderer
    from .occlusion import OcclusionResult


@dataclass
class FillContext:
    """What a 3D-aware inpainter may use besides the pixels (the refinement step passes it; 2D inpainters never see it).

    Attributes:
        object_cloud: the object's Gaussians (after selection and pruning).
        cameras: the cameras of the views, in grid order (row by row).
        renderer: draws the object in those cameras.
        background: RGB behind the renders.
        occlusion: the occlusion reasoning of the views (renders, occluded and inpainting masks), if any.
        up: the scene's up axis, if known. [3]
        seen_empty: a function of world points ``[N, 3]`` returning which of them (bool ``[N]``) a training view sees
            as empty space, if known (:func:`roodi_toolkit.pipeline.occlusion.seen_empty`); a 3D completion drops
            what it would put there.
        support: the height along ``up`` of the surface the object stands on, if known
            (:func:`roodi_toolkit.pipeline.support.support_height`).
        pixel: the width in world units of one training-view pixel at the object (the median over the training
            views), if known: Gaussians much smaller than that render wider than they are (every splat is widened
            by a fraction of a pixel), so a completion sizes its Gaussians no smaller.
        obstacles: positions ``[M, 3]`` of the scene's Gaussians that are not the object's (opaque enough to be
            surfaces), if known: what hides the object's unseen part also bounds it.
        rows: grid rows the views are tiled in.
        cols: grid columns.
        completion: the Gaussians the inpainter's :meth:`Inpainter.complete` returned before the views were
            chosen (the refinement sets it), or None.
        proposed: set by the inpainter: Gaussians it proposes to add to the object (same columns), or None.
    """

    object_cloud: "GaussianCloud"
    cameras: "list[Camera]"
    renderer: "Renderer"
    background: Sequence[float] = (1.0, 1.0, 1.0)
    occlusion: "Optional[OcclusionResult]" = field(default=None, repr=False)
    up: Optional[Sequence[float]] = None
    seen_empty: Optional[Callable[[np.ndarray], np.ndarray]] = field(default=None, repr=False)
    support: Optional[float] = None
    pixel: Optional[float] = None
    obstacles: Optional[np.ndarray] = field(default=None, repr=False)
    rows: int = 2
    cols: int = 2
    completion: "Optional[GaussianCloud]" = field(default=None, repr=False)
    proposed: "Optional[GaussianCloud]" = field(default=None, repr=False)


class Inpainter(ABC):
    """Base class of inpainter plugins. Subclasses take their options as keyword arguments of ``__init__``."""

    name: str = ""
    #: True: :meth:`fill` takes a fourth argument, the :class:`FillContext` (or None); see the module docstring.
    uses_context: bool = False

    @classmethod
    def available(cls) -> tuple[bool, str]:
        """Return (True, "") if this inpainter can run on this machine, else (False, why not and what to do)."""
        return True, ""

    def complete(self, context: FillContext) -> "Optional[GaussianCloud]":
        """Return the Gaussians a 3D-aware inpainter adds to the object, from the context's object, up axis,
        support and see-through test alone (before any view exists: ``context.cameras`` may be empty), or None.

        The refinement calls it first and frames the views around the object with what it returns; 2D inpainters
        keep this default (None), so their views and fills are as before.
        """
        return None

    @abstractmethod
    def fill(self, images: Tensor, masks: Tensor, prompt: str) -> Tensor:
        """Return the images with the masked pixels filled in (the backend's own work; see :meth:`inpaint`).

        Args:
            images: float32 RGB in [0, 1]. [B, H, W, 3]
            masks: bool, True where pixels are to be filled. [B, H, W]
            prompt: text guidance ("" for none; backends without text ignore it).

        Returns:
            float RGB in [0, 1]. [B, H, W, 3]
        """

    def inpaint(self, images: Tensor, masks: Tensor, prompt: Optional[str] = None,
                context: Optional[FillContext] = None) -> Tensor:
        """Return the images with the masked pixels inpainted and all other pixels exactly unchanged.

        Args:
            images: float RGB in [0, 1]. [B, H, W, 3]
            masks: True (or > 0.5) where pixels are to be filled. [B, H, W]
            prompt: optional text guidance; None means no prompt (the paper uses none).
            context: the object, cameras and renderer behind the images, for inpainters with ``uses_context``
                (others ignore it).

        Raises:
            ConfigError: malformed images or masks.
            PluginError: the backend returned something of the wrong shape or with non-finite values.
        """
        images, masks = check_batch(images, masks)
        if not bool(masks.any()):
            return images.clone()
        if self.uses_context:
            out = self.fill(images, masks, prompt or "", context)  # type: ignore[call-arg]
        else:
            out = self.fill(images, masks, prompt or "")
        if not isinstance(out, Tensor) or tuple(out.shape) != tuple(images.shape):
            shape = list(out.shape) if isinstance(out, Tensor) else type(out).__name__
            raise PluginError(f"inpainter {self.name or type(self).__name__!r} returned {shape}, expected "
                              f"{list(images.shape)}")
        out = out.to(images.dtype)
        if not bool(torch.isfinite(out).all()):
            raise PluginError(f"inpainter {self.name or type(self).__name__!r} returned NaN or Inf")
        return torch.where(masks[..., None], out.clamp(0, 1), images)


def check_batch(images: Tensor, masks: Tensor) -> tuple[Tensor, Tensor]:
    """Return ``(images as float32, masks as bool)`` after checking shapes ``[B, H, W, 3]`` and ``[B, H, W]``."""
    images = torch.as_tensor(images)
    masks = torch.as_tensor(masks)
    if images.ndim != 4 or images.shape[-1] != 3:
        raise ConfigError(f"inpainting needs images [B, H, W, 3], got {list(images.shape)}")
    if tuple(masks.shape) != tuple(images.shape[:3]):
        raise ConfigError(f"inpainting masks must be [B, H, W] = {list(images.shape[:3])}, got {list(masks.shape)}")
    images = images.float()
    if not bool(torch.isfinite(images).all()) or float(images.min()) < 0 or float(images.max()) > 1:
        raise ConfigError("inpainting images must be finite and in [0, 1]")
    masks = masks if masks.dtype == torch.bool else masks > 0.5
    return images, masks


def outline_region(mask: np.ndarray, radius: float = 0.1) -> np.ndarray:
    """Return the masked pixels ``[H, W]`` (bool) inside the outline of the unmasked region: its morphological
    closing with a disc of ``radius`` times the image's shorter side (holes and bays narrower than about that).

    Example:
        >>> m = np.ones((20, 20), bool)
        >>> m[5:15, 5:15] = False  # a known square ...
        >>> m[9:11, 9:11] = True  # ... with a hole
        >>> r = outline_region(m, 0.1)
        >>> bool(r[9:11, 9:11].all()), bool(r[0, 0])
        (True, False)
    """
    if mask.all():
        return mask
    r = max(1, round(radius * min(mask.shape)))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    known = (~mask).astype(np.uint8)
    # pad so that the closing does not treat the image border as foreground
    padded = cv2.copyMakeBorder(known, r, r, r, r, cv2.BORDER_CONSTANT, value=0)
    closed = cv2.morphologyEx(padded, cv2.MORPH_CLOSE, disc)[r:-r, r:-r].astype(bool)
    return mask & closed


# ---------------------------------------------------------------------------------------------------------- grids


def to_grid(views: Tensor, rows: int = 2, cols: int = 2) -> Tensor:
    """Return ``rows * cols`` views tiled into one image, row by row.

    Args:
        views: channels-last views (any trailing dims). [rows * cols, H, W, ...]

    Example:
        >>> v = torch.arange(4.0).reshape(4, 1, 1).expand(4, 2, 3)
        >>> to_grid(v)
        tensor([[0., 0., 0., 1., 1., 1.],
                [0., 0., 0., 1., 1., 1.],
                [2., 2., 2., 3., 3., 3.],
                [2., 2., 2., 3., 3., 3.]])
    """
    if views.ndim < 3 or views.shape[0] != rows * cols:
        raise ConfigError(f"a {rows}x{cols} grid needs {rows * cols} views [N, H, W, ...], got {list(views.shape)}")
    n, h, w, *rest = views.shape
    return views.reshape(rows, cols, h, w, *rest).transpose(1, 2).reshape(rows * h, cols * w, *rest)


def from_grid(grid: Tensor, rows: int = 2, cols: int = 2) -> Tensor:
    """Return the views of a grid made by :func:`to_grid`. [rows * cols, H, W, ...]

    Example:
        >>> v = torch.rand(4, 5, 7, 3)
        >>> bool(torch.equal(from_grid(to_grid(v)), v))
        True
    """
    if grid.ndim < 2 or grid.shape[0] % rows or grid.shape[1] % cols:
        raise ConfigError(f"a grid of size {list(grid.shape[:2])} does not split into {rows}x{cols} views")
    gh, gw, *rest = grid.shape
    h, w = gh // rows, gw // cols
    return grid.reshape(rows, h, cols, w, *rest).transpose(1, 2).reshape(rows * cols, h, w, *rest)


def inpaint_views(inpainter: "Inpainter", images: Tensor, masks: Tensor, prompt: Optional[str] = None, *,
                  rows: int = 2, cols: int = 2,
                  context: Optional[FillContext] = None) -> tuple[Tensor, dict[str, Tensor]]:
    """Return the views inpainted together as one grid, and the grids before and after (for debug images).

    Args:
        inpainter: the backend.
        images: the views, float RGB in [0, 1]. [rows * cols, H, W, 3]
        masks: where to fill. [rows * cols, H, W]
        prompt: optional text guidance.
        rows: grid rows.
        cols: grid columns.
        context: passed on to a 3D-aware inpainter (its ``rows`` and ``cols`` are set to the grid's).

    Returns:
        The inpainted views ``[rows * cols, H, W, 3]`` and ``{"before": grid, "mask": grid mask, "after": grid}``.
    """
    images, masks = check_batch(images, masks)
    grid = to_grid(images, rows, cols)
    grid_mask = to_grid(masks, rows, cols)
    if context is not None:
        context.rows, context.cols = rows, cols
    # context only to an inpainter that asks for it: one overriding inpaint() with the older three-argument form
    # still works
    extra = (context,) if context is not None and getattr(inpainter, "uses_context", False) else ()
    after = inpainter.inpaint(grid[None], grid_mask[None], prompt, *extra)[0]
    return from_grid(after, rows, cols), {"before": grid, "mask": grid_mask, "after": after}


# ------------------------------------------------------------------------------------------------------ registry


def inpainter_names() -> list[str]:
    """Return the names of the registered inpainters (loaded or not)."""
    return [spec.name for spec in discover("inpainters")]


def get_inpainter(name: str = "opencv", **options: Any) -> Inpainter:
    """Return an instance of the inpainter registered as ``name``, built with ``options``.

    Raises:
        PluginError: unknown name, failed import, not an :class:`Inpainter`, not available here (the message says
            why, e.g. missing weights), or options it does not take.
    """
    return instantiate("inpainters", name, Inpainter, **options)


# ------------------------------------------------------------------------------------------------ built-in: OpenCV


class OpenCVInpainter(Inpainter):
    """Classical inpainting with OpenCV (Telea's fast marching or Navier-Stokes), no weights, fully offline.

    What it can do: fill holes and occluded patches with colour propagated smoothly from their borders, which is
    right for small gaps and for flat or slowly varying surfaces. What it cannot do: invent texture, structure or
    shape that is not at the border of the hole (a hidden handle stays missing; a large hole becomes a smooth smear),
    and it has no notion of objects or of multi-view consistency: each pixel is filled from its neighbours in the grid.

    Because the paper's mask includes the whole background (so a generative inpainter can redraw the object's
    outline), filling *all* of it from the object's border would smear the object over the frame. With
    ``extent="outline"`` (the default) only masked pixels inside the outline of the unmasked region are filled: its
    morphological closing with a disc of ``outline_radius`` times the image's shorter side, i.e. holes and bays
    narrower than about that; masked pixels outside stay as they came in (the rendered background). ``extent="all"``
    fills every masked pixel, the plain OpenCV behaviour.

    To keep fills smooth across large holes, the image is filled coarse to fine (``levels``): each level is filled at
    half resolution first and the upsampled coarse fill seeds the hole's interior, so colours far from the border come
    from a wide neighbourhood rather than from the last few border pixels that the fast-marching front reached.

    Args:
        method: ``"telea"`` (cv2.INPAINT_TELEA, default) or ``"ns"`` (cv2.INPAINT_NS).
        radius: neighbourhood radius in pixels at full resolution (OpenCV's ``inpaintRadius``).
        extent: ``"outline"`` or ``"all"`` (see above).
        outline_radius: closing radius as a fraction of the shorter image side.
        levels: coarse-to-fine levels (1: plain single-scale OpenCV).

    Example:
        >>> img = torch.full((1, 48, 48, 3), 0.25)
        >>> mask = torch.zeros(1, 48, 48, dtype=torch.bool)
        >>> mask[0, 20:28, 20:28] = True
        >>> img[mask] = 1.0
        >>> out = OpenCVInpainter().inpaint(img, mask)
        >>> round(float((out - 0.25).abs().max()), 2)
        0.0
    """

    name = "opencv"

    def __init__(self, *, method: str = "telea", radius: float = 3.0, extent: str = "outline",
                 outline_radius: float = 0.1, levels: int = 3) -> None:
        if method not in ("telea", "ns"):
            raise ConfigError(f"opencv inpainter: method must be 'telea' or 'ns', got {method!r}")
        if extent not in ("outline", "all"):
            raise ConfigError(f"opencv inpainter: extent must be 'outline' or 'all', got {extent!r}")
        if radius <= 0 or not 0 < outline_radius < 1 or levels < 1:
            raise ConfigError(f"opencv inpainter: need radius > 0, 0 < outline_radius < 1, levels >= 1; got "
                              f"{radius}, {outline_radius}, {levels}")
        self.method = method
        self.radius = float(radius)
        self.extent = extent
        self.outline_radius = float(outline_radius)
        self.levels = int(levels)

    def fill_region(self, mask: np.ndarray) -> np.ndarray:
        """Return the part of ``mask`` [H, W] (bool) this inpainter fills: all of it, or what lies inside the outline."""
        return mask if self.extent == "all" else outline_region(mask, self.outline_radius)

    def _fill_one(self, image: np.ndarray, region: np.ndarray, radius: float, levels: int) -> np.ndarray:
        flag = cv2.INPAINT_TELEA if self.method == "telea" else cv2.INPAINT_NS
        h, w = region.shape
        work = image.copy()
        if levels > 1 and min(h, w) >= 16 and region.any():
            # average only known pixels into each coarse pixel: the values inside the hole are meaningless
            known = (~region).astype(np.float32)
            size = (w // 2, h // 2)
            small_known = cv2.resize(known, size, interpolation=cv2.INTER_AREA)
            small_img = cv2.resize(image * known[..., None], size, interpolation=cv2.INTER_AREA)
            small_img = small_img / np.maximum(small_known, 1e-6)[..., None]
            small_region = small_known < 1e-6
            coarse = self._fill_one(small_img, small_region, max(1.0, radius / 2), levels - 1)
            coarse = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_LINEAR)
            # seed the interior (farther than the radius from known pixels) with the coarse fill; only the band near
            # the border is left to the fine fast-marching pass, which then blends into the seeded interior
            dist = cv2.distanceTransform(region.astype(np.uint8), cv2.DIST_L2, 3)
            interior = dist > 2 * radius
            work[interior] = coarse[interior]
            region = region & ~interior
        if not region.any():
            return work
        img8 = (np.clip(work, 0, 1) * 255 + 0.5).astype(np.uint8)
        filled = cv2.inpaint(img8, region.astype(np.uint8), radius, flag).astype(np.float32) / 255.0
        out = work.copy()
        out[region] = filled[region]
        return out

    def fill(self, images: Tensor, masks: Tensor, prompt: str) -> Tensor:
        out = images.clone()
        for b in range(images.shape[0]):
            mask = masks[b].numpy()
            region = self.fill_region(mask)
            if not region.any():
                continue
            filled = self._fill_one(images[b].numpy().astype(np.float32), region, self.radius, self.levels)
            out[b] = torch.from_numpy(filled)
        return out
