"""Pinhole cameras in the internal convention: world-to-camera 4x4 in OpenCV axes (x right, y down, z forward).

This is the convention of COLMAP and gsplat. Blender / NeRF-synthetic files store camera-to-world in OpenGL axes
(x right, y up, z backward); :func:`opengl_c2w_to_w2c` converts (flip columns 1 and 2, invert).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .errors import ConfigError, DatasetError
from .gaussians import quat_to_rotmat


ROTATION_TOLERANCE = 1e-3
"""Largest deviation of a pose's rotation from orthonormal accepted (float32 files round to about 1e-7)."""


@dataclass(frozen=True)
class Camera:
    """A posed pinhole camera.

    Attributes:
        world_to_camera: ``[4, 4]`` float64, OpenCV axes.
        K: ``[3, 3]`` float64 intrinsics (fx, fy, cx, cy; pixel centres at +0.5).
        width: image width in pixels.
        height: image height in pixels.
        near: near clipping distance (Gaussians closer than this along z are culled).
        far: far clipping distance.
        name: the view's name (image file stem), used to match masks and outputs.
    """

    world_to_camera: np.ndarray = field(repr=False)
    K: np.ndarray = field(repr=False)
    width: int
    height: int
    near: float = 0.01
    far: float = 1e10
    name: str = ""

    def __post_init__(self) -> None:
        w2c = np.asarray(self.world_to_camera, dtype=np.float64)
        K = np.asarray(self.K, dtype=np.float64)
        if w2c.shape != (4, 4):
            raise ConfigError(f"camera {self.name!r}: world_to_camera must be [4, 4], got {list(w2c.shape)}")
        if K.shape != (3, 3):
            raise ConfigError(f"camera {self.name!r}: K must be [3, 3], got {list(K.shape)}")
        if not (np.isfinite(w2c).all() and np.isfinite(K).all()):
            raise ConfigError(f"camera {self.name!r}: pose or intrinsics contain NaN/Inf")
        fx, fy = K[0, 0], K[1, 1]
        if not (fx > 0 and fy > 0):  # a zero focal length projects every point to infinity
            raise ConfigError(f"camera {self.name!r}: focal lengths must be positive, got fx={fx:g} fy={fy:g}")
        rot = w2c[:3, :3]
        # a pose must be a rotation and a translation; a scaled, sheared or mirrored matrix is a broken file
        if (np.abs(rot.T @ rot - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(rot) <= 0
                or np.abs(w2c[3] - (0.0, 0.0, 0.0, 1.0)).max() > ROTATION_TOLERANCE):
            raise ConfigError(f"camera {self.name!r}: the pose is not a rotation and translation (its rotation is not "
                              "orthonormal with determinant +1); check the camera file")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ConfigError(f"camera {self.name!r}: size must be positive, got {self.width}x{self.height}")
        if not 0 < self.near < self.far:
            raise ConfigError(f"camera {self.name!r}: need 0 < near < far, got near={self.near} far={self.far}")
        object.__setattr__(self, "world_to_camera", w2c)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @property
    def camera_to_world(self) -> np.ndarray:
        """``[4, 4]`` camera-to-world in OpenCV axes."""
        return invert_rigid(self.world_to_camera)

    @property
    def center(self) -> np.ndarray:
        """``[3]`` camera centre in world coordinates."""
        return self.camera_to_world[:3, 3]

    def backproject(self, pixels_rc: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Return world points ``[P, 3]`` of pixels ``[P, 2]`` (row, col; their centres) at z-depths ``[P]``.

        Example:
            >>> cam = Camera(np.eye(4), intrinsics_from_fov(1.0, 8, 8), 8, 8)
            >>> uv, z = cam.project(cam.backproject(np.array([[2, 5]]), np.array([3.0])))
            >>> [round(float(x), 6) for x in (*uv[0], z[0])]
            [5.5, 2.5, 3.0]
        """
        K = self.K
        rc = np.asarray(pixels_rc, dtype=np.float64).reshape(-1, 2)
        z = np.asarray(depth, dtype=np.float64).reshape(-1)
        cam = np.stack([(rc[:, 1] + 0.5 - K[0, 2]) / K[0, 0] * z, (rc[:, 0] + 0.5 - K[1, 2]) / K[1, 1] * z, z], axis=1)
        c2w = self.camera_to_world
        return cam @ c2w[:3, :3].T + c2w[:3, 3]

    @property
    def fov_x(self) -> float:
        """Horizontal field of view in radians."""
        return 2.0 * math.atan(self.width / (2.0 * self.K[0, 0]))

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return pixel coordinates ``[N, 2]`` (continuous, pixel centres at +0.5) and depths ``[N]`` of world points."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        cam = pts @ self.world_to_camera[:3, :3].T + self.world_to_camera[:3, 3]
        z = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (cam[:, :2] / z[:, None]) * np.array([self.K[0, 0], self.K[1, 1]]) + self.K[:2, 2]
        return uv, z

    def scaled(self, factor: float) -> "Camera":
        """Return this camera for images resized by ``factor`` (0.5 halves the resolution)."""
        K = self.K.copy()
        K[:2] *= factor
        return Camera(self.world_to_camera, K, max(1, round(self.width * factor)), max(1, round(self.height * factor)),
                      self.near, self.far, self.name)

    def cropped(self, x0: int, y0: int, width: int, height: int) -> "Camera":
        """Return this camera seeing only the ``width`` x ``height`` pixels from column ``x0``, row ``y0`` (the same
        rays: the principal point moves).

        Example:
            >>> cam = Camera(np.eye(4), np.array([[100.0, 0, 50], [0, 100, 40], [0, 0, 1]]), 100, 80)
            >>> cam.cropped(10, 20, 30, 30).K[:2, 2].tolist()
            [40.0, 20.0]
        """
        K = self.K.copy()
        K[0, 2] -= x0
        K[1, 2] -= y0
        return Camera(self.world_to_camera, K, int(width), int(height), self.near, self.far, self.name)

    def with_size(self, width: int, height: int) -> "Camera":
        """Return this camera rescaled to another image size (intrinsics scaled per axis)."""
        K = self.K.copy()
        K[0] *= width / self.width
        K[1] *= height / self.height
        return Camera(self.world_to_camera, K, width, height, self.near, self.far, self.name)


def qvec_to_rotmat(qvec: np.ndarray) -> np.ndarray:
    """Return the ``[3, 3]`` rotation of one quaternion ``[4]`` (w, x, y, z), normalised first.

    Raises:
        DatasetError: the quaternion is zero or not finite (a file's camera that has no rotation).
    """
    q = np.asarray(qvec, dtype=np.float64)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n == 0:
        raise DatasetError(f"quaternion {q.tolist()} has zero or non-finite norm")
    return quat_to_rotmat(q[None])[0]


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


def invert_rigid(T: np.ndarray) -> np.ndarray:
    """Return the inverse of a rigid ``[4, 4]`` transform (rotation + translation)."""
    T = np.asarray(T, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def intrinsics_from_fov(fov_x: float, width: int, height: int, fov_y: float | None = None) -> np.ndarray:
    """Return ``[3, 3]`` intrinsics for a horizontal field of view in radians (square pixels unless fov_y given)."""
    if not 0 < fov_x < math.pi:
        raise ConfigError(f"field of view must be in (0, pi) radians, got {fov_x}")
    fx = 0.5 * width / math.tan(0.5 * fov_x)
    fy = fx if fov_y is None else 0.5 * height / math.tan(0.5 * fov_y)
    return np.array([[fx, 0.0, 0.5 * width], [0.0, fy, 0.5 * height], [0.0, 0.0, 1.0]])


_GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def opengl_c2w_to_w2c(c2w: np.ndarray) -> np.ndarray:
    """Convert a Blender/NeRF camera-to-world (OpenGL axes) to world-to-camera (OpenCV axes)."""
    c2w = np.asarray(c2w, dtype=np.float64)
    if c2w.shape == (3, 4):
        c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
    return invert_rigid(c2w @ _GL_TO_CV)


def w2c_to_opengl_c2w(w2c: np.ndarray) -> np.ndarray:
    """Convert world-to-camera (OpenCV axes) to a Blender/NeRF camera-to-world (OpenGL axes)."""
    return invert_rigid(np.asarray(w2c, dtype=np.float64)) @ _GL_TO_CV


def look_at(eye: Sequence[float], target: Sequence[float], up: Sequence[float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Return the ``[4, 4]`` world-to-camera (OpenCV axes) of a camera at ``eye`` looking at ``target``.

    Example:
        >>> w2c = look_at([0, -2, 0], [0, 0, 0])
        >>> np.round(w2c[:3, :3] @ np.zeros(3) + w2c[:3, 3], 6).tolist()  # the target is 2 ahead on +z
        [0.0, 0.0, 2.0]
    """
    eye = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    norm = np.linalg.norm(forward)
    if norm == 0:
        raise ConfigError("look_at: eye and target coincide")
    forward /= norm
    up = np.asarray(up, dtype=np.float64)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-8:  # looking along the up axis: pick any perpendicular
        alt = np.array([0.0, 1.0, 0.0]) if abs(forward[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        right = np.cross(forward, alt)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])  # rows: camera axes in world coordinates
    w2c = np.eye(4)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ eye
    return w2c


def horizontal_basis(up: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the unit ``up`` vector and two unit axes spanning the plane perpendicular to it (right-handed)."""
    up_v = np.asarray(up, dtype=np.float64)
    norm = np.linalg.norm(up_v)
    if norm == 0:
        raise ConfigError("the up vector must not be zero")
    up_v = up_v / norm
    helper = np.array([1.0, 0.0, 0.0]) if abs(up_v[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(up_v, helper)
    e1 /= np.linalg.norm(e1)
    return up_v, e1, np.cross(up_v, e1)


def orbit_cameras(center: Sequence[float], radius: float, n: int, *, elevation_deg: float = 20.0, width: int = 256,
                  height: int = 256, fov_x_deg: float = 50.0, azimuth0_deg: float = 0.0,
                  up: Sequence[float] = (0.0, 0.0, 1.0), near: float = 0.01, far: float = 1e10) -> list[Camera]:
    """Return ``n`` cameras evenly spaced in azimuth on a circle around ``center``, looking at it."""
    if n < 1:
        raise ConfigError(f"orbit needs at least one view, got {n}")
    if radius <= 0:
        raise ConfigError(f"orbit radius must be positive, got {radius}")
    center = np.asarray(center, dtype=np.float64)
    up_v, e1, e2 = horizontal_basis(up)
    K = intrinsics_from_fov(math.radians(fov_x_deg), width, height)
    el = math.radians(elevation_deg)
    cams = []
    for i in range(n):
        az = math.radians(azimuth0_deg) + 2.0 * math.pi * i / n
        direction = math.cos(el) * (math.cos(az) * e1 + math.sin(az) * e2) + math.sin(el) * up_v
        eye = center + radius * direction
        cams.append(Camera(look_at(eye, center, up_v), K, width, height, near, far, name=f"orbit_{i:03d}"))
    return cams


def spread_cameras(cameras: Sequence[Camera], k: int) -> list[int]:
    """Return the indices (ascending) of ``k`` of ``cameras`` spread round the scene: farthest-point sampling from the
    first camera over each camera's centre (relative to their mean, in units of their mean distance from it) and
    viewing direction (a unit vector), so that neither a capture's scale nor the order its photos were taken in
    decides which are chosen. All of them when ``k >= len(cameras)``.

    Example:
        >>> ring = orbit_cameras((0, 0, 0), 3.0, 8)
        >>> spread_cameras(ring, 4)
        [0, 2, 4, 6]
    """
    n = len(cameras)
    if k >= n:
        return list(range(n))
    centres = np.stack([c.center for c in cameras])
    centres = centres - centres.mean(axis=0)
    centres /= max(float(np.linalg.norm(centres, axis=1).mean()), 1e-12)
    points = np.concatenate([centres, np.stack([c.world_to_camera[2, :3] for c in cameras])], axis=1)
    chosen = [0]
    gap = np.linalg.norm(points - points[0], axis=1)
    gap[0] = -1.0
    while len(chosen) < max(int(k), 1):
        i = int(np.argmax(gap))  # never one already chosen, even among cameras at the same pose
        chosen.append(i)
        gap = np.minimum(gap, np.linalg.norm(points - points[i], axis=1))
        gap[chosen] = -1.0
    return sorted(chosen)
