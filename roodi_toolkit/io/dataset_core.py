"""The :class:`Dataset` type every loader returns and the helpers the loaders share (crop to a common size, checks of
``downscale`` and ``background``, the COLMAP model search, scene bounds, the train/eval split).

The format modules (:mod:`roodi_toolkit.io.blender`, :mod:`roodi_toolkit.io.colmap`, :mod:`roodi_toolkit.io.nerfstudio`)
build on this module, and :mod:`roodi_toolkit.io.dataset` (format detection,
:func:`~roodi_toolkit.io.dataset.load_dataset`) on them; every name here is importable from
:mod:`roodi_toolkit.io.dataset` as well.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np
import torch

from ..cameras import Camera
from ..errors import ConfigError, DatasetError, RoodiError
from .files import read_json

__all__ = [
    "Dataset",
    "SPLITS",
    "LLFF_HOLD",
    "estimate_bounds",
    "split_views",
    "to_loaded_pixel",
]

SPLITS = ("train", "val", "test")
LLFF_HOLD = 8  # 3DGS: every 8th image (index % 8 == 0 in name order) is a test view


# ----------------------------------------------------------------------------------------------------- data type


@dataclass
class Dataset:
    """A posed image set in the internal convention, whatever the format on disk.

    Attributes:
        images: ``[N, H, W, 3]`` float32 in [0, 1], composited on ``background`` where the file had alpha.
        cameras: N cameras (OpenCV world-to-camera, intrinsics at the loaded resolution); ``camera.name`` is the
            image's name (file stem for Blender, the COLMAP image name without extension for COLMAP).
        splits: N strings, each ``"train"``, ``"val"`` or ``"test"``.
        background: RGB in [0, 1] that transparent pixels were composited on.
        bounds: ``[2, 3]`` float64 axis-aligned scene box (min row, max row).
        alphas: ``[N, H, W]`` float32 in [0, 1] when the images had alpha, else None.
        masks: ``[N, H, W]`` int64 instance ids (0 = background) when the dataset has masks, else None.
        depths: ``[N, H, W]`` float32 z-depth along the optical axis (0 = no surface) when present, else None.
        valid: ``[N, H, W]`` float32 in [0, 1], how much each pixel counts in the photometric loss (0 = ignore it: a
            nerfstudio ``mask_path``), else None (every pixel counts).
        points: ``[P, 3]`` float64 sparse points for initialisation (COLMAP), else None.
        point_colors: ``[P, 3]`` uint8 colours of ``points``, else None.
        root: the folder the dataset was read from.
        format: ``"blender"``, ``"colmap"`` or ``"nerfstudio"`` (also instant-ngp's ``transforms.json``).
        metadata: format-specific extras (e.g. ``depth_scale``, the COLMAP camera models), and from the loaders
            ``downscale``, ``crop`` (the common size and each cut image's own size and offset, when the images differ
            slightly in size) and ``source_pixels`` (per view name, how the photo's pixels map to the loaded ones; see
            :func:`to_loaded_pixel`).
    """

    images: torch.Tensor = field(repr=False)
    cameras: list[Camera] = field(repr=False)
    splits: list[str]
    background: tuple[float, float, float]
    bounds: np.ndarray = field(repr=False)
    alphas: torch.Tensor | None = field(default=None, repr=False)
    masks: torch.Tensor | None = field(default=None, repr=False)
    depths: torch.Tensor | None = field(default=None, repr=False)
    valid: torch.Tensor | None = field(default=None, repr=False)
    points: np.ndarray | None = field(default=None, repr=False)
    point_colors: np.ndarray | None = field(default=None, repr=False)
    root: Path | None = None
    format: str = ""
    metadata: dict[str, Any] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        n = len(self.cameras)
        if self.images.ndim != 4 or self.images.shape[-1] != 3 or self.images.shape[0] != n:
            raise DatasetError(f"dataset images must be [N, H, W, 3] with N = {n} cameras, got "
                               f"{list(self.images.shape)}")
        if len(self.splits) != n:
            raise DatasetError(f"dataset has {n} cameras but {len(self.splits)} split labels")
        bad = sorted(set(self.splits) - set(SPLITS))
        if bad:
            raise DatasetError(f"unknown split labels {bad}; expected {list(SPLITS)}")
        hw = tuple(self.images.shape[1:3])
        for name, t in (("alphas", self.alphas), ("masks", self.masks), ("depths", self.depths),
                        ("valid", self.valid)):
            if t is not None and (t.ndim != 3 or t.shape[0] != n or tuple(t.shape[1:]) != hw):
                raise DatasetError(f"dataset {name} must be [{n}, {hw[0]}, {hw[1]}], got {list(t.shape)}")
        self.bounds = np.asarray(self.bounds, dtype=np.float64).reshape(2, 3)

    def __len__(self) -> int:
        return len(self.cameras)

    @property
    def height(self) -> int:
        """Image height in pixels."""
        return int(self.images.shape[1])

    @property
    def width(self) -> int:
        """Image width in pixels."""
        return int(self.images.shape[2])

    @property
    def names(self) -> list[str]:
        """The views' names, in order."""
        return [c.name for c in self.cameras]

    @property
    def train_indices(self) -> list[int]:
        """Indices of the training views."""
        return [i for i, s in enumerate(self.splits) if s == "train"]

    @property
    def test_indices(self) -> list[int]:
        """Indices of the test views."""
        return [i for i, s in enumerate(self.splits) if s == "test"]

    @property
    def val_indices(self) -> list[int]:
        """Indices of the validation views."""
        return [i for i, s in enumerate(self.splits) if s == "val"]

    def subset(self, indices: Sequence[int]) -> "Dataset":
        """Return the dataset restricted to ``indices`` (in the given order); points and bounds are kept."""
        idx = [int(i) for i in indices]
        for i in idx:
            if not 0 <= i < len(self):
                raise DatasetError(f"view index {i} out of range for a dataset of {len(self)} views")
        sel = torch.as_tensor(idx, dtype=torch.long)

        def take(t: torch.Tensor | None) -> torch.Tensor | None:
            return None if t is None else t.index_select(0, sel)

        return replace(self, images=take(self.images), cameras=[self.cameras[i] for i in idx],
                       splits=[self.splits[i] for i in idx], alphas=take(self.alphas), masks=take(self.masks),
                       depths=take(self.depths), valid=take(self.valid))

    def split(self, name: str) -> "Dataset":
        """Return the views of one split (``"train"``, ``"val"`` or ``"test"``)."""
        if name not in SPLITS:
            raise DatasetError(f"unknown split {name!r}; expected one of {list(SPLITS)}")
        return self.subset([i for i, s in enumerate(self.splits) if s == name])


def _is_colmap_model_dir(p: Path) -> bool:
    return all((p / f"{n}.bin").is_file() for n in ("cameras", "images")) or \
        all((p / f"{n}.txt").is_file() for n in ("cameras", "images"))


def _find_colmap_sparse(root: Path) -> Path | None:
    for cand in (root / "sparse" / "0", root / "sparse", root):
        if cand.is_dir() and _is_colmap_model_dir(cand):
            return cand
    return None


# ------------------------------------------------------------------------------------------------ image helpers


MAX_CROP_FRACTION = 0.10  # most of an image's width or height that cropping to a common size may discard


@dataclass(frozen=True)
class _Crop:
    """The common image size of a dataset whose images differ slightly in size, and each image's centred crop.

    COLMAP's undistorter writes every image at its own size (656 to 662 px high for one capture, say); the
    :class:`Dataset` holds one ``[N, H, W, 3]`` tensor, so each image is cut to the smallest width and height, centred,
    and its principal point moved by the same offset: the geometry stays exact, only border pixels are lost.
    """

    width: int
    height: int
    offsets: tuple[tuple[int, int], ...]  # per image (x0, y0) of the crop in its own pixels
    sizes: tuple[tuple[int, int], ...]  # per image its own (width, height)

    @property
    def cropped(self) -> bool:
        """Whether any image is cut."""
        return any(s != (self.width, self.height) for s in self.sizes)

    def record(self, names: Sequence[str]) -> dict[str, Any]:
        """Return the metadata entry naming the common size and each cut image's own size and crop offset."""
        return {"size": [self.width, self.height],
                "images": {n: {"size": list(s), "offset": list(o)} for n, s, o in zip(names, self.sizes, self.offsets)
                           if s != (self.width, self.height)}}


def _plan_crop(paths: Sequence[Path], sizes: Sequence[tuple[int, int]],
               max_fraction: float = MAX_CROP_FRACTION) -> _Crop:
    """Return the centred crop of every image to the smallest width and height among ``sizes`` (width, height).

    Raises:
        DatasetError: the crop would discard more than ``max_fraction`` of some image's width or height (images of
            really different sizes, not one capture's undistorted frames).
    """
    w0 = min(w for w, _ in sizes)
    h0 = min(h for _, h in sizes)
    too_far = [i for i, (w, h) in enumerate(sizes) if (w - w0) > max_fraction * w or (h - h0) > max_fraction * h]
    if too_far:
        counts = Counter((int(w), int(h)) for w, h in sizes).most_common()
        common = counts[0][0] if len(counts) == 1 or counts[0][1] > counts[1][1] else None
        rule = (f"images of one dataset may differ in size by at most {max_fraction:.0%} (they are cropped to the "
                "common size): resize them to one size first")
        if common is not None:
            # name the odd one out: the image farthest from the size most images have (an 8x8 image among 48x48
            # ones is the 8x8 one, though the crop it forces is refused at every 48x48 image)
            cw, ch = common
            odd = max(range(len(sizes)), key=lambda i: max(abs(sizes[i][0] - cw) / cw, abs(sizes[i][1] - ch) / ch))
            raise DatasetError(f"{paths[odd]}: image is {sizes[odd][0]}x{sizes[odd][1]} but most of the dataset's "
                               f"images are {cw}x{ch}; {rule}")
        small = min(range(len(sizes)), key=lambda i: sizes[i][0] * sizes[i][1])
        large = max(range(len(sizes)), key=lambda i: sizes[i][0] * sizes[i][1])
        raise DatasetError(f"{paths[small]}: image is {sizes[small][0]}x{sizes[small][1]} but {paths[large]} is "
                           f"{sizes[large][0]}x{sizes[large][1]}; {rule}")
    return _Crop(w0, h0, tuple(((w - w0) // 2, (h - h0) // 2) for w, h in sizes),
                 tuple((int(w), int(h)) for w, h in sizes))


def _source_pixels(names: Sequence[str], photo_sizes: Sequence[tuple[int, int]], read_sizes: Sequence[tuple[int, int]],
                   crop: _Crop, out_size: tuple[int, int]) -> dict[str, dict[str, list[float]]]:
    """Return, per view name, how its photo's pixels map to the loaded image's: ``x_loaded = x * scale - offset``.

    ``photo_sizes``: the photos' own sizes (the camera model's); ``read_sizes``: the files actually decoded (a
    reduced ``images_4`` copy, say); then the crop and the reduction to ``out_size`` (width, height).
    """
    out: dict[str, dict[str, list[float]]] = {}
    sx2, sy2 = out_size[0] / crop.width, out_size[1] / crop.height
    for name, (pw, ph), (rw, rh), (ox, oy) in zip(names, photo_sizes, read_sizes, crop.offsets):
        ax, ay = rw / pw * sx2, rh / ph * sy2
        out[name] = {"size": [int(pw), int(ph)], "scale": [ax, ay], "offset": [ox * sx2, oy * sy2]}
    return out


def to_loaded_pixel(dataset: "Dataset", view: str, x: float, y: float) -> tuple[float, float]:
    """Return the loaded image's pixel ``(x, y)`` of a pixel of view ``view``'s original photo.

    Clicks are given in the photo's own pixels (what an image viewer shows); the dataset may be reduced
    (``downscale``, ``images_N``) and cropped to a common size, and this undoes both.

    Raises:
        ConfigError: the pixel is outside the photo, or in a border the common-size crop cut away.
    """
    m = dataset.metadata.get("source_pixels", {}).get(view)
    if m is None:  # a dataset built in memory: its images are the photos
        m = {"size": [dataset.width, dataset.height], "scale": [1.0, 1.0], "offset": [0.0, 0.0]}
    (pw, ph), (ax, ay), (bx, by) = m["size"], m["scale"], m["offset"]
    if not (0 <= x < pw and 0 <= y < ph):
        raise ConfigError(f"click {x:g},{y:g} is outside the {pw}x{ph} image {view}")
    ux, uy = x, y
    if "undistort" in m:  # a distorted photo (COLMAP OPENCV ...): where its pixel lies in the undistorted image
        u = m["undistort"]
        shift = np.diag([1.0, 1.0, 1.0])
        shift[:2, 2] = -0.5  # OpenCV puts pixel centres at integers, we at +0.5
        undistort_points = cv2.fisheye.undistortPoints if u.get("fisheye") else cv2.undistortPoints
        pt = undistort_points(np.array([[[x - 0.5, y - 0.5]]]), shift @ np.asarray(u["K"]),
                              np.asarray(u["dist"]), P=shift @ np.asarray(u["new_K"]))
        ux, uy = float(pt[0, 0, 0]) + 0.5, float(pt[0, 0, 1]) + 0.5
    lx, ly = ux * ax - bx, uy * ay - by
    if not (0 <= lx < dataset.width and 0 <= ly < dataset.height):
        raise ConfigError(f"click {x:g},{y:g} in {view} lies in the border cut away to bring the images to one size "
                          f"({dataset.metadata.get('crop', {}).get('size')}); click further inside")
    return lx, ly


def _crop_camera(cam: Camera, offset: tuple[int, int], width: int, height: int) -> Camera:
    """Return ``cam`` for its image cut to ``width`` x ``height`` starting at pixel ``offset`` (x0, y0)."""
    if offset == (0, 0) and (cam.width, cam.height) == (width, height):
        return cam
    K = cam.K.copy()
    K[0, 2] -= offset[0]
    K[1, 2] -= offset[1]
    return Camera(cam.world_to_camera, K, width, height, cam.near, cam.far, cam.name)


def _downscaled_size(width: int, height: int, downscale: float) -> tuple[int, int]:
    return max(1, round(width / downscale)), max(1, round(height / downscale))


def _check_downscale(downscale: float) -> float:
    try:
        d = float(downscale)
    except (TypeError, ValueError):
        raise DatasetError(f"downscale must be a number >= 1, got {downscale!r}") from None
    if not (math.isfinite(d) and d >= 1):
        raise DatasetError(f"downscale must be a number >= 1, got {downscale!r}")
    return d


def _check_background(bg: Any, where: Path) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in bg)
    except (TypeError, ValueError):
        raise DatasetError(f"{where}: background must be three numbers in [0, 1], got {bg!r}") from None
    if len(vals) != 3 or not all(0.0 <= v <= 1.0 for v in vals):
        raise DatasetError(f"{where}: background must be three numbers in [0, 1], got {bg!r}")
    return vals  # type: ignore[return-value]


def estimate_bounds(cameras: Sequence[Camera], points: np.ndarray | None = None) -> np.ndarray:
    """Return a ``[2, 3]`` scene box: the 1st-99th percentile box of ``points`` if given, else one from the cameras.

    Without points the scene is taken to be where the cameras look: the least-squares point closest to all optical
    axes, with a half-size of half the median camera distance to it (cameras around an object, as in Blender scenes).
    """
    if points is not None and len(points) >= 4:
        pts = np.asarray(points, dtype=np.float64)
        lo, hi = np.percentile(pts, 1, axis=0), np.percentile(pts, 99, axis=0)
        pad = 0.05 * (hi - lo) + 1e-6
        return np.stack([lo - pad, hi + pad])
    if not cameras:
        return np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    centres = np.stack([c.center for c in cameras])
    dirs = np.stack([c.camera_to_world[:3, 2] for c in cameras])
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for o, dvec in zip(centres, dirs):
        P = np.eye(3) - np.outer(dvec, dvec)
        A += P
        b += P @ o
    if len(cameras) >= 2 and np.linalg.cond(A) < 1e8:
        focus = np.linalg.solve(A, b)
    else:
        focus = centres.mean(axis=0) + dirs.mean(axis=0)
    half = 0.5 * float(np.median(np.linalg.norm(centres - focus, axis=1)))
    half = half if half > 0 else 1.0
    return np.stack([focus - half, focus + half])


def split_views(dataset: Dataset, holdout_every: int = 8) -> tuple[list[int], list[int]]:
    """Return (train, eval) view indices: the test split if the dataset has one, else every n-th train view held out.

    With ``holdout_every`` 0 and no test split, nothing is held out and evaluation is on no views.
    """
    train = dataset.train_indices
    if dataset.test_indices:
        return train, dataset.test_indices
    if holdout_every and len(train) > 1:
        held = train[::holdout_every]
        return [i for i in train if i not in set(held)], held
    return train, []


def _read_frames_json(json_path: Path, what: str, expected: str) -> dict[str, Any]:
    """Return a transforms file's JSON object (Blender, nerfstudio, instant-ngp), its read errors as DatasetError;
    refuse one that is not an object (``expected`` says what it should hold) or has no ``frames`` list."""
    try:
        meta = read_json(json_path, what)
    except DatasetError:
        raise
    except RoodiError as exc:
        raise DatasetError(str(exc)) from None
    if not isinstance(meta, dict):
        raise DatasetError(f"{json_path}: expected a JSON object with {expected}")
    if not isinstance(meta.get("frames"), list):
        raise DatasetError(f"{json_path}: missing the 'frames' list")
    return meta
