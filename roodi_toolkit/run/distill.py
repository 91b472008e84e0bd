"""Distil a trained model folder into a distillation folder: the folders around
:func:`roodi_toolkit.pipeline.distill.distill_scene` (in memory).

A distillation folder (:mod:`roodi_toolkit.io.model`) holds ``features.npy``, ``object_classifier.pt``,
``object_masks/<view>.png``, ``distill.png`` (per view: image, masks, rendered classes, rendered probability of the
predicted class) and ``distill.json``; it names the model file its features belong to and never writes into it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..errors import ConfigError
from ..gaussians import GaussianCloud
from ..io import files
from ..io.dataset import Dataset, load_dataset
from ..io.model import (DISTILL_RECORD, Distillation, ModelFolder, open_model, read_distillation, read_scene,
                        write_distillation)
from ..pipeline.distill import (DistillConfig, DistilledScene, ObjectClassifier, cloud_features, distill_scene,
                                with_features, without_features)
from ..pipeline.model_frame import settle_model_frame
from ..pipeline.segment import SegmentPrompt, resolve_prompt
from ..progress import ProgressFactory, null_progress
from ..render.renderer import Renderer
from .masks import options_with_masks
from .records import scene_labels


def check_model_frame(model: ModelFolder, dataset: Dataset, renderer: Renderer | None = None) -> dict[str, Any]:
    """Return what checking another tool's model against its photos measured, its scene file read for it
    (:func:`~roodi_toolkit.pipeline.model_frame.settle_model_frame`, which picks its frame where the files leave
    two); {} for a model this toolkit trained (not checked, not read).

    Raises:
        ConfigError: the scene does not explain the photos (another frame, or other photos).
    """
    if model.kind == "roodi":
        return {}
    return settle_model_frame(model, read_scene(model.ply_path), dataset, renderer)


def save_distilled(out_dir: str | Path, distilled: DistilledScene, model_ply: str | Path,
                   record: dict[str, Any] | None = None) -> Path:
    """Write a distilled scene as a distillation folder of its own (features, classifier, masks, picture, record);
    return the record's path. ``model_ply`` is the scene file the features belong to (never written)."""
    masks = distilled.masks
    dtype = np.uint8 if masks.num_classes <= 256 else np.uint16
    return write_distillation(
        out_dir, model_ply=Path(model_ply), features=cloud_features(distilled.cloud).numpy(),
        classifier_state=distilled.classifier.state_dict(), record={**distilled.summary, **(record or {})},
        masks={stem: m.astype(dtype) for stem, m in zip(files.file_stems(masks.names), masks.masks.numpy())},
        picture=distilled.picture)


def load_distillation(distill_dir: str | Path, scene: GaussianCloud | None = None,
                      ) -> tuple[Distillation, GaussianCloud, ObjectClassifier]:
    """Return a distillation folder, its scene with the object features as columns, and its classifier.

    ``scene``: the model file's cloud when the caller has read it already (the file is still checked by its digest).

    Raises:
        ModelError: not a distillation folder, or its model file changed or is gone.
    """
    distillation = read_distillation(distill_dir)
    cloud = distillation.read_scene() if scene is None else scene
    if len(cloud) != len(distillation.features):
        raise ConfigError(f"{distillation.root}: {len(distillation.features)} features for the "
                          f"{len(cloud)} Gaussians of {distillation.model_ply}; run roodi-toolkit distill again")
    classifier = ObjectClassifier.from_state_dict(distillation.classifier_state, str(distillation.root))
    return distillation, with_features(without_features(cloud), distillation.features), classifier


def run_distill(model_dir: str | Path, data_dir: str | Path, out_dir: str | Path, *, segmenter: str = "files",
                clicks: Sequence[Any] = (), mask_dir: str | Path | None = None,
                segmenter_options: dict[str, Any] | None = None, config: DistillConfig = DistillConfig(),
                downscale: float | None = None, overwrite: bool = False,
                progress: ProgressFactory = null_progress, renderer: Renderer | None = None,
                dataparser_transforms: str | Path | None = None) -> dict[str, Any]:
    """Segment and distil a trained model folder into a distillation folder ``out_dir``; return its record
    (``renderer``: draws every view, the click segmenter's included; default the built-in CPU renderer).

    Reads ``MODEL_DIR`` as :func:`~roodi_toolkit.io.model.open_model` does (``point_cloud/iteration_N``, ``cfg.json``
    with the downscale and held-out views, also scored here; or another tool's model, checked against the photos
    by :func:`check_model_frame`). Writes into ``out_dir`` only (the module's
    docstring). The model folder and the data folder are inputs and are never written.
    """
    model = open_model(model_dir, data_dir, dataparser_transforms=dataparser_transforms)
    inputs = [model.root, model_dir, data_dir, dataparser_transforms]
    files.check_output_dir(out_dir, overwrite=overwrite, inputs=inputs)
    ds_scale = float(downscale if downscale is not None else model.config.get("downscale", 1) or 1)
    dataset = load_dataset(data_dir, ds_scale, progress=progress)
    check_model_frame(model, dataset, renderer)  # another tool's scene: does it fit the photos?
    # clicks come in the photos' own pixels, whatever the downscale (as extract takes them)
    _, prompt = resolve_prompt(SegmentPrompt(tuple(clicks), None if mask_dir is None else Path(mask_dir)), dataset)
    out = files.prepare_output_dir(out_dir, overwrite=overwrite, inputs=inputs)
    options = options_with_masks(segmenter, segmenter_options, prompt, dataset, max_pixels=config.max_pixels,
                                 progress=progress)
    distilled = distill_scene(model.read_cloud(), dataset, segmenter=segmenter, prompt=prompt,
                              segmenter_options=options, config=config,
                              holdout_every=int(model.config.get("holdout_every", 8)), labels=scene_labels(data_dir),
                              progress=progress, renderer=renderer)
    save_distilled(out, distilled, model.ply_path, {"data_dir": str(Path(data_dir).resolve()), "downscale": ds_scale,
                                                    "model_dir": str(model.root.resolve()), **model.record()})
    return {**distilled.summary, "model": str(model.ply_path), "data_dir": str(data_dir), "downscale": ds_scale,
            "out_dir": str(out), "record": str(out / DISTILL_RECORD), "picture": str(out / "distill.png")}
