"""From posed images to clean objects (paper Fig. 2), the stages in memory: the settings of every stage
(:class:`ExtractConfig`), and one object's selection, pruning and refinement (occlusion reasoning, inpainting,
fine-tuning) as functions of the distilled scene, the dataset and a renderer that return their result.

Nothing here opens, names or checks a file: the run layer (:mod:`roodi_toolkit.run.extract`) walks the chain from
the data folder to the object PLY, trains and distils the scene, reuses finished stages and writes the output folder.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional, Sequence

import torch

from ..errors import ConfigError
from ..gaussians import GaussianCloud
from ..progress import ProgressFactory, null_progress
from ..prune.outliers import PruneConfig
from ..render.renderer import Renderer
from . import budget
from .distill import DistillConfig, ObjectClassifier, without_features
from .finetune import FinetuneConfig, PerView, RefineResult, refine_object
from .occlusion import OcclusionConfig
from .segment import SegmentPrompt
from .select import prune_selection, select_object
from ..settings import check_settings, documented, setting
from .train import TrainConfig


@documented
@dataclass(frozen=True)
class ExtractConfig:
    """Settings of every stage; the defaults are each stage's own (sources in their modules). The ablations: prune
    ``False`` (``--no-prune``), ``prune_config`` with ``distance="euclidean"`` or ``rule="paper"``, inpaint ``False``
    (``--no-inpaint``), single_stage ``True`` (w/o two-stage, :mod:`roodi_toolkit.pipeline.joint`; needs the dataset's
    masks). The segmenter's clicks (``prompt``) are in the original photo's pixels (what an image viewer shows),
    whatever ``downscale``; a click whose view is ``""`` is in the first training view."""

    train: TrainConfig = setting(factory=lambda: TrainConfig(init="auto"),
                                 help="Scene training (only when no trained model is given).", prefix="")
    downscale: Optional[float] = setting(None, "Image downscale [the --model's own, from its cfg.json; else 1].",
                                         low=1)
    distill: DistillConfig = setting(factory=DistillConfig, help="Mask distillation.", prefix="distill")
    # Gaussian Grouping: 0.3
    threshold: float = setting(0.3, "Selection: keep Gaussians whose probability of the object exceeds this.",
                               low=0, high=1, low_open=True, high_open=True)
    # paper: yes
    prune: bool = setting(True, "Prune the selection's floaters (ROODI 3.2); --no-prune skips it (ablation).")
    prune_config: PruneConfig = setting(factory=PruneConfig, help="Pruning of the selection.", prefix="")
    inpaint: bool = setting(True, "Occlusion reasoning, inpainting and fine-tuning; --no-inpaint skips them "
                            "(ablation).")
    inpainter: str = setting("opencv", "Inpainter plugin: opencv, exemplar, symmetry (objects with never-seen parts), "
                             "sdxl, ... (see roodi-toolkit plugins).")
    # unprefixed: OcclusionConfig.size is --view-size
    occlusion: OcclusionConfig = setting(factory=OcclusionConfig, help="Occlusion reasoning.", prefix="")
    finetune: FinetuneConfig = setting(factory=FinetuneConfig, help="Fine-tuning.", prefix="finetune")
    single_stage: bool = setting(False, "Learn the object features together with the scene instead of after it "
                                 "(ablation: w/o two-stage).")
    segmenter: str = setting("files", "Segmenter plugin whose masks are distilled: files (the dataset's instance "
                             "masks), click (the clicked object), sam2, ...")
    prompt: SegmentPrompt = setting(factory=SegmentPrompt, help="The segmenter's clicks or mask folder.", cli=False)
    segmenter_options: dict = setting(factory=dict, help="Keyword options of the segmenter.", cli=False)
    inpainter_options: dict = setting(factory=dict, help="Keyword options of the inpainter (text values "
                                     "take the type of the plugin's default).", cli=False)

    def __post_init__(self) -> None:
        check_settings(self)


def object_ids(requested: Sequence[int | str], num_classes: int) -> list[int]:
    """Return the object ids to extract: ``requested`` as integers, ``"all"`` meaning every class of the
    distillation's ``num_classes`` but the background (0).

    Raises:
        ConfigError: an id that is not an integer or not one of the distillation's classes.
    """
    ids: list[int] = []
    for value in requested:
        if str(value).strip().lower() == "all":
            ids += [i for i in range(1, num_classes) if i not in ids]
            continue
        try:
            i = int(value)
        except (TypeError, ValueError):
            raise ConfigError(f"--object: expected an instance id or 'all', got {value!r}") from None
        if not 0 < i < num_classes:
            raise ConfigError(f"--object {i}: not one of the distillation's objects 1..{num_classes - 1}")
        if i not in ids:
            ids.append(i)
    if not ids:
        raise ConfigError("give at least one object id to extract (or --object all)")
    return ids


def object_masks(masks: torch.Tensor, object_id: int, views: Sequence[int]) -> torch.Tensor:
    """Return the object's masks ``[V, H, W]`` in ``views`` from class maps ``[N, H, W]``."""
    return masks[list(views)] == object_id


def select_stage(cloud: GaussianCloud, classifier: ObjectClassifier, object_id: int, config: ExtractConfig, *,
                 progress: ProgressFactory = null_progress) -> tuple[GaussianCloud, dict[str, Any]]:
    """Return object ``object_id`` selected from the distilled scene ``cloud`` and pruned (the crude model of the
    paper's Fig. 2d, without feature columns) and its report entry (counts, the pruning's report)."""
    entry: dict[str, Any] = {}
    sel = select_object(cloud, classifier, int(object_id), threshold=config.threshold, prune=False)
    if config.prune and int(sel.selected.sum()) > config.prune_config.k:
        sel = prune_selection(sel, config.prune_config, progress=progress)
    elif config.prune:
        entry["prune_skipped"] = (f"only {int(sel.selected.sum())} Gaussians selected, not more than "
                                  f"k = {config.prune_config.k} neighbours")
    selected = without_features(sel.cloud)
    entry["selected"] = int(sel.selected.sum())
    if sel.prune_report is not None:
        entry["prune"] = sel.prune_report.to_dict()
    return selected, entry


def refine_stage(selected: GaussianCloud, scene: GaussianCloud, dataset: Any, masks: torch.Tensor, object_id: int,
                 config: ExtractConfig, *, renderer: Renderer,
                 progress: ProgressFactory = null_progress, lpips: torch.nn.Module | None = None) -> RefineResult:
    """Return the selected object after occlusion reasoning, inpainting and fine-tuning on the dataset's training
    views (``masks``: the class maps ``[N, H, W]`` the features were distilled from; ``lpips``: the network of the
    fine-tuning's perceptual loss, :func:`roodi_toolkit.pipeline.finetune.finetune_object`).

    Raises:
        ResourceError: the refinement would not fit in memory (checked before anything is allocated).
    """
    views = dataset.train_indices
    budget.check_refine(len(scene), len(selected), len(views), dataset.width, dataset.height)
    photos = PerView(len(views), lambda i: dataset.images[views[i]])  # read in place, not copied
    return refine_object(selected, scene, photos, [dataset.cameras[v] for v in views],
                         object_masks(masks, int(object_id), views), inpainter=config.inpainter,
                         inpainter_options=config.inpainter_options, occlusion=config.occlusion,
                         finetune=config.finetune, progress=progress, renderer=renderer, lpips=lpips)
