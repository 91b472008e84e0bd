"""Object features: distil per-view masks into the Gaussians of a trained scene (ROODI Sec. 3.1).

ROODI follows Gaussian Grouping: every Gaussian gets a 16-dim object feature, rendered like colour (the same
alpha-compositing weights, no background); a 1x1 convolution maps the rendered feature map to C class logits, trained
with cross-entropy against the masks divided by log(C) so the loss starts near 1 whatever C is. The scene's geometry and
appearance stay frozen: only the features and the classifier change, so the scene's RGB renders are untouched. 500
iterations, one training view each (paper).

In memory a distilled scene is the scene's :class:`~roodi_toolkit.gaussians.GaussianCloud` with extra columns
``object_feature_0..15`` plus its :class:`ObjectClassifier`; on disk it is a distillation folder of its own
(:mod:`roodi_toolkit.io.model`, written and read by :mod:`roodi_toolkit.run.distill`) that names the model file it
belongs to, so the model folder is never written and any number of objects can be selected
(:mod:`roodi_toolkit.pipeline.select`) from one distillation. Nothing here opens a file.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ..cameras import Camera, spread_cameras
from ..errors import CloudError, ConfigError, InputError
from ..io.dataset import Dataset, split_views
from ..gaussians import GaussianCloud
from ..settings import check_settings, documented, setting
from ..params import GaussianParams
from ..render.renderer import Renderer, has_compositing_weights, resolve_renderer
from ..render.renderer import render_features as composite_features
from ..progress import ProgressFactory, null_progress
from ..imaging import class_map_ious
from . import budget
from .weight_cache import WeightCache
from .resolution import working_dataset
from ..render.pictures import colorize_ids, heat, probability_grid
from .segment import SegmentPrompt, ViewMasks, get_segmenter

FEATURE_PREFIX = "object_feature_"
CLASSIFIER_FORMAT = "roodi-object-classifier"


@documented
@dataclass(frozen=True)
class DistillConfig:
    """Hyperparameters of the distillation, with their sources."""

    # paper: 500
    iterations: int = setting(500, "Distillation steps, one training view each.", low=1)
    # the masks are distilled from this many training views spread round the scene (cameras.spread_cameras), not
    # all: a real scene's view holds 60-140 MB of compositing weights, so its 90-300 views do not fit the cache and
    # most steps would render; on a 650k-Gaussian scene with 90 views of 400 px, 32 spread views select the object at
    # IoU 0.983 where all 90 give 0.988, in 97 s instead of 153 s with all cached (benchmarks/RESULTS.md, "The
    # views distillation needs")
    max_views: int = setting(32, "Distil from this many training views spread round the scene (0: all of them).",
                             low=0)
    # Gaussian Grouping: 16
    feature_dim: int = setting(16, "Object feature size.", low=1, cli=False)
    # Gaussian Grouping trains _objects_dc at its feature_lr 2.5e-3 and the classifier at 5e-4, but jointly with the
    # scene for 30,000 steps; in the paper's 500 steps those rates leave the loss at 0.42 at step 410 where 10x both
    # are at 0.08 (measured on a generated scene, benchmarks/RESULTS.md), so the defaults are 10x Gaussian Grouping's
    # (pass 2.5e-3 / 5e-4 for its exact rates)
    feature_lr: float = setting(2.5e-2, "Adam rate of the object features.", low=0, low_open=True)
    classifier_lr: float = setting(5e-3, "Adam rate of the classifier.", low=0, low_open=True)
    # small, so Gaussians that no view sees keep a near-zero feature and fall to the classifier's bias (the most
    # frequent class, the background) instead of a random class (Gaussian Grouping starts from uniform noise because
    # it trains for 30,000 steps)
    feature_init_std: float = setting(1e-2, "Standard deviation of the initial features.", low=0, cli=False)
    seed: int = setting(0, "Seed of the initial features, the classifier and the view order.")
    # the geometry is frozen, so rendering features is a fixed sparse linear map per view (the compositing weights):
    # each view's map is computed once (WeightCache) and features rendered with a sparse product, for as many views
    # as fit in cache_mb; the other views (all of them with False) render every step (the same result to float
    # rounding)
    cache_weights: bool = setting(True, "Render features from cached compositing weights.", cli=False)
    # counted in bytes held: a map and its transpose in CSR with 32-bit indices, 16 bytes a (pixel, Gaussian) pair (a
    # real scene's 400-500 px working view holds about 4-20M pairs, 60-320 MB), and never more than half of what the
    # machine has available beyond the rest of the stage (budget.cache_bytes); 4 GB holds max_views' 32 views of
    # 650k Gaussians at 400 px (2.0 GB) and of 1.5M at 500 px (110-140 MB a view)
    cache_mb: float = setting(4096, "Memory bound of the cached weights in MB.", low=0, cli=False)
    # segmentation and distillation work on the views scaled down by the smallest integer factor that brings them to
    # this many pixels (pipeline/resolution.py); a selection needs masks of the object, not sharp ones (measured:
    # benchmarks/RESULTS.md, "Working resolution")
    max_pixels: int = setting(512 * 512, "Pixels of the working views.", low=1, cli=False)

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass
class ObjectClassifier:
    """The 1x1 convolution from object features to class logits, as a plain linear map.

    Attributes:
        weight: ``[C, F]`` (the Conv2d weight without its 1x1 kernel dims).
        bias: ``[C]``.
        labels: optional class names by id (e.g. from a generated scene's scene.json).
    """

    weight: Tensor
    bias: Tensor
    labels: dict[int, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.weight.ndim != 2 or self.bias.shape != (self.weight.shape[0],):
            raise ConfigError(f"classifier weight must be [C, F] and bias [C], got {list(self.weight.shape)} and "
                              f"{list(self.bias.shape)}")

    @property
    def num_classes(self) -> int:
        return int(self.weight.shape[0])

    @property
    def feature_dim(self) -> int:
        return int(self.weight.shape[1])

    def logits(self, features: Tensor) -> Tensor:
        """Return class logits ``[..., C]`` of features ``[..., F]`` (per Gaussian or per pixel)."""
        return features @ self.weight.T + self.bias

    def probabilities(self, features: Tensor) -> Tensor:
        """Return softmax class probabilities ``[..., C]`` of features ``[..., F]``."""
        return torch.softmax(self.logits(features), dim=-1)

    def state_dict(self) -> dict[str, Any]:
        return {"format": CLASSIFIER_FORMAT, "version": 1, "weight": self.weight.detach().clone(),
                "bias": self.bias.detach().clone(), "labels": {str(k): v for k, v in self.labels.items()}}

    @classmethod
    def from_state_dict(cls, state: Any, where: str = "classifier") -> "ObjectClassifier":
        if not isinstance(state, dict) or state.get("format") != CLASSIFIER_FORMAT:
            raise InputError(f"{where}: not a roodi-toolkit object classifier (run roodi-toolkit distill first)")
        try:
            labels = {int(k): str(v) for k, v in dict(state.get("labels", {})).items()}
            return cls(state["weight"].float(), state["bias"].float(), labels)
        except (KeyError, AttributeError, ValueError) as exc:
            raise InputError(f"{where}: malformed object classifier ({exc})") from None


@dataclass
class DistillResult:
    """What :func:`distill_object_features` produced.

    Attributes:
        features: per-Gaussian object features. [N, F]
        classifier: the trained classifier.
        history: ``{"step", "loss"}`` every 10 steps.
        seconds: wall time of the optimisation.
        train_views: indices of the views trained on (``config.max_views`` of those given).
        cached: whether any view's compositing weights were cached (else every step rendered).
        cached_views: how many of ``train_views`` had theirs cached within ``cache_mb``.
        cache_mb: the memory the cached maps held.
        geometry: the frozen Gaussians the features were rendered with (what scoring and the picture render with
            too, made once; None: the caller makes it).
    """

    features: Tensor
    classifier: ObjectClassifier
    history: list[dict[str, float]]
    seconds: float
    train_views: list[int]
    cached: bool = False
    cached_views: int = 0
    cache_mb: float = 0.0
    geometry: GaussianParams | None = field(default=None, repr=False)


def render_features(params: GaussianParams, features: Tensor, camera: Camera, *,
                    renderer: Renderer | None = None) -> Tensor:
    """Return the composited object features ``[H, W, F]`` of Gaussians ``features`` ``[N, F]`` seen from ``camera``.

    Args:
        params: the frozen Gaussians (only their geometry and opacities matter).
        features: per-Gaussian features (may require grad). [N, F]
        camera: the view.
        renderer: draws the features (default: the built-in CPU renderer).
    """
    n = features.shape[0]
    if len(params) != n:
        raise ConfigError(f"features must be [N, F] with N = {len(params)}, got {list(features.shape)}")
    # the colours are not needed: zero degree-0 SH skips the higher bands' evaluation where the renderer has no
    # features-only path
    geometry = GaussianParams(params.means, params.quats_wxyz, params.log_scales, params.opacity_logits,
                              torch.zeros(n, 3, dtype=features.dtype), torch.zeros(n, 0, 3, dtype=features.dtype))
    return composite_features(resolve_renderer(renderer), geometry, features, camera)[0]


def distill_object_features(cloud: GaussianCloud, dataset: Dataset, masks: ViewMasks,
                            config: DistillConfig = DistillConfig(), *, train_views: Sequence[int] | None = None,
                            progress: ProgressFactory = null_progress,
                            renderer: Renderer | None = None) -> DistillResult:
    """Return per-Gaussian object features and a classifier trained so the rendered class map matches ``masks``.

    The cloud's geometry and colours are only read (no gradient reaches them).

    Args:
        cloud: the trained scene. N Gaussians.
        dataset: its posed images (cameras and sizes; the masks come from ``masks``).
        masks: one mask per view of ``dataset`` (:class:`~roodi_toolkit.pipeline.segment.ViewMasks`).
        config: hyperparameters.
        train_views: the training views (default: every view); ``config.max_views`` of them spread round the scene
            are trained on.
        progress: progress factory (the bar shows the loss).
        renderer: renders the features (default: the built-in CPU renderer); its compositing weights are cached
            when ``config.cache_weights`` and it has them, else it renders every step.

    Raises:
        ConfigError: masks that do not match the dataset, or no training views.
    """
    if len(masks) != len(dataset) or tuple(masks.masks.shape[1:]) != (dataset.height, dataset.width):
        raise ConfigError(f"masks are {list(masks.masks.shape)} but the dataset has {len(dataset)} views of "
                          f"{dataset.width}x{dataset.height}")
    views = list(range(len(dataset))) if train_views is None else [int(v) for v in train_views]
    if not views:
        raise ConfigError("no views to distil the masks from")
    if config.max_views:
        views = [views[i] for i in spread_cameras([dataset.cameras[v] for v in views], config.max_views)]
    C = masks.num_classes
    gen = torch.Generator().manual_seed(config.seed)
    renderer = resolve_renderer(renderer)
    cached = config.cache_weights and has_compositing_weights(renderer)
    n, pixels = len(cloud), dataset.width * dataset.height
    budget.check_distill(n, config.feature_dim, pixels, len(views))  # before any of it is allocated
    frozen = GaussianParams.from_cloud(cloud, sh_degree=0)
    features = torch.nn.Parameter(torch.randn(n, config.feature_dim, generator=gen) * config.feature_init_std)
    weight, bias = (torch.nn.Parameter(t) for t in initial_classifier(C, config.feature_dim, gen))
    # fused: one compiled pass instead of about ten tensor operations, the same update to float rounding (N x 16
    # features at 650k Gaussians: 34 ms a step against 150 ms)
    opt_features = torch.optim.Adam([features], lr=config.feature_lr, eps=1e-15, fused=True)
    opt_classifier = torch.optim.Adam([weight, bias], lr=config.classifier_lr, fused=True)
    log_c = math.log(C)
    history: list[dict[str, float]] = []
    order = torch.empty(0, dtype=torch.long)
    pos = 0
    t0 = time.perf_counter()
    room = budget.cache_bytes(config.cache_mb, budget.distill_fixed_bytes(n, config.feature_dim, pixels))
    cache = WeightCache.build(frozen, {v: dataset.cameras[v] for v in views}, room if cached else 0,
                              renderer=renderer, progress=progress)
    with progress(total=config.iterations, desc="distill") as bar:
        for step in range(1, config.iterations + 1):
            if pos >= len(order):
                order = torch.randperm(len(views), generator=gen)
                pos = 0
            v = views[int(order[pos])]
            pos += 1
            if v in cache:
                rendered = cache.render(v, features)  # [H*W, F]
            else:
                rendered = render_features(frozen, features, dataset.cameras[v], renderer=renderer).reshape(
                    -1, config.feature_dim)
            # the 1x1 convolution, written as the per-pixel linear map it is
            logits = rendered @ weight.T + bias  # [H*W, C]
            loss = F.cross_entropy(logits.reshape(-1, C), masks.masks[v].reshape(-1).long()) / log_c
            opt_features.zero_grad(set_to_none=True)
            opt_classifier.zero_grad(set_to_none=True)
            loss.backward()
            opt_features.step()
            opt_classifier.step()
            value = float(loss.detach())
            if step % 10 == 0 or step == config.iterations:
                history.append({"step": step, "loss": value})
            bar.update(1)
            bar.set_postfix_str(f"loss {value:.4f}", refresh=False)
    seconds = time.perf_counter() - t0
    classifier = ObjectClassifier(weight.detach().clone(), bias.detach().clone())
    return DistillResult(features.detach().clone(), classifier, history, seconds, views, len(cache) > 0, len(cache),
                         cache.bytes / 2**20, frozen)


# ---------------------------------------------------------------------------------------------------- the cloud


def feature_names(dim: int) -> list[str]:
    """Return the PLY column names of ``dim`` object features: ``object_feature_0`` ...

    Example:
        >>> feature_names(2)
        ['object_feature_0', 'object_feature_1']
    """
    return [f"{FEATURE_PREFIX}{i}" for i in range(dim)]


def with_features(cloud: GaussianCloud, features: Tensor | np.ndarray) -> GaussianCloud:
    """Return a copy of ``cloud`` whose object-feature columns are ``features`` ``[N, F]`` (old ones replaced)."""
    f = np.asarray(features.detach().cpu().numpy() if isinstance(features, Tensor) else features, dtype=np.float32)
    if f.ndim != 2 or f.shape[0] != len(cloud):
        raise ConfigError(f"features must be [N, F] with N = {len(cloud)}, got {list(f.shape)}")
    out = cloud.copy()
    extras = {k: v for k, v in out.extras.items() if not k.startswith(FEATURE_PREFIX)}
    extras.update({name: np.ascontiguousarray(f[:, i]) for i, name in enumerate(feature_names(f.shape[1]))})
    out.extras = extras
    return out


def cloud_features(cloud: GaussianCloud) -> Tensor:
    """Return the object features ``[N, F]`` stored in a cloud's ``object_feature_*`` columns.

    Raises:
        InputError: the cloud has none (it was not distilled).
    """
    names = sorted((k for k in cloud.extras if re.fullmatch(rf"{FEATURE_PREFIX}\d+", k)),
                   key=lambda k: int(k[len(FEATURE_PREFIX):]))
    if not names:
        raise CloudError("the model has no object features (object_feature_* columns); run roodi-toolkit distill "
                         "first")
    if names != feature_names(len(names)):
        raise CloudError(f"the model's object feature columns are not numbered 0..{len(names) - 1}: {names}")
    return torch.as_tensor(np.stack([cloud.extras[k].astype(np.float32) for k in names], axis=1))


def initial_classifier(num_classes: int, feature_dim: int, generator: torch.Generator) -> tuple[Tensor, Tensor]:
    """Return a fresh classifier's weight ``[C, F]`` and bias ``[C]``: nn.Conv2d's default initialisation.

    Drawn from ``generator`` (weight first, then bias) so that runs repeat exactly.
    """
    bound = 1.0 / math.sqrt(feature_dim)
    weight = (torch.rand(num_classes, feature_dim, generator=generator) * 2 - 1) * bound
    bias = (torch.rand(num_classes, generator=generator) * 2 - 1) * bound
    return weight, bias



# ---------------------------------------------------------------------------------------------------- evaluation


def evaluate_class_maps(cloud: GaussianCloud, classifier: ObjectClassifier, dataset: Dataset, masks: ViewMasks,
                        views: Sequence[int], *, object_ids: Sequence[int] | None = None,
                        progress: ProgressFactory = null_progress, renderer: Renderer | None = None,
                        geometry: GaussianParams | None = None) -> dict[str, Any]:
    """Return IoUs of the rendered class map (argmax) against ``masks`` on ``views``.

    ``mean_iou`` is the mean over (view, object) pairs of the objects present in the view's mask (background
    excluded); ``per_object`` averages each object over the views it appears in. ``geometry``: the cloud's frozen
    Gaussians when the caller has them (default: made from ``cloud``).
    """
    feats = cloud_features(cloud)
    frozen = GaussianParams.from_cloud(cloud, sh_degree=0) if geometry is None else geometry
    renderer = resolve_renderer(renderer)
    pairs: list[tuple[int, int, float]] = []
    with progress(total=len(views), desc="evaluate") as bar, torch.no_grad():
        for v in views:
            pred = classifier.logits(render_features(frozen, feats, dataset.cameras[v], renderer=renderer)).argmax(
                -1).numpy()
            true = masks.masks[v].numpy()
            ids = None if object_ids is None else [i for i in object_ids if (true == i).any()]
            for i, iou in class_map_ious(pred, true, ids).items():
                pairs.append((v, i, iou))
            bar.update(1)
    per_object: dict[int, list[float]] = {}
    for _, i, iou in pairs:
        per_object.setdefault(i, []).append(iou)
    return {"views": [dataset.names[v] for v in views],
            "mean_iou": float(np.mean([p[2] for p in pairs])) if pairs else float("nan"),
            "per_object": {i: float(np.mean(v)) for i, v in sorted(per_object.items())},
            "pairs": len(pairs)}


# ---------------------------------------------------------------------------------------------------- commands


def picture_views(eval_views: Sequence[int], train_views: Sequence[int], n: int = 4) -> list[int]:
    views = list(eval_views)[:n]
    rest = [v for v in train_views if v not in views]
    step = max(1, len(rest) // max(1, n - len(views)))
    return views + rest[::step][:n - len(views)]




# ---------------------------------------------------------------------------------------------------- whole stage


@dataclass
class DistilledScene:
    """A distilled scene in memory, what :func:`distill_scene` hands to the next stage.

    Attributes:
        cloud: the scene with ``object_feature_*`` columns (its own columns unchanged).
        classifier: the trained classifier, with class labels.
        masks: the segmenter's masks, one per view.
        picture: per picture view: image, masks, rendered classes, rendered probability of that class. [H', W', 3]
        summary: JSON-ready figures (loss, held-out IoU, settings, seconds).
    """

    cloud: GaussianCloud
    classifier: ObjectClassifier
    masks: ViewMasks
    picture: np.ndarray
    summary: dict[str, Any]


def distill_scene(cloud: GaussianCloud, dataset: Dataset, *, segmenter: str = "files",
                  prompt: SegmentPrompt = SegmentPrompt(), segmenter_options: dict[str, Any] | None = None,
                  config: DistillConfig = DistillConfig(), holdout_every: int = 8,
                  labels: dict[int, str] | None = None, progress: ProgressFactory = null_progress,
                  renderer: Renderer | None = None) -> DistilledScene:
    """Return the scene distilled from a segmenter's masks: segment, distil, score the held-out views, picture.

    Args:
        cloud: the trained scene (object feature columns it may have are replaced).
        dataset: its posed images, decoded once by the caller.
        segmenter: the segmenter plugin's name.
        prompt: clicks or a mask folder for the segmenter.
        segmenter_options: keyword options of the segmenter.
        config: distillation hyperparameters.
        holdout_every: the training run's held-out split (every n-th view is scored, not trained on).
        labels: class names by id (default: "rest"/"target" for binary masks).
        progress: progress factory.
        renderer: draws every view, the click segmenter's included (default: the built-in CPU renderer).
    """
    cloud = without_features(cloud)
    renderer = resolve_renderer(renderer)
    options = dict(segmenter_options or {})
    if segmenter == "click":
        options.setdefault("renderer", renderer)
    seg = get_segmenter(segmenter, **options)
    work, factor = working_dataset(dataset, config.max_pixels)
    prompt = replace(prompt, clicks=tuple(replace(c, x=c.x / factor, y=c.y / factor) for c in prompt.clicks))
    if seg.needs_scene:
        budget.check_click(len(cloud), work.width, work.height, len(work))
    t0 = time.perf_counter()
    masks = seg.segment(work, prompt, scene=cloud if seg.needs_scene else None, progress=progress)
    seg_seconds = time.perf_counter() - t0
    train_views, _ = split_views(work, holdout_every)
    result = distill_object_features(cloud, work, masks, config, train_views=train_views, progress=progress,
                                     renderer=renderer)
    distilled = finish_distillation(cloud, result, work, masks, holdout_every=holdout_every, labels=labels,
                                    progress=progress, renderer=renderer)
    distilled.summary.update({"segmenter": segmenter, "config": asdict(config), "segment_seconds": seg_seconds,
                              "working_downscale": factor, "working_size": [work.width, work.height],
                              "cached_weights": result.cached, "cached_views": result.cached_views,
                              "cache_mb": round(result.cache_mb, 1)})
    return distilled


def finish_distillation(cloud: GaussianCloud, result: DistillResult, dataset: Dataset, masks: ViewMasks, *,
                        holdout_every: int = 8, labels: dict[int, str] | None = None,
                        progress: ProgressFactory = null_progress,
                        renderer: Renderer | None = None) -> DistilledScene:
    """Return the distilled scene of features learned from ``masks``: class labels set, the held-out views scored
    and the picture made (shared by the two-stage distillation and single-stage training), both rendered with the
    geometry the features were learned with (made here once when ``result`` has none)."""
    train_views, eval_views = split_views(dataset, holdout_every)
    renderer = resolve_renderer(renderer)
    if masks.kind != "instances" or labels is None:
        labels = {0: "rest", 1: "target"} if masks.kind != "instances" else {}
    result.classifier.labels = {i: n for i, n in labels.items() if i < masks.num_classes}
    distilled = with_features(cloud, result.features)
    frozen = GaussianParams.from_cloud(cloud, sh_degree=0) if result.geometry is None else result.geometry
    held = evaluate_class_maps(distilled, result.classifier, dataset, masks, eval_views, progress=progress,
                               renderer=renderer, geometry=frozen) \
        if eval_views else {"views": [], "mean_iou": float("nan"), "per_object": {}, "pairs": 0}
    rows = []
    with torch.no_grad():
        for v in picture_views(eval_views, train_views):
            prob = result.classifier.probabilities(render_features(frozen, result.features, dataset.cameras[v],
                                                                   renderer=renderer))
            pred = prob.argmax(-1).numpy()
            rows.append([dataset.images[v].numpy(), colorize_ids(masks.masks[v].numpy()), colorize_ids(pred),
                         heat(prob.max(-1).values.numpy())])
    summary = {
        "mask_kind": masks.kind, "mask_source": masks.source,
        "num_classes": masks.num_classes, "labels": {str(k): v for k, v in result.classifier.labels.items()},
        "num_gaussians": len(cloud), "holdout_every": holdout_every,
        "train_views": len(result.train_views), "train_views_of": len(train_views),
        "distilled_from": [dataset.names[v] for v in result.train_views], "seconds": result.seconds,
        "final_loss": result.history[-1]["loss"] if result.history else float("nan"), "history": result.history,
        "held_out": {**held, "per_object": {str(k): v for k, v in held["per_object"].items()}},
        "picture_columns": ["image", "masks", "rendered classes", "rendered probability of that class"],
    }
    return DistilledScene(distilled, result.classifier, masks, probability_grid(rows), summary)


def without_features(cloud: GaussianCloud) -> GaussianCloud:
    """Return the cloud without object feature columns (the scene as trained)."""
    if not any(k.startswith(FEATURE_PREFIX) for k in cloud.extras):
        return cloud
    out = cloud.copy()
    out.extras = {k: v for k, v in out.extras.items() if not k.startswith(FEATURE_PREFIX)}
    return out
