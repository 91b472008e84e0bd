"""The segmenter plugin interface: a dataset and a prompt -> per-view masks of the target object(s).

A segmenter is a class registered under the entry-point group ``roodi_toolkit.segmenters``; the built-ins register in
this package's ``setup.cfg`` exactly as a third-party one does (``plugins/roodi-sam2`` registers ``sam2``)::

    [options.entry_points]
    roodi_toolkit.segmenters =
        files = roodi_toolkit.pipeline.segment:FilesSegmenter
        click = roodi_toolkit.pipeline.click:ClickSegmenter

A segmenter subclasses :class:`Segmenter`: ``available()`` says whether it can run here, and
``segment(dataset, prompt, scene=...)`` returns :class:`ViewMasks`: one ``[H, W]`` integer map per view of the
dataset, either binary (0 = rest, 1 = the target) or instance ids (0 = background, 1..C-1 objects).

Built-ins:

- ``files`` (default): masks or instance-id maps given in memory, keyed by view name (its ``masks`` option: the run
  layer reads the folder of PNGs the prompt names with :func:`roodi_toolkit.io.masks.read_mask_folder`), or the
  dataset's own masks (Blender frames with ``mask_path``, as the generated benchmark scenes have).
- ``click``: clicks in one view, positive on the target and optionally negative on what is not; the clicked surface's
  Gaussians (by their compositing weights there) are grown through a 3D neighbour graph of the trained scene's
  Gaussians, and every view's mask is where the selected Gaussians give most of the rendered alpha (see
  :class:`roodi_toolkit.pipeline.click.ClickSegmenter`).
"""

from __future__ import annotations

import math
import os
import re
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from typing import Any, Mapping, Optional, Sequence

import numpy as np
import torch

from ..errors import ConfigError, DatasetError, PluginError, RoodiError
from ..gaussians import GaussianCloud
from ..io.dataset import Dataset, to_loaded_pixel
from ..masks import mask_from_array
from ..plugins import discover, instantiate
from ..progress import ProgressFactory, null_progress

MASK_KINDS = ("binary", "instances")


class SegmentationError(RoodiError):
    """A segmenter ran but found no object (for example a click that selects nothing)."""


# ------------------------------------------------------------------------------------------------------ prompt


@dataclass(frozen=True)
class Click:
    """A click on view ``view`` at pixel ``(x, y)`` (x right, y down; pixel centres at +0.5): on the target
    (``positive``, the default) or on something that is not the target (a negative click, as SAM's point labels).

    ``view`` is a view name (the image's file stem, e.g. ``r_003``) or a view index as text.
    """

    view: str
    x: float
    y: float
    positive: bool = True

    @classmethod
    def parse(cls, text: str, positive: bool = True) -> "Click":
        """Return the click written as ``VIEW:x,y`` (e.g. ``r_003:41,57``).

        Example:
            >>> Click.parse("r_003:41,57.5")
            Click(view='r_003', x=41.0, y=57.5, positive=True)
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
        return cls(m.group(1), x, y, positive)


@dataclass(frozen=True)
class SegmentPrompt:
    """What the user gives a segmenter.

    Attributes:
        clicks: clicks in one view (``click``, ``sam2``): at least one positive (on the target), and negative ones
            (``positive=False``) on what must not be selected.
        mask_dir: a folder of mask PNGs named like the views, as the user named it (recorded with the run). For the
            ``files`` segmenter the run layer reads it (:func:`roodi_toolkit.io.masks.read_mask_folder`) and hands the
            masks over as that segmenter's ``masks`` option; None: the dataset's own masks.
    """

    clicks: tuple[Click, ...] = ()
    mask_dir: Optional[str | os.PathLike] = None


MAX_MASK_ID = 1023
"""Largest object id a mask may hold (the distilled classifier has one class per id, 0 to the largest)."""


@dataclass
class ViewMasks:
    """Per-view masks, one for every view of the dataset, in dataset order.

    Attributes:
        masks: class id per pixel, 0 = background / rest; stored as uint8 (int32 above id 255): take ``.long()``
            of a view for a loss. [N, H, W]
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
        if len(self.masks) and int(self.masks.min()) < 0:
            raise PluginError("mask ids must be non-negative")
        top = int(self.masks.max()) if self.masks.numel() else 0
        if top > MAX_MASK_ID:  # the classifier has one class per id up to the largest: id 65535 made 65,536 classes
            raise DatasetError(f"{self.source or 'masks'}: mask id {top} is above the largest supported id "
                               f"{MAX_MASK_ID}; number the objects 1, 2, 3, ... (0 is the background)")
        if self.kind == "binary" and top > 1:
            raise PluginError(f"binary masks must hold 0 and 1 only, found id {top}")
        self.num_classes = max(int(self.num_classes), top + 1, 2)
        # one byte a pixel where the ids fit (90 views of 800x800 are 58 MB, not 461 MB as int64)
        self.masks = self.masks.to(torch.uint8 if top <= 255 else torch.int32)

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
            prompt: clicks and/or the mask folder the user named.
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


MAX_CLICKS = 8
"""Most clicks, positive and negative together, a prompt may hold."""


def check_clicks(dataset: Dataset, clicks: Sequence[Click], max_clicks: int = MAX_CLICKS) -> int:
    """Return the index of the view the clicks are in, after checking there is a positive one, at most
    ``max_clicks`` in all, all in one view and on screen.

    Raises:
        ConfigError: no positive click, too many, in several views, or outside the image.
    """
    if not any(c.positive for c in clicks):
        raise ConfigError("this segmenter needs a click on the target: --click VIEW:x,y (e.g. r_000:48,40)"
                          + ("; negative clicks alone say only what the target is not" if clicks else ""))
    if len(clicks) > max_clicks:
        raise ConfigError(f"give at most {max_clicks} clicks (positive and negative), got {len(clicks)}")
    views = {view_index(dataset, c.view) for c in clicks}
    if len(views) != 1:
        raise ConfigError("all clicks must be in the same view")
    for c in clicks:
        if not (0 <= c.x < dataset.width and 0 <= c.y < dataset.height):
            raise ConfigError(f"click {c.view}:{c.x:g},{c.y:g} is outside the {dataset.width}x{dataset.height} image")
    return views.pop()


def resolve_prompt(prompt: SegmentPrompt, dataset: Dataset) -> tuple[SegmentPrompt, SegmentPrompt]:
    """Return ``prompt`` with each click's view resolved (``""``: the first training view; a name may carry its file
    extension), and the same with the clicks moved from the photos' own pixels (what an image viewer shows) to the
    loaded images' (downscaled, ``images_N``, cropped to a common size).

    Raises:
        ConfigError: an unknown view, or a click outside its photo.
    """
    if not prompt.clicks:
        return prompt, prompt
    given, clicks = [], []
    for c in prompt.clicks:
        name = c.view or dataset.names[(dataset.train_indices or [0])[0]]
        stem = os.path.splitext(os.path.basename(name))[0]
        if name not in dataset.names and stem in dataset.names:  # given with its file extension
            name = stem
        name = dataset.names[view_index(dataset, name)]
        given.append(Click(name, c.x, c.y, c.positive))
        clicks.append(Click(name, *to_loaded_pixel(dataset, name, c.x, c.y), c.positive))
    return replace(prompt, clicks=tuple(given)), replace(prompt, clicks=tuple(clicks))


# ------------------------------------------------------------------------------------------------------ files


class FilesSegmenter(Segmenter):
    """Masks given in memory, one per view keyed by view name, or the dataset's own masks; opens no file.

    The masks may be binary (0 and 255, or 0 and 1: the target is 1) or instance ids (any other values,
    0 = background). Without ``masks`` the dataset's masks are used (``mask_path`` in Blender transforms).

    Args:
        masks: the mask of every view, keyed by view name: ``[H, W]`` ids (8 or 16 bit) at the view's size, an exact
            multiple of it or its size divided by an integer (brought to the view's size as
            :func:`roodi_toolkit.masks.mask_from_array` does: the dataset given to :meth:`segment` may be the mask
            stages' working resolution); as :func:`roodi_toolkit.io.masks.read_mask_folder` reads a folder of PNGs.
        source: where the masks came from, for messages and reports (the folder).

    Example (a folder: ``masks=read_mask_folder(folder, dataset.names, (dataset.width, dataset.height))``):
        >>> from types import SimpleNamespace
        >>> views = SimpleNamespace(names=["r_000"], width=2, height=1, masks=None)  # a Dataset's names and size
        >>> found = FilesSegmenter({"r_000": np.array([[0, 255]], np.uint8)}).segment(views)
        >>> found.kind, found.masks.tolist()
        ('binary', [[[0, 1]]])
    """

    name = "files"

    def __init__(self, masks: Optional[Mapping[str, np.ndarray]] = None, source: str = "") -> None:
        if masks is not None and not isinstance(masks, Mapping):
            raise PluginError(f"the files segmenter's masks must map view names to arrays, got "
                              f"{type(masks).__name__}; give a mask folder with --masks DIR")
        self.masks = masks
        self.source = source

    def segment(self, dataset: Dataset, prompt: SegmentPrompt = SegmentPrompt(), *,
                scene: Optional[GaussianCloud] = None, progress: ProgressFactory = null_progress) -> ViewMasks:
        """Return the masks of every view (those given, or the dataset's own masks).

        Raises:
            ConfigError: the prompt names a mask folder but no masks were given (this segmenter reads no folder).
            DatasetError: no masks given and none in the dataset, a view without a mask (listed), colour or
                mis-sized masks.
        """
        if self.masks is None:
            if prompt.mask_dir is not None:
                raise ConfigError(f"{prompt.mask_dir}: the files segmenter reads no folder; read it with "
                                  "roodi_toolkit.io.masks.read_mask_folder and give the masks as its masks option")
            if dataset.masks is None:
                raise DatasetError("the dataset has no masks (its transforms frames have no mask_path); give a "
                                   "folder of mask PNGs named like the views, or use --segmenter click")
            masks = dataset.masks.clone()
            return ViewMasks(masks, dataset.names, "instances", int(masks.max()) + 1, source="dataset masks")
        return given_masks(self.masks, dataset, self.source or "the given masks")


def given_masks(given: Mapping[str, np.ndarray], dataset: Dataset, source: str, *,
                keys: Sequence[str] | None = None) -> ViewMasks:
    """Return the masks keyed by view name (or by ``keys``, one a view of ``dataset``) as the dataset's
    :class:`ViewMasks` (binary or instance ids).

    Raises:
        DatasetError: a view without a mask (listed), colour or mis-sized masks.
    """
    names = dataset.names
    keys = names if keys is None else list(keys)
    missing = [k for k in keys if k not in given]
    if missing:
        shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
        raise DatasetError(f"{source}: no mask for {len(missing)} of {len(keys)} views: {shown}")
    # a byte a pixel while the ids fit (every 8-bit mask): 300 views of 800 px are 192 MB, not the 1.5 GB of
    # int64 and the copies a whole-array unique and a cast made of it
    out = np.zeros((len(names), dataset.height, dataset.width), dtype=np.uint8)
    values: set[int] = set()
    for i, (n, k) in enumerate(zip(names, keys)):
        m = mask_from_array(given[k], (dataset.width, dataset.height), f"{source}: the mask of view {n}")
        ids = np.unique(m)
        if out.dtype == np.uint8 and (ids.min() < 0 or ids.max() > 255):
            out = out.astype(np.int64)  # ids of a 16-bit mask
        out[i] = m
        values.update(ids.tolist())
    if values <= {0, 255}:
        out //= 255  # 255 -> 1, in place
        kind = "binary"
    elif values <= {0, 1}:
        kind = "binary"
    else:
        kind = "instances"
    return ViewMasks(torch.from_numpy(out), names, kind, int(out.max()) + 1, source=source)
