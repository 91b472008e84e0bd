"""Summary statistics of a Gaussian cloud in user units (what ``roodi-toolkit info`` shows)."""

from __future__ import annotations

from typing import Any

import numpy as np

from .gaussians import LOW_OPACITY, GaussianCloud


def _summary(values: np.ndarray) -> dict[str, float]:
    v = values[np.isfinite(values)]
    if v.size == 0:
        return {"min": float("nan"), "p5": float("nan"), "median": float("nan"), "p95": float("nan"),
                "max": float("nan"), "mean": float("nan")}
    p5, med, p95 = np.percentile(v, [5, 50, 95])
    return {"min": float(v.min()), "p5": float(p5), "median": float(med), "p95": float(p95), "max": float(v.max()),
            "mean": float(v.mean())}


def describe_cloud(cloud: GaussianCloud) -> dict[str, Any]:
    """Return counts and statistics of a cloud: SH degree, bounding box, opacity and scale in user units, bad rows.

    Opacities are linear (sigmoid of the logits), scales are world units (exp of the log-scales); statistics skip
    non-finite values, which are counted separately.

    Example:
        >>> c = GaussianCloud.from_activated(np.eye(3), scales=np.full((3, 3), 0.01), opacities=np.full(3, 0.5),
        ...                                  rgb=np.zeros((3, 3)))
        >>> d = describe_cloud(c)
        >>> d["count"], d["bbox"]["max"], round(d["opacity"]["median"], 3)
        (3, [1.0, 1.0, 1.0], 0.5)
    """
    nonfinite = cloud.nonfinite_rows()
    finite = ~nonfinite
    means = cloud.means[finite].astype(np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        opac = cloud.opacities.astype(np.float64)
        scales = np.exp(cloud.log_scales.astype(np.float64))
    if means.size:
        lo, hi = means.min(axis=0), means.max(axis=0)
        bbox = {"min": lo.tolist(), "max": hi.tolist(), "size": (hi - lo).tolist(), "center": ((lo + hi) / 2).tolist()}
    else:
        bbox = {"min": None, "max": None, "size": None, "center": None}
    return {
        "count": len(cloud),
        "sh_degree": cloud.sh_degree,
        "bbox": bbox,
        "opacity": {**_summary(opac[finite]), "below_1_255": int(np.sum(opac[finite] < LOW_OPACITY))},
        "scale_max_axis": _summary(scales[finite].max(axis=1) if finite.any() else np.empty(0)),
        "scale_min_axis": _summary(scales[finite].min(axis=1) if finite.any() else np.empty(0)),
        "nonfinite_rows": int(nonfinite.sum()),
        "zero_norm_quats": int(cloud.zero_quat_rows().sum()),
        "extra_columns": {name: str(col.dtype) for name, col in cloud.extras.items()},
        "has_normals": cloud.normals is not None,
    }
