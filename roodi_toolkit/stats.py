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


ABSURD_SCALE_FACTOR = 1.0
"""A Gaussian is counted as absurdly large when its largest scale (1 sigma) exceeds this times the diagonal of the
bounding box of all finite centres: no real splat needs a Gaussian wider than the scene it belongs to."""


def absurd_scale_rows(cloud: GaussianCloud) -> np.ndarray:
    """``[N]`` bool, True where a Gaussian's largest scale is wider than the scene (see :data:`ABSURD_SCALE_FACTOR`)
    or so large that it overflows (a finite log-scale such as 1e30 whose scale is infinite); infinite or NaN
    log-scales are non-finite rows instead."""
    with np.errstate(over="ignore", invalid="ignore"):
        largest = np.exp(cloud.log_scales.astype(np.float64)).max(axis=1)
    raw_finite = np.isfinite(cloud.log_scales).all(axis=1)
    out = raw_finite & ~np.isfinite(largest)
    finite = np.isfinite(cloud.means).all(axis=1)
    if not finite.any():
        return out
    pts = cloud.means[finite].astype(np.float64)
    diag = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
    if diag <= 0:
        return out
    return out | (np.isfinite(largest) & (largest > ABSURD_SCALE_FACTOR * diag))


def count_bad_values(cloud: GaussianCloud) -> dict[str, Any]:
    """Return how many values of each kind are non-finite or extreme, per field, and the rows they touch.

    ``opacity_pos_inf`` / ``opacity_neg_inf`` are fully opaque / transparent Gaussians as quantised formats decode
    them (readers map them to finite logits unless asked for raw values); ``nan`` and ``inf`` count values per raw
    field; ``absurd_scale_rows`` counts Gaussians wider than the scene (see :data:`ABSURD_SCALE_FACTOR`).
    """
    fields = {"means": cloud.means, "quats": cloud.quats_wxyz, "log_scales": cloud.log_scales,
              "opacity": cloud.opacity_logits, "sh_dc": cloud.sh_dc, "sh_rest": cloud.sh_rest}
    nan = {k: int(np.isnan(v).sum()) for k, v in fields.items()}
    inf = {k: int(np.isinf(v).sum()) for k, v in fields.items() if k != "opacity"}
    n = len(cloud)
    nan_rows = np.zeros(n, dtype=bool)
    for v in fields.values():
        nan_rows |= np.isnan(v.reshape(n, -1)).any(axis=1)
    absurd = int(absurd_scale_rows(cloud).sum())
    return {"nan": nan, "inf": inf, "nan_rows": int(nan_rows.sum()),
            "opacity_pos_inf": int(np.isposinf(cloud.opacity_logits).sum()),
            "opacity_neg_inf": int(np.isneginf(cloud.opacity_logits).sum()), "absurd_scale_rows": absurd}


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
        "bad_values": count_bad_values(cloud),
        "zero_norm_quats": int(cloud.zero_quat_rows().sum()),
        "extra_columns": {name: str(col.dtype) for name, col in cloud.extras.items()},
        "has_normals": cloud.normals is not None,
    }
