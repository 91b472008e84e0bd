"""Select an object of a distillation folder into a PLY and a picture: the files around
:func:`roodi_toolkit.pipeline.select.select_object` (in memory)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..io import files
from ..io.dataset import load_dataset, split_views
from ..io.model import Distillation
from ..io.ply import write_ply
from ..params import GaussianParams
from ..pipeline.distill import ObjectClassifier, cloud_features, picture_views, render_features
from ..pipeline.select import Selection, select_object
from ..progress import ProgressFactory, null_progress
from ..prune.outliers import PruneConfig
from ..gaussians import GaussianCloud
from ..render.pictures import heat, probability_grid
from ..render.renderer import Renderer, render_cloud, resolve_renderer
from .distill import load_distillation
from .masks import folder_masks

PICTURE_COLUMNS = ["image", "mask of the object", "rendered probability", "selection alone"]


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
    data_dir = record.get("data_dir")
    if data_dir and Path(data_dir).exists() and distillation.masks_dir.is_dir():
        grid = _selection_picture(distillation, cloud, classifier, sel, object_id, resolve_renderer(renderer))
        summary["picture"] = str(files.write_image(grid, pic))
        summary["picture_columns"] = PICTURE_COLUMNS
    return summary


def _selection_picture(distillation: Distillation, cloud: GaussianCloud, classifier: ObjectClassifier,
                       sel: Selection, object_id: int, renderer: Renderer) -> np.ndarray:
    """Return the selection's picture (:data:`PICTURE_COLUMNS`, one row per picture view) on the distillation's
    dataset and masks."""
    record = distillation.record
    dataset = load_dataset(record["data_dir"], float(record.get("downscale", 1)))
    masks = folder_masks(distillation.masks_dir, dataset)
    train_views, eval_views = split_views(dataset, int(record.get("holdout_every", 8)))
    feats = cloud_features(cloud)
    frozen = GaussianParams.from_cloud(cloud, sh_degree=0)
    rows = []
    with torch.no_grad():
        for v in picture_views(eval_views, train_views):
            cam = dataset.cameras[v]
            prob = classifier.probabilities(render_features(frozen, feats, cam, renderer=renderer))[
                ..., object_id].numpy()
            alone = render_cloud(sel.cloud, cam, renderer=renderer, background=(1.0, 1.0, 1.0)).rgb.clamp(
                0, 1).numpy()
            target = (masks.masks[v].numpy() == object_id).astype(np.float32)
            rows.append([dataset.images[v].numpy(), target, heat(prob), alone])
    return probability_grid(rows)
