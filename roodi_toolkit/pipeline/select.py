"""Select one object's Gaussians from a distilled scene, then prune its floaters (ROODI Sec. 3.2, Fig. 2d).

Selection applies the distillation's classifier to each Gaussian's own feature (a 1x1 convolution is a linear map per
pixel, hence per feature vector) and keeps the Gaussians whose softmax probability of the target exceeds 0.3
(Gaussian Grouping's removal threshold); the statistical outlier removal of :mod:`roodi_toolkit.prune.outliers` then
drops the floaters, giving the crude object model of the paper's Fig. 2d.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
import torch
from torch import Tensor

from ..errors import ConfigError, InputError
from ..gaussians import GaussianCloud
from ..progress import ProgressFactory, null_progress
from ..render.renderer import Renderer
from ..prune.outliers import PruneConfig, PruneReport
from .distill import ObjectClassifier, cloud_features


def gaussian_probabilities(cloud: GaussianCloud, classifier: ObjectClassifier) -> Tensor:
    """Return each Gaussian's class probabilities ``[N, C]``: the classifier applied to its own feature."""
    feats = cloud_features(cloud)
    if feats.shape[1] != classifier.feature_dim:
        raise InputError(f"the model has {feats.shape[1]} object features but the classifier expects "
                         f"{classifier.feature_dim}; were they saved by different distillations?")
    with torch.no_grad():
        return classifier.probabilities(feats)


@dataclass
class Selection:
    """One object taken out of a distilled scene.

    Attributes:
        cloud: the object's Gaussians after pruning (or before, without pruning).
        selected: Gaussians over the scene whose target probability exceeds the threshold. [N] bool
        keep: Gaussians over the scene in ``cloud``. [N] bool
        probabilities: each scene Gaussian's target probability. [N]
        prune_report: the pruning report, or None without pruning.
    """

    cloud: GaussianCloud
    selected: np.ndarray
    keep: np.ndarray
    probabilities: np.ndarray
    prune_report: Optional[PruneReport]


def select_object(cloud: GaussianCloud, classifier: ObjectClassifier, object_id: int, *, threshold: float = 0.3,
                  prune: bool = True, prune_config: PruneConfig | None = None,
                  progress: ProgressFactory = null_progress) -> Selection:
    """Return the Gaussians of object ``object_id``: probability above ``threshold``, then outlier removal.

    Args:
        cloud: a distilled scene (with ``object_feature_*`` columns).
        classifier: its classifier.
        object_id: the class id of the object (an instance id of the masks; 1 for binary masks).
        threshold: softmax probability the Gaussian's own feature must exceed (Gaussian Grouping: 0.3).
        prune: remove statistical outliers from the selection (paper: at this point).
        prune_config: pruning settings (default: the pruning module's defaults).
        progress: progress factory for the pruning.

    Raises:
        ConfigError: a bad id or threshold, or no Gaussian above the threshold.
    """
    if not 0 <= object_id < classifier.num_classes:
        raise ConfigError(f"object id {object_id} is not one of the classifier's classes 0..{classifier.num_classes - 1}")
    if not 0 < threshold < 1:
        raise ConfigError(f"threshold is a probability in (0, 1), got {threshold}")
    prob = gaussian_probabilities(cloud, classifier)[:, object_id].numpy()
    selected = prob > threshold
    if not selected.any():
        raise ConfigError(f"no Gaussian has a probability above {threshold} for object {object_id} (highest "
                          f"{prob.max():.3f}); check the id or lower --threshold")
    selection = Selection(cloud.select(selected), selected, selected.copy(), prob, None)
    return prune_selection(selection, prune_config, progress=progress) if prune else selection


def prune_selection(selection: Selection, config: PruneConfig | None = None, *,
                    progress: ProgressFactory = null_progress) -> Selection:
    """Return ``selection`` with statistical outliers removed from its Gaussians (paper: at this point).

    Raises:
        ConfigError: no more Gaussians selected than the ``k`` neighbours the pruning needs.
    """
    from ..prune.outliers import remove_statistical_outliers

    config = config or PruneConfig()
    if len(selection.cloud) <= config.k:
        raise ConfigError(f"only {len(selection.cloud)} Gaussians selected, too few to prune with k = {config.k}; use "
                          "--no-prune or check the object id")
    obj, sub_keep, report = remove_statistical_outliers(selection.cloud, config, progress=progress)
    keep = np.zeros(len(selection.keep), bool)
    keep[np.flatnonzero(selection.selected)[sub_keep]] = True
    return Selection(obj, selection.selected, keep, selection.probabilities, report)


def run_select(distill_dir: str | Path, object_id: int, output_ply: str | Path, *, threshold: float = 0.3,
               prune: bool = True, prune_config: PruneConfig | None = None, picture: str | Path | None = None,
               overwrite: bool = False, progress: ProgressFactory = null_progress,
               renderer: Renderer | None = None) -> dict[str, Any]:
    """Select object ``object_id`` of a distillation folder, write it as a PLY and a picture (drawn by ``renderer``,
    default the built-in CPU one); return a summary.

    The picture (default ``OUT.png`` beside ``OUT.ply``) shows per view: the image, the object's mask, the rendered
    probability of the object, and the selected Gaussians rendered alone on white. It needs the dataset the
    distillation used; without it no picture is written. Nothing is written into the distillation or model folder.
    """
    from ..io import files
    from ..io.ply import write_ply
    from ..render.pictures import heat, probability_grid
    from ..params import GaussianParams
    from ..render.renderer import render_cloud, resolve_renderer
    from .distill import _picture_views, load_distillation, render_features

    distillation, cloud, classifier = load_distillation(distill_dir)
    # the distillation, the whole model folder (not only the PLY's iteration folder) and the dataset are inputs
    record = distillation.record
    inputs = [distillation.root, distillation.model_ply.parent, record.get("model_dir"), record.get("data_dir")]
    out = Path(output_ply)
    pic = Path(picture) if picture is not None else out.with_suffix(".png")
    files.check_outputs([("OUT.ply", out), ("--picture", pic)], overwrite=overwrite, inputs=inputs)
    sel = select_object(cloud, classifier, object_id, threshold=threshold, prune=prune, prune_config=prune_config,
                        progress=progress)
    write_ply(sel.cloud, out)
    summary: dict[str, Any] = {
        "object": object_id, "label": classifier.labels.get(object_id, ""), "threshold": threshold,
        "num_gaussians": len(cloud), "selected": int(sel.selected.sum()), "kept": len(sel.cloud),
        "pruned": None if sel.prune_report is None else int(sel.selected.sum() - len(sel.cloud)),
        "output": str(out), "picture": None,
    }
    record = distillation.record
    data_dir = record.get("data_dir")
    if data_dir and Path(data_dir).exists() and distillation.masks_dir.is_dir():
        from ..io.dataset import load_dataset
        from .segment import FilesSegmenter, SegmentPrompt
        from .train import split_views

        dataset = load_dataset(data_dir, float(record.get("downscale", 1)))
        masks = FilesSegmenter(distillation.masks_dir).segment(dataset, SegmentPrompt())
        train_views, eval_views = split_views(dataset, int(record.get("holdout_every", 8)))
        feats = cloud_features(cloud)
        frozen = GaussianParams.from_cloud(cloud, sh_degree=0)
        renderer = resolve_renderer(renderer)
        rows = []
        with torch.no_grad():
            for v in _picture_views(eval_views, train_views):
                cam = dataset.cameras[v]
                prob = classifier.probabilities(render_features(frozen, feats, cam, renderer=renderer))[
                    ..., object_id].numpy()
                alone = render_cloud(sel.cloud, cam, renderer=renderer, background=(1.0, 1.0, 1.0)).rgb.clamp(
                    0, 1).numpy()
                target = (masks.masks[v].numpy() == object_id).astype(np.float32)
                rows.append([dataset.images[v].numpy(), target, heat(prob), alone])
        summary["picture"] = str(files.write_image(probability_grid(rows), pic))
        summary["picture_columns"] = ["image", "mask of the object", "rendered probability", "selection alone"]
    return summary
