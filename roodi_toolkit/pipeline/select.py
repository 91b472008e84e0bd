"""Select one object's Gaussians from a distilled scene, then prune its floaters (ROODI Sec. 3.2, Fig. 2d).

Selection applies the distillation's classifier to each Gaussian's own feature (a 1x1 convolution is a linear map per
pixel, hence per feature vector) and keeps the Gaussians whose softmax probability of the target exceeds 0.3
(Gaussian Grouping's removal threshold); the statistical outlier removal of :mod:`roodi_toolkit.prune.outliers` then
drops the floaters, giving the crude object model of the paper's Fig. 2d. Nothing here opens a file (a
distillation folder's selection, its PLY and picture: :mod:`roodi_toolkit.run.select`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import torch
from torch import Tensor

from ..errors import ConfigError, InputError
from ..gaussians import GaussianCloud
from ..progress import ProgressFactory, null_progress
from ..prune.outliers import PruneConfig, PruneReport, remove_statistical_outliers
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
    config = config or PruneConfig()
    if len(selection.cloud) <= config.k:
        raise ConfigError(f"only {len(selection.cloud)} Gaussians selected, too few to prune with k = {config.k}; use "
                          "--no-prune or check the object id")
    obj, sub_keep, report = remove_statistical_outliers(selection.cloud, config, progress=progress)
    keep = np.zeros(len(selection.keep), bool)
    keep[np.flatnonzero(selection.selected)[sub_keep]] = True
    return Selection(obj, selection.selected, keep, selection.probabilities, report)
