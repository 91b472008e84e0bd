"""Projection of 3D Gaussians into a pinhole camera (EWA splatting), fast and as a reference written from the equations.

As the reference 3DGS rasterizer ("classic" mode): ``cov2d = J W Sigma W^T J^T + eps2d * I`` with the perspective
Jacobian ``J`` evaluated at the camera-space mean whose ``x/z`` and ``y/z`` are clamped to the view frustum widened by
30% (3DGS' ``1.3 * tan(fov)``, gsplat's ``lim_x_pos/lim_x_neg`` for off-centre principal points); ``eps2d = 0.3``.
Gaussians with ``z <= near`` or ``z >= far`` are culled. :mod:`roodi_toolkit.render.rasterizer` composites the result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from kornia.geometry.conversions import quaternion_to_rotation_matrix
from torch import Tensor

from ..errors import CloudError, ConfigError

__all__ = ["EPS2D", "Projection", "project_gaussians", "project_gaussians_reference", "check_inputs", "camera_tensors"]

EPS2D = 0.3
"""Added to the diagonal of every 2D covariance (3DGS low-pass filter, gsplat ``eps2d``)."""


@dataclass
class Projection:
    """Gaussians projected into one camera (the output of :func:`project_gaussians`).

    Attributes:
        means2d: pixel coordinates of the means. [N, 2]
        cov2d: 2D covariances including ``eps2d``. [N, 2, 2]
        conics: upper triangle ``(a, b, c)`` of the inverse 2D covariance. [N, 3]
        depths: camera-space z. [N]
        in_range: ``near < z < far``. [N]
    """

    means2d: Tensor
    cov2d: Tensor
    conics: Tensor
    depths: Tensor
    in_range: Tensor


# ------------------------------------------------------------------------------------------------ input checking
def _check(name: str, t: Tensor, shape: tuple) -> None:
    if not isinstance(t, Tensor):
        raise CloudError(f"{name} must be a torch.Tensor, got {type(t).__name__}")
    if t.ndim != len(shape) or any(s is not None and d != s for d, s in zip(t.shape, shape)):
        want = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise CloudError(f"{name} must have shape {want}, got {list(t.shape)}")


def camera_tensors(world_to_camera, K, dtype, device) -> tuple[Tensor, Tensor]:
    w2c = torch.as_tensor(np.asarray(world_to_camera) if not isinstance(world_to_camera, Tensor) else world_to_camera)
    k = torch.as_tensor(np.asarray(K) if not isinstance(K, Tensor) else K)
    if w2c.shape != (4, 4):
        raise ConfigError(f"world_to_camera must be [4, 4], got {list(w2c.shape)}")
    if k.shape != (3, 3):
        raise ConfigError(f"K must be [3, 3], got {list(k.shape)}")
    return w2c.to(device=device, dtype=dtype), k.to(device=device, dtype=dtype)


def check_inputs(means, quats_wxyz, log_scales, opacity_logits, colors, features, width, height, near, far):
    _check("means", means, (None, 3))
    n = means.shape[0]
    _check("quats_wxyz", quats_wxyz, (n, 4))
    _check("log_scales", log_scales, (n, 3))
    _check("opacity_logits", opacity_logits, (n,))
    if colors.ndim == 2:
        _check("colors", colors, (n, 3))
    else:
        _check("colors", colors, (n, None, 3))
        if colors.shape[1] not in (1, 4, 9, 16):
            raise CloudError(f"colors as SH must have 1, 4, 9 or 16 coefficients, got {colors.shape[1]}")
    if features is not None:
        _check("features", features, (n, None))
    if not means.dtype.is_floating_point:
        raise CloudError(f"means must be floating point, got {means.dtype}")
    if int(width) <= 0 or int(height) <= 0:
        raise ConfigError(f"image size must be positive, got {width}x{height}")
    if not 0 < near < far:
        raise ConfigError(f"need 0 < near < far, got near={near} far={far}")


# ------------------------------------------------------------------------------------------------ projection
def project_gaussians(
    means: Tensor,  # [N, 3]
    quats_wxyz: Tensor,  # [N, 4]
    log_scales: Tensor,  # [N, 3]
    world_to_camera: Tensor,  # [4, 4]
    K: Tensor,  # [3, 3]
    width: int,
    height: int,
    *,
    near: float = 0.01,
    far: float = 1e10,
    eps2d: float = EPS2D,
) -> Projection:
    """Return the EWA projection of 3D Gaussians into a pinhole camera (differentiable).

    Args:
        means: world-space centres. [N, 3]
        quats_wxyz: rotations, w first, not necessarily normalised (zero -> identity). [N, 4]
        log_scales: log standard deviations along the rotated axes. [N, 3]
        world_to_camera: OpenCV-axes view matrix. [4, 4]
        K: intrinsics. [3, 3]
        width: image width (sets the Jacobian clamp).
        height: image height.
        near: Gaussians with ``z <= near`` are marked out of range.
        far: Gaussians with ``z >= far`` are marked out of range.
        eps2d: added to the 2D covariance diagonal.

    Example:
        >>> proj = project_gaussians(torch.tensor([[0.0, 0.0, 2.0]]), torch.tensor([[1.0, 0, 0, 0]]),
        ...     torch.log(torch.full((1, 3), 0.1)), torch.eye(4), torch.tensor([[100.0, 0, 32], [0, 100, 32], [0, 0, 1]]),
        ...     64, 64)
        >>> proj.means2d.tolist(), round(proj.cov2d[0, 0, 0].item(), 4)  # (100 * 0.1 / 2)^2 + 0.3
        ([[32.0, 32.0]], 25.3)
    """
    R = quaternion_to_rotation_matrix(quats_wxyz)  # [N, 3, 3]
    M = R * torch.exp(log_scales)[:, None, :]
    W = world_to_camera[:3, :3]
    cam = means @ W.T + world_to_camera[:3, 3]
    Mc = W @ M  # camera-space R S
    z = cam[:, 2]
    in_range = (z > near) & (z < far)
    z = torch.where(in_range, z, torch.ones_like(z))  # keep culled Gaussians finite (no NaN in the backward)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    tan_fovx = 0.5 * width / fx
    tan_fovy = 0.5 * height / fy
    xz = cam[:, 0] / z
    yz = cam[:, 1] / z
    xz_c = torch.minimum(torch.maximum(xz, -(cx / fx + 0.3 * tan_fovx)), (width - cx) / fx + 0.3 * tan_fovx)
    yz_c = torch.minimum(torch.maximum(yz, -(cy / fy + 0.3 * tan_fovy)), (height - cy) / fy + 0.3 * tan_fovy)
    # J = [[fx/z, 0, -fx x/z^2], [0, fy/z, -fy y/z^2]] with the clamped x/z, y/z; T = J Mc is [N, 2, 3]
    T0 = (fx / z)[:, None] * (Mc[:, 0, :] - xz_c[:, None] * Mc[:, 2, :])
    T1 = (fy / z)[:, None] * (Mc[:, 1, :] - yz_c[:, None] * Mc[:, 2, :])
    c00 = (T0 * T0).sum(-1) + eps2d
    c01 = (T0 * T1).sum(-1)
    c11 = (T1 * T1).sum(-1) + eps2d
    det = (c00 * c11 - c01 * c01).clamp_min(1e-30)
    conics = torch.stack([c11 / det, -c01 / det, c00 / det], dim=-1)
    means2d = torch.stack([fx * xz + cx, fy * yz + cy], dim=-1)
    cov2d = torch.stack([c00, c01, c01, c11], dim=-1).reshape(-1, 2, 2)
    return Projection(means2d, cov2d, conics, cam[:, 2], in_range)


def project_gaussians_reference(means, quats_wxyz, log_scales, w2c, K, width, height, near, far, eps2d):
    """The projection written with explicit matrices (J W Sigma W^T J^T, matrix inverse), for the dense reference."""
    R = quaternion_to_rotation_matrix(quats_wxyz)  # [N, 3, 3], normalised inside (w, x, y, z)
    S = torch.diag_embed(torch.exp(log_scales))
    Sigma = R @ S @ S @ R.transpose(1, 2)
    W = w2c[:3, :3]
    cam = means @ W.T + w2c[:3, 3]
    tz = cam[:, 2]
    in_range = (tz > near) & (tz < far)
    tz = torch.where(in_range, tz, torch.ones_like(tz))
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    limx_pos = (width - cx) / fx + 0.3 * (0.5 * width / fx)
    limx_neg = cx / fx + 0.3 * (0.5 * width / fx)
    limy_pos = (height - cy) / fy + 0.3 * (0.5 * height / fy)
    limy_neg = cy / fy + 0.3 * (0.5 * height / fy)
    tx = tz * torch.minimum(torch.maximum(cam[:, 0] / tz, -limx_neg), limx_pos)
    ty = tz * torch.minimum(torch.maximum(cam[:, 1] / tz, -limy_neg), limy_pos)
    zero = torch.zeros_like(tz)
    J = torch.stack([fx / tz, zero, -fx * tx / tz**2, zero, fy / tz, -fy * ty / tz**2], -1).reshape(-1, 2, 3)
    cov2d = J @ W @ Sigma @ W.T @ J.transpose(1, 2) + eps2d * torch.eye(2, dtype=means.dtype)
    inv = torch.linalg.inv(cov2d)
    means2d = torch.stack([fx * cam[:, 0] / tz + cx, fy * cam[:, 1] / tz + cy], -1)
    return means2d, inv, cam[:, 2], in_range
