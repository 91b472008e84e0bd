"""Train a scene into a model folder: the folder, its records, checkpoints and pictures around
:func:`roodi_toolkit.pipeline.train.train` (the loop, in memory).

Layout of the model folder (the Inria layout other 3DGS tools read)::

    point_cloud/iteration_N/point_cloud.ply   the trained scene (Inria PLY)
    checkpoints/latest.pt                     the resumable state, every ``checkpoint_every`` steps, atomically
    cfg.json                                  the settings, the data folder and the downscale (how resume checks)
    metrics.json                              held-out figures, timings and the history
    training.png, renders/                    loss and PSNR curves; held-out renders beside the ground truth
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

import torch

from ..errors import ConfigError, InputError
from ..gaussians import GaussianCloud
from ..io import files
from ..io.dataset import Dataset, load_dataset
from ..io.model import checkpoint_file, iteration_ply
from ..io.ply import write_ply
from ..pipeline.distill import DistillConfig, DistilledScene
from ..pipeline.joint import JointTrainer, finish_joint
from ..pipeline.segment import FilesSegmenter, SegmentPrompt
from ..pipeline.train import Trained, TrainConfig, Trainer, train
from ..progress import ProgressFactory, null_progress
from ..render.renderer import Renderer
from ..viz.figures import new_figure
from .records import scene_labels


@dataclass
class TrainResult:
    """What :func:`train_scene` produced."""

    ply_path: Path
    iterations: int
    num_gaussians: int
    metrics: dict[str, float]
    seconds: float
    seconds_per_iteration: float
    history: list[dict[str, float]]
    cloud: GaussianCloud | None = None


def _check_resume_matches(out: Path, data_dir: str | Path, downscale: float) -> None:
    """Refuse to resume a run on another dataset or downscale than the one its checkpoint was trained on (its
    ``cfg.json`` records them): the views would silently change mid-training."""
    cfg_file = out / "cfg.json"
    if not cfg_file.is_file():
        return
    cfg = files.read_json(cfg_file, "training settings")
    if not isinstance(cfg, dict):
        raise InputError(f"{cfg_file}: not a roodi-toolkit training settings file")
    was_dir, was_down = cfg.get("data_dir"), cfg.get("downscale")
    if was_dir is not None and Path(was_dir).exists() and not files.same_file(was_dir, data_dir):
        raise ConfigError(f"{out}: the checkpoint was trained on {was_dir}, not {data_dir}; resume with that "
                          "DATA_DIR or start afresh with --overwrite")
    if isinstance(was_down, (int, float)) and float(was_down) != float(downscale):
        raise ConfigError(f"{out}: the checkpoint was trained at --downscale {was_down:g}, not {downscale:g}; resume "
                          "with that --downscale or start afresh with --overwrite")


def _resume_state(out: Path, data_dir: str | Path, downscale: float) -> dict[str, Any]:
    """Return the checkpoint of the unfinished run in ``out``, checked against the data folder and downscale.

    Raises:
        ConfigError: nothing to resume, or a checkpoint of another dataset or downscale.
        InputError: not a training checkpoint.
    """
    ckpt_file = checkpoint_file(out)
    if not ckpt_file.is_file():
        raise ConfigError(f"{out}: nothing to resume (no {ckpt_file.relative_to(out)}); run without --resume")
    state = files.load_checkpoint(ckpt_file)
    if not isinstance(state, dict) or "config" not in state:
        raise InputError(f"{ckpt_file}: not a roodi-toolkit training checkpoint")
    files.refuse_inside_inputs(out, [data_dir])
    _check_resume_matches(out, data_dir, downscale)
    return state


def train_scene(data_dir: str | Path, out_dir: str | Path, config: TrainConfig = TrainConfig(), *,
                downscale: float = 1, resume: bool = False, overwrite: bool = False,
                progress: ProgressFactory = null_progress, iterations_override: int | None = None,
                on_step: Callable[[Trainer, dict[str, float]], None] | None = None,
                make_trainer: Callable[[Dataset, TrainConfig], Trainer] | None = None,
                dataset: Dataset | None = None, renderer: Renderer | None = None, atomic: bool = False) -> TrainResult:
    """Train a scene model and write it in the layout other 3DGS tools read (the module's docstring); return where
    it is and its figures.

    Args:
        data_dir: a Blender or COLMAP dataset folder.
        out_dir: the output folder; refused if non-empty unless ``resume`` or ``overwrite``.
        config: hyperparameters (ignored on resume: the checkpoint's own are used).
        downscale: image downscale factor.
        resume: continue from ``out_dir/checkpoints/latest.pt``.
        overwrite: start afresh in a non-empty ``out_dir``.
        progress: progress factory (the bar shows loss, PSNR and Gaussian count).
        iterations_override: on resume, train to this many iterations instead of the checkpoint's (the position
            learning-rate decay keeps the original schedule).
        on_step: called after every step (tests use it to interrupt a run).
        make_trainer: builds the trainer from the dataset and config (default :class:`Trainer`; the single-stage
            ablation passes one that also trains object features, with its own renderer).
        dataset: ``data_dir`` already decoded at ``downscale`` (the caller's copy is used, not read again).
        renderer: draws the training views (default: the built-in CPU renderer).
        atomic: the model folder is never half made (the ``train`` command's): ``cfg.json`` appears with the first
            checkpoint (together they are a state ``resume`` continues), each checkpoint lands whole, and the model
            PLY, ``metrics.json``, ``training.png`` and ``renders/`` appear together at the end; a signal or a full
            disk before the first checkpoint leaves no folder at all.
    """
    if not atomic:
        return _train_scene(data_dir, out_dir, config, downscale, resume, overwrite, progress, iterations_override,
                            on_step, make_trainer, dataset, renderer)
    with files.output_group() as outputs:
        def land_checkpoint(trainer: Trainer, info: dict[str, float]) -> None:
            if outputs.holds(checkpoint_file(out_dir)):
                outputs.commit()
            if on_step is not None:
                on_step(trainer, info)

        return _train_scene(data_dir, out_dir, config, downscale, resume, overwrite, progress, iterations_override,
                            land_checkpoint, make_trainer, dataset, renderer)


def _train_scene(data_dir: str | Path, out_dir: str | Path, config: TrainConfig, downscale: float, resume: bool,
                 overwrite: bool, progress: ProgressFactory, iterations_override: int | None,
                 on_step: Callable[[Trainer, dict[str, float]], None] | None,
                 make_trainer: Callable[[Dataset, TrainConfig], Trainer] | None, dataset: Dataset | None,
                 renderer: Renderer | None) -> TrainResult:
    """Train into ``out_dir`` (arguments as :func:`train_scene`)."""
    out = Path(out_dir)
    state = None
    if resume:
        state = _resume_state(out, data_dir, downscale)
        config = TrainConfig.from_dict(state["config"])
        if iterations_override is not None:
            config = replace(config, iterations=iterations_override)
    else:
        files.refuse_inside_inputs(out, [data_dir])
    if dataset is None:
        dataset = load_dataset(data_dir, downscale)
    if not resume:
        # after the dataset is read, so that a bad dataset leaves nothing behind, not even an empty folder
        files.prepare_output_dir(out, overwrite=overwrite, inputs=[data_dir])
    trainer = make_trainer(dataset, config) if make_trainer else Trainer(dataset, config, renderer=renderer)
    if state is not None:
        trainer.load_state_dict(state)
    (out / "checkpoints").mkdir(parents=True, exist_ok=True)
    files.write_json({"data_dir": str(Path(data_dir).resolve()), "downscale": downscale, "scene_scale": trainer.scale,
                      "train_views": len(trainer.train_indices), "eval_views": len(trainer.eval_indices),
                      "dataset_has_alpha": dataset.alphas is not None, **trainer.config.to_dict()}, out / "cfg.json")
    trained = train(trainer, progress=progress, on_step=on_step,
                    on_checkpoint=lambda t: files.save_checkpoint(t.state_dict(), checkpoint_file(out)))
    return _write_model(out, trainer, trained)


def _write_model(out: Path, trainer: Trainer, trained: Trained) -> TrainResult:
    """Write the trained scene, ``metrics.json`` and the pictures into the model folder ``out``; return the result."""
    ply_path = iteration_ply(out, trainer.step)
    ply_path.parent.mkdir(parents=True, exist_ok=True)
    write_ply(trained.cloud, ply_path)
    result = TrainResult(ply_path, trainer.step, trainer.num_gaussians, trained.metrics, trained.seconds,
                         trained.seconds_per_iteration, trained.history, trained.cloud)
    files.write_json({"iterations": trainer.step, "num_gaussians": trainer.num_gaussians, "eval": trained.metrics,
                      "eval_views": [trainer.dataset.cameras[i].name for i in trainer.eval_indices],
                      "seconds_this_run": trained.seconds, "seconds_per_iteration": result.seconds_per_iteration,
                      "history": trained.history}, out / "metrics.json")
    write_training_pictures(trainer, out)
    return result


def write_training_pictures(trainer: Trainer, out: Path, max_renders: int = 4) -> None:
    """Write the loss/PSNR plot and a few held-out renders beside their ground truth."""
    hist = trainer.history
    train_rows = [h for h in hist if "loss" in h]
    evals = [h for h in hist if "eval_psnr" in h]
    fig, (ax1, ax2) = new_figure(1, 2, figsize=(10, 3.5))
    if train_rows:
        ax1.plot([h["step"] for h in train_rows], [h["loss"] for h in train_rows], lw=1)
        ax2.plot([h["step"] for h in train_rows], [h["psnr"] for h in train_rows], lw=1, alpha=0.6,
                 label="train view")
    if evals:
        ax2.plot([h["step"] for h in evals], [h["eval_psnr"] for h in evals], "o-", label="held-out views")
    ax1.set(xlabel="iteration", ylabel="loss", yscale="log", title="training loss")
    ax2.set(xlabel="iteration", ylabel="PSNR (dB)", title="PSNR")
    ax2.legend()
    files.save_figure(fig, out / "training.png")
    renders = out / "renders"
    renders.mkdir(exist_ok=True)
    background = torch.tensor(trainer.dataset.background, dtype=torch.float32)
    colour_only = trainer.params.with_features(None)
    with torch.no_grad():
        for i in (trainer.eval_indices or trainer.train_indices)[:max_renders]:
            cam = trainer.dataset.cameras[i]
            img = trainer.renderer.render(colour_only, cam, sh_degree=trainer.sh_degree, background=background).rgb
            pair = torch.cat([img.clamp(0, 1), trainer.dataset.images[i]], dim=1).numpy()
            files.write_image(pair, renders / f"{cam.name or i}_render_vs_gt.png")


def train_joint(data_dir: str | Path, out_dir: str | Path, config: TrainConfig = TrainConfig(),
                distill: DistillConfig = DistillConfig(), *, downscale: float = 1, resume: bool = False,
                overwrite: bool = False, dataset: Dataset | None = None, progress: ProgressFactory = null_progress,
                renderer: Renderer | None = None) -> tuple[TrainResult, DistilledScene]:
    """Train a scene and its object features together from the dataset's own instance masks into a model folder
    (as :func:`train_scene`); return the training result and the distilled scene (for
    :func:`roodi_toolkit.run.distill.save_distilled`).

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
    distilled = finish_joint(trainers[-1], distill, time.perf_counter() - t0, holdout_every=config.holdout_every,
                             labels=scene_labels(data_dir), progress=progress, renderer=renderer)
    return result, distilled
