"""From posed images to clean objects in one call (paper Fig. 2): train the scene, distil the object masks, select each
object, prune it, reason about occlusion, inpaint and fine-tune.

Every stage writes its result atomically into the output folder and a re-run with the same folder reuses the stages
that finished (the scene model, the distillation, each object's selection and refinement), so an interrupted run
continues where it stopped and several objects share one scene and one distillation.

Layout of ``OUT_DIR``::

    scene/                      the trained scene (roodi-toolkit train layout), distilled in place
    object_<ID>/selected.ply    the object after selection and pruning (the crude model of the paper's Fig. 2d)
    object_<ID>/object.ply      the final object (Inria PLY)
    object_<ID>/debug/          occlusion masks, inpainting grids, renders before and after fine-tuning
    object_<ID>/object.png      the final object from four directions
    report.json                 counts, thresholds and times of every stage
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from .distill import CLASSIFIER_FILE, FEATURE_PREFIX, DistillConfig
from ..errors import ConfigError, DatasetError
from .finetune import FinetuneConfig
from ..gaussians import GaussianCloud
from .occlusion import OcclusionConfig
from ..prune.outliers import PruneConfig
from ..progress import ProgressFactory, null_progress
from .train import TrainConfig


@dataclass(frozen=True)
class ExtractConfig:
    """Settings of every stage; the defaults are each stage's own (sources in their modules).

    Attributes:
        train: scene training (used only when no trained model is given).
        downscale: image downscale factor of the dataset.
        distill: mask distillation.
        threshold: selection probability (Gaussian Grouping: 0.3).
        prune: prune the selection (paper: yes; ``--no-prune`` for the ablation).
        prune_config: pruning settings (``distance="euclidean"`` and ``rule="paper"`` for the ablations).
        inpaint: occlusion reasoning, inpainting and fine-tuning (``--no-inpaint`` for the ablation).
        inpainter: the inpainter plugin.
        occlusion: occlusion-reasoning settings.
        finetune: fine-tuning settings.
        single_stage: train the object features together with the scene instead of distilling them into the trained
            scene (the paper's "w/o two-stage" ablation, :mod:`roodi_toolkit.pipeline.joint`); needs the dataset's masks.
    """

    train: TrainConfig = field(default_factory=lambda: TrainConfig(init="auto"))
    downscale: float = 1.0
    distill: DistillConfig = DistillConfig()
    threshold: float = 0.3
    prune: bool = True
    prune_config: PruneConfig = PruneConfig()
    inpaint: bool = True
    inpainter: str = "opencv"
    occlusion: OcclusionConfig = OcclusionConfig()
    finetune: FinetuneConfig = FinetuneConfig()
    single_stage: bool = False

    def __post_init__(self) -> None:
        if not 0 < self.threshold < 1:
            raise ConfigError(f"threshold is a probability in (0, 1), got {self.threshold}")


def _scene_only(cloud: GaussianCloud) -> GaussianCloud:
    """Return the cloud without the object-feature columns (what renders and fine-tuning use)."""
    out = cloud.copy()
    out.extras = {k: v for k, v in out.extras.items() if not k.startswith(FEATURE_PREFIX)}
    return out


def _trained(model_dir: Path, iterations: int) -> bool:
    return (model_dir / "point_cloud" / f"iteration_{iterations}" / "point_cloud.ply").is_file()


def _object_masks(dataset: Any, model_dir: Path, object_id: int, views: Sequence[int]) -> torch.Tensor:
    """Return the object's masks ``[V, H, W]`` in ``views``: the dataset's instance maps, else the distilled masks."""
    from ..io.files import read_image

    if dataset.masks is not None:
        return dataset.masks[list(views)] == object_id
    folder = model_dir / "object_masks"
    masks = []
    for v in views:
        path = folder / f"{dataset.cameras[v].name}.png"
        if not path.is_file():
            raise DatasetError(f"{path}: no mask of view {dataset.cameras[v].name}; the dataset has no instance masks "
                               "and the distillation's masks are missing")
        masks.append(torch.as_tensor(read_image(path).astype(np.int64)) == object_id)
    return torch.stack(masks)


def _picture(cloud: GaussianCloud, path: Path, size: int = 192) -> None:
    """Write the object from four directions on white."""
    from ..io.files import write_image
    from ..render.views import framing_orbit
    from ..render.renderer import render_cloud

    cams = framing_orbit(cloud, 4, elevation_deg=25.0, width=size, height=size)
    row = [render_cloud(cloud, c, background=(1.0, 1.0, 1.0)).rgb.clamp(0, 1).numpy() for c in cams]
    write_image(np.concatenate(row, axis=1), path)


def extract_objects(data_dir: str | Path, out_dir: str | Path, object_ids: Sequence[int], *,
                    model_dir: str | Path | None = None, config: ExtractConfig = ExtractConfig(),
                    overwrite: bool = False, progress: ProgressFactory = null_progress) -> dict[str, Any]:
    """Return a report of every stage after writing each object's clean model into ``out_dir``.

    Args:
        data_dir: the posed images (Blender or COLMAP; masks from the dataset's instance maps).
        out_dir: the output folder; an existing one is reused stage by stage (``overwrite`` starts afresh).
        object_ids: the instance ids of the objects to extract (they share the scene and the distillation).
        model_dir: a trained scene (``roodi-toolkit train`` output) to use instead of training one; it is distilled
            in place if it has no classifier yet.
        config: settings of every stage.
        overwrite: remove what a previous run left instead of reusing it.
        progress: progress factory.
    """
    from ..io import files
    from ..io.dataset import load_dataset
    from .distill import load_distillation, run_distill, select_object
    from .finetune import refine_object
    from ..io.ply import read_ply, write_ply
    from .train import train_scene

    if not object_ids:
        raise ConfigError("give at least one object id to extract")
    if config.single_stage and model_dir is not None:
        raise ConfigError("single-stage training trains the scene itself; it cannot start from a trained model")
    out = files.prepare_output_dir(out_dir, overwrite=overwrite, allow_existing=True)
    report: dict[str, Any] = {"data_dir": str(data_dir), "objects": {}, "stages": {}, "reused": []}
    timings = report["stages"]

    t = time.perf_counter()
    if model_dir is None:
        model = out / "scene"
        if _trained(model, config.train.iterations) and not overwrite:
            report["reused"].append("train")
        else:
            resume = (model / "checkpoints" / "latest.pt").is_file() and not overwrite
            if config.single_stage:
                from .joint import train_joint

                train_joint(data_dir, model, config.train, config.distill, downscale=config.downscale,
                            resume=resume, overwrite=not resume, progress=progress)
            else:
                train_scene(data_dir, model, config.train, downscale=config.downscale, resume=resume,
                            overwrite=not resume, progress=progress)
    else:
        model = Path(model_dir)
    timings["train_s"] = time.perf_counter() - t

    t = time.perf_counter()
    if config.single_stage:
        pass  # learned with the scene
    elif (model / CLASSIFIER_FILE).is_file() and (not overwrite or model_dir is not None):
        # a given model is an input: --overwrite replaces this run's outputs, never its distillation
        report["reused"].append("distill")
    else:
        report["distill"] = run_distill(model, data_dir, config=config.distill, downscale=config.downscale,
                                        progress=progress)
    folder, cloud, classifier = load_distillation(model)
    timings["distill_s"] = time.perf_counter() - t
    scene_cloud = _scene_only(cloud)
    dataset = None

    for object_id in object_ids:
        odir = out / f"object_{object_id}"
        odir.mkdir(exist_ok=True)
        entry: dict[str, Any] = {}
        t = time.perf_counter()
        selected_path = odir / "selected.ply"
        if selected_path.is_file() and not overwrite:
            selected = read_ply(selected_path)
            report["reused"].append(f"select {object_id}")
        else:
            sel = select_object(cloud, classifier, int(object_id), threshold=config.threshold, prune=False)
            if len(sel.cloud) == 0:
                raise ConfigError(f"object {object_id}: no Gaussian has probability > {config.threshold}; check the "
                                  "object id (an instance id of the masks) or lower the threshold")
            if config.prune and int(sel.selected.sum()) > config.prune_config.k:
                sel = select_object(cloud, classifier, int(object_id), threshold=config.threshold, prune=True,
                                    prune_config=config.prune_config, progress=progress)
            elif config.prune:
                entry["prune_skipped"] = (f"only {int(sel.selected.sum())} Gaussians selected, not more than "
                                          f"k = {config.prune_config.k} neighbours")
            selected = _scene_only(sel.cloud)
            write_ply(selected, selected_path)
            entry["selected"] = int(sel.selected.sum())
            if sel.prune_report is not None:
                entry["prune"] = sel.prune_report.to_dict()
        entry["select_s"] = time.perf_counter() - t
        entry["gaussians_selected_and_pruned"] = len(selected)
        final = selected
        t = time.perf_counter()
        if config.inpaint:
            refined_path = odir / "refined.ply"
            if refined_path.is_file() and not overwrite:
                final = read_ply(refined_path)
                report["reused"].append(f"refine {object_id}")
            else:
                if dataset is None:
                    dataset = load_dataset(data_dir, config.downscale)
                views = dataset.train_indices
                res = refine_object(selected, scene_cloud, dataset.images[views], [dataset.cameras[v] for v in views],
                                    _object_masks(dataset, model, int(object_id), views), inpainter=config.inpainter,
                                    occlusion=config.occlusion, finetune=config.finetune, debug_dir=odir / "debug",
                                    progress=progress)
                final = res.cloud
                write_ply(final, refined_path)
                entry["perceptual_loss"] = res.finetune.perceptual
                entry["inpainter"] = res.inpainter
        entry["refine_s"] = time.perf_counter() - t
        write_ply(final, odir / "object.ply")
        _picture(final, odir / "object.png")
        entry["object_ply"] = str(odir / "object.ply")
        entry["gaussians"] = len(final)
        report["objects"][str(object_id)] = entry
    report["model"] = str(folder.root)
    report["config"] = asdict(config)
    files.write_json(report, out / "report.json")
    return report
