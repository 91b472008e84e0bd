"""The paper's baselines (Sec. 4, Table 1), run from the same trained scene and object features as ROODI.

- **Gaussian Grouping**: the Gaussians whose classifier logit for the target is the largest of all classes
  (``rule="argmax"``; the paper's wording), whose softmax probability exceeds a threshold (``"threshold"``), or, as
  Gaussian Grouping's own code takes an object out of a scene (its ``edit_object_removal.py``), those above the
  threshold (0.3) together with every Gaussian inside the convex hull of their centres, after dropping selected
  centres outside 1x the interquartile range on any axis (``"threshold_hull"``); no pruning, no inpainting.
- **SAGA / OmniSeg3D-GS**: a pixel is clicked on the target; the Gaussians whose own feature has a cosine similarity
  with the feature rendered at that pixel above a threshold are the object. The paper "carefully chose the threshold
  and the pixel for best results"; here both are chosen without looking at the test views: the pixel is the one
  deepest inside the target's mask (distance transform) in the training view that shows most of it, and the threshold
  is the one whose 2D similarity map (rendered features against the clicked feature) best matches the target's masks
  in the training views, which is how a user tunes it in those tools' previews.

Our features are trained with a classifier (Gaussian Grouping's loss), not with SAGA's or OmniSeg3D's contrastive
losses; the issue asks for the selection rules on shared features, so the baselines differ from ROODI only in how
Gaussians are taken out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np
import torch
from scipy.spatial import Delaunay, QhullError

from ..errors import CloudError, ConfigError
from ..gaussians import GaussianCloud
from ..imaging import mask_iou
from ..io.dataset import Dataset
from ..params import GaussianParams
from ..pipeline.distill import ObjectClassifier, cloud_features, render_features
from ..render.renderer import Renderer, resolve_renderer

SIMILARITY_THRESHOLDS = tuple(np.round(np.arange(0.50, 0.991, 0.02), 2))


@dataclass
class BaselineSelection:
    """An object taken out by a baseline.

    Attributes:
        cloud: its Gaussians.
        keep: which scene Gaussians it holds. [N] bool
        details: how it was chosen (rule, click, threshold, 2D IoU of the chosen threshold ...).
    """

    cloud: GaussianCloud
    keep: np.ndarray
    details: dict


def _take(cloud: GaussianCloud, keep: np.ndarray, what: str) -> GaussianCloud:
    if not keep.any():
        raise CloudError(f"{what} selected no Gaussian")
    out = cloud.select(np.flatnonzero(keep))
    out.extras = {k: v for k, v in out.extras.items() if not k.startswith("object_feature_")}
    return out


def inside_hull(points: np.ndarray, chosen: np.ndarray, iqr_factor: float = 1.0) -> np.ndarray:
    """Return which of ``points`` [N, 3] lie inside the convex hull of the ``chosen`` ones [N] (bool), after dropping
    chosen points beyond ``iqr_factor`` interquartile ranges below the first or above the third quartile on any axis;
    all False when fewer than 4 remain or they span no volume.

    Example:
        >>> corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
        >>> pts = np.vstack([corners, [[0.5, 0.5, 0.5], [2.0, 0.5, 0.5]]])
        >>> inside_hull(pts, np.r_[np.ones(8, bool), False, False]).tolist()[-2:]
        [True, False]
    """
    points = np.asarray(points, dtype=np.float64)
    pts = points[chosen]
    if len(pts) >= 4:
        q1, q3 = np.percentile(pts, [25, 75], axis=0)
        spread = iqr_factor * (q3 - q1)
        pts = pts[np.all((pts >= q1 - spread) & (pts <= q3 + spread), axis=1)]
    if len(pts) < 4:
        return np.zeros(len(points), dtype=bool)
    try:
        hull = Delaunay(pts)
    except (QhullError, ValueError):  # flat or degenerate: no volume to be inside of
        return np.zeros(len(points), dtype=bool)
    return hull.find_simplex(points) >= 0


def gaussian_grouping(cloud: GaussianCloud, classifier: ObjectClassifier, object_id: int, *, rule: str = "argmax",
                      threshold: float = 0.3) -> BaselineSelection:
    """Return the Gaussian-Grouping-style extraction of ``object_id``, without pruning: argmax of the classifier,
    probability above ``threshold`` (``rule="threshold"``), or that with every Gaussian inside the convex hull of
    their centres added, as Gaussian Grouping's object removal selects (``rule="threshold_hull"``).
    """
    if not 0 <= object_id < classifier.num_classes:
        raise ConfigError(f"object id {object_id} is not one of the classifier's classes 0..{classifier.num_classes - 1}")
    with torch.no_grad():
        logits = classifier.logits(cloud_features(cloud))
    if rule == "argmax":
        keep = (logits.argmax(-1) == object_id).numpy()
    elif rule in ("threshold", "threshold_hull"):
        keep = (torch.softmax(logits, -1)[:, object_id] > threshold).numpy()
    else:
        raise ConfigError(f"rule must be argmax, threshold or threshold_hull, got {rule!r}")
    details = {"method": "gaussian_grouping", "rule": rule, "selected": int(keep.sum())}
    if rule != "argmax":
        details["threshold"] = threshold
    if rule == "threshold_hull":
        hull = inside_hull(cloud.means, keep) & ~keep
        details["added_by_hull"] = int(hull.sum())
        keep = keep | hull
    return BaselineSelection(_take(cloud, keep, f"Gaussian Grouping ({rule})"), keep, details)


def click_in_mask(mask: np.ndarray) -> tuple[int, int]:
    """Return the pixel ``(x, y)`` deepest inside a binary mask (largest distance to its border)."""
    m = np.pad(np.asarray(mask, dtype=np.uint8), 1)
    if not m.any():
        raise ConfigError("the mask is empty: nothing to click on")
    dist = cv2.distanceTransform(m, cv2.DIST_L2, 5)[1:-1, 1:-1]
    y, x = np.unravel_index(int(np.argmax(dist)), dist.shape)
    return int(x), int(y)


def _unit(x: torch.Tensor) -> torch.Tensor:
    return x / x.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def feature_similarity(cloud: GaussianCloud, dataset: Dataset, masks: torch.Tensor, object_id: int, *,
                       views: Sequence[int], threshold: float | None = None,
                       candidates: Sequence[float] = SIMILARITY_THRESHOLDS,
                       renderer: Renderer | None = None) -> BaselineSelection:
    """Return the SAGA/OmniSeg3D-style extraction of ``object_id`` from one click.

    Args:
        cloud: a distilled scene (``object_feature_*`` columns).
        dataset: its posed images.
        masks: instance masks of the dataset's views. [V, H, W]
        object_id: the target.
        views: the training views (the click and the threshold are chosen on them).
        threshold: cosine similarity to keep a Gaussian; None chooses it among ``candidates`` by the 2D IoU with the
            training views' masks.
        candidates: thresholds to choose from.
        renderer: renders the features (default: the built-in CPU renderer).
    """
    views = [int(v) for v in views]
    areas = [int((masks[v] == object_id).sum()) for v in views]
    if not views or max(areas) == 0:
        raise ConfigError(f"object {object_id} is in no training view's mask: nowhere to click")
    view = views[int(np.argmax(areas))]
    x, y = click_in_mask((masks[view] == object_id).numpy())
    feats = cloud_features(cloud)
    frozen = GaussianParams.from_cloud(cloud, sh_degree=0)
    renderer = resolve_renderer(renderer)
    with torch.no_grad():
        rendered = {v: _unit(render_features(frozen, feats, dataset.cameras[v], renderer=renderer)) for v in views}
        query = rendered[view][y, x]
        chosen_iou = None
        if threshold is None:
            seen = [v for v, a in zip(views, areas) if a]
            sims = {v: rendered[v] @ query for v in seen}
            scores = [float(np.mean([mask_iou(sims[v] > t, masks[v] == object_id) for v in seen])) for t in candidates]
            best = int(np.argmax(scores))
            threshold, chosen_iou = float(candidates[best]), scores[best]
        keep = ((_unit(feats) @ query) > threshold).numpy()
    details = {"method": "feature_similarity", "view": dataset.cameras[view].name, "click": [x, y],
               "threshold": float(threshold), "train_mask_iou": chosen_iou, "selected": int(keep.sum())}
    return BaselineSelection(_take(cloud, keep, "feature similarity"), keep, details)
