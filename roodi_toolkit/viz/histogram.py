"""The histogram to tune a prune's threshold by eye: the per-Gaussian values the prune judged, its threshold marked.

:mod:`roodi_toolkit.viz.inspect` shows the same prune in 3D (and re-exports these functions, as ``inspect --histogram``
and the library's users know them).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure

from ..errors import ConfigError, OutputError
from ..io.files import atomic_path

if TYPE_CHECKING:  # pragma: no cover
    from ..prune.outliers import PruneReport

__all__ = ["distance_is_log", "distance_label", "histogram_figure", "save_histogram"]


def distance_is_log(report: "PruneReport") -> bool:
    """Return whether the report's per-Gaussian values are the statistical rule's distances (shown on a log scale)
    rather than the local tests' blob scores (:func:`roodi_toolkit.prune.scene.blob_scores`, already a log ratio,
    shown on a linear scale), which the scene and object modes report in ``mean_distances``."""
    return report.mode == "statistical"


def distance_label(report: "PruneReport") -> str:
    """Return what the report's distances are, e.g. ``"mean W2² to the 16 nearest"``, for axis and bar titles."""
    if not distance_is_log(report):
        return "blob score (smallest axis over spacing and neighbours' size, log units)"
    cfg = report.config
    k = cfg.get("k", "K")
    if cfg.get("distance", "w2") == "w2":
        return f"mean W2² to {k} neighbours"
    return f"mean distance to {k} neighbours"


def histogram_figure(report: "PruneReport", *, bins: int = 80, figsize: tuple[float, float] = (7.5, 4.2),
                     title: str | None = None, keep: np.ndarray | None = None) -> "Figure":
    """Return a matplotlib figure of the per-Gaussian values the prune judged, with its threshold marked.

    For the statistical rule these are the mean neighbour distances (log x axis); the Gaussians past the threshold
    (the statistical stage's removals) are shaded and their share annotated, and for iterative rules the
    first-round threshold is drawn dashed. For the local tests (scene and object modes) they are the blob scores
    (a log ratio, linear x axis) with the oversized limit; there the Gaussians shaded as removed are those any test
    removed (detached, oversized, fog, after the photo check) when ``keep`` is given, else those over the limit.
    The threshold drawn is ``report.threshold``, the one ``prune --report`` writes.

    Args:
        report: the report of :func:`~roodi_toolkit.prune.scene.prune_cloud` or
            :func:`~roodi_toolkit.prune.outliers.remove_statistical_outliers`.
        bins: histogram bins (log-spaced for distances).
        figsize: figure size in inches.
        title: figure title (defaults to the rule and its alpha, or the mode and its limit).
        keep: ``[N]`` the prune's keep mask (local modes: which evaluated Gaussians count as removed).

    Example:
        >>> from roodi_toolkit.prune.outliers import remove_statistical_outliers
        >>> from roodi_toolkit.synth.floaters import FloaterMix, planted_floater_cloud
        >>> report = remove_statistical_outliers(planted_floater_cloud(FloaterMix(n_object=2000), 0).cloud).report
        >>> fig = histogram_figure(report)
        >>> bool(fig.axes[0].get_xscale() == "log"), fig._roodi_threshold == report.threshold
        (True, True)
    """
    d = np.asarray(report.mean_distances, dtype=np.float64)
    if d.size == 0:
        raise ConfigError("the report has no per-Gaussian distances (nothing reached the statistics)")
    threshold = float(report.threshold)
    log_x = distance_is_log(report)
    flagged = d > threshold
    if not log_x and keep is not None:
        flagged = ~np.asarray(keep, dtype=bool)[np.asarray(report.evaluated, dtype=np.int64)]
    shown = (d > 0) if log_x else np.isfinite(d)
    hidden = int((~shown).sum())
    cfg = report.config

    fig = Figure(figsize=figsize)
    ax = fig.add_subplot(1, 1, 1)
    if shown.any():
        lo, hi = float(d[shown].min()), float(d[shown].max())
        if np.isfinite(threshold) and (threshold > 0 or not log_x):
            lo, hi = min(lo, threshold), max(hi, threshold)
        if hi <= lo:
            hi = lo * 1.01 + 1e-30 if log_x else lo + 1.0
        edges = np.geomspace(lo, hi, bins + 1) if log_x else np.linspace(lo, hi, bins + 1)
        ax.hist(d[shown & ~flagged], bins=edges, color="#4c78a8", label="kept")
        if (shown & flagged).any():
            ax.hist(d[shown & flagged], bins=edges, color="#e45756", label="removed")
    if log_x:
        ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(distance_label(report) + (" (log scale)" if log_x else ""))
    ax.set_ylabel("Gaussians")
    if np.isfinite(threshold) and (threshold > 0 or not log_x):
        name = "threshold" if log_x else "oversized limit"
        ax.axvline(threshold, color="black", linewidth=1.5, label=f"{name} {threshold:.4g}")
    first = report.thresholds[0] if report.thresholds else float("nan")
    if len(report.thresholds) > 1 and np.isfinite(first) and first > 0 and not np.isclose(first, threshold):
        ax.axvline(first, color="grey", linestyle="--", linewidth=1, label=f"first round {first:.4g}")
    share = float(flagged.mean())
    note = f"removed {share:.2%} ({int(flagged.sum()):,} of {d.size:,} evaluated)"
    if hidden:
        note += f"\n{hidden:,} at distance 0 not shown" if log_x else f"\n{hidden:,} without a score not shown"
    ax.text(0.98, 0.95, note, transform=ax.transAxes, ha="right", va="top", fontsize=9,
            bbox={"facecolor": "white", "alpha": 0.85, "edgecolor": "none"})
    ax.legend(loc="best", fontsize=8, frameon=False)
    if title is None:
        title = (f"rule {cfg.get('rule', '?')}, alpha {cfg.get('alpha', float('nan')):g}, K {cfg.get('k', '?')}"
                 if log_x else f"{report.mode} mode, K {cfg.get('k', '?')}")
    ax.set_title(title)
    fig.tight_layout()
    # what the picture shows, for save_histogram's PNG metadata and for tests
    fig._roodi_threshold = threshold  # type: ignore[attr-defined]
    fig._roodi_removed_share = share  # type: ignore[attr-defined]
    return fig


def save_histogram(fig: "Figure", path: str | os.PathLike, dpi: int = 110) -> None:
    """Write the histogram figure atomically; a PNG carries the threshold and removed share as text metadata.

    The metadata (keys ``roodi:threshold``, ``roodi:removed_share``, full precision) lets a script read back
    exactly which threshold the picture marks.
    """
    metadata: dict[str, str] = {}
    if str(path).lower().endswith(".png"):
        for key, attr in (("roodi:threshold", "_roodi_threshold"), ("roodi:removed_share", "_roodi_removed_share")):
            if hasattr(fig, attr):
                metadata[key] = repr(float(getattr(fig, attr)))
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight", metadata=metadata or None)
    except ValueError as exc:  # unknown format from the extension
        raise OutputError(f"{path}: cannot write the histogram ({exc})") from None
