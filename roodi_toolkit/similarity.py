"""Moving and scaling Gaussian clouds: similarity transforms (rotation, translation, uniform scale) applied exactly.

A similarity ``p -> s R p + t`` moves every part of a Gaussian: its mean, its rotation (``q_R * q``), its scales
(``+ log s``) and its view-dependent colour: every SH band is rotated by its exact Wigner block
(:func:`sh_rotation`), so a rotated cloud looks from the rotated cameras exactly as the original did
from the original ones. Mirror images are refused: a Gaussian's rotation cannot hold one.

The same type says how a file's frame relates to a dataset's (a nerfstudio export and its
``dataparser_transforms.json``, a gsplat checkpoint's normalised world) and how ``convert`` moves a splat. The
``convert`` actions follow PlayCanvas splat-transform 2.7.1 (:func:`splat_transform_actions`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .cameras import rotmat_to_qvec
from .errors import ConfigError
from .gaussians import SH_C0, SH_C1, SH_C2, SH_C3, GaussianCloud

__all__ = ["Similarity", "euler_rotation", "rotation_between", "sh_rotation", "splat_transform_actions",
           "transform_cloud", "SPLAT_TRANSFORM_FRAME"]

ROTATION_TOLERANCE = 1e-4
"""Largest deviation from orthonormal accepted in a rotation read from a file (float32 files round to ~1e-7)."""

SPLAT_TRANSFORM_FRAME = np.diag([-1.0, -1.0, 1.0])
"""splat-transform 2.7.1 applies its actions in PlayCanvas's engine frame; PLY, SPZ, SOG, .splat and .ksplat files
hold their Gaussians half a turn about z from it (its ``Transform.PLY``): file ``(x, y, z)`` is engine
``(-x, -y, z)``."""


def _as_rotation(R: np.ndarray, where: str) -> np.ndarray:
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3) or not np.isfinite(R).all():
        raise ConfigError(f"{where}: a rotation must be a finite 3x3 matrix")
    if np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOLERANCE:
        raise ConfigError(f"{where}: the matrix is not a rotation (not orthonormal after taking out a uniform scale)")
    if np.linalg.det(R) < 0:
        raise ConfigError(f"{where}: the matrix mirrors the scene (determinant < 0); a Gaussian splat cannot be "
                          "mirrored by rotating its Gaussians")
    return R


@dataclass(frozen=True)
class Similarity:
    """``p -> scale * rotation @ p + translation``.

    Attributes:
        rotation: a proper rotation. [3, 3]
        translation: [3]
        scale: uniform scale, > 0.

    Example:
        >>> s = Similarity(euler_rotation(0, 0, 90), np.array([1.0, 0.0, 0.0]), 2.0)
        >>> np.round(s.apply(np.array([[1.0, 0.0, 0.0]])), 6).tolist()
        [[1.0, 2.0, 0.0]]
        >>> np.round(s.inverse().apply(s.apply(np.array([[0.3, -2.0, 5.0]]))), 6).tolist()
        [[0.3, -2.0, 5.0]]
    """

    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "rotation", _as_rotation(self.rotation, "similarity"))
        t = np.asarray(self.translation, dtype=np.float64).reshape(-1)
        if t.shape != (3,) or not np.isfinite(t).all():
            raise ConfigError("similarity: the translation must be three finite numbers")
        object.__setattr__(self, "translation", t)
        s = float(self.scale)
        if not (math.isfinite(s) and s > 0):
            raise ConfigError(f"similarity: the scale must be a finite number > 0, got {self.scale!r}")
        object.__setattr__(self, "scale", s)

    @classmethod
    def from_matrix(cls, matrix: Sequence[Sequence[float]] | np.ndarray, where: str = "transform") -> "Similarity":
        """Return the similarity of a ``[3, 4]`` or ``[4, 4]`` matrix ``[sR | t]`` (uniform scale taken out of the
        rotation block).

        Raises:
            ConfigError: not a matrix of finite numbers of that shape, a non-uniform scale, a shear or a mirror.
        """
        try:
            m = np.asarray(matrix, dtype=np.float64)
        except (TypeError, ValueError):
            raise ConfigError(f"{where}: expected a 3x4 or 4x4 matrix of numbers") from None
        if m.shape not in ((3, 4), (4, 4)) or not np.isfinite(m).all():
            raise ConfigError(f"{where}: expected a 3x4 or 4x4 matrix of finite numbers, got shape {list(m.shape)}")
        if m.shape == (4, 4) and np.abs(m[3] - (0.0, 0.0, 0.0, 1.0)).max() > ROTATION_TOLERANCE:
            raise ConfigError(f"{where}: the last row of a 4x4 transform must be 0 0 0 1")
        block = m[:3, :3]
        scale = float(np.cbrt(abs(np.linalg.det(block))))
        if scale <= 0 or not math.isfinite(scale):
            raise ConfigError(f"{where}: the matrix collapses the scene (zero scale)")
        return cls(_as_rotation(block / scale, where), m[:3, 3], scale)

    def matrix(self) -> np.ndarray:
        """Return the ``[4, 4]`` matrix."""
        out = np.eye(4)
        out[:3, :3] = self.scale * self.rotation
        out[:3, 3] = self.translation
        return out

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Return the moved points ``[N, 3]`` (float64)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return self.scale * p @ self.rotation.T + self.translation

    def then(self, other: "Similarity") -> "Similarity":
        """Return this similarity followed by ``other``."""
        return Similarity(other.rotation @ self.rotation, other.scale * other.rotation @ self.translation
                          + other.translation, other.scale * self.scale)

    def inverse(self) -> "Similarity":
        """Return the inverse similarity."""
        R = self.rotation.T
        return Similarity(R, -(R @ self.translation) / self.scale, 1.0 / self.scale)

    def is_identity(self, tol: float = 1e-12) -> bool:
        """Whether this moves nothing (to ``tol``)."""
        return bool(np.abs(self.matrix() - np.eye(4)).max() <= tol)

    def conjugated(self, frame: np.ndarray) -> "Similarity":
        """Return this similarity expressed in another frame: ``F^T S F`` for a rotation ``F`` from that frame."""
        F = _as_rotation(frame, "frame")
        return Similarity(F.T @ self.rotation @ F, F.T @ self.translation, self.scale)

    def to_dict(self) -> dict:
        """Return the similarity as JSON-ready lists (the ``[4, 4]`` matrix)."""
        return {"matrix": self.matrix().tolist()}


def euler_rotation(x_deg: float, y_deg: float, z_deg: float) -> np.ndarray:
    """Return the ``[3, 3]`` rotation of Euler angles in degrees as PlayCanvas (and splat-transform) read them: about
    x first, then y, then z, all about the fixed axes (``R = Rz @ Ry @ Rx``).

    Example:
        >>> np.round(euler_rotation(90, 0, 0) @ np.array([0.0, 1.0, 0.0]), 6).tolist()
        [0.0, 0.0, 1.0]
    """
    ax, ay, az = (math.radians(float(v)) for v in (x_deg, y_deg, z_deg))
    cx, sx, cy, sy, cz, sz = math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay), math.cos(az), math.sin(az)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    Ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    Rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ Ry @ Rx


def rotation_between(a: Sequence[float], b: Sequence[float]) -> np.ndarray:
    """Return the smallest rotation ``[3, 3]`` taking direction ``a`` onto direction ``b`` (half a turn about a
    perpendicular axis when they are opposite).

    Example:
        >>> np.round(rotation_between([0, -1, 0], [0, 0, 1]) @ np.array([0.0, -1.0, 0.0]), 6).tolist()
        [0.0, 0.0, 1.0]
    """
    u = np.asarray(a, dtype=np.float64)
    v = np.asarray(b, dtype=np.float64)
    if u.shape != (3,) or v.shape != (3,) or not (np.linalg.norm(u) > 0 and np.linalg.norm(v) > 0):
        raise ConfigError("a direction must be three numbers, not all zero")
    u, v = u / np.linalg.norm(u), v / np.linalg.norm(v)
    c = float(u @ v)
    if c < -1.0 + 1e-12:  # opposite: half a turn about any axis perpendicular to u
        helper = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        axis = np.cross(u, helper)
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    w = np.cross(u, v)
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    return np.eye(3) + K + K @ K / (1.0 + c)


def splat_transform_actions(actions: Sequence[tuple[str, Sequence[float] | float]]) -> Similarity:
    """Return what splat-transform 2.7.1 does to a file's Gaussians for its actions, in the order given.

    ``actions``: ``("translate", (x, y, z))``, ``("rotate", (x, y, z))`` (Euler degrees, :func:`euler_rotation`) or
    ``("scale", s)``. splat-transform applies each one after the ones before it, in PlayCanvas's engine frame, which is
    half a turn about z from the file's (:data:`SPLAT_TRANSFORM_FRAME`): ``-t 1,0,0`` moves a PLY's Gaussians by -1
    along the file's x. The same numbers here give the same file.

    Example:
        >>> s = splat_transform_actions([("translate", (1.0, 2.0, 3.0))])
        >>> s.translation.tolist()
        [-1.0, -2.0, 3.0]
    """
    total = Similarity()
    for kind, value in actions:
        if kind == "translate":
            step = Similarity(translation=np.asarray(value, dtype=np.float64))
        elif kind == "rotate":
            step = Similarity(rotation=euler_rotation(*value))
        elif kind == "scale":
            step = Similarity(scale=float(value))  # type: ignore[arg-type]
        else:
            raise ConfigError(f"unknown transform action {kind!r}; expected translate, rotate or scale")
        total = total.then(step)
    return total.conjugated(SPLAT_TRANSFORM_FRAME)


def _sh_basis_values(degree: int, dirs: np.ndarray) -> np.ndarray:
    """Return the real SH basis ``[N, (degree+1)^2]`` at unit directions ``[N, 3]``: :func:`roodi_toolkit.sh.sh_bases`
    in NumPy (a moved cloud needs no PyTorch; the tests keep the two equal)."""
    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    out = [np.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [SH_C2[0] * xy, SH_C2[1] * yz, SH_C2[2] * (2.0 * zz - xx - yy), SH_C2[3] * xz, SH_C2[4] * (xx - yy)]
    if degree >= 3:
        out += [SH_C3[0] * y * (3.0 * xx - yy), SH_C3[1] * xy * z, SH_C3[2] * y * (4.0 * zz - xx - yy),
                SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy), SH_C3[4] * x * (4.0 * zz - xx - yy),
                SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3.0 * yy)]
    return np.stack(out, axis=-1)


def sh_rotation(rotation: np.ndarray, degree: int) -> np.ndarray:
    """Return the ``[K-1, K-1]`` float64 matrix (K = (degree+1)^2) that rotates the higher SH coefficients of a
    Gaussian whose world is rotated by ``rotation``: ``rest_new = M @ rest`` (coefficient-major, as ``sh_rest``).

    The rotated colour must be the old colour seen from the old direction, ``f_new(R d) = f(d)``. Each band is an
    invariant subspace of the rotations, so the band's block is solved exactly (to float64 rounding) by least squares
    over directions spread on the sphere: ``Y(D R) = Y(D) M^T`` for directions ``D`` as rows. Bands are never mixed,
    and the DC term is unchanged.

    Args:
        rotation: a proper rotation. [3, 3]
        degree: the SH degree, 0..3 (0 gives a ``[0, 0]`` matrix).

    Example:
        >>> M = sh_rotation(np.diag([-1.0, -1.0, 1.0]), 1)  # half a turn about z: the x and y bases change sign
        >>> (np.round(M, 12) + 0.0).tolist()
        [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]
    """
    R = np.asarray(rotation, dtype=np.float64)
    if R.shape != (3, 3):
        raise ConfigError(f"an SH rotation needs a [3, 3] rotation matrix, got {list(R.shape)}")
    if degree not in (0, 1, 2, 3):
        raise ConfigError(f"SH degree must be 0, 1, 2 or 3, got {degree}")
    k = (degree + 1) ** 2
    out = np.zeros((k - 1, k - 1))
    if k == 1:
        return out
    # a fixed, well spread set of directions: a Fibonacci sphere of 64 points (far more than the 7 of band 3)
    i = np.arange(64) + 0.5
    z = 1.0 - 2.0 * i / 64
    phi = np.pi * (1.0 + 5.0 ** 0.5) * i
    dirs = np.stack([np.sqrt(1.0 - z * z) * np.cos(phi), np.sqrt(1.0 - z * z) * np.sin(phi), z], axis=1)  # [64, 3]
    Y = _sh_basis_values(degree, dirs)  # [64, K]
    Y_rot = _sh_basis_values(degree, dirs @ R)  # rows R^T d: the old direction of each new one
    for band in range(1, degree + 1):
        sl = slice(band * band, (band + 1) * (band + 1))
        # f_new(d) = f(R^T d): Y(d) . c_new = Y(R^T d) . c for every d, so c_new = pinv(Y) Y_rot c
        block, *_ = np.linalg.lstsq(Y[:, sl], Y_rot[:, sl], rcond=None)
        out[sl.start - 1:sl.stop - 1, sl.start - 1:sl.stop - 1] = block
    return out


def _quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the Hamilton products ``a * b`` of w,x,y,z quaternions (``a`` [4] or [N, 4], ``b`` [N, 4])."""
    aw, ax, ay, az = np.moveaxis(np.broadcast_to(a, b.shape), -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def transform_cloud(cloud: GaussianCloud, similarity: Similarity) -> GaussianCloud:
    """Return ``cloud`` moved by ``similarity``: means, rotations, scales, normals and every SH band (extras kept).

    Rotations are composed as ``q_R * q`` on the stored (unnormalised) quaternions, so their norms are kept; a
    zero quaternion stays zero.

    Example:
        >>> c = GaussianCloud.from_activated(np.array([[1.0, 0.0, 0.0]]), scales=np.full((1, 3), 0.1),
        ...                                  opacities=np.array([0.5]), rgb=np.full((1, 3), 0.5))
        >>> moved = transform_cloud(c, Similarity(euler_rotation(0, 0, 90), np.zeros(3), 2.0))
        >>> np.round(moved.means, 5).tolist(), np.round(moved.scales.astype(float), 5).tolist()
        ([[0.0, 2.0, 0.0]], [[0.2, 0.2, 0.2]])
    """
    if similarity.is_identity():
        return cloud.copy()
    R, s = similarity.rotation, similarity.scale
    means = similarity.apply(cloud.means).astype(cloud.means.dtype)
    q_r = rotmat_to_qvec(R)
    quats = _quat_multiply(q_r, cloud.quats_wxyz.astype(np.float64)).astype(cloud.quats_wxyz.dtype)
    log_scales = (cloud.log_scales.astype(np.float64) + math.log(s)).astype(cloud.log_scales.dtype)
    sh_rest = cloud.sh_rest
    if cloud.sh_degree > 0:
        M = sh_rotation(R, cloud.sh_degree)  # [K-1, K-1]
        sh_rest = np.einsum("ij,njc->nic", M, cloud.sh_rest.astype(np.float64)).astype(cloud.sh_rest.dtype)
    normals = None if cloud.normals is None else (cloud.normals.astype(np.float64) @ R.T).astype(cloud.normals.dtype)
    return GaussianCloud(means, quats, log_scales, cloud.opacity_logits.copy(), cloud.sh_dc.copy(), sh_rest,
                         {k: v.copy() for k, v in cloud.extras.items()}, normals)
