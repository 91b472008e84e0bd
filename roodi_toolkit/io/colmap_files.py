"""COLMAP's sparse model files: the ``{cameras,images,points3D}.{bin,txt}`` reader and writer and their data types.

:mod:`roodi_toolkit.io.colmap` builds datasets and cameras on them.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from ..cameras import qvec_to_rotmat
from ..errors import DatasetError
from .files import atomic_path

__all__ = ["COLMAP_CAMERA_MODELS", "ColmapCamera", "ColmapImage", "ColmapPoints", "ColmapModel", "read_colmap_model",
           "write_colmap_model"]

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
