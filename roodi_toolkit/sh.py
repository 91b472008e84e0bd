"""Real spherical harmonics of degree 0-3 with the constants and sign conventions of the reference 3DGS code.

Colours are ``max(0, 0.5 + sum_k basis_k(dir) * coeff_k)`` where ``dir`` is the unit vector from the camera centre
to the Gaussian's mean (3DGS ``computeColorFromSH``, gsplat ``spherical_harmonics`` + ``clamp_min(colors + 0.5, 0)``).
Coefficients are ``[N, K, 3]``, coefficient-major (as :attr:`roodi_toolkit.gaussians.GaussianCloud.sh`), DC first.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .errors import ConfigError
from .gaussians import SH_C0  # defined with the cloud, whose colour needs it without importing torch
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
         1.445305721320277, -0.5900435899266435)


def num_sh_bases(degree: int) -> int:
    """Return the number of SH coefficients per channel, ``(degree + 1) ** 2``, for degree 0..3."""
    if degree not in (0, 1, 2, 3):
        raise ConfigError(f"SH degree must be 0, 1, 2 or 3, got {degree}")
    return (degree + 1) ** 2


def sh_bases(degree: int, dirs: Tensor) -> Tensor:
    """Return the real SH basis values ``[..., (degree+1)^2]`` at unit directions.

    Args:
        degree: 0..3.
        dirs: unit vectors. [..., 3]

    Example:
        >>> sh_bases(1, torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)).tolist()
        [[0.28209479177387814, -0.0, 0.4886025119029199, -0.0]]
    """
    n = num_sh_bases(degree)
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, SH_C0)]
    if n > 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if n > 4:
        xx, yy, zz = x * x, y * y, z * z
        xy, yz, xz = x * y, y * z, x * z
        out += [SH_C2[0] * xy, SH_C2[1] * yz, SH_C2[2] * (2.0 * zz - xx - yy), SH_C2[3] * xz, SH_C2[4] * (xx - yy)]
    if n > 9:
        out += [
            SH_C3[0] * y * (3.0 * xx - yy),
            SH_C3[1] * xy * z,
            SH_C3[2] * y * (4.0 * zz - xx - yy),
            SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            SH_C3[4] * x * (4.0 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(out, dim=-1)


def eval_sh_colors(sh: Tensor, dirs: Tensor, degree: int | None = None) -> Tensor:
    """Return view-dependent RGB ``[N, 3]`` (3DGS convention: +0.5, clamped below at 0) of SH coefficients.

    Args:
        sh: coefficients, DC first, coefficient-major. [N, K, 3]
        dirs: viewing directions camera -> Gaussian, need not be unit length. [N, 3]
        degree: use only the bases up to this degree (the progressive SH of 3DGS training); default all of ``sh``.

    Example:
        >>> sh = torch.zeros(1, 4, 3); sh[0, 2] = 1.0  # the z basis only
        >>> eval_sh_colors(sh, torch.tensor([[0.0, 0.0, 1.0]])).tolist()[0][0] > eval_sh_colors(
        ...     sh, torch.tensor([[0.0, 0.0, -1.0]])).tolist()[0][0]
        True
    """
    if sh.ndim != 3 or sh.shape[-1] != 3:
        raise ConfigError(f"SH coefficients must have shape [N, K, 3], got {list(sh.shape)}")
    k = sh.shape[1]
    full = {1: 0, 4: 1, 9: 2, 16: 3}.get(k)
    if full is None:
        raise ConfigError(f"{k} SH coefficients per channel is no SH degree (expected 1, 4, 9 or 16)")
    degree = full if degree is None else degree
    if not 0 <= degree <= full:
        raise ConfigError(f"SH degree {degree} needs more than the {k} coefficients given")
    n = num_sh_bases(degree)
    unit = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    bases = sh_bases(degree, unit)  # [N, n]
    return torch.clamp_min(torch.einsum("nk,nkc->nc", bases, sh[:, :n]) + 0.5, 0.0)


def sh_rotation(rotation, degree: int):
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
        >>> import numpy as np
        >>> M = sh_rotation(np.diag([-1.0, -1.0, 1.0]), 1)  # half a turn about z: the x and y bases change sign
        >>> (np.round(M, 12) + 0.0).tolist()
        [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]
    """
    import numpy as np

    R = np.asarray(rotation, dtype=np.float64)
    if R.shape != (3, 3):
        raise ConfigError(f"an SH rotation needs a [3, 3] rotation matrix, got {list(R.shape)}")
    k = num_sh_bases(degree)
    out = np.zeros((k - 1, k - 1))
    if k == 1:
        return out
    # a fixed, well spread set of directions: a Fibonacci sphere of 64 points (far more than the 7 of band 3)
    i = np.arange(64) + 0.5
    z = 1.0 - 2.0 * i / 64
    phi = np.pi * (1.0 + 5.0 ** 0.5) * i
    dirs = np.stack([np.sqrt(1.0 - z * z) * np.cos(phi), np.sqrt(1.0 - z * z) * np.sin(phi), z], axis=1)  # [64, 3]
    Y = sh_bases(degree, torch.from_numpy(dirs)).numpy()  # [64, K]
    Y_rot = sh_bases(degree, torch.from_numpy(dirs @ R)).numpy()  # rows R^T d: the old direction of each new one
    for band in range(1, degree + 1):
        sl = slice(band * band, (band + 1) * (band + 1))
        # f_new(d) = f(R^T d): Y(d) . c_new = Y(R^T d) . c for every d, so c_new = pinv(Y) Y_rot c
        block, *_ = np.linalg.lstsq(Y[:, sl], Y_rot[:, sl], rcond=None)
        out[sl.start - 1:sl.stop - 1, sl.start - 1:sl.stop - 1] = block
    return out
