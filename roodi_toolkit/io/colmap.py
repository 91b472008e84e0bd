"""COLMAP datasets: the ``sparse/0/{cameras,images,points3D}.{bin,txt}`` reader and writer, and :func:`load_colmap`.

World-to-camera, quaternions w, x, y, z, images in ``images/``; PINHOLE and SIMPLE_PINHOLE cameras (any other model is
refused by name); test views are every 8th image in name order (3DGS ``llffhold``).

Example:
    >>> import numpy as np
    >>> q = rotmat_to_qvec(qvec_to_rotmat(np.array([0.5, 0.5, 0.5, 0.5])))
    >>> np.round(q, 6).tolist()
    [0.5, 0.5, 0.5, 0.5]
"""

from __future__ import annotations

import math
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Sequence

import numpy as np

from ..cameras import Camera, qvec_to_rotmat, rotmat_to_qvec
from ..errors import DatasetError, RoodiError, UnsupportedFormatError
from ..progress import ProgressFactory, null_progress
from .dataset import (LLFF_HOLD, Dataset, _check_background, _check_downscale, _composite, _downscale_dataset,
                      _find_colmap_sparse, _read_rgb, _SameSize, estimate_bounds)
from .files import atomic_path

__all__ = [
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
    """A COLMAP camera model other than PINHOLE and SIMPLE_PINHOLE (the images need undistorting first)."""

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

    def count(self, min_item_bytes: int) -> int:
        """Read a uint64 record count, refused if the rest of the file cannot hold that many records (a corrupt
        count must not size an array of 2^64 entries)."""
        (n,) = self.read("Q")
        if n * min_item_bytes > len(self.data) - self.pos:
            raise DatasetError(f"{self.path}: claims {n} records but holds {len(self.data) - self.pos} bytes "
                               "(truncated or not a COLMAP binary)")
        return n

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
    n = r.count(struct.calcsize("<qdddBBBdQ"))
    ids = np.zeros(n, np.int64)
    xyz = np.zeros((n, 3))
    rgb = np.zeros((n, 3), np.uint8)
    err = np.zeros(n)
    tracks = []
    for k in range(n):
        pid, x, y, z, cr, cg, cb, e, tl = r.read("qdddBBBdQ")  # signed: ids fit int64, a corrupt one stays so
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
        raise UnsupportedCameraModelError(f"{where}: camera {cam.id} uses the COLMAP camera model {cam.model}, which is "
                                          f"not supported (supported: {', '.join(SUPPORTED_COLMAP_MODELS)}); undistort "
                                          "the images first, e.g. `colmap image_undistorter`")
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


def load_colmap_cameras(path: Path) -> list[Camera]:
    """Return the cameras of a COLMAP model folder (``sparse/0``), sorted by image name, without reading images."""
    return [cam for cam, _ in _colmap_cameras(read_colmap_model(path))]


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
