"""How far two decodings of the same Gaussians are apart, field by field (used to check readers and writers against
the reference implementation, splat-transform)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..errors import CloudError
from ..gaussians import GaussianCloud


def _max_abs(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a.astype(np.float64), b.astype(np.float64)
    both = np.isfinite(a) & np.isfinite(b)
    same_inf = (a == b) & ~np.isfinite(a)  # +inf against +inf agrees
    if not np.all(both | same_inf):
        return float("inf")
    return float(np.abs(a[both] - b[both]).max()) if both.any() else 0.0


def cloud_differences(a: GaussianCloud, b: GaussianCloud, *, match: bool = False) -> dict[str, float]:
    """Return the largest per-field difference between two clouds of the same Gaussians.

    Args:
        a: the reference decoding.
        b: the other one.
        match: pair rows by nearest centre instead of by index (for writers that reorder, such as compressed PLY's
            Morton sort); rows are then compared with the Gaussian of ``a`` nearest to each of ``b``.

    Returns:
        ``position_rel`` (max centre distance per axis over the largest bounding-box side), ``log_scale``,
        ``rotation`` (unit quaternions, sign-insensitive, max component), ``sh_dc``, ``sh_rest``, ``alpha`` (opacity
        after the sigmoid, because 8-bit alphas make logits near 0 and 1 arbitrary) and ``opacity_logit``; plus
        ``count`` of each. A value is inf when one side is non-finite where the other is not.

    Example:
        >>> c = GaussianCloud.from_activated(np.eye(3), scales=np.full((3, 3), 0.1), opacities=np.full(3, 0.5),
        ...                                  rgb=np.zeros((3, 3)))
        >>> cloud_differences(c, c)["position_rel"]
        0.0
    """
    if len(a) != len(b):
        raise CloudError(f"cannot compare clouds of {len(a)} and {len(b)} Gaussians")
    if match:
        _, idx = cKDTree(a.means.astype(np.float64)).query(b.means.astype(np.float64))
        a = a.select(idx)
    finite = np.isfinite(a.means).all(axis=1)
    extent = float(np.ptp(a.means[finite], axis=0).max()) if finite.any() else 1.0
    qa, qb = a.quats_normalized.astype(np.float64), b.quats_normalized.astype(np.float64)
    rot = float(np.minimum(np.abs(qa - qb).max(axis=1), np.abs(qa + qb).max(axis=1)).max())
    per = min(a.sh_rest.shape[1], b.sh_rest.shape[1])
    return {
        "count": float(len(a)),
        "position_rel": _max_abs(a.means, b.means) / (extent or 1.0),
        "log_scale": _max_abs(a.log_scales, b.log_scales),
        "rotation": rot,
        "sh_dc": _max_abs(a.sh_dc, b.sh_dc),
        "sh_rest": _max_abs(a.sh_rest[:, :per], b.sh_rest[:, :per]) if per else 0.0,
        "alpha": _max_abs(a.opacities, b.opacities),
        "opacity_logit": _max_abs(a.opacity_logits, b.opacity_logits),
    }
