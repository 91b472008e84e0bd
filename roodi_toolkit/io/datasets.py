"""Posed-image datasets: one :class:`Dataset` type, Blender/NeRF-synthetic and COLMAP loaders, COLMAP writers.

Every loader returns the same type: images as float32 tensors in [0, 1], cameras in the internal OpenCV convention
(:class:`~roodi_toolkit.cameras.Camera`), the train/test split, scene bounds and the background colour, plus what the
format offers besides (alpha, per-pixel instance ids, depth, sparse points).

Formats:

- Blender / NeRF-synthetic: ``transforms_{train,val,test}.json`` with ``camera_angle_x`` and ``frames[]`` holding
  ``file_path`` (extension optional, ``.png`` tried) and ``transform_matrix`` (camera-to-world, OpenGL axes). RGBA
  images are composited on the background colour. Optional keys written by :mod:`roodi_toolkit.synth.scenegen` and read
  here: ``w``/``h``, ``fl_x``/``fl_y``/``cx``/``cy``, per-frame ``mask_path`` (8-bit instance ids, 0 = background) and
  ``depth_path`` (16-bit PNG times ``depth_scale`` = z-depth), top-level ``background`` and ``scene_bounds``.
- COLMAP: ``sparse/0/{cameras,images,points3D}.{bin,txt}`` (world-to-camera, quaternions w, x, y, z), images in
  ``images/``; PINHOLE and SIMPLE_PINHOLE cameras; test views are every 8th image in name order (3DGS ``llffhold``).

This module is the I/O module of datasets: it opens the dataset files (through :mod:`roodi_toolkit.io.files` where a
helper exists).
"""

from __future__ import annotations

import math
import os
import struct
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, BinaryIO, Sequence

import numpy as np
import torch

from ..cameras import Camera, opengl_c2w_to_w2c, w2c_to_opengl_c2w
from ..errors import DatasetError, RoodiError
from .files import atomic_path, read_image, read_json, write_json
from ..progress import ProgressFactory, null_progress

__all__ = [
    "Dataset",
    "ColmapCamera",
    "ColmapImage",
    "ColmapPoints",
    "ColmapModel",
    "load_dataset",
    "load_cameras",
    "load_blender",
    "load_colmap",
    "detect_format",
    "read_colmap_model",
    "write_colmap_model",
    "colmap_model_from_cameras",
    "write_blender_transforms",
    "qvec_to_rotmat",
    "rotmat_to_qvec",
    "estimate_bounds",
]

SPLITS = ("train", "val", "test")
DEFAULT_BLENDER_BACKGROUND = (1.0, 1.0, 1.0)  # NeRF-synthetic convention (white_background)
DEFAULT_COLMAP_BACKGROUND = (0.0, 0.0, 0.0)  # 3DGS default for real captures
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
        points: ``[P, 3]`` float64 sparse points for initialisation (COLMAP), else None.
        point_colors: ``[P, 3]`` uint8 colours of ``points``, else None.
        root: the folder the dataset was read from.
        format: ``"blender"`` or ``"colmap"``.
        metadata: format-specific extras (e.g. ``depth_scale``, the COLMAP camera models).
    """

    images: torch.Tensor = field(repr=False)
    cameras: list[Camera] = field(repr=False)
    splits: list[str]
    background: tuple[float, float, float]
    bounds: np.ndarray = field(repr=False)
    alphas: torch.Tensor | None = field(default=None, repr=False)
    masks: torch.Tensor | None = field(default=None, repr=False)
    depths: torch.Tensor | None = field(default=None, repr=False)
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
        for name, t in (("alphas", self.alphas), ("masks", self.masks), ("depths", self.depths)):
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
                       depths=take(self.depths))

    def split(self, name: str) -> "Dataset":
        """Return the views of one split (``"train"``, ``"val"`` or ``"test"``)."""
        if name not in SPLITS:
            raise DatasetError(f"unknown split {name!r}; expected one of {list(SPLITS)}")
        return self.subset([i for i, s in enumerate(self.splits) if s == name])


# ----------------------------------------------------------------------------------------------------- detection


def detect_format(path: str | os.PathLike) -> str:
    """Return ``"blender"`` or ``"colmap"`` for a dataset folder (or a ``transforms_*.json`` file).

    Raises:
        DatasetError: the path is missing or holds neither format.
    """
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"{p}: dataset not found")
    if p.is_file():
        if p.suffix.lower() == ".json":
            return "blender"
        raise DatasetError(f"{p}: not a dataset; give a folder with transforms_*.json or sparse/0, or a "
                           "transforms_*.json file")
    if any((p / f"transforms_{s}.json").is_file() for s in SPLITS):
        return "blender"
    if _find_colmap_sparse(p) is not None:
        return "colmap"
    raise DatasetError(f"{p}: no dataset found: expected transforms_train/val/test.json (Blender) or "
                       "sparse/0/cameras.bin|txt (COLMAP)")


def load_dataset(path: str | os.PathLike, downscale: float = 1, *, background: Sequence[float] | None = None,
                 splits: Sequence[str] | None = None, test_every: int = LLFF_HOLD,
                 progress: ProgressFactory = null_progress) -> Dataset:
    """Return the dataset at ``path``, detecting Blender or COLMAP format.

    Args:
        path: a dataset folder or a ``transforms_*.json`` file.
        downscale: divide the image resolution by this factor (>= 1; images area-averaged, masks nearest).
        background: RGB in [0, 1] to composite transparent pixels on; defaults to the dataset's (``background`` key
            of a generated scene), else white for Blender and black for COLMAP.
        splits: Blender only: which of train/val/test to read (default all present).
        test_every: COLMAP only: every ``test_every``-th image in name order is a test view (0: all train).
        progress: progress factory.

    Raises:
        DatasetError: the dataset is missing, malformed or inconsistent.
    """
    fmt = detect_format(path)
    if fmt == "blender":
        return load_blender(path, downscale, background=background, splits=splits, progress=progress)
    return load_colmap(path, downscale, background=background, test_every=test_every, progress=progress)


def load_cameras(path: str | os.PathLike, *, splits: Sequence[str] | None = None) -> list[Camera]:
    """Return the cameras of a dataset without reading its images (sizes come from the files' metadata).

    Args:
        path: a dataset folder, a ``transforms_*.json`` file, or a COLMAP model folder (``sparse/0``).
        splits: Blender only: which splits to include, in this order (default train, val, test as present).
    """
    p = Path(path)
    if p.is_dir() and _is_colmap_model_dir(p):
        model = read_colmap_model(p)
        return [cam for cam, _ in _colmap_cameras(model)]
    fmt = detect_format(p)
    if fmt == "blender":
        cams: list[Camera] = []
        for json_path, split in _blender_json_files(p, splits):
            meta = _read_transforms(json_path)
            for frame_idx, frame in enumerate(meta["frames"]):
                image_path = _frame_image_path(json_path, frame, frame_idx)
                if "w" in meta and "h" in meta:
                    size = (int(meta["w"]), int(meta["h"]))
                else:
                    size = _image_size(image_path)
                cams.append(_blender_camera(json_path, meta, frame, frame_idx, size, image_path.stem))
        return cams
    model = read_colmap_model(_find_colmap_sparse(p))
    return [cam for cam, _ in _colmap_cameras(model)]


# ------------------------------------------------------------------------------------------------------- Blender


def _blender_json_files(path: Path, splits: Sequence[str] | None) -> list[tuple[Path, str]]:
    if path.is_file():
        stem = path.stem
        split = stem.split("_", 1)[1] if stem.startswith("transforms_") else "train"
        if split not in SPLITS:
            split = "train"
        return [(path, split)]
    wanted = list(splits) if splits is not None else list(SPLITS)
    for s in wanted:
        if s not in SPLITS:
            raise DatasetError(f"unknown split {s!r}; expected some of {list(SPLITS)}")
    found = [(path / f"transforms_{s}.json", s) for s in wanted if (path / f"transforms_{s}.json").is_file()]
    if not found:
        raise DatasetError(f"{path}: none of " + ", ".join(f"transforms_{s}.json" for s in wanted) + " found")
    return found


def _read_transforms(json_path: Path) -> dict[str, Any]:
    try:
        meta = read_json(json_path, "Blender transforms file")
    except DatasetError:
        raise
    except RoodiError as exc:
        raise DatasetError(str(exc)) from None
    if not isinstance(meta, dict):
        raise DatasetError(f"{json_path}: expected a JSON object with camera_angle_x and frames")
    if "frames" not in meta or not isinstance(meta["frames"], list):
        raise DatasetError(f"{json_path}: missing the 'frames' list")
    if "camera_angle_x" not in meta and "fl_x" not in meta:
        raise DatasetError(f"{json_path}: missing 'camera_angle_x' (or 'fl_x'): the focal length is unknown")
    if "camera_angle_x" in meta:
        try:
            angle = float(meta["camera_angle_x"])
        except (TypeError, ValueError):
            raise DatasetError(f"{json_path}: 'camera_angle_x' must be a number, got "
                               f"{meta['camera_angle_x']!r}") from None
        if not 0 < angle < math.pi:
            raise DatasetError(f"{json_path}: 'camera_angle_x' must be in (0, pi) radians, got {angle}")
    return meta


def _frame_image_path(json_path: Path, frame: Any, frame_idx: int) -> Path:
    if not isinstance(frame, dict) or "file_path" not in frame:
        raise DatasetError(f"{json_path}: frame {frame_idx} has no 'file_path'")
    return _resolve_file(json_path, str(frame["file_path"]), f"frame {frame_idx} image")


def _resolve_file(json_path: Path, rel: str, what: str) -> Path:
    base = json_path.parent / rel
    candidates = [base]
    if not base.suffix or base.suffix.lower() not in (".png", ".jpg", ".jpeg", ".exr", ".npy"):
        candidates += [base.with_name(base.name + ext) for ext in (".png", ".jpg", ".jpeg")]
    for c in candidates:
        if c.is_file():
            return c
    tried = ", ".join(str(c) for c in candidates)
    raise DatasetError(f"{json_path}: {what} not found (tried {tried})")


def _image_size(path: Path) -> tuple[int, int]:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as img:
            return int(img.size[0]), int(img.size[1])
    except FileNotFoundError:
        raise DatasetError(f"{path}: image not found") from None
    except (UnidentifiedImageError, OSError) as exc:
        raise DatasetError(f"{path}: cannot read image ({exc})") from None


def _blender_camera(json_path: Path, meta: dict[str, Any], frame: dict[str, Any], frame_idx: int,
                    size: tuple[int, int], name: str) -> Camera:
    width, height = size
    if "transform_matrix" not in frame:
        raise DatasetError(f"{json_path}: frame {frame_idx} has no 'transform_matrix'")
    try:
        c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(f"{json_path}: frame {frame_idx}: 'transform_matrix' is not a matrix of numbers") from None
    if c2w.shape not in ((4, 4), (3, 4)) or not np.isfinite(c2w).all():
        raise DatasetError(f"{json_path}: frame {frame_idx}: 'transform_matrix' must be a finite 4x4 matrix, got shape "
                           f"{list(c2w.shape)}")
    try:
        if "fl_x" in meta:
            fx = float(meta["fl_x"])
            fy = float(meta.get("fl_y", fx))
            cx = float(meta.get("cx", width / 2.0))
            cy = float(meta.get("cy", height / 2.0))
            # fl_x/cx are given at the resolution of w/h; rescale to the actual image size
            if "w" in meta and "h" in meta and (int(meta["w"]), int(meta["h"])) != (width, height):
                sx, sy = width / float(meta["w"]), height / float(meta["h"])
                fx, cx, fy, cy = fx * sx, cx * sx, fy * sy, cy * sy
        else:
            fx = 0.5 * width / math.tan(0.5 * float(meta["camera_angle_x"]))
            fy = fx
            cx, cy = width / 2.0, height / 2.0
    except (TypeError, ValueError):
        raise DatasetError(f"{json_path}: intrinsics (fl_x, fl_y, cx, cy, w, h) must be numbers") from None
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    near = float(meta.get("near", 0.01))
    far = float(meta.get("far", 1e10))
    try:
        return Camera(opengl_c2w_to_w2c(c2w), K, width, height, near=near, far=far, name=name)
    except RoodiError as exc:
        raise DatasetError(f"{json_path}: frame {frame_idx}: {exc}") from None


def _to_float_image(arr: np.ndarray, path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Return (rgb [H,W,3] float32, alpha [H,W] float32 or None) from a uint8/uint16 image array."""
    if arr.dtype == np.uint16:
        scale = 65535.0
    elif arr.dtype == np.uint8:
        scale = 255.0
    else:
        raise DatasetError(f"{path}: unsupported image data type {arr.dtype}")
    img = arr.astype(np.float32) / scale
    if img.ndim == 2:
        return np.repeat(img[..., None], 3, axis=2), None
    if img.shape[2] == 4:
        return img[..., :3], img[..., 3]
    if img.shape[2] == 3:
        return img, None
    raise DatasetError(f"{path}: expected a grey, RGB or RGBA image, got {img.shape[2]} channels")


def _read_rgb(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    return _to_float_image(_read_dataset_image(path), path)


class _SameSize:
    """Remembers the first image's size and refuses an image of any other size."""

    def __init__(self) -> None:
        self.size: tuple[int, int] | None = None
        self.first: Path | None = None

    def __call__(self, path: Path, width: int, height: int) -> None:
        if self.size is None:
            self.size, self.first = (width, height), path
        elif self.size != (width, height):
            raise DatasetError(f"{path}: image is {width}x{height} but {self.first} is {self.size[0]}x{self.size[1]}; "
                               "all images of a dataset must have the same size")


def _read_dataset_image(path: Path) -> np.ndarray:
    """Return an image file's array, its read errors as DatasetError."""
    try:
        return read_image(path)
    except RoodiError as exc:
        raise DatasetError(str(exc)) from None


def _read_mask(path: Path) -> np.ndarray:
    arr = _read_dataset_image(path)
    if arr.ndim == 3:
        # an RGB(A) mask: instance ids are stored in the first channel
        arr = arr[..., 0]
    return arr.astype(np.int64)


def _read_depth(path: Path, scale: float) -> np.ndarray:
    if path.suffix.lower() == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise DatasetError(f"{path}: cannot read depth ({exc})") from None
        return np.asarray(arr, dtype=np.float32).reshape(arr.shape[:2])
    arr = _read_dataset_image(path)
    if arr.ndim == 3:
        arr = arr[..., 0]
    return arr.astype(np.float32) * np.float32(scale)


def _resize_stack(images: torch.Tensor, size: tuple[int, int], mode: str) -> torch.Tensor:
    """Resize ``[N, H, W, C]`` or ``[N, H, W]`` to ``size`` (height, width)."""
    squeeze = images.ndim == 3
    x = images[..., None] if squeeze else images
    x = x.permute(0, 3, 1, 2)
    dtype = x.dtype
    if mode == "nearest":
        # "nearest-exact" samples pixel centres: the one that keeps instance ids on the same pixel grid
        out = torch.nn.functional.interpolate(x.float(), size=size, mode="nearest-exact").to(dtype)
    else:
        out = torch.nn.functional.interpolate(x, size=size, mode="area")
    out = out.permute(0, 2, 3, 1)
    return out[..., 0] if squeeze else out.contiguous()


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


def load_blender(path: str | os.PathLike, downscale: float = 1, *, background: Sequence[float] | None = None,
                 splits: Sequence[str] | None = None, progress: ProgressFactory = null_progress) -> Dataset:
    """Return a Blender / NeRF-synthetic dataset (``transforms_{train,val,test}.json``).

    Args:
        path: the dataset folder, or one ``transforms_*.json`` file.
        downscale: divide the resolution by this factor (>= 1).
        background: RGB in [0, 1] for transparent pixels; default the file's ``background`` key, else white.
        splits: which splits to read (default all present).
        progress: progress factory.

    Raises:
        DatasetError: malformed JSON, a missing image, images of different sizes, a bad camera.
    """
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"{p}: dataset not found")
    d = _check_downscale(downscale)
    files = _blender_json_files(p, splits)
    metas = [(jp, s, _read_transforms(jp)) for jp, s in files]
    total = sum(len(m["frames"]) for _, _, m in metas)
    if total == 0:
        raise DatasetError(f"{p}: the transforms files list no frames")

    bg_given = background is not None
    bg = _check_background(background if bg_given else
                           next((m["background"] for _, _, m in metas if "background" in m), DEFAULT_BLENDER_BACKGROUND),
                           p)
    rgbs: list[np.ndarray] = []
    alphas: list[np.ndarray | None] = []
    masks: list[np.ndarray | None] = []
    depths: list[np.ndarray | None] = []
    cameras: list[Camera] = []
    split_labels: list[str] = []
    same_size = _SameSize()
    depth_scale: float | None = None
    with progress(total=total, desc="load images") as bar:
        for json_path, split, meta in metas:
            for frame_idx, frame in enumerate(meta["frames"]):
                image_path = _frame_image_path(json_path, frame, frame_idx)
                rgb, alpha = _read_rgb(image_path)
                h, w = rgb.shape[:2]
                same_size(image_path, w, h)
                cam = _blender_camera(json_path, meta, frame, frame_idx, (w, h), image_path.stem)
                mask = None
                if "mask_path" in frame:
                    mask_path = _resolve_file(json_path, str(frame["mask_path"]), f"frame {frame_idx} mask")
                    mask = _read_mask(mask_path)
                    if mask.shape != (h, w):
                        raise DatasetError(f"{mask_path}: mask is {mask.shape[1]}x{mask.shape[0]} but its image "
                                           f"{image_path.name} is {w}x{h}")
                depth = None
                if "depth_path" in frame:
                    depth_path = _resolve_file(json_path, str(frame["depth_path"]), f"frame {frame_idx} depth")
                    scale = float(frame.get("depth_scale", meta.get("depth_scale", 1.0)))
                    depth_scale = scale if depth_scale is None else depth_scale
                    depth = _read_depth(depth_path, scale)
                    if depth.shape != (h, w):
                        raise DatasetError(f"{depth_path}: depth is {depth.shape[1]}x{depth.shape[0]} but its image "
                                           f"{image_path.name} is {w}x{h}")
                rgbs.append(rgb)
                alphas.append(alpha)
                masks.append(mask)
                depths.append(depth)
                cameras.append(cam)
                split_labels.append(split)
                bar.update(1)

    images_t, alpha_t = _composite(rgbs, alphas, bg)
    mask_t = None
    if any(m is not None for m in masks):
        if any(m is None for m in masks):
            missing = next(c.name for c, m in zip(cameras, masks) if m is None)
            raise DatasetError(f"{p}: some frames have a mask_path and others (e.g. {missing}) do not")
        mask_t = torch.from_numpy(np.stack(masks))
    depth_t = None
    if any(x is not None for x in depths):
        if any(x is None for x in depths):
            missing = next(c.name for c, x in zip(cameras, depths) if x is None)
            raise DatasetError(f"{p}: some frames have a depth_path and others (e.g. {missing}) do not")
        depth_t = torch.from_numpy(np.stack(depths))

    bounds_meta = next((m["scene_bounds"] for _, _, m in metas if "scene_bounds" in m), None)
    if bounds_meta is not None:
        bounds = np.asarray(bounds_meta, dtype=np.float64)
        if bounds.shape != (2, 3) or not np.isfinite(bounds).all():
            raise DatasetError(f"{p}: 'scene_bounds' must be [[xmin, ymin, zmin], [xmax, ymax, zmax]]")
    else:
        bounds = estimate_bounds(cameras)

    metadata: dict[str, Any] = {"transforms": [str(jp) for jp, _, _ in metas]}
    if depth_scale is not None:
        metadata["depth_scale"] = depth_scale
    ds = Dataset(images=images_t, cameras=cameras, splits=split_labels, background=bg, bounds=bounds, alphas=alpha_t,
                 masks=mask_t, depths=depth_t, root=p if p.is_dir() else p.parent, format="blender",
                 metadata=metadata)
    return _downscale_dataset(ds, d)


def _composite(rgbs: list[np.ndarray], alphas: list[np.ndarray | None],
               background: Sequence[float]) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Return images ``[N, H, W, 3]`` composited on ``background`` where they had alpha, and the alphas (or None)."""
    images = np.stack(rgbs)
    if not any(a is not None for a in alphas):
        return torch.from_numpy(images.astype(np.float32)), None
    alpha = np.stack([a if a is not None else np.ones(rgbs[0].shape[:2], np.float32) for a in alphas])
    images = images * alpha[..., None] + np.asarray(background, np.float32) * (1.0 - alpha[..., None])
    return torch.from_numpy(images.astype(np.float32)), torch.from_numpy(alpha.astype(np.float32))


def _check_background(bg: Any, where: Path) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in bg)
    except (TypeError, ValueError):
        raise DatasetError(f"{where}: background must be three numbers in [0, 1], got {bg!r}") from None
    if len(vals) != 3 or not all(0.0 <= v <= 1.0 for v in vals):
        raise DatasetError(f"{where}: background must be three numbers in [0, 1], got {bg!r}")
    return vals  # type: ignore[return-value]


def _downscale_dataset(ds: Dataset, downscale: float) -> Dataset:
    if downscale == 1:
        return ds
    w, h = _downscaled_size(ds.width, ds.height, downscale)
    images = _resize_stack(ds.images, (h, w), "area")
    alphas = None if ds.alphas is None else _resize_stack(ds.alphas, (h, w), "area")
    masks = None if ds.masks is None else _resize_stack(ds.masks, (h, w), "nearest")
    depths = None if ds.depths is None else _resize_stack(ds.depths, (h, w), "nearest")
    cameras = [c.with_size(w, h) for c in ds.cameras]
    meta = dict(ds.metadata, downscale=downscale)
    return replace(ds, images=images, alphas=alphas, masks=masks, depths=depths, cameras=cameras, metadata=meta)


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


def write_blender_transforms(path: str | os.PathLike, cameras: Sequence[Camera], file_paths: Sequence[str], *,
                             extra: dict[str, Any] | None = None,
                             frame_extra: Sequence[dict[str, Any]] | None = None) -> Path:
    """Write a ``transforms_*.json`` for ``cameras`` and return its path.

    All cameras must share one image size and intrinsics with square pixels centred principal point for
    ``camera_angle_x`` to describe them exactly; ``fl_x``, ``fl_y``, ``cx``, ``cy``, ``w``, ``h`` are written too.

    Args:
        path: the JSON file to write.
        cameras: the views.
        file_paths: per view, the image path relative to the JSON's folder (extension optional).
        extra: more top-level keys (e.g. ``background``, ``scene_bounds``, ``depth_scale``).
        frame_extra: per view, more frame keys (e.g. ``mask_path``, ``depth_path``).
    """
    if len(cameras) != len(file_paths):
        raise DatasetError(f"{len(cameras)} cameras but {len(file_paths)} file paths")
    if not cameras:
        raise DatasetError("cannot write a transforms file without cameras")
    c0 = cameras[0]
    for c in cameras[1:]:
        if (c.width, c.height) != (c0.width, c0.height) or not np.allclose(c.K, c0.K):
            raise DatasetError(f"camera {c.name!r} differs in size or intrinsics from {c0.name!r}; a transforms file "
                               "holds one set of intrinsics")
    meta: dict[str, Any] = {
        "camera_angle_x": c0.fov_x,
        "fl_x": float(c0.K[0, 0]), "fl_y": float(c0.K[1, 1]),
        "cx": float(c0.K[0, 2]), "cy": float(c0.K[1, 2]),
        "w": c0.width, "h": c0.height,
    }
    if extra:
        meta.update(extra)
    frames = []
    for i, (cam, fp) in enumerate(zip(cameras, file_paths)):
        frame: dict[str, Any] = {"file_path": fp, "transform_matrix": w2c_to_opengl_c2w(cam.world_to_camera).tolist()}
        if frame_extra is not None:
            frame.update(frame_extra[i])
        frames.append(frame)
    meta["frames"] = frames
    return write_json(meta, path)


# -------------------------------------------------------------------------------------------------------- COLMAP

# model id -> (name, number of parameters), as in COLMAP's src/colmap/sensor/models.h
COLMAP_CAMERA_MODELS: dict[int, tuple[str, int]] = {
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
    11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
}
_MODEL_IDS = {name: (mid, n) for mid, (name, n) in COLMAP_CAMERA_MODELS.items()}
SUPPORTED_COLMAP_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")


@dataclass
class ColmapCamera:
    """One COLMAP camera (intrinsics shared by images).

    Attributes:
        id: the camera id.
        model: model name, e.g. ``"PINHOLE"``.
        width: image width.
        height: image height.
        params: ``[P]`` float64 model parameters (PINHOLE: fx, fy, cx, cy; SIMPLE_PINHOLE: f, cx, cy).
    """

    id: int
    model: str
    width: int
    height: int
    params: np.ndarray


@dataclass
class ColmapImage:
    """One registered COLMAP image.

    Attributes:
        id: the image id.
        qvec_wxyz: ``[4]`` world-to-camera rotation quaternion (w, x, y, z).
        tvec: ``[3]`` world-to-camera translation.
        camera_id: id of its :class:`ColmapCamera`.
        name: file name relative to the images folder.
        xys: ``[M, 2]`` float64 2D keypoints.
        point3d_ids: ``[M]`` int64 ids of their 3D points (-1 = none).
    """

    id: int
    qvec_wxyz: np.ndarray
    tvec: np.ndarray
    camera_id: int
    name: str
    xys: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    point3d_ids: np.ndarray = field(default_factory=lambda: np.zeros((0,), dtype=np.int64))

    def world_to_camera(self) -> np.ndarray:
        """Return the ``[4, 4]`` world-to-camera (OpenCV axes) of this image."""
        w2c = np.eye(4)
        w2c[:3, :3] = qvec_to_rotmat(self.qvec_wxyz)
        w2c[:3, 3] = self.tvec
        return w2c


@dataclass
class ColmapPoints:
    """COLMAP's sparse 3D points.

    Attributes:
        ids: ``[P]`` int64 point ids.
        xyz: ``[P, 3]`` float64 positions.
        rgb: ``[P, 3]`` uint8 colours.
        errors: ``[P]`` float64 reprojection errors.
        tracks: P arrays ``[L, 2]`` int64 of (image_id, point2D_idx).
    """

    ids: np.ndarray
    xyz: np.ndarray
    rgb: np.ndarray
    errors: np.ndarray
    tracks: list[np.ndarray] = field(default_factory=list)

    def __post_init__(self) -> None:
        n = len(self.ids)
        self.ids = np.asarray(self.ids, dtype=np.int64).reshape(n)
        self.xyz = np.asarray(self.xyz, dtype=np.float64).reshape(n, 3)
        self.rgb = np.asarray(self.rgb, dtype=np.uint8).reshape(n, 3)
        self.errors = np.asarray(self.errors, dtype=np.float64).reshape(n)
        if not self.tracks:
            self.tracks = [np.zeros((0, 2), dtype=np.int64) for _ in range(n)]
        if len(self.tracks) != n:
            raise DatasetError(f"COLMAP points: {n} points but {len(self.tracks)} tracks")

    @staticmethod
    def empty() -> "ColmapPoints":
        """Return an empty point set."""
        return ColmapPoints(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0))


@dataclass
class ColmapModel:
    """A COLMAP sparse model: cameras and images by id, and the 3D points."""

    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    points: ColmapPoints


def qvec_to_rotmat(qvec: np.ndarray) -> np.ndarray:
    """Return the ``[3, 3]`` rotation of a quaternion (w, x, y, z), normalised first."""
    q = np.asarray(qvec, dtype=np.float64)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n == 0:
        raise DatasetError(f"quaternion {q.tolist()} has zero or non-finite norm")
    w, x, y, z = q / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rotmat_to_qvec(R: np.ndarray) -> np.ndarray:
    """Return the unit quaternion (w, x, y, z), w >= 0, of a ``[3, 3]`` rotation matrix."""
    R = np.asarray(R, dtype=np.float64)
    # symmetric 4x4 whose top eigenvector is the quaternion (Bar-Itzhack); robust for every rotation
    Rxx, Ryx, Rzx, Rxy, Ryy, Rzy, Rxz, Ryz, Rzz = R.flat
    Kmat = np.array([
        [Rxx - Ryy - Rzz, 0, 0, 0],
        [Ryx + Rxy, Ryy - Rxx - Rzz, 0, 0],
        [Rzx + Rxz, Rzy + Ryz, Rzz - Rxx - Ryy, 0],
        [Ryz - Rzy, Rzx - Rxz, Rxy - Ryx, Rxx + Ryy + Rzz],
    ]) / 3.0
    vals, vecs = np.linalg.eigh(Kmat)
    q = vecs[[3, 0, 1, 2], np.argmax(vals)]
    if q[0] < 0:
        q = -q
    return q


def _is_colmap_model_dir(p: Path) -> bool:
    return all((p / f"{n}.bin").is_file() for n in ("cameras", "images")) or \
        all((p / f"{n}.txt").is_file() for n in ("cameras", "images"))


def _find_colmap_sparse(root: Path) -> Path | None:
    for cand in (root / "sparse" / "0", root / "sparse", root):
        if cand.is_dir() and _is_colmap_model_dir(cand):
            return cand
    return None


class _Reader:
    """Little-endian binary reader that names the file and offset when the data ends early."""

    def __init__(self, data: bytes, path: Path) -> None:
        self.data, self.path, self.pos = data, path, 0

    def read(self, fmt: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise DatasetError(f"{self.path}: file ends early at byte {self.pos} (truncated or not a COLMAP binary)")
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def array(self, dtype: str, count: int) -> np.ndarray:
        dt = np.dtype(dtype).newbyteorder("<")
        size = dt.itemsize * count
        if count < 0 or self.pos + size > len(self.data):
            raise DatasetError(f"{self.path}: file ends early at byte {self.pos} (truncated or not a COLMAP binary)")
        out = np.frombuffer(self.data, dtype=dt, count=count, offset=self.pos).copy()
        self.pos += size
        return out

    def cstring(self) -> str:
        end = self.data.find(b"\x00", self.pos)
        if end < 0:
            raise DatasetError(f"{self.path}: unterminated image name at byte {self.pos}")
        s = self.data[self.pos:end].decode("utf-8", errors="replace")
        self.pos = end + 1
        return s


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise DatasetError(f"{path}: not found") from None
    except OSError as exc:
        raise DatasetError(f"{path}: cannot read ({exc.strerror})") from None


def _read_text_lines(path: Path) -> list[tuple[int, str]]:
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise DatasetError(f"{path}: not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{path}: cannot read ({exc})") from None
    return [(i + 1, line.strip()) for i, line in enumerate(text.splitlines()) if not line.lstrip().startswith("#")]


def _check_model(model: str, n_params: int, where: str) -> None:
    if model not in _MODEL_IDS:
        raise DatasetError(f"{where}: unknown COLMAP camera model {model!r}")
    expected = _MODEL_IDS[model][1]
    if n_params != expected:
        raise DatasetError(f"{where}: camera model {model} takes {expected} parameters, got {n_params}")


def _read_cameras_bin(path: Path) -> dict[int, ColmapCamera]:
    r = _Reader(_read_bytes(path), path)
    (n,) = r.read("Q")
    cams = {}
    for _ in range(n):
        cam_id, model_id, width, height = r.read("iiQQ")
        if model_id not in COLMAP_CAMERA_MODELS:
            raise DatasetError(f"{path}: camera {cam_id} has unknown COLMAP camera model id {model_id}")
        name, n_params = COLMAP_CAMERA_MODELS[model_id]
        params = r.array("f8", n_params)
        cams[cam_id] = ColmapCamera(cam_id, name, int(width), int(height), params)
    return cams


def _read_cameras_txt(path: Path) -> dict[int, ColmapCamera]:
    cams = {}
    for lineno, line in _read_text_lines(path):
        if not line:
            continue
        parts = line.split()
        where = f"{path}: line {lineno}"
        if len(parts) < 4:
            raise DatasetError(f"{where}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...', got {line!r}")
        try:
            cam_id, model, width, height = int(parts[0]), parts[1], int(parts[2]), int(parts[3])
            params = np.array([float(v) for v in parts[4:]])
        except ValueError:
            raise DatasetError(f"{where}: expected numbers in {line!r}") from None
        _check_model(model, len(params), where)
        cams[cam_id] = ColmapCamera(cam_id, model, width, height, params)
    return cams


def _read_images_bin(path: Path) -> dict[int, ColmapImage]:
    r = _Reader(_read_bytes(path), path)
    (n,) = r.read("Q")
    images = {}
    for _ in range(n):
        image_id, qw, qx, qy, qz, tx, ty, tz, cam_id = r.read("idddddddi")
        name = r.cstring()
        (n2d,) = r.read("Q")
        rec = r.array("u1", n2d * 24).view(np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")]))
        images[image_id] = ColmapImage(image_id, np.array([qw, qx, qy, qz]), np.array([tx, ty, tz]), cam_id, name,
                                       np.stack([rec["x"], rec["y"]], axis=1).astype(np.float64),
                                       rec["id"].astype(np.int64))
    return images


def _read_images_txt(path: Path) -> dict[int, ColmapImage]:
    # images.txt has two lines per image; the second (keypoints) may be empty, so empty lines are not skipped
    lines = _read_text_lines(path)
    while lines and not lines[-1][1]:
        lines.pop()
    images = {}
    i = 0
    while i < len(lines):
        lineno, line = lines[i]
        if not line and (i + 1 >= len(lines) or not lines[i + 1][1]):
            i += 1
            continue
        parts = line.split()
        where = f"{path}: line {lineno}"
        if len(parts) < 10:
            raise DatasetError(f"{where}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME', got {line!r}")
        try:
            image_id = int(parts[0])
            q = np.array([float(v) for v in parts[1:5]])
            t = np.array([float(v) for v in parts[5:8]])
            cam_id = int(parts[8])
        except ValueError:
            raise DatasetError(f"{where}: expected numbers in {line!r}") from None
        name = " ".join(parts[9:])
        pts_line = lines[i + 1][1] if i + 1 < len(lines) else ""
        vals = pts_line.split()
        if len(vals) % 3:
            raise DatasetError(f"{path}: line {lineno + 1}: keypoints must come in (X, Y, POINT3D_ID) triples")
        try:
            arr = np.array([float(v) for v in vals]).reshape(-1, 3)
        except ValueError:
            raise DatasetError(f"{path}: line {lineno + 1}: expected numbers in the keypoint line") from None
        images[image_id] = ColmapImage(image_id, q, t, cam_id, name, arr[:, :2].copy(), arr[:, 2].astype(np.int64))
        i += 2
    return images


def _read_points_bin(path: Path) -> ColmapPoints:
    r = _Reader(_read_bytes(path), path)
    (n,) = r.read("Q")
    ids = np.zeros(n, np.int64)
    xyz = np.zeros((n, 3))
    rgb = np.zeros((n, 3), np.uint8)
    err = np.zeros(n)
    tracks = []
    for k in range(n):
        pid, x, y, z, cr, cg, cb, e, tl = r.read("QdddBBBdQ")
        ids[k], xyz[k], rgb[k], err[k] = pid, (x, y, z), (cr, cg, cb), e
        tracks.append(r.array("i4", 2 * tl).reshape(-1, 2).astype(np.int64))
    return ColmapPoints(ids, xyz, rgb, err, tracks)


def _read_points_txt(path: Path) -> ColmapPoints:
    ids, xyz, rgb, err, tracks = [], [], [], [], []
    for lineno, line in _read_text_lines(path):
        if not line:
            continue
        parts = line.split()
        if len(parts) < 8 or (len(parts) - 8) % 2:
            raise DatasetError(f"{path}: line {lineno}: expected 'POINT3D_ID X Y Z R G B ERROR TRACK...', got "
                               f"{line[:80]!r}")
        try:
            ids.append(int(parts[0]))
            xyz.append([float(v) for v in parts[1:4]])
            rgb.append([int(v) for v in parts[4:7]])
            err.append(float(parts[7]))
            tracks.append(np.array([int(v) for v in parts[8:]], dtype=np.int64).reshape(-1, 2))
        except ValueError:
            raise DatasetError(f"{path}: line {lineno}: expected numbers in {line[:80]!r}") from None
    if not ids:
        return ColmapPoints.empty()
    return ColmapPoints(np.array(ids), np.array(xyz), np.array(rgb), np.array(err), tracks)


def read_colmap_model(path: str | os.PathLike) -> ColmapModel:
    """Return the COLMAP model in a folder (``.bin`` files preferred over ``.txt``; ``points3D`` optional).

    Raises:
        DatasetError: files missing, truncated or malformed, or an unknown camera model.
    """
    p = Path(path)
    if (p / "cameras.bin").is_file() and (p / "images.bin").is_file():
        cams = _read_cameras_bin(p / "cameras.bin")
        images = _read_images_bin(p / "images.bin")
        pts = _read_points_bin(p / "points3D.bin") if (p / "points3D.bin").is_file() else ColmapPoints.empty()
    elif (p / "cameras.txt").is_file() and (p / "images.txt").is_file():
        cams = _read_cameras_txt(p / "cameras.txt")
        images = _read_images_txt(p / "images.txt")
        pts = _read_points_txt(p / "points3D.txt") if (p / "points3D.txt").is_file() else ColmapPoints.empty()
    else:
        raise DatasetError(f"{p}: no COLMAP model: expected cameras.bin and images.bin, or cameras.txt and images.txt")
    for img in images.values():
        if img.camera_id not in cams:
            raise DatasetError(f"{p}: image {img.name!r} refers to camera {img.camera_id}, which is not in the model")
    return ColmapModel(cams, images, pts)


def write_colmap_model(model: ColmapModel, path: str | os.PathLike, *, binary: bool = True) -> Path:
    """Write a COLMAP model (``cameras``, ``images``, ``points3D``) as ``.bin`` or ``.txt`` and return the folder.

    Args:
        model: the model to write.
        path: an existing folder, e.g. ``scene/sparse/0``.
        binary: write the binary format (else the text format).
    """
    p = Path(path)
    if not p.is_dir():
        raise DatasetError(f"{p}: folder does not exist; create it before writing a COLMAP model")
    for cam in model.cameras.values():
        _check_model(cam.model, len(cam.params), f"camera {cam.id}")
    if binary:
        _write_bin(p / "cameras.bin", lambda f: _cameras_bin(model, f))
        _write_bin(p / "images.bin", lambda f: _images_bin(model, f))
        _write_bin(p / "points3D.bin", lambda f: _points_bin(model, f))
    else:
        _write_text(p / "cameras.txt", _cameras_txt(model))
        _write_text(p / "images.txt", _images_txt(model))
        _write_text(p / "points3D.txt", _points_txt(model))
    return p


def _write_bin(path: Path, fill: Any) -> None:
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        fill(f)


def _write_text(path: Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def _cameras_bin(model: ColmapModel, f: BinaryIO) -> None:
    f.write(struct.pack("<Q", len(model.cameras)))
    for cam in model.cameras.values():
        f.write(struct.pack("<iiQQ", cam.id, _MODEL_IDS[cam.model][0], cam.width, cam.height))
        f.write(np.asarray(cam.params, dtype="<f8").tobytes())


def _images_bin(model: ColmapModel, f: BinaryIO) -> None:
    f.write(struct.pack("<Q", len(model.images)))
    for img in model.images.values():
        f.write(struct.pack("<idddddddi", img.id, *np.asarray(img.qvec_wxyz, float), *np.asarray(img.tvec, float),
                            img.camera_id))
        f.write(img.name.encode("utf-8") + b"\x00")
        rec = np.zeros(len(img.xys), dtype=np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")]))
        if len(img.xys):
            rec["x"], rec["y"], rec["id"] = img.xys[:, 0], img.xys[:, 1], img.point3d_ids
        f.write(struct.pack("<Q", len(rec)))
        f.write(rec.tobytes())


def _points_bin(model: ColmapModel, f: BinaryIO) -> None:
    pts = model.points
    f.write(struct.pack("<Q", len(pts.ids)))
    for k in range(len(pts.ids)):
        tr = np.asarray(pts.tracks[k], dtype="<i4").reshape(-1, 2)
        f.write(struct.pack("<QdddBBBdQ", int(pts.ids[k]), *pts.xyz[k], *(int(c) for c in pts.rgb[k]),
                            float(pts.errors[k]), len(tr)))
        f.write(tr.tobytes())


def _cameras_txt(model: ColmapModel) -> str:
    lines = ["# Camera list with one line of data per camera:",
             "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
             f"# Number of cameras: {len(model.cameras)}"]
    for cam in model.cameras.values():
        lines.append(" ".join([str(cam.id), cam.model, str(cam.width), str(cam.height)]
                              + [repr(float(v)) for v in cam.params]))
    return "\n".join(lines) + "\n"


def _images_txt(model: ColmapModel) -> str:
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)",
             f"# Number of images: {len(model.images)}"]
    for img in model.images.values():
        lines.append(" ".join([str(img.id)] + [repr(float(v)) for v in img.qvec_wxyz]
                              + [repr(float(v)) for v in img.tvec] + [str(img.camera_id), img.name]))
        lines.append(" ".join(f"{float(x)!r} {float(y)!r} {int(i)}" for (x, y), i in zip(img.xys, img.point3d_ids)))
    return "\n".join(lines) + "\n"


def _points_txt(model: ColmapModel) -> str:
    pts = model.points
    lines = ["# 3D point list with one line of data per point:",
             "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
             f"# Number of points: {len(pts.ids)}"]
    for k in range(len(pts.ids)):
        track = " ".join(f"{int(a)} {int(b)}" for a, b in np.asarray(pts.tracks[k]).reshape(-1, 2))
        lines.append(" ".join([str(int(pts.ids[k]))] + [repr(float(v)) for v in pts.xyz[k]]
                              + [str(int(c)) for c in pts.rgb[k]] + [repr(float(pts.errors[k]))]) +
                     (" " + track if track else ""))
    return "\n".join(lines) + "\n"


def _colmap_intrinsics(cam: ColmapCamera, where: str) -> np.ndarray:
    if cam.model not in SUPPORTED_COLMAP_MODELS:
        raise DatasetError(f"{where}: camera {cam.id} uses the COLMAP camera model {cam.model}, which is not supported "
                           f"(supported: {', '.join(SUPPORTED_COLMAP_MODELS)}); undistort the images first, e.g. "
                           "`colmap image_undistorter`")
    if cam.model == "SIMPLE_PINHOLE":
        f, cx, cy = cam.params
        fx = fy = f
    else:
        fx, fy, cx, cy = cam.params
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _colmap_cameras(model: ColmapModel, where: str = "COLMAP model") -> list[tuple[Camera, ColmapImage]]:
    """Return (camera, image) pairs sorted by image name (the order 3DGS uses for its split)."""
    out = []
    for img in sorted(model.images.values(), key=lambda im: im.name):
        cam = model.cameras[img.camera_id]
        K = _colmap_intrinsics(cam, where)
        try:
            camera = Camera(img.world_to_camera(), K, cam.width, cam.height, name=Path(img.name).stem)
        except RoodiError as exc:
            raise DatasetError(f"{where}: image {img.name!r}: {exc}") from None
        out.append((camera, img))
    return out


def load_colmap(path: str | os.PathLike, downscale: float = 1, *, background: Sequence[float] | None = None,
                test_every: int = LLFF_HOLD, images_dir: str = "images",
                progress: ProgressFactory = null_progress) -> Dataset:
    """Return a COLMAP dataset: ``sparse/0`` model (binary or text) and the images in ``images/``.

    Args:
        path: the dataset folder (holding ``sparse/0`` or ``sparse``, and ``images``).
        downscale: divide the resolution by this factor (>= 1).
        background: RGB in [0, 1] for transparent pixels (default black).
        test_every: every ``test_every``-th image in name order (index % test_every == 0) is a test view, as 3DGS's
            ``llffhold``; 0 makes every image a training view.
        images_dir: the images folder, relative to ``path``.
        progress: progress factory.

    Raises:
        DatasetError: missing model or images, malformed files, unsupported camera model, inconsistent sizes.
    """
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: dataset folder not found")
    if int(test_every) < 0:
        raise DatasetError(f"test_every must be >= 0, got {test_every}")
    d = _check_downscale(downscale)
    sparse = _find_colmap_sparse(root)
    if sparse is None:
        raise DatasetError(f"{root}: no COLMAP model found in sparse/0 or sparse (cameras.bin/.txt, images.bin/.txt)")
    model = read_colmap_model(sparse)
    if not model.images:
        raise DatasetError(f"{sparse}: the COLMAP model has no registered images")
    pairs = _colmap_cameras(model, str(sparse))
    bg = _check_background(background if background is not None else DEFAULT_COLMAP_BACKGROUND, root)
    img_root = root / images_dir
    if not img_root.is_dir():
        raise DatasetError(f"{root}: images folder {images_dir!r} not found")
    rgbs, alphas, cameras = [], [], []
    same_size = _SameSize()
    with progress(total=len(pairs), desc="load images") as bar:
        for cam, img in pairs:
            image_path = img_root / img.name
            if not image_path.is_file():
                raise DatasetError(f"{image_path}: image of COLMAP image {img.id} ({img.name!r}) not found")
            rgb, alpha = _read_rgb(image_path)
            h, w = rgb.shape[:2]
            same_size(image_path, w, h)
            if (w, h) != (cam.width, cam.height):
                # images already resized on disk (e.g. the images_2 folders of 3DGS): scale the intrinsics
                cam = cam.with_size(w, h)
            rgbs.append(rgb)
            alphas.append(alpha)
            cameras.append(cam)
            bar.update(1)
    images_t, alpha_t = _composite(rgbs, alphas, bg)
    hold = int(test_every)
    splits = ["test" if hold > 0 and i % hold == 0 else "train" for i in range(len(cameras))]
    points = model.points.xyz if len(model.points.ids) else None
    colors = model.points.rgb if len(model.points.ids) else None
    bounds = estimate_bounds(cameras, points)
    ds = Dataset(images=images_t, cameras=cameras, splits=splits, background=bg,
                 bounds=bounds, alphas=alpha_t, points=points, point_colors=colors, root=root, format="colmap",
                 metadata={"sparse": str(sparse), "camera_models": sorted({c.model for c in model.cameras.values()})})
    return _downscale_dataset(ds, d)


def colmap_model_from_cameras(cameras: Sequence[Camera], image_names: Sequence[str],
                              points: ColmapPoints | None = None, *, model: str = "PINHOLE") -> ColmapModel:
    """Return a COLMAP model of ``cameras`` (one COLMAP camera per distinct intrinsics), e.g. to export a dataset.

    Args:
        cameras: the views.
        image_names: per view, the file name in the images folder.
        points: sparse points (default none).
        model: ``"PINHOLE"`` or ``"SIMPLE_PINHOLE"`` (the latter needs fx == fy).
    """
    if len(cameras) != len(image_names):
        raise DatasetError(f"{len(cameras)} cameras but {len(image_names)} image names")
    if model not in SUPPORTED_COLMAP_MODELS:
        raise DatasetError(f"cannot write COLMAP camera model {model}; use one of {list(SUPPORTED_COLMAP_MODELS)}")
    cams: dict[int, ColmapCamera] = {}
    keys: dict[tuple, int] = {}
    images: dict[int, ColmapImage] = {}
    for i, (cam, name) in enumerate(zip(cameras, image_names)):
        fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
        if model == "SIMPLE_PINHOLE":
            if not math.isclose(fx, fy, rel_tol=1e-9):
                raise DatasetError(f"camera {cam.name!r}: fx != fy, cannot be a SIMPLE_PINHOLE camera; use PINHOLE")
            params = np.array([fx, cx, cy])
        else:
            params = np.array([fx, fy, cx, cy])
        key = (cam.width, cam.height, *params.tolist())
        if key not in keys:
            keys[key] = len(keys) + 1
            cams[keys[key]] = ColmapCamera(keys[key], model, cam.width, cam.height, params)
        w2c = cam.world_to_camera
        images[i + 1] = ColmapImage(i + 1, rotmat_to_qvec(w2c[:3, :3]), w2c[:3, 3].copy(), keys[key], name)
    return ColmapModel(cams, images, points if points is not None else ColmapPoints.empty())

