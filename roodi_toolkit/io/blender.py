"""Blender / NeRF-synthetic datasets: the ``transforms_{train,val,test}.json`` reader and writer.

``camera_angle_x`` and ``frames[]`` holding ``file_path`` (extension optional, ``.png`` tried) and
``transform_matrix`` (camera-to-world, OpenGL axes). RGBA images are composited on the background colour. Optional
keys written by :mod:`roodi_toolkit.synth.scene` and read here: ``w``/``h``, ``fl_x``/``fl_y``/``cx``/``cy``,
per-frame ``mask_path`` (8-bit instance ids, 0 = background) and ``depth_path`` (16-bit PNG times ``depth_scale`` =
z-depth), top-level ``background`` and ``scene_bounds``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from ..cameras import Camera, opengl_c2w_to_w2c, w2c_to_opengl_c2w
from ..errors import DatasetError, RoodiError
from ..progress import ProgressFactory, null_progress
from .dataset_core import (SPLITS, Dataset, _check_background, _check_downscale, _crop_camera, _downscaled_size,
                           _plan_crop, _read_frames_json, _source_pixels, estimate_bounds)
from .files import write_json
from .photos import _image_size, _read_depth, _read_mask, _ViewStack

__all__ = ["DEFAULT_BLENDER_BACKGROUND", "load_blender", "load_blender_cameras", "write_blender_transforms"]

DEFAULT_BLENDER_BACKGROUND = (1.0, 1.0, 1.0)  # NeRF-synthetic convention (white_background)



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
    meta = _read_frames_json(json_path, "Blender transforms file", "camera_angle_x and frames")
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
        near = float(meta.get("near", 0.01))
        far = float(meta.get("far", 1e10))
    except KeyError:
        raise DatasetError(f"{json_path}: no intrinsics: give camera_angle_x or fl_x") from None
    except (TypeError, ValueError, ZeroDivisionError, OverflowError):  # None, "x", w = 0, w = inf
        raise DatasetError(f"{json_path}: intrinsics (camera_angle_x, fl_x, fl_y, cx, cy, w, h, near, far) must be "
                           "finite numbers, w and h positive") from None
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    try:
        return Camera(opengl_c2w_to_w2c(c2w), K, width, height, near=near, far=far, name=name)
    except RoodiError as exc:
        raise DatasetError(f"{json_path}: frame {frame_idx}: {exc}") from None


def load_blender_cameras(path: Path, splits: Sequence[str] | None = None) -> list[Camera]:
    """Return the cameras of a Blender dataset (folder or ``transforms_*.json``) without reading its images."""
    cams: list[Camera] = []
    for json_path, split in _blender_json_files(path, splits):
        meta = _read_transforms(json_path)
        size = _stated_size(json_path, meta)
        for frame_idx, frame in enumerate(meta["frames"]):
            if size is not None:
                # the file states the size (nerfstudio's and our w/h keys): the images need not exist
                if not isinstance(frame, dict) or "file_path" not in frame:
                    raise DatasetError(f"{json_path}: frame {frame_idx} has no 'file_path'")
                name = Path(str(frame["file_path"])).stem
                cams.append(_blender_camera(json_path, meta, frame, frame_idx, size, name))
            else:
                image_path = _frame_image_path(json_path, frame, frame_idx)
                cams.append(_blender_camera(json_path, meta, frame, frame_idx, _image_size(image_path),
                                            image_path.stem))
    return cams


def _stated_size(json_path: Path, meta: dict[str, Any]) -> tuple[int, int] | None:
    """Return the (width, height) a transforms file states with its ``w`` and ``h`` keys, or None."""
    if "w" not in meta or "h" not in meta:
        return None
    try:
        w, h = int(meta["w"]), int(meta["h"])
    except (TypeError, ValueError, OverflowError):
        raise DatasetError(f"{json_path}: 'w' and 'h' must be whole numbers, got {meta['w']!r} and {meta['h']!r}") \
            from None
    if w <= 0 or h <= 0:
        raise DatasetError(f"{json_path}: 'w' and 'h' must be positive, got {w} and {h}")
    return w, h


def _stack_all_or_none(values: list, cameras: Sequence[Camera], where: Path, key: str) -> "torch.Tensor | None":
    """Return the per-frame maps stacked ``[N, H, W]``, None when no frame has them; refuse a dataset where only
    some frames name ``key``."""
    if all(v is None for v in values):
        return None
    if any(v is None for v in values):
        missing = next(c.name for c, v in zip(cameras, values) if v is None)
        raise DatasetError(f"{where}: some frames have a {key} and others (e.g. {missing}) do not")
    return torch.stack(values)


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
        DatasetError: malformed JSON, a missing image, image sizes differing by more than 10% (smaller differences
            are cropped away, centred, as :func:`~roodi_toolkit.io.colmap.load_colmap` does), a bad camera.
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
    frames = [(json_path, split, meta, frame_idx, frame, _frame_image_path(json_path, frame, frame_idx))
              for json_path, split, meta in metas for frame_idx, frame in enumerate(meta["frames"])]
    # sizes from the file headers first, so each image can be decoded straight to its final (cropped, reduced) size
    sizes = [_image_size(f[5]) for f in frames]
    crop = _plan_crop([f[5] for f in frames], sizes)
    out_w, out_h = _downscaled_size(crop.width, crop.height, d)
    stack = _ViewStack(crop, (out_w, out_h), bg)
    cameras: list[Camera] = []
    split_labels: list[str] = []
    depth_scale: float | None = None
    with progress(total=total, desc="load images") as bar:
        for i, (json_path, split, meta, frame_idx, frame, image_path) in enumerate(frames):
            w, h = sizes[i]
            cam = _blender_camera(json_path, meta, frame, frame_idx, (w, h), image_path.stem)
            cam = _crop_camera(cam, crop.offsets[i], crop.width, crop.height)
            if (out_w, out_h) != (crop.width, crop.height):
                cam = cam.with_size(out_w, out_h)
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
            stack.add(image_path, i, mask, depth)
            cameras.append(cam)
            split_labels.append(split)
            bar.update(1)

    images_t, alpha_t = stack.images()
    masks, depths = stack.masks, stack.depths
    mask_t = _stack_all_or_none(masks, cameras, p, "mask_path")
    depth_t = _stack_all_or_none(depths, cameras, p, "depth_path")

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
    if d != 1:
        metadata["downscale"] = d
    if crop.cropped:
        metadata["crop"] = crop.record([c.name for c in cameras])
    metadata["source_pixels"] = _source_pixels([c.name for c in cameras], sizes, sizes, crop, (out_w, out_h))
    return Dataset(images=images_t, cameras=cameras, splits=split_labels, background=bg, bounds=bounds, alphas=alpha_t,
                 masks=mask_t, depths=depth_t, root=p if p.is_dir() else p.parent, format="blender",
                 metadata=metadata)


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
