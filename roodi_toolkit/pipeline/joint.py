"""Single-stage training: geometry and object features learned together (the paper's "w/o two-stage" ablation).

ROODI trains the scene first and distils the masks into object features afterwards with the geometry frozen
(:mod:`roodi_toolkit.pipeline.distill`). Gaussian Grouping, and the paper's "w/o-two-stage" row of Table 2, learn both at once:
every training step renders the features beside the colour, and the classifier's cross-entropy against the view's
mask, divided by log(C), is added to the photometric loss with weight 1 (Gaussian Grouping's ``loss_obj``), so the
object loss also moves the geometry. Relocation and growth of the MCMC strategy copy the features with the other
per-Gaussian parameters. The result is a trained model folder plus a distilled scene in memory, saved like any
distillation, so selection and everything after it run unchanged (the model folder and the training run:
:func:`roodi_toolkit.run.train.train_joint`).
"""

from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from ..errors import ConfigError
from ..io.dataset import Dataset
from ..progress import ProgressFactory, null_progress
from ..render.renderer import Renderer, RenderOutput
from .distill import (DistillConfig, DistilledScene, DistillResult, ObjectClassifier, finish_distillation,
                      initial_classifier)
from .segment import ViewMasks
from .train import TrainConfig, Trainer


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
                                                       eps=1e-15, fused=True)
        self.optimizers["classifier"] = torch.optim.Adam(list(self.classifier_params.values()),
                                                         lr=self.distill.classifier_lr, fused=True)

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


def finish_joint(trainer: JointTrainer, distill: DistillConfig, seconds: float, *, holdout_every: int = 8,
                 labels: dict[int, str] | None = None, progress: ProgressFactory = null_progress,
                 renderer: Renderer | None = None) -> DistilledScene:
    """Return the distilled scene a finished single-stage training learned (its features, classifier and masks),
    scored and pictured as a two-stage distillation is; ``seconds``: the training's time."""
    cloud = trainer.to_cloud()
    cloud.extras = {}
    features = trainer.params.features.detach().clone()
    learned = DistillResult(features, trainer.classifier(), [], seconds, list(trainer.train_indices))
    distilled = finish_distillation(cloud, learned, trainer.dataset, trainer.masks, holdout_every=holdout_every,
                                    labels=labels, progress=progress, renderer=renderer)
    distilled.summary.update({"segmenter": "files", "config": asdict(distill), "single_stage": True})
    return distilled
