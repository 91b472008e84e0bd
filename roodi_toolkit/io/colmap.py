"""COLMAP datasets: :func:`load_colmap` and :func:`load_colmap_cameras` on ``sparse/0/{cameras,images,points3D}``
(the files themselves: :mod:`roodi_toolkit.io.colmap_files`, whose names this module re-exports).

World-to-camera, quaternions w, x, y, z, images in ``images/``; PINHOLE and SIMPLE_PINHOLE cameras as they are, the
distorted SIMPLE_RADIAL, RADIAL, OPENCV and FULL_OPENCV cameras undistorted on loading (OpenCV, same image size, the
focal length chosen so that every pixel has data), the fisheye and other models refused by name; test views are every
8th image in name order (3DGS ``llffhold``).

Example:
    >>> import numpy as np
    >>> q = rotmat_to_qvec(qvec_to_rotmat(np.array([0.5, 0.5, 0.5, 0.5])))
    >>> np.round(q, 6).tolist()
    [0.5, 0.5, 0.5, 0.5]
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from ..cameras import Camera, qvec_to_rotmat, rotmat_to_qvec
from ..errors import DatasetError, RoodiError, UnsupportedFormatError
from ..progress import ProgressFactory, null_progress
from .colmap_files import (COLMAP_CAMERA_MODELS, ColmapCamera, ColmapImage, ColmapModel, ColmapPoints,
                           read_colmap_model, write_colmap_model)
from .dataset_core import (LLFF_HOLD, Dataset, _check_background, _check_downscale, _crop_camera, _downscaled_size,
                           _find_colmap_sparse, _plan_crop, _source_pixels, estimate_bounds)
from .photos import _image_size, _ViewStack

__all__ = [
    "COLMAP_CAMERA_MODELS",
    "ColmapCamera",
    "ColmapImage",
    "ColmapPoints",
    "ColmapModel",
    "load_colmap",
    "load_colmap_cameras",
    "read_colmap_model",
    "write_colmap_model",
    "colmap_model_from_cameras",
    "qvec_to_rotmat",
    "rotmat_to_qvec",
]

DEFAULT_COLMAP_BACKGROUND = (0.0, 0.0, 0.0)  # 3DGS default for real captures


class UnsupportedCameraModelError(DatasetError, UnsupportedFormatError):
    """A COLMAP camera model the loader can neither use nor undistort (fisheye and the other exotic models)."""


SUPPORTED_COLMAP_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")
UNDISTORTED_COLMAP_MODELS = ("SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")  # OpenCV's own distortion models


def _distortion(cam: ColmapCamera) -> tuple[np.ndarray, np.ndarray]:
    """Return a camera's ``[3, 3]`` intrinsics (pixel centres at +0.5) and its OpenCV distortion coefficients."""
    p = np.asarray(cam.params, dtype=np.float64)
    if cam.model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
        k = list(p[3:]) + [0.0] * (4 - len(p[3:]))  # k1 (SIMPLE_RADIAL), k1 k2 (RADIAL); no p1, p2
        dist = [] if cam.model == "SIMPLE_PINHOLE" else k[:4]
    else:  # PINHOLE, OPENCV, FULL_OPENCV: fx, fy, cx, cy, then k1, k2, p1, p2 (, k3, k4, k5, k6: rational model)
        fx, fy, cx, cy = p[:4]
        dist = list(p[4:])
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), np.asarray(dist, dtype=np.float64)


def _opencv_k(K: np.ndarray) -> np.ndarray:
    """Return intrinsics in OpenCV's pixel convention (pixel centres at integers) from ours (centres at +0.5)."""
    out = K.copy()
    out[:2, 2] -= 0.5
    return out


def _colmap_intrinsics(cam: ColmapCamera, where: str) -> np.ndarray:
    """Return the pinhole intrinsics the loaded images have: the camera's own, or for a distorted camera those of its
    undistorted images (same size; OpenCV's ``getOptimalNewCameraMatrix`` with ``alpha=0``: every pixel has data)."""
    if cam.model in SUPPORTED_COLMAP_MODELS:
        return _distortion(cam)[0]
    if cam.model not in UNDISTORTED_COLMAP_MODELS:
        raise UnsupportedCameraModelError(
            f"{where}: camera {cam.id} uses the COLMAP camera model {cam.model}, which is not supported (pinhole: "
            f"{', '.join(SUPPORTED_COLMAP_MODELS)}; undistorted on loading: {', '.join(UNDISTORTED_COLMAP_MODELS)}); "
            "undistort the images first, e.g. `colmap image_undistorter`")
    K, dist = _distortion(cam)
    new, _ = cv2.getOptimalNewCameraMatrix(_opencv_k(K), dist, (cam.width, cam.height), 0.0)
    new = np.asarray(new, dtype=np.float64)
    new[:2, 2] += 0.5
    if not np.isfinite(new).all() or new[0, 0] <= 0 or new[1, 1] <= 0:
        raise DatasetError(f"{where}: camera {cam.id} ({cam.model}): its distortion cannot be undone (parameters "
                           f"{np.round(cam.params, 6).tolist()})")
    return new


class _Undistorter:
    """Undistorts a distorted camera's images onto its pinhole intrinsics (:func:`_colmap_intrinsics`), at whatever
    size they were read (a reduced ``images_N`` copy scales both intrinsics; the coefficients are in normalised
    coordinates and stay)."""

    def __init__(self, cam: ColmapCamera, new_K: np.ndarray) -> None:
        self.K, self.dist = _distortion(cam)
        self.new_K, self.size = new_K, (cam.width, cam.height)
        self._maps: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def __call__(self, img: np.ndarray) -> np.ndarray:
        h, w = img.shape[:2]
        if (w, h) not in self._maps:
            scale = np.diag([w / self.size[0], h / self.size[1], 1.0])
            self._maps[(w, h)] = cv2.initUndistortRectifyMap(_opencv_k(scale @ self.K), self.dist, None,
                                                             _opencv_k(scale @ self.new_K), (w, h), cv2.CV_32FC1)
        m1, m2 = self._maps[(w, h)]
        return cv2.remap(img, m1, m2, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


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


def load_colmap_cameras(path: Path) -> list[Camera]:
    """Return the cameras of a COLMAP model folder (``sparse/0``), sorted by image name, without reading images
    (distorted cameras as the pinhole cameras of their undistorted images, as :func:`load_colmap` loads them)."""
    return [cam for cam, _ in _colmap_cameras(read_colmap_model(path))]


def load_colmap(path: str | os.PathLike, downscale: float = 1, *, background: Sequence[float] | None = None,
                test_every: int = LLFF_HOLD, images_dir: str = "images",
                progress: ProgressFactory = null_progress) -> Dataset:
    """Return a COLMAP dataset: ``sparse/0`` model (binary or text) and the images in ``images/``.

    Every camera keeps its own intrinsics. Images of slightly different sizes (COLMAP's undistorter writes each at its
    own size) are cut to the smallest width and height, centred, with each principal point shifted by its crop
    offset, so the geometry stays exact; ``metadata["crop"]`` records the common size and every cropped image's size
    and offset. More than 10% of an image's width or height to discard is refused. Each image is decoded and reduced
    one at a time, so memory follows the loaded size, not the photos'.

    Args:
        path: the dataset folder (holding ``sparse/0`` or ``sparse``, and ``images``).
        downscale: divide the resolution by this factor (>= 1); for 2, 4 or 8 the ``images_2``/``_4``/``_8`` folder
            is read instead when it holds every image at that reduced size (``metadata["images_dir"]`` says which).
        background: RGB in [0, 1] for transparent pixels (default black).
        test_every: every ``test_every``-th image in name order (index % test_every == 0) is a test view, as 3DGS's
            ``llffhold``; 0 makes every image a training view.
        images_dir: the images folder, relative to ``path``.
        progress: progress factory.

    Raises:
        DatasetError: missing model or images, malformed files, unsupported camera model, sizes differing by more
            than 10%.
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
    for cam, img in pairs:
        if not (img_root / img.name).is_file():
            raise DatasetError(f"{img_root / img.name}: image of COLMAP image {img.id} ({img.name!r}) not found")
    img_root, d = _reduced_images(root, images_dir, pairs, d)
    paths = [img_root / img.name for _, img in pairs]
    sizes = [_image_size(path) for path in paths]
    crop = _plan_crop(paths, sizes)
    out_w, out_h = _downscaled_size(crop.width, crop.height, d)
    stack = _ViewStack(crop, (out_w, out_h), bg)
    cameras = []
    undistorters: dict[int, _Undistorter] = {}
    with progress(total=len(pairs), desc="load images") as bar:
        for i, ((cam, img), path) in enumerate(zip(pairs, paths)):
            if sizes[i] != (cam.width, cam.height):
                _check_reduced(path, sizes[i], cam, img.camera_id)
                # images already reduced on disk (e.g. the images_2 folders of 3DGS): scale the intrinsics
                cam = cam.with_size(*sizes[i])
            cam = _crop_camera(cam, crop.offsets[i], crop.width, crop.height)
            if (out_w, out_h) != (crop.width, crop.height):
                cam = cam.with_size(out_w, out_h)
            undistort = None
            if model.cameras[img.camera_id].model in UNDISTORTED_COLMAP_MODELS:
                if img.camera_id not in undistorters:
                    undistorters[img.camera_id] = _Undistorter(model.cameras[img.camera_id], pairs[i][0].K)
                undistort = undistorters[img.camera_id]
            stack.add(path, i, undistort=undistort)
            cameras.append(cam)
            bar.update(1)
    images_t, alpha_t = stack.images()
    hold = int(test_every)
    splits = ["test" if hold > 0 and i % hold == 0 else "train" for i in range(len(cameras))]
    points = model.points.xyz if len(model.points.ids) else None
    colors = model.points.rgb if len(model.points.ids) else None
    bounds = estimate_bounds(cameras, points)
    metadata: dict[str, Any] = {"sparse": str(sparse), "images_dir": img_root.name,
                                "camera_models": sorted({c.model for c in model.cameras.values()})}
    if float(downscale) != 1:
        metadata["downscale"] = float(downscale)
    if crop.cropped:
        metadata["crop"] = crop.record([c.name for c in cameras])
    metadata["source_pixels"] = _source_pixels([c.name for c in cameras], [(c.width, c.height) for c, _ in pairs],
                                               sizes, crop, (out_w, out_h))
    for (cam, img), loaded in zip(pairs, cameras):
        if img.camera_id in undistorters:  # a photo's pixel moves by the lens distortion before it is scaled
            u = undistorters[img.camera_id]
            metadata["source_pixels"][loaded.name]["undistort"] = {"K": u.K.tolist(), "dist": u.dist.tolist(),
                                                                   "new_K": u.new_K.tolist()}
    return Dataset(images=images_t, cameras=cameras, splits=splits, background=bg, bounds=bounds, alphas=alpha_t,
                   points=points, point_colors=colors, root=root, format="colmap", metadata=metadata)


def _check_reduced(path: Path, size: tuple[int, int], cam: Camera, camera_id: int) -> None:
    """Refuse an image whose size is not its camera's nor a reduced copy of it (same aspect to within a pixel)."""
    w, h = size
    if w > cam.width or h > cam.height or abs(cam.height * w / cam.width - h) > 1:
        raise DatasetError(f"{path}: image is {w}x{h} but its COLMAP camera {camera_id} is {cam.width}x{cam.height} "
                           "(neither that size nor a reduced copy of it); the images do not belong to this model")


def _reduced_images(root: Path, images_dir: str, pairs: list[tuple[Camera, ColmapImage]],
                    downscale: float) -> tuple[Path, float]:
    """Return the folder to read and the downscale left to apply: ``images_2``/``_4``/``_8`` (3DGS's pre-reduced
    copies) when ``downscale`` is that factor, the folder holds every image, and each is the reduced size of its
    camera to within a pixel; else ``images_dir`` and ``downscale`` unchanged."""
    if images_dir != "images" or downscale not in (2.0, 4.0, 8.0):
        return root / images_dir, downscale
    reduced = root / f"images_{int(downscale)}"
    if not reduced.is_dir():
        return root / images_dir, downscale
    for cam, img in pairs:
        path = reduced / img.name
        if not path.is_file():
            return root / images_dir, downscale
        w, h = _image_size(path)
        if abs(w - cam.width / downscale) > 1 or abs(h - cam.height / downscale) > 1:
            return root / images_dir, downscale
    return reduced, 1.0


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
