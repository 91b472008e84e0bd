"""Real spherical harmonics of degree 0-3 with the constants and sign conventions of the reference 3DGS code.

Colours are ``max(0, 0.5 + sum_k basis_k(dir) * coeff_k)`` where ``dir`` is the unit vector from the camera centre
to the Gaussian's mean (3DGS ``computeColorFromSH``, gsplat ``spherical_harmonics`` + ``clamp_min(colors + 0.5, 0)``).
Coefficients are ``[N, K, 3]``, coefficient-major (as :attr:`roodi_toolkit.gaussians.GaussianCloud.sh`), DC first.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .errors import ConfigError
# defined with the cloud, whose colour needs them without importing torch (and moving a cloud turns its SH bands)
from .gaussians import SH_C0, SH_C1, SH_C2, SH_C3


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

