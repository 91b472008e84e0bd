"""Single-stage training: geometry and object features learned together (the paper's "w/o two-stage" ablation).

ROODI trains the scene first and distils the masks into object features afterwards with the geometry frozen
(:mod:`roodi_toolkit.pipeline.distill`). Gaussian Grouping, and the paper's "w/o-two-stage" row of Table 2, learn both at once:
every training step renders the features beside the colour, and the classifier's cross-entropy against the view's
mask, divided by log(C), is added to the photometric loss with weight 1 (Gaussian Grouping's ``loss_obj``), so the
object loss also moves the geometry. Relocation and growth of the MCMC strategy copy the features with the other
per-Gaussian parameters. The result is a trained model folder plus a distilled scene in memory, saved like any
distillation, so selection and everything after it run unchanged.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from ..errors import ConfigError
from ..io.dataset import Dataset
from ..progress import ProgressFactory, null_progress
from ..render.renderer import Renderer, RenderOutput
from .distill import DistillConfig, DistilledScene, DistillResult, ObjectClassifier, initial_classifier
from .distill import finish_distillation, scene_labels
from .segment import FilesSegmenter, SegmentPrompt, ViewMasks
from .train import TrainConfig, Trainer, TrainResult, train_scene


class JointTrainer(Trainer):
    """A :class:`~roodi_toolkit.pipeline.train.Trainer` that also learns object features and their 1x1 classifier.

    Args:
        dataset: the posed images.
        config: scene hyperparameters.
        masks: one mask per view of ``dataset``.
        distill: feature size, learning rates and initial spread of the features (the distillation's own).
        object_weight: weight of the object loss (Gaussian Grouping: 1).
        train_indices: views to optimise on (default as :class:`Trainer`).
        renderer: draws colour and features of every view (default: the built-in CPU renderer).
    """

    def __init__(self, dataset: Dataset, config: TrainConfig, masks: ViewMasks, distill: DistillConfig = DistillConfig(),
                 *, object_weight: float = 1.0, train_indices: list[int] | None = None,
                 renderer: Renderer | None = None) -> None:
        if len(masks) != len(dataset) or tuple(masks.masks.shape[1:]) != (dataset.height, dataset.width):
            raise ConfigError(f"masks are {list(masks.masks.shape)} but the dataset has {len(dataset)} views of "
                              f"{dataset.width}x{dataset.height}")
        self.masks = masks
        self.distill = distill
        self.object_weight = float(object_weight)
        self.classifier_params: dict[str, torch.nn.Parameter] = {}
        super().__init__(dataset, config, train_indices, renderer=renderer)

    def _make_optimizers(self) -> None:
        super()._make_optimizers()
        dim, n, C = self.distill.feature_dim, len(self.params), self.masks.num_classes
        if self.params.features is None:  # set: rendered beside the colour, moved by the strategy's edits
            self.params.features = torch.nn.Parameter(
                torch.randn(n, dim, generator=self.generator) * self.distill.feature_init_std)
        if not self.classifier_params:
            weight, bias = initial_classifier(C, dim, self.generator)
            self.classifier_params = {"weight": torch.nn.Parameter(weight), "bias": torch.nn.Parameter(bias)}
        self.optimizers["features"] = torch.optim.Adam([self.params.features], lr=self.distill.feature_lr,
                                                       eps=1e-15)
        self.optimizers["classifier"] = torch.optim.Adam(list(self.classifier_params.values()),
                                                         lr=self.distill.classifier_lr)

    def _extra_loss(self, out: RenderOutput, view: int) -> Tensor | None:
        C = self.masks.num_classes
        logits = out.features.reshape(-1, self.distill.feature_dim) @ self.classifier_params["weight"].T \
            + self.classifier_params["bias"]
        return self.object_weight * F.cross_entropy(logits, self.masks.masks[view].reshape(-1).long()) / math.log(C)

    def classifier(self) -> ObjectClassifier:
        """Return the current classifier."""
        return ObjectClassifier(self.classifier_params["weight"].detach().clone(),
                                self.classifier_params["bias"].detach().clone())

    def state_dict(self) -> dict[str, Any]:
        state = super().state_dict()
        state["classifier"] = {k: v.detach().clone() for k, v in self.classifier_params.items()}
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        with torch.no_grad():
            for k, v in state.get("classifier", {}).items():
                self.classifier_params[k].copy_(v)
        super().load_state_dict(state)


def train_joint(data_dir: str | Path, out_dir: str | Path, config: TrainConfig = TrainConfig(),
                distill: DistillConfig = DistillConfig(), *, downscale: float = 1, resume: bool = False,
                overwrite: bool = False, dataset: Dataset | None = None, progress: ProgressFactory = null_progress,
                renderer: Renderer | None = None) -> tuple[TrainResult, DistilledScene]:
    """Train a scene and its object features together from the dataset's own instance masks; return the training
    result (the model folder written as :func:`~roodi_toolkit.pipeline.train.train_scene` does) and the distilled
    scene (for :func:`~roodi_toolkit.pipeline.distill.save_distilled`).

    Raises:
        RoodiError: no masks in the dataset, or what training raises.
    """
    trainers: list[JointTrainer] = []

    def make(ds: Dataset, cfg: TrainConfig) -> JointTrainer:
        trainers.append(JointTrainer(ds, cfg, FilesSegmenter().segment(ds, SegmentPrompt()), distill,
                                     renderer=renderer))
        return trainers[-1]

    t0 = time.perf_counter()
    result = train_scene(data_dir, out_dir, config, downscale=downscale, resume=resume, overwrite=overwrite,
                         progress=progress, make_trainer=make, dataset=dataset)
    trainer = trainers[-1]
    cloud = trainer.to_cloud()
    cloud.extras = {}
    features = trainer.params.features.detach().clone()
    learned = DistillResult(features, trainer.classifier(), [], time.perf_counter() - t0, list(trainer.train_indices))
    distilled = finish_distillation(cloud, learned, trainer.dataset, trainer.masks,
                                    holdout_every=config.holdout_every, labels=scene_labels(data_dir),
                                    progress=progress, renderer=renderer)
    distilled.summary.update({"segmenter": "files", "config": asdict(distill), "single_stage": True})
    return result, distilled
