"""The filters that run before any pruning mode, as splat-transform users know them: NaN/Inf rows, low opacity, a
box, a sphere and value ranges (``--filter-value NAME,MIN,MAX``)."""

from __future__ import annotations

import time
from dataclasses import asdict

import numpy as np

from ..gaussians import GaussianCloud
from .config import PruneConfig, PruneReport


def named_value(cloud: GaussianCloud, name: str) -> np.ndarray:
    """Return ``[N]`` the quantity a value range bounds (:data:`~roodi_toolkit.prune.outliers.VALUE_NAMES`)."""
    if name in ("x", "y", "z"):
        return cloud.means[:, "xyz".index(name)].astype(np.float64)
    if name == "opacity":
        return cloud.opacities.astype(np.float64)
    log_scales = cloud.log_scales.astype(np.float64)
    return np.exp(log_scales.max(axis=1) if name == "scale" else log_scales.min(axis=1))


def filter_mask(cloud: GaussianCloud, config: PruneConfig) -> tuple[np.ndarray, list[tuple[str, int]]]:
    """Return the keep mask ``[N]`` of the pre-statistics filters and the removed count of each filter, in order.

    Raises:
        CloudError: NaN/Inf rows without ``filter_nan``.
    """
    keep, removed = _filter_stages(cloud, config)
    return keep, [(name, int(mask.sum())) for name, mask, _ in removed]


def _filter_stages(cloud: GaussianCloud, config: PruneConfig) -> tuple[np.ndarray, list[tuple[str, np.ndarray, str]]]:
    """Return the keep mask ``[N]`` after the filters and, per filter in order, its name, what it removed ``[N]``
    and that in a few words."""
    n = len(cloud)
    keep = np.ones(n, dtype=bool)
    stages: list[tuple[str, np.ndarray, str]] = []
    bad = cloud.nonfinite_rows()
    if bad.any() and not config.filter_nan:
        cloud.require_finite("input")
    stages.append(("nonfinite", bad, "NaN or Inf values (--filter-nan)"))
    keep &= ~bad
    if config.min_opacity is not None:
        low = keep & (cloud.opacities < config.min_opacity)
        stages.append(("min_opacity", low, f"opacity under {config.min_opacity:g} (--min-opacity)"))
        keep &= ~low
    if config.box is not None:
        lo, hi = np.asarray(config.box[:3]), np.asarray(config.box[3:])
        inside = np.all((cloud.means >= lo) & (cloud.means <= hi), axis=1)
        stages.append(("box", keep & ~inside, "outside --filter-box"))
        keep &= inside
    if config.sphere is not None:
        c, r = np.asarray(config.sphere[:3], dtype=np.float64), float(config.sphere[3])
        dist2 = np.sum((cloud.means.astype(np.float64) - c) ** 2, axis=1)
        inside = dist2 <= r * r
        stages.append(("sphere", keep & ~inside, "outside --filter-sphere"))
        keep &= inside
    for name, low, high in config.value_ranges:
        with np.errstate(invalid="ignore"):
            value = named_value(cloud, name)
            inside = (value >= low) & (value <= high)
        label = f"{name} in [{low:g}, {high:g}]"
        stages.append((label, keep & ~inside, f"{name} outside [{low:g}, {high:g}] (--filter-value)"))
        keep &= inside
    return keep, stages


def filtered_report(cloud: GaussianCloud, config: PruneConfig) -> tuple[PruneReport, np.ndarray, np.ndarray]:
    """Return a new report holding the filters' stages and time, the keep mask after the filters ``[N]`` and the
    indices of the Gaussians left to evaluate (the common start of every pruning mode)."""
    t0 = time.perf_counter()
    report = PruneReport(input_count=len(cloud))
    report.config = {**asdict(config), "alpha": config.effective_alpha}
    keep, stages = _filter_stages(cloud, config)
    for name, removed, detail in stages:
        report.remove(name, removed, detail)
    report.timings["filters"] = time.perf_counter() - t0
    return report, keep, np.flatnonzero(keep)
