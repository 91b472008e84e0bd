"""The README's main job on embedded data: plant floaters around an object's surface, prune them, show the result.

Needs no GPU, no downloads and no input files: the cloud is generated (:mod:`roodi_toolkit.synthetic`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .gaussians import GaussianCloud
from .progress import ProgressFactory, null_progress


@dataclass
class DemoResult:
    """Where the demo wrote its files and how well pruning did against the planted truth."""

    out_dir: Path
    files: dict[str, Path]
    scores: dict[str, float]
    input_count: int
    kept_count: int
    seconds: float


def _projection_panel(ax, cloud: GaussianCloud, keep: np.ndarray, axes: tuple[int, int], title: str) -> None:
    rgb = np.clip(cloud.rgb, 0, 1)
    x, y = cloud.means[:, axes[0]], cloud.means[:, axes[1]]
    ax.scatter(x[keep], y[keep], s=0.3, c=rgb[keep], linewidths=0, rasterized=True)
    if (~keep).any():
        ax.scatter(x[~keep], y[~keep], s=2.5, c="red", linewidths=0, rasterized=True, label="removed")
        ax.legend(loc="upper right", markerscale=3, fontsize=8)
    ax.set_title(title, fontsize=9)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def run_prune_demo(out_dir: str | Path, *, seed: int = 0, surface: str = "ant", n_object: int = 20_000,
                   overwrite: bool = False, progress: ProgressFactory = null_progress) -> DemoResult:
    """Return the figures of a prune run on a generated cloud with planted floaters, after writing its files.

    Writes ``with_floaters.ply`` (the input), ``pruned.ply``, ``floaters.ply`` (what was removed), ``report.json`` and
    ``prune_demo.png`` (the cloud before and after, removed Gaussians in red) into ``out_dir``.
    """
    import time

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from . import files
    from .outliers import remove_statistical_outliers
    from .ply import write_ply
    from .synthetic import FloaterMix, planted_floater_cloud, removal_scores

    out = files.prepare_output_dir(out_dir, overwrite=overwrite)
    t0 = time.perf_counter()
    planted = planted_floater_cloud(FloaterMix(surface, n_object=n_object), seed=seed)
    paths = {"input": out / "with_floaters.ply", "pruned": out / "pruned.ply", "floaters": out / "floaters.ply",
             "report": out / "report.json", "picture": out / "prune_demo.png"}
    write_ply(planted.cloud, paths["input"])
    pruned, keep, report = remove_statistical_outliers(planted.cloud, progress=progress)
    write_ply(pruned, paths["pruned"])
    if (~keep).any():
        write_ply(planted.cloud.select(~keep), paths["floaters"])
    else:
        del paths["floaters"]
    scores = removal_scores(planted.labels, keep)
    summary = report.to_dict()
    summary["planted_truth"] = {"object_lost": scores["object"], "far_removed": scores["far"],
                                "near_removed": scores["near"]}
    files.write_json(summary, paths["report"])

    # look along the axis in which the object is thinnest, so its outline is clearest
    extent = np.ptp(pruned.means, axis=0)
    thin = int(np.argmin(extent))
    view = tuple(i for i in range(3) if i != thin)
    along = "xyz"[thin]
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.2))
    _projection_panel(axes[0], planted.cloud, np.ones(len(keep), dtype=bool), view,
                      f"input: {len(keep):,} Gaussians (view along {along})")
    _projection_panel(axes[1], planted.cloud, keep, view, f"flagged by pruning: {(~keep).sum():,}")
    _projection_panel(axes[2], pruned, np.ones(len(pruned), dtype=bool), view, f"pruned: {len(pruned):,}")
    fig.suptitle(f"W2 statistical outlier pruning: far floaters removed {scores['far']:.1%}, near-surface floaters "
                 f"removed {scores['near']:.1%}, object lost {scores['object']:.2%}", fontsize=10)
    files.save_figure(fig, paths["picture"])
    return DemoResult(out, paths, scores, len(keep), int(keep.sum()), time.perf_counter() - t0)
