"""From posed images to clean objects in one call (paper Fig. 2): the run that walks the data folder down the stages
(train the scene, distil the object masks, then per object: select, prune, reason about occlusion, inpaint and
fine-tune; :mod:`roodi_toolkit.pipeline`, in memory) and writes their results.

The dataset is decoded once and each stage hands its result to the next. Files are written only as outputs and as
the checkpoints a re-run resumes from (the trained scene, the distillation, each object's result), each with the
settings that made it: a re-run with the same folder reuses a finished stage only when its settings are the same, and
says which stages it reused and which it made again and why. Nothing is ever written into the data folder, a given
``--model`` folder or a given ``--distill`` folder.

Layout of ``OUT_DIR``::

    scene/                      the trained scene (roodi-toolkit train layout), unless --model was given
    distill/                    the distillation (roodi-toolkit distill layout), unless --distill was given
    object_<ID>/selected.ply    the object after selection and pruning (the crude model of the paper's Fig. 2d)
    object_<ID>/object.ply      the final object (Inria PLY)
    object_<ID>/object.png      the final object from four directions
    object_<ID>/fill.png        the four object-centred views before (top) and after (bottom) inpainting and
                                fine-tuning: what the fill added outlined in red, what the scene hides in yellow
    object_<ID>/debug/          occlusion masks, inpainting grids, renders before and after fine-tuning
    object_<ID>/stage.json      the settings and inputs the object was made with (how a re-run knows to reuse it)
    report.json                 counts, thresholds and times of every stage
"""

from __future__ import annotations

import shutil
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np
import torch

from ..errors import ConfigError
from ..gaussians import GaussianCloud
from ..io import files
from ..io.dataset import load_dataset
from ..io.lpips_weights import lpips_for_loss
from ..io.model import DISTILL_RECORD, checkpoint_file, find_model, open_model
from ..io.ply import read_ply, write_ply
from ..pipeline.distill import distill_scene, without_features
from ..pipeline.extract import ExtractConfig, object_ids, refine_stage, select_stage
from ..pipeline.occlusion import fill_picture
from ..pipeline.segment import resolve_prompt
from ..progress import ProgressFactory, null_progress
from ..render.renderer import render_cloud, resolve_renderer
from ..render.upright import cameras_up
from ..render.views import framing_orbit
from .distill import check_model_frame, load_distillation, save_distilled
from .masks import folder_masks, options_with_masks
from .refine import write_refine_debug
from .records import Stages, changed_error, read_record, scene_labels, settings, train_record
from .train import train_joint, train_scene


def _train_wanted(config: ExtractConfig, data_dir: Path, downscale: float, has_alpha: bool) -> dict[str, Any]:
    train = config.train
    if train.random_background is None:  # as the Trainer resolves it, so that a finished scene's record matches
        train = replace(train, random_background=has_alpha)
    return {**settings(train.to_dict()), "downscale": downscale, "data_dir": str(data_dir.resolve())}


def _picture(cloud: GaussianCloud, path: Path, size: int = 192, renderer: Any = None,
             cameras: Sequence[Any] = ()) -> None:
    """Write the object from four directions on white, standing on the training cameras' mean up (z without them)."""
    try:
        up = cameras_up(cameras) if len(cameras) else np.array([0.0, 0.0, 1.0])
    except ConfigError:  # cameras whose ups cancel out (a capture all around, upside down half the time)
        up = np.array([0.0, 0.0, 1.0])
    cams = framing_orbit(cloud, 4, elevation_deg=25.0, width=size, height=size, up=up)
    row = [render_cloud(cloud, c, renderer=renderer, background=(1.0, 1.0, 1.0)).rgb.clamp(0, 1).numpy()
           for c in cams]
    files.write_image(np.concatenate(row, axis=1), path)


@dataclass
class PreparedScene:
    """The stages every object of a scene shares, in memory: what :func:`prepare_scene` hands to
    :func:`extract_object`.

    Attributes:
        out: the extraction's output folder.
        dataset: the posed images, decoded once.
        scene: the trained scene without object features.
        cloud: the scene with its object features as columns.
        classifier: the distillation's classifier.
        masks: class maps ``[N, H, W]`` of the dataset's views (the dataset's own, or the distilled masks), or None.
        model: the trained model folder.
        distill_dir: the distillation folder.
        distill_record: its ``distill.json``.
        downscale: the image downscale of every stage.
        report: the shared stages' part of the report (timings, reused and remade stages).
        renderer: the :class:`~roodi_toolkit.render.renderer.Renderer` every stage renders with.
    """

    out: Path
    dataset: Any
    scene: GaussianCloud
    cloud: GaussianCloud
    classifier: Any
    masks: Optional[torch.Tensor]
    model: Any
    distill_dir: Path
    distill_record: dict[str, Any]
    downscale: float
    report: dict[str, Any]
    renderer: Any

    def object_ids(self, requested: Sequence[int | str]) -> list[int]:
        """Return the object ids to extract (:func:`roodi_toolkit.pipeline.extract.object_ids`).

        Raises:
            ConfigError: an id that is not an integer or not one of the distillation's classes.
        """
        return object_ids(requested, self.classifier.num_classes)


def _check_sources(config: ExtractConfig, model_dir: str | Path | None, distill_dir: str | Path | None,
                   dataparser_transforms: str | Path | None) -> None:
    """Refuse given stages that cannot go together.

    Raises:
        ConfigError: ``--model`` or ``--distill`` with single-stage training, ``--distill`` or
            ``--dataparser-transforms`` without ``--model``.
    """
    if config.single_stage and (model_dir is not None or distill_dir is not None):
        raise ConfigError("single-stage training trains the scene and its features together; it cannot start from "
                          "--model or --distill")
    if distill_dir is not None and model_dir is None:
        raise ConfigError("--distill needs the --model it was distilled from")
    if dataparser_transforms is not None and model_dir is None:
        raise ConfigError("--dataparser-transforms goes with the nerfstudio export given as --model")


def _data_folder(data_dir: str | Path | None, model: Any) -> Path:
    """Return the data folder: ``data_dir``, or without it the one the given model's cfg.json names.

    Raises:
        ConfigError: neither, or the named folder is gone.
    """
    if data_dir is None:
        recorded = model.config.get("data_dir") if model is not None else None
        if not recorded:
            raise ConfigError("give the data folder: no --model, or its cfg.json names no data_dir")
        data_dir = recorded
        if not Path(data_dir).exists():
            raise ConfigError(f"{data_dir}: the data folder named in {model.root / 'cfg.json'} is gone; give DATA_DIR")
    return Path(data_dir)


def _train_stage(config: ExtractConfig, data_dir: Path, model_root: Path, dataset: Any, downscale: float,
                 distill_fresh: bool, stages: Stages, overwrite: bool, replace_changed: bool,
                 progress: ProgressFactory, renderer: Any) -> tuple[Any, GaussianCloud, Any]:
    """Return the scene trained into ``model_root``: its model folder, its cloud and, with single-stage training,
    its distillation (else None). A finished run of the same settings is reused, an unfinished one resumed from its
    checkpoint, anything else trained afresh.

    ``distill_fresh``: whether the distillation there can be reused (single-stage training learns it with the scene,
    so a changed one means training again).

    Raises:
        OutputError: an unfinished run of other settings, neither ``overwrite`` nor ``replace_changed``.
    """
    train_wanted = _train_wanted(config, data_dir, downscale, dataset.alphas is not None)
    old = train_record(model_root)
    if config.single_stage and old is not None and not distill_fresh:
        old = None
    if stages.fresh("train", old, train_wanted, overwrite, model_root):
        model = find_model(model_root)
        return model, read_ply(model.ply_path), None
    record = read_record(model_root / "cfg.json", "training record")
    same = isinstance(record, dict) and all(record.get(k) == v for k, v in train_wanted.items())
    if isinstance(record, dict) and not same and not overwrite and not replace_changed:
        # an unfinished run of other settings: starting afresh would replace what it wrote
        raise changed_error(model_root, "train", sorted(k for k, v in train_wanted.items() if record.get(k) != v))
    resume = same and checkpoint_file(model_root).is_file() and not overwrite
    distilled = None
    if config.single_stage:
        result, distilled = train_joint(data_dir.resolve(), model_root, config.train, config.distill,
                                        downscale=downscale, resume=resume, overwrite=not resume,
                                        dataset=dataset, progress=progress, renderer=renderer)
    else:
        result = train_scene(data_dir.resolve(), model_root, config.train, downscale=downscale, resume=resume,
                             overwrite=not resume, dataset=dataset, progress=progress, renderer=renderer)
    return find_model(model_root), result.cloud, distilled


def _distill_stage(config: ExtractConfig, distill_out: Path, distill_old: dict[str, Any] | None,
                   distill_wanted: dict[str, Any], distilled: Any, model: Any, scene: GaussianCloud, dataset: Any,
                   data_dir: Path, downscale: float, prompt: Any, stages: Stages, overwrite: bool,
                   report: dict[str, Any], progress: ProgressFactory, renderer: Any) -> tuple[GaussianCloud, Any]:
    """Return the scene with its object features and their classifier, distilled into ``distill_out`` (or taken
    from the single-stage training's ``distilled``); a finished distillation of the same settings is reused. A new
    one's summary goes into ``report``.

    Raises:
        OutputError: a distillation of other settings there, neither ``overwrite`` nor ``replace_changed``.
    """
    wanted = {**distill_wanted, "model_ply": str(model.ply_path.resolve())}
    if distilled is None and stages.fresh("distill", distill_old, wanted, overwrite, distill_out):
        _, cloud, classifier = load_distillation(distill_out, scene)
        return cloud, classifier
    if distilled is None:
        options = options_with_masks(config.segmenter, config.segmenter_options, prompt, dataset,
                                     max_pixels=config.distill.max_pixels, progress=progress)
        distilled = distill_scene(scene, dataset, segmenter=config.segmenter, prompt=prompt,
                                  segmenter_options=options, config=config.distill,
                                  holdout_every=int(model.config.get("holdout_every", 8)),
                                  labels=scene_labels(data_dir), progress=progress, renderer=renderer)
    save_distilled(distill_out, distilled, model.ply_path,
                   {"downscale": downscale, "data_dir": wanted["data_dir"], "prompt": wanted["prompt"],
                    "segmenter_options": wanted["segmenter_options"],
                    "single_stage": config.single_stage, "model_dir": str(model.root.resolve()),
                    **model.record()})
    report["distill"] = {k: v for k, v in distilled.summary.items() if k != "history"}
    return distilled.cloud, distilled.classifier


def _scene_stage(config: ExtractConfig, model: Any, data_dir: Path, out: Path, dataset: Any, downscale: float,
                 distill_old: dict[str, Any] | None, distill_wanted: dict[str, Any], stages: Stages, overwrite: bool,
                 replace_changed: bool, progress: ProgressFactory, renderer: Any) -> tuple[Any, GaussianCloud, Any]:
    """Return the model, the scene without features and the single-stage training's distillation (or None): the
    given model's, or trained into ``out/scene`` (:func:`_train_stage`)."""
    if model is not None:
        return model, without_features(model.read_cloud()), None
    distill_fresh = Stages({}).fresh("", distill_old, distill_wanted, False)
    model, scene, distilled = _train_stage(config, data_dir, out / "scene", dataset, downscale, distill_fresh,
                                           stages, overwrite, replace_changed, progress, renderer)
    return model, without_features(scene), distilled


def prepare_scene(data_dir: str | Path | None, out_dir: str | Path, *, model_dir: str | Path | None = None,
                  distill_dir: str | Path | None = None, config: ExtractConfig = ExtractConfig(),
                  overwrite: bool = False, progress: ProgressFactory = null_progress,
                  renderer: Any = None, replace_changed: bool = True,
                  dataparser_transforms: str | Path | None = None) -> PreparedScene:
    """Return the stages the objects of a scene share: the decoded dataset, the trained scene (trained into
    ``out_dir/scene`` unless ``model_dir`` is given) and its distillation (into ``out_dir/distill`` unless
    ``distill_dir`` is given), each reused when a previous run made it with the same settings.
    Arguments as :func:`extract_objects`.
    """
    _check_sources(config, model_dir, distill_dir, dataparser_transforms)
    model = open_model(model_dir, data_dir, dataparser_transforms=dataparser_transforms) \
        if model_dir is not None else None
    data_dir = _data_folder(data_dir, model)
    out = files.prepare_output_dir(out_dir, overwrite=overwrite, allow_existing=True,
                                   inputs=[data_dir, model_dir, distill_dir, dataparser_transforms,
                                           model.root if model is not None else None])
    renderer = resolve_renderer(renderer)
    report: dict[str, Any] = {"data_dir": str(data_dir), "objects": {}, "stages": {},
                              "replace_changed": replace_changed}
    stages = Stages(report, replace_changed)
    timings = report["stages"]
    downscale = config.downscale
    if downscale is None:
        downscale = float(model.config.get("downscale", 1) or 1) if model is not None else 1.0
    report["downscale"] = downscale
    dataset = load_dataset(data_dir, downscale, progress=progress)  # decoded once; every stage reads it from memory
    if model is not None:
        report.update(check_model_frame(model, dataset, renderer))  # another tool's scene: does it fit the photos?
    given, prompt = resolve_prompt(config.prompt, dataset)  # checked now, before any training
    distill_out = out / "distill"
    distill_wanted = {"config": settings(config.distill), "segmenter": config.segmenter,
                      "prompt": settings(given), "segmenter_options": settings(config.segmenter_options),
                      "downscale": downscale, "data_dir": str(data_dir.resolve()),
                      "single_stage": config.single_stage}
    distill_old = read_record(distill_out / DISTILL_RECORD, "distillation record")

    t = time.perf_counter()
    model, scene, distilled = _scene_stage(config, model, data_dir, out, dataset, downscale, distill_old,
                                           distill_wanted, stages, overwrite, replace_changed, progress, renderer)
    timings["train_s"] = time.perf_counter() - t

    t = time.perf_counter()
    if distill_dir is not None:
        distillation, cloud, classifier = load_distillation(distill_dir)
        if not distillation.model_ply.samefile(model.ply_path):
            raise ConfigError(f"{distill_dir} is a distillation of {distillation.model_ply}, not of --model "
                              f"{model.ply_path}")
        distill_out = Path(distill_dir)
    else:
        cloud, classifier = _distill_stage(config, distill_out, distill_old, distill_wanted, distilled, model, scene,
                                           dataset, data_dir, downscale, prompt, stages, overwrite, report,
                                           progress, renderer)
    report["distill_dir"] = str(distill_out)
    timings["distill_s"] = time.perf_counter() - t
    masks = dataset.masks
    if masks is None and config.inpaint:  # the masks the features were distilled from
        masks = folder_masks(distill_out / "object_masks", dataset).masks
    report["model"] = str(model.root)
    if model.notes:
        report["model_notes"] = list(model.notes)
    return PreparedScene(out, dataset, scene, cloud, classifier, masks, model, distill_out,
                         files.read_json(distill_out / DISTILL_RECORD, "distillation record"), downscale, report,
                         renderer)


def _object_wanted(prepared: PreparedScene, object_id: int, config: ExtractConfig) -> dict[str, Any]:
    """Return the settings and inputs an object is made with (its ``stage.json``, how a re-run knows to reuse it)."""
    record = prepared.distill_record
    wanted = {"object": int(object_id), "threshold": config.threshold, "prune": config.prune,
              "prune_config": settings(config.prune_config), "inpaint": config.inpaint,
              "inpainter": config.inpainter, "occlusion": settings(config.occlusion),
              "finetune": settings(config.finetune), "downscale": prepared.downscale,
              "features_of": record.get("model_ply_sha256"),
              "distillation": {k: record.get(k) for k in ("config", "segmenter", "prompt", "data_dir")}}
    if config.inpainter_options:  # only when given: records of runs without them stay the same
        wanted["inpainter_options"] = settings(config.inpainter_options)
    return wanted


def extract_object(prepared: PreparedScene, object_id: int, *, config: ExtractConfig = ExtractConfig(),
                   overwrite: bool = False, progress: ProgressFactory = null_progress) -> dict[str, Any]:
    """Return the report entry of one object after writing it into ``OUT/object_<ID>/`` (selection, pruning,
    occlusion-reasoned inpainting, fine-tuning); an earlier result made with the same settings is reused."""
    stages = Stages(prepared.report, bool(prepared.report.get("replace_changed", True)))
    odir = prepared.out / f"object_{object_id}"
    odir.mkdir(exist_ok=True)
    wanted = _object_wanted(prepared, object_id, config)
    stage_file = odir / "stage.json"
    old = read_record(stage_file, "object record")
    if (odir / "object.ply").is_file() and stages.fresh(f"object {object_id}", old, wanted, overwrite, odir):
        return old["entry"]
    t = time.perf_counter()
    selected, entry = select_stage(prepared.cloud, prepared.classifier, object_id, config, progress=progress)
    write_ply(selected, odir / "selected.ply")
    entry["select_s"] = time.perf_counter() - t
    entry["gaussians_selected_and_pruned"] = len(selected)
    final = selected
    t = time.perf_counter()
    if config.inpaint:
        lpips = lpips_for_loss(config.finetune.perceptual, config.finetune.lpips_weights)
        res = refine_stage(selected, prepared.scene, prepared.dataset, prepared.masks, object_id, config,
                           renderer=prepared.renderer, progress=progress, lpips=lpips)
        write_refine_debug(res, odir / "debug", prepared.renderer)
        final = res.cloud
        files.write_image(fill_picture(res.occlusion.object_rgb, res.after_views, res.filled, res.occlusion.occluded),
                          odir / "fill.png")
        entry["proposed_gaussians"] = res.proposed
        entry["perceptual_loss"] = res.finetune.perceptual
        entry["inpainter"] = res.inpainter
    entry["refine_s"] = time.perf_counter() - t
    write_ply(final, odir / "object.ply")
    _picture(final, odir / "object.png", renderer=prepared.renderer, cameras=prepared.dataset.cameras)
    entry["object_ply"] = str(odir / "object.ply")
    entry["gaussians"] = len(final)
    files.write_json({**wanted, "entry": entry}, stage_file)  # last: marks the object as finished
    return entry


def extract_objects(data_dir: str | Path | None, out_dir: str | Path, object_ids: Sequence[int | str], *,
                    model_dir: str | Path | None = None, distill_dir: str | Path | None = None,
                    config: ExtractConfig = ExtractConfig(), overwrite: bool = False,
                    progress: ProgressFactory = null_progress, renderer: Any = None,
                    replace_changed: bool = True, dataparser_transforms: str | Path | None = None) -> dict[str, Any]:
    """Return a report of every stage after writing each object's clean model into ``out_dir``.

    Args:
        data_dir: the posed images (Blender or COLMAP; masks from the dataset's instance maps, or the segmenter's);
            None: the ``data_dir`` that ``model_dir``'s ``cfg.json`` names.
        out_dir: the output folder; finished stages in it are reused when made with the same settings
            (``overwrite`` makes every stage again).
        object_ids: the instance ids of the objects to extract, or ``"all"`` (they share the scene and the
            distillation); 1 for the object a click segmenter's binary masks hold.
        model_dir: a trained scene to use instead of training one; only read: a ``roodi-toolkit train`` output, or
            what :func:`~roodi_toolkit.io.model.open_model` opens (an Inria or gsplat output, a gsplat checkpoint, a
            splat file with ``data_dir``).
        distill_dir: a distillation of that scene (``roodi-toolkit distill`` output) to use instead of distilling;
            only read.
        config: settings of every stage.
        overwrite: make every stage again instead of reusing what a previous run left.
        progress: progress factory.
        renderer: a :class:`~roodi_toolkit.render.renderer.Renderer` (or registered name) every stage renders with;
            default the built-in CPU renderer.
        dataparser_transforms: with a nerfstudio export as ``model_dir``, its run's ``dataparser_transforms.json``.
        replace_changed: make a finished stage of other settings again (True), or refuse to replace it without
            ``overwrite`` (False: the ``extract`` command, whose outputs are replaced only with ``--overwrite``).

    Raises:
        OutputError: with ``replace_changed=False``, a finished (or started) stage in ``out_dir`` made with other
            settings; the message names it, what changed and how to go on.
    """
    if not object_ids:
        raise ConfigError("give at least one object id to extract (or --object all)")
    out = Path(out_dir)
    created = not out.exists()
    try:
        prepared = prepare_scene(data_dir, out_dir, model_dir=model_dir, distill_dir=distill_dir, config=config,
                                 overwrite=overwrite, progress=progress, renderer=renderer,
                                 replace_changed=replace_changed, dataparser_transforms=dataparser_transforms)
    except BaseException:
        # a refused input (a bad click, say) leaves nothing behind; a partly trained scene stays, to resume from
        if created and out.is_dir() and not any(p.is_file() for p in out.rglob("*")):
            shutil.rmtree(out)
        raise
    report = prepared.report
    for object_id in prepared.object_ids(object_ids):
        report["objects"][str(object_id)] = extract_object(prepared, object_id, config=config, overwrite=overwrite,
                                                           progress=progress)
    report["config"] = asdict(config)
    files.write_json(report, prepared.out / "report.json")
    return report
