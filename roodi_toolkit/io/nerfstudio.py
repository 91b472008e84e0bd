"""nerfstudio and instant-ngp captures: one ``transforms.json`` beside the images.

``ns-process-data`` writes this file (and so do the Polycam, Record3D, KIRI and Metashape exports that go through
it), and instant-ngp's captures look alike. It is read as nerfstudio's own data parser reads it
(``nerfstudio/data/dataparsers/nerfstudio_dataparser.py``):

- ``frames[]``, each with ``file_path`` (relative to the file's folder, extension optional) and
  ``transform_matrix``: camera-to-world in OpenGL axes, used as given (the Inria code reads it the same way);
- intrinsics ``fl_x fl_y cx cy w h`` at the top level or in each frame (a frame's own win); ``camera_angle_x`` (and
  ``camera_angle_y``) when there is no ``fl_x``; ``w h`` from the image when absent;
- ``camera_model`` ``PINHOLE``/``SIMPLE_PINHOLE``/``OPENCV`` (``k1 k2 k3 p1 p2``, or ``distortion_params``) and
  ``OPENCV_FISHEYE`` (``k1``-``k4``; instant-ngp's ``is_fisheye``), at either level: distorted photos are undistorted on
  loading onto a pinhole camera of the same size that sees no border (OpenCV's ``alpha=0`` / ``balance=0``), as
  :mod:`roodi_toolkit.io.colmap` does for COLMAP's distorted models. Without ``camera_model`` a camera with
  distortion coefficients is ``OPENCV``, as nerfstudio takes it;
- ``mask_path`` per frame: pixels where the mask is 0 are ignored by training (:attr:`Dataset.valid`), nerfstudio's
  meaning (not instance ids, unlike a Blender ``mask_path``);
- ``ply_file_path``: the SfM points (x, y, z and colours if any) for initialisation, in the file's frame;
- ``train_filenames`` / ``val_filenames`` / ``test_filenames``: the split (val and test views are held out);
  without them every 8th frame in name order is held out, and a warning says so;
- ``applied_transform`` (what ``ns-process-data`` turned the COLMAP world by) kept in ``metadata``; for an older
  capture without it but with ``colmap/sparse/0``, nerfstudio's value for those;
- ``images_2``/``_4``/``_8`` (and ``masks_N``): the reduced copies nerfstudio reads for ``downscale`` 2, 4 or 8.

Frames whose image is missing are left out with one warning that counts them (at least 3 must remain). Frames are
ordered by file name (nerfstudio's order). instant-ngp's extra keys (``aabb_scale``, ``sharpness``, ``scale``,
``offset``) are ignored: the poses are used as given.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np
import torch
from plyfile import PlyData

from ..cameras import Camera, opengl_c2w_to_w2c
from ..errors import DatasetError, InputWarning, RoodiError
from ..progress import ProgressFactory, null_progress
from ..similarity import Similarity
from .dataset_core import (LLFF_HOLD, SPLITS, Dataset, _check_background, _check_downscale, _crop_camera,
                           _downscaled_size, _plan_crop, _read_frames_json, _source_pixels, estimate_bounds)
from .photos import _image_size, _read_dataset_image, _ViewStack

__all__ = ["NERFSTUDIO_FILE", "NERFSTUDIO_CAMERA_MODELS", "is_nerfstudio_file", "load_nerfstudio",
           "load_nerfstudio_cameras"]

NERFSTUDIO_FILE = "transforms.json"
NERFSTUDIO_CAMERA_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "OPENCV", "OPENCV_FISHEYE")
DEFAULT_NERFSTUDIO_BACKGROUND = (0.0, 0.0, 0.0)  # real captures, as COLMAP
MIN_FRAMES = 3
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG")
OLD_COLMAP_APPLIED_TRANSFORM = [[0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0]]
"""What nerfstudio takes ``applied_transform`` to be for a capture written before the key existed that still has its
``colmap/sparse/0`` (its data parser's own fallback)."""

_INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y")
_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


def is_nerfstudio_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` names a nerfstudio / instant-ngp transforms file: a ``.json`` not named like a Blender split
    (``transforms_train.json`` ...), or a folder holding ``transforms.json``."""
    p = Path(path)
    if p.is_dir():
        return (p / NERFSTUDIO_FILE).is_file()
    return p.suffix.lower() == ".json" and not p.name.lower().startswith("transforms_")


def _json_path(path: Path) -> Path:
    if path.is_dir():
        jp = path / NERFSTUDIO_FILE
        if not jp.is_file():
            raise DatasetError(f"{path}: no {NERFSTUDIO_FILE} in the folder")
        return jp
    if not path.exists():
        raise DatasetError(f"{path}: dataset not found")
    return path


def _read_meta(json_path: Path) -> dict[str, Any]:
    return _read_frames_json(json_path, "transforms file", "a 'frames' list")


@dataclass
class _Frame:
    """One listed frame, resolved: its image, pose, stated size and lens."""

    index: int  # position in the file's frames list
    name: str  # the view's name: the image file's stem
    image: Path
    c2w: np.ndarray  # [4, 4] OpenGL camera-to-world
    size: tuple[int, int] | None  # (w, h) the file states, else None (read from the image)
    keys: dict[str, float]  # the intrinsic keys given (frame's own over the file's)
    model: str  # one of NERFSTUDIO_CAMERA_MODELS
    dist: np.ndarray  # OpenCV coefficients: [k1, k2, p1, p2, k3], or fisheye [k1, k2, k3, k4]
    mask: Path | None


def _number(json_path: Path, where: str, key: str, value: Any) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError, OverflowError):
        raise DatasetError(f"{json_path}: {where}: '{key}' must be a number, got {value!r}") from None
    if not math.isfinite(out):
        raise DatasetError(f"{json_path}: {where}: '{key}' must be a finite number, got {value!r}")
    return out


def _lens(json_path: Path, meta: dict[str, Any], frame: dict[str, Any], where: str) -> tuple[str, np.ndarray]:
    """Return the frame's camera model and its OpenCV distortion coefficients."""
    model = frame.get("camera_model", meta.get("camera_model"))
    fisheye = bool(frame.get("is_fisheye", meta.get("is_fisheye", False)))  # instant-ngp
    src = frame if any(k in frame for k in (*_DISTORTION_KEYS, "distortion_params")) else meta
    if "distortion_params" in src:
        params = src["distortion_params"]
        if not isinstance(params, list) or len(params) != 6:
            raise DatasetError(f"{json_path}: {where}: 'distortion_params' must be six numbers (k1 k2 k3 k4 p1 p2), "
                               f"got {params!r}")
        k = dict(zip(_DISTORTION_KEYS, (_number(json_path, where, "distortion_params", v) for v in params)))
    else:
        k = {name: _number(json_path, where, name, src[name]) if name in src else 0.0 for name in _DISTORTION_KEYS}
    if model is None:
        model = "OPENCV_FISHEYE" if fisheye else ("OPENCV" if any(k.values()) else "PINHOLE")
    if not isinstance(model, str) or model.upper() not in NERFSTUDIO_CAMERA_MODELS:
        raise DatasetError(f"{json_path}: {where}: 'camera_model' {model!r} is not supported (use one of "
                           f"{', '.join(NERFSTUDIO_CAMERA_MODELS)}); convert the images to one of them first")
    model = model.upper()
    if model == "OPENCV_FISHEYE":
        return model, np.array([k["k1"], k["k2"], k["k3"], k["k4"]])
    if k["k4"] != 0:
        raise DatasetError(f"{json_path}: {where}: 'k4' is {k['k4']:g}, but the {model} camera model has no k4 "
                           "(only k1 k2 k3 p1 p2; nerfstudio refuses it too)")
    return model, np.array([k["k1"], k["k2"], k["p1"], k["p2"], k["k3"]])


def _find_image(json_dir: Path, rel: str) -> Path | None:
    base = json_dir / rel
    candidates = [base]
    if base.suffix.lower() not in (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff", ".webp", ".bmp"):
        candidates += [base.with_name(base.name + ext) for ext in IMAGE_EXTENSIONS]
    return next((c for c in candidates if c.is_file()), None)


def _parse_frames(json_path: Path, meta: dict[str, Any]) -> tuple[list[_Frame], list[str]]:
    """Return the frames whose images exist, sorted by image file name, and the listed images that are missing."""
    json_dir = json_path.parent
    frames: list[_Frame] = []
    missing: list[str] = []
    for idx, frame in enumerate(meta["frames"]):
        where = f"frame {idx}"
        if not isinstance(frame, dict):
            raise DatasetError(f"{json_path}: {where} is not a JSON object")
        if not isinstance(frame.get("file_path"), str) or not frame["file_path"].strip():
            raise DatasetError(f"{json_path}: {where} has no 'file_path'")
        rel = frame["file_path"]
        if "transform_matrix" not in frame:
            raise DatasetError(f"{json_path}: {where} ({rel}) has no 'transform_matrix'")
        try:
            c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise DatasetError(f"{json_path}: {where} ({rel}): 'transform_matrix' is not a matrix of numbers") from None
        if c2w.shape not in ((4, 4), (3, 4)) or not np.isfinite(c2w).all():
            raise DatasetError(f"{json_path}: {where} ({rel}): 'transform_matrix' must be a finite 4x4 (or 3x4) "
                               f"matrix, got shape {list(c2w.shape)}")
        if c2w.shape == (3, 4):
            c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
        keys = {}
        for key in _INTRINSIC_KEYS:
            if key in frame or key in meta:
                keys[key] = _number(json_path, where, key, frame.get(key, meta.get(key)))
        size = None
        if "w" in keys and "h" in keys:
            w, h = keys["w"], keys["h"]
            if w != int(w) or h != int(h) or w <= 0 or h <= 0 or w > 1e6 or h > 1e6:
                raise DatasetError(f"{json_path}: {where}: 'w' and 'h' must be positive whole numbers, got "
                                   f"{w:g} and {h:g}")
            size = (int(w), int(h))
        if "fl_x" not in keys and "camera_angle_x" not in keys:
            raise DatasetError(f"{json_path}: {where}: no focal length: give 'fl_x' (and 'fl_y', 'cx', 'cy', 'w', "
                               "'h'), in the frame or at the top level, or 'camera_angle_x'")
        model, dist = _lens(json_path, meta, frame, where)
        image = _find_image(json_dir, rel)
        if image is None:
            missing.append(rel)
            continue
        mask = None
        if "mask_path" in frame:
            if not isinstance(frame["mask_path"], str) or not frame["mask_path"].strip():
                raise DatasetError(f"{json_path}: {where}: 'mask_path' must be a file name, got "
                                   f"{frame['mask_path']!r}")
            mask = _find_image(json_dir, frame["mask_path"])
            if mask is None:
                raise DatasetError(f"{json_path}: {where}: mask {frame['mask_path']!r} not found")
        frames.append(_Frame(idx, Path(rel).stem, image, c2w, size, keys, model, dist, mask))
    frames.sort(key=lambda f: str(f.image))
    names = [f.name for f in frames]
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise DatasetError(f"{json_path}: two frames have images named {dup!r}; view names must be unique")
    masked = [f.mask is not None for f in frames]
    if any(masked) and not all(masked):
        lacking = next(f for f in frames if f.mask is None)
        raise DatasetError(f"{json_path}: some frames have a 'mask_path' and others (frame {lacking.index}, "
                           f"{lacking.name}) do not; give one for every frame or none")
    return frames, missing


def _checked_frames(json_path: Path, meta: dict[str, Any]) -> list[_Frame]:
    """Return the frames with images, warning once about the missing ones; refuse fewer than :data:`MIN_FRAMES`."""
    frames, missing = _parse_frames(json_path, meta)
    listed = len(meta["frames"])
    if len(frames) < MIN_FRAMES:
        gone = f" ({len(missing)} of its {listed} listed images are missing, e.g. {missing[0]})" if missing else ""
        raise DatasetError(f"{json_path}: {len(frames)} frames with images{gone}; at least {MIN_FRAMES} are needed")
    if missing:
        shown = ", ".join(missing[:3]) + (", ..." if len(missing) > 3 else "")
        warnings.warn(f"{json_path}: {len(missing)} of the {listed} listed images are missing ({shown}); using the "
                      f"other {len(frames)} frames", InputWarning, stacklevel=3)
    return frames


def _intrinsics(frame: _Frame, size: tuple[int, int]) -> np.ndarray:
    """Return the frame's ``[3, 3]`` intrinsics for its image of ``size`` (the stated w/h, else the image's)."""
    w, h = size
    k = frame.keys
    if "fl_x" in k:
        fx = k["fl_x"]
        fy = k.get("fl_y", fx)
    else:
        ax = k["camera_angle_x"]
        if not 0 < ax < math.pi:
            raise DatasetError(f"{frame.image}: 'camera_angle_x' must be in (0, pi) radians, got {ax:g}")
        fx = 0.5 * w / math.tan(0.5 * ax)
        ay = k.get("camera_angle_y")
        fy = 0.5 * h / math.tan(0.5 * ay) if ay is not None and 0 < ay < math.pi else fx
    cx, cy = k.get("cx", w / 2.0), k.get("cy", h / 2.0)
    if not (fx > 0 and fy > 0):
        raise DatasetError(f"{frame.image}: focal lengths must be positive, got fl_x {fx:g}, fl_y {fy:g}")
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


class _Lens:
    """Undistorts one camera's photos onto a pinhole camera of the same size that sees no border (OpenCV's
    ``getOptimalNewCameraMatrix(alpha=0)``, or ``fisheye.estimateNewCameraMatrixForUndistortRectify(balance=0)``),
    at whatever size they are read (a reduced ``images_N`` copy scales both intrinsics)."""

    def __init__(self, K: np.ndarray, dist: np.ndarray, size: tuple[int, int], fisheye: bool, where: Path) -> None:
        self.K, self.dist, self.size, self.fisheye = K, dist, size, fisheye
        cv_k = self._cv(K)
        try:
            if fisheye:
                new = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(cv_k, dist.reshape(4, 1), size,
                                                                             np.eye(3), balance=0.0)
            else:
                new, _ = cv2.getOptimalNewCameraMatrix(cv_k, dist, size, 0.0)
        except cv2.error as exc:
            raise DatasetError(f"{where}: its lens distortion cannot be undone ({' '.join(str(exc).split())[:120]})") \
                from None
        new = np.asarray(new, dtype=np.float64).copy()
        new[:2, 2] += 0.5
        if not np.isfinite(new).all() or new[0, 0] <= 0 or new[1, 1] <= 0:
            raise DatasetError(f"{where}: its lens distortion cannot be undone (coefficients "
                               f"{np.round(dist, 6).tolist()})")
        self.new_K = new
        self._maps: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    @staticmethod
    def _cv(K: np.ndarray) -> np.ndarray:
        out = K.copy()
        out[:2, 2] -= 0.5  # OpenCV puts pixel centres at integers, we at +0.5
        return out

    def __call__(self, img: np.ndarray) -> np.ndarray:
        h, w = img.shape[:2]
        if (w, h) not in self._maps:
            scale = np.diag([w / self.size[0], h / self.size[1], 1.0])
            K, new = self._cv(scale @ self.K), self._cv(scale @ self.new_K)
            if self.fisheye:
                maps = cv2.fisheye.initUndistortRectifyMap(K, self.dist.reshape(4, 1), np.eye(3), new, (w, h),
                                                           cv2.CV_32FC1)
            else:
                maps = cv2.initUndistortRectifyMap(K, self.dist, None, new, (w, h), cv2.CV_32FC1)
            self._maps[(w, h)] = maps
        m1, m2 = self._maps[(w, h)]
        return cv2.remap(img, m1, m2, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def record(self) -> dict[str, Any]:
        """How a photo's pixel moves (for :func:`~roodi_toolkit.io.dataset.to_loaded_pixel`)."""
        return {"K": self.K.tolist(), "dist": self.dist.tolist(), "new_K": self.new_K.tolist(),
                "fisheye": self.fisheye}


def _camera(json_path: Path, frame: _Frame, size: tuple[int, int]) -> tuple[Camera, _Lens | None]:
    """Return the frame's pinhole camera at ``size`` (undistorted intrinsics if the lens distorts) and its lens."""
    K = _intrinsics(frame, size)
    lens = None
    if frame.model == "OPENCV_FISHEYE" or np.any(frame.dist):
        lens = _Lens(K, frame.dist, size, frame.model == "OPENCV_FISHEYE", frame.image)
        K = lens.new_K
    try:
        return Camera(opengl_c2w_to_w2c(frame.c2w), K, size[0], size[1], name=frame.name), lens
    except RoodiError as exc:
        raise DatasetError(f"{json_path}: frame {frame.index} ({frame.name}): {exc}") from None


def _photo_size(frame: _Frame) -> tuple[int, int]:
    return frame.size if frame.size is not None else _image_size(frame.image)


def load_nerfstudio_cameras(path: str | os.PathLike) -> list[Camera]:
    """Return the cameras of a ``transforms.json`` (or its folder), in file-name order, without decoding images
    (distorted cameras as the pinhole cameras of their undistorted photos, as :func:`load_nerfstudio` loads them).
    Frames whose image is missing are left out with a warning."""
    json_path = _json_path(Path(path))
    meta = _read_meta(json_path)
    return [_camera(json_path, f, _photo_size(f))[0] for f in _checked_frames(json_path, meta)]


def _splits(json_path: Path, meta: dict[str, Any], frames: Sequence[_Frame],
            test_every: int) -> tuple[list[str], str]:
    """Return each frame's split label and how the split was chosen."""
    lists = {s: meta[f"{s}_filenames"] for s in SPLITS if f"{s}_filenames" in meta}
    if not lists:
        hold = int(test_every)
        labels = ["test" if hold > 0 and i % hold == 0 else "train" for i in range(len(frames))]
        how = (f"every {hold}th frame in name order held out ({labels.count('test')} of {len(frames)}): the file has "
               "no train_filenames / val_filenames" if hold > 0 else "every frame trains (test_every 0)")
        return labels, how
    json_dir = json_path.parent
    by_path = {f.image.resolve(): i for i, f in enumerate(frames)}
    by_name = {f.name: i for i, f in enumerate(frames)}
    labels = ["val"] * len(frames)  # listed in no split: neither trained on nor scored
    for split in ("test", "val", "train"):  # train last: a frame listed twice trains
        names = lists.get(split)
        if names is None:
            continue
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise DatasetError(f"{json_path}: '{split}_filenames' must be a list of file names")
        for n in names:
            found = _find_image(json_dir, n)
            i = by_path.get(found.resolve()) if found is not None else by_name.get(Path(n).stem)
            if i is not None:
                labels[i] = "train" if split == "train" else "test"
    if "train" not in labels:
        raise DatasetError(f"{json_path}: 'train_filenames' names none of the frames with images")
    how = (f"train_filenames / val_filenames of the file: {labels.count('train')} training, {labels.count('test')} "
           f"held-out, {labels.count('val')} in neither")
    return labels, how


def _read_points(json_path: Path, meta: dict[str, Any]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Return the SfM points ``[P, 3]`` and their colours ``[P, 3]`` uint8 (or None) of ``ply_file_path``."""
    if "ply_file_path" not in meta:
        return None, None
    rel = meta["ply_file_path"]
    if not isinstance(rel, str) or not rel.strip():
        raise DatasetError(f"{json_path}: 'ply_file_path' must be a file name, got {rel!r}")
    path = json_path.parent / rel
    if not path.is_file():
        raise DatasetError(f"{json_path}: 'ply_file_path' {rel!r} not found ({path})")
    try:
        vertex = PlyData.read(str(path))["vertex"]
        names = vertex.data.dtype.names or ()
        xyz = np.stack([np.asarray(vertex[c], dtype=np.float64) for c in ("x", "y", "z")], axis=1)
        rgb = None
        if all(c in names for c in ("red", "green", "blue")):
            rgb = np.stack([np.asarray(vertex[c]) for c in ("red", "green", "blue")], axis=1)
            rgb = (np.clip(rgb, 0, 1) * 255).astype(np.uint8) if rgb.dtype.kind == "f" else \
                np.clip(rgb, 0, 255).astype(np.uint8)
    except (KeyError, ValueError) as exc:
        raise DatasetError(f"{path}: not a point cloud with x, y, z ('ply_file_path' of {json_path.name}: "
                           f"{' '.join(str(exc).split())[:120]})") from None
    except Exception as exc:  # noqa: BLE001 - plyfile raises many kinds on a corrupt file; one line naming it
        raise DatasetError(f"{path}: cannot read the points ('ply_file_path' of {json_path.name}: "
                           f"{type(exc).__name__}: {' '.join(str(exc).split())[:120]})") from None
    finite = np.isfinite(xyz).all(axis=1)
    if not finite.any():
        return None, None
    return xyz[finite], None if rgb is None else rgb[finite]


def _reduced(json_dir: Path, frames: Sequence[_Frame], downscale: float,
             sizes: Sequence[tuple[int, int]]) -> tuple[list[Path], list[Path | None], float]:
    """Return the image and mask files to read and the downscale left to apply: nerfstudio's ``images_N`` (and
    ``masks_N``) copies when ``downscale`` is N in 2, 4, 8 and every image is there at its reduced size."""
    images = [f.image for f in frames]
    masks = [f.mask for f in frames]
    if downscale not in (2.0, 4.0, 8.0):
        return images, masks, downscale
    n = int(downscale)
    reduced = [json_dir / f"images_{n}" / f.image.name for f in frames]
    for path, (w, h) in zip(reduced, sizes):
        if not path.is_file():
            return images, masks, downscale
        rw, rh = _image_size(path)
        if abs(rw - w / n) > 1 or abs(rh - h / n) > 1:
            return images, masks, downscale
    if all(m is not None for m in masks):
        small = [json_dir / f"masks_{n}" / m.name for m in masks]  # type: ignore[union-attr]
        if all(p.is_file() for p in small):
            masks = small  # type: ignore[assignment]
    return reduced, masks, 1.0


def load_nerfstudio(path: str | os.PathLike, downscale: float = 1, *, background: Sequence[float] | None = None,
                    test_every: int = LLFF_HOLD, progress: ProgressFactory = null_progress) -> Dataset:
    """Return a nerfstudio / instant-ngp capture (module docstring).

    Args:
        path: the folder holding ``transforms.json``, or the JSON file itself.
        downscale: divide the resolution by this factor (>= 1); 2, 4 or 8 read the ``images_N`` copies when every
            image is there at that size.
        background: RGB in [0, 1] for transparent pixels (default black).
        test_every: without split lists in the file, every ``test_every``-th frame in name order is held out (0: none).
        progress: progress factory.

    Raises:
        DatasetError: a malformed file (naming the frame and field), fewer than 3 frames with images, an image
            whose size is neither the stated one nor a reduced copy of it, an unsupported camera model.
    """
    json_path = _json_path(Path(path))
    d = _check_downscale(downscale)
    if int(test_every) < 0:
        raise DatasetError(f"test_every must be >= 0, got {test_every}")
    meta = _read_meta(json_path)
    frames = _checked_frames(json_path, meta)
    splits, split_how = _splits(json_path, meta, frames, test_every)
    if "train_filenames" not in meta and "val_filenames" not in meta and "test_filenames" not in meta \
            and int(test_every) > 0:
        warnings.warn(f"{json_path}: {split_how}", InputWarning, stacklevel=2)
    bg = _check_background(background if background is not None else DEFAULT_NERFSTUDIO_BACKGROUND, json_path)
    photo_sizes = [_photo_size(f) for f in frames]
    paths, mask_paths, d_left = _reduced(json_path.parent, frames, d, photo_sizes)
    read_sizes = [_image_size(p) for p in paths]
    crop = _plan_crop(paths, read_sizes)
    out_w, out_h = _downscaled_size(crop.width, crop.height, d_left)
    stack = _ViewStack(crop, (out_w, out_h), bg)
    valid = None
    if any(m is not None for m in mask_paths):
        valid = torch.ones(len(frames), out_h, out_w, dtype=torch.float32)
    cameras: list[Camera] = []
    lenses: dict[str, _Lens] = {}
    with progress(total=len(frames), desc="load images") as bar:
        for i, (frame, path) in enumerate(zip(frames, paths)):
            cam, lens = _camera(json_path, frame, photo_sizes[i])
            if read_sizes[i] != photo_sizes[i]:
                _check_size(json_path, frame, path, read_sizes[i], photo_sizes[i])
                cam = cam.with_size(*read_sizes[i])
            cam = _crop_camera(cam, crop.offsets[i], crop.width, crop.height)
            if (out_w, out_h) != (crop.width, crop.height):
                cam = cam.with_size(out_w, out_h)
            stack.add(path, i, undistort=lens)
            if valid is not None:
                valid[i] = _mask_weights(stack, i, mask_paths[i], read_sizes[i], lens, frame)  # type: ignore[arg-type]
            if lens is not None:
                lenses[frame.name] = lens
            cameras.append(cam)
            bar.update(1)
    images_t, alpha_t = stack.images()
    points, colors = _read_points(json_path, meta)
    metadata: dict[str, Any] = {"transforms": str(json_path), "split": split_how, "images_dir": paths[0].parent.name,
                                "camera_models": sorted({f.model for f in frames}),
                                "frames_listed": len(meta["frames"]), "frames_missing": len(meta["frames"]) -
                                len(frames)}
    applied = _applied_transform(json_path, meta)
    if applied is not None:
        metadata["applied_transform"] = applied
    for key in ("applied_scale", "aabb_scale"):
        if key in meta:
            metadata[key] = meta[key]
    if d != 1:
        metadata["downscale"] = d
    if crop.cropped:
        metadata["crop"] = crop.record([c.name for c in cameras])
    metadata["source_pixels"] = _source_pixels([c.name for c in cameras], photo_sizes, read_sizes, crop,
                                               (out_w, out_h))
    for name, lens in lenses.items():
        metadata["source_pixels"][name]["undistort"] = lens.record()
    return Dataset(images=images_t, cameras=cameras, splits=splits, background=bg,
                   bounds=estimate_bounds(cameras, points), alphas=alpha_t, valid=valid, points=points,
                   point_colors=colors, root=json_path.parent, format="nerfstudio", metadata=metadata)


def _check_size(json_path: Path, frame: _Frame, path: Path, size: tuple[int, int], stated: tuple[int, int]) -> None:
    """Refuse an image that is neither the stated size nor a reduced copy of it (same aspect to within a pixel)."""
    w, h = size
    sw, sh = stated
    if w > sw or h > sh or abs(sh * w / sw - h) > 1:
        raise DatasetError(f"{path}: image is {w}x{h} but {json_path.name} gives frame {frame.index} 'w' {sw} and 'h' "
                           f"{sh} (neither that size nor a reduced copy of it)")


def _mask_weights(stack: _ViewStack, index: int, path: Path, size: tuple[int, int], lens: _Lens | None,
                  frame: _Frame) -> Any:
    """Return how much each loaded pixel of view ``index`` counts: its mask's non-zero share, undistorted, cropped and
    area-reduced like the image."""
    arr = _read_dataset_image(path)
    if arr.ndim == 3:
        arr = arr[..., 0]  # an RGB(A) mask: nerfstudio's masks are one channel, black = ignore
    keep = (arr > 0).astype(np.float32)
    if keep.shape != (size[1], size[0]):
        if abs(keep.shape[1] * size[1] / size[0] - keep.shape[0]) > 1:
            raise DatasetError(f"{path}: mask is {keep.shape[1]}x{keep.shape[0]} but its image {frame.image.name} is "
                               f"{size[0]}x{size[1]}")
        keep = cv2.resize(keep, size, interpolation=cv2.INTER_AREA)
    if lens is not None:
        keep = lens(keep)
    return stack._fit(np.clip(keep, 0.0, 1.0), index, "area")


def _applied_transform(json_path: Path, meta: dict[str, Any]) -> list[list[float]] | None:
    """Return ``applied_transform`` ``[3, 4]`` as nerfstudio takes it (its fallback for old COLMAP captures)."""
    if "applied_transform" in meta:
        value = meta["applied_transform"]
        try:
            Similarity.from_matrix(value, f"{json_path}: 'applied_transform'")
        except RoodiError as exc:
            raise DatasetError(str(exc)) from None
        return np.asarray(value, dtype=np.float64)[:3].tolist()
    if (json_path.parent / "colmap" / "sparse" / "0").is_dir():
        return [row[:] for row in OLD_COLMAP_APPLIED_TRANSFORM]
    return None
