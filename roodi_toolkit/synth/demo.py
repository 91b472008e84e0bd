"""The README's main job on generated data: extract one object from a generated scene and score it (no GPU, no
downloads, no input files), and the earlier planted-floater pruning demo.

:func:`run_extract_demo` generates a multi-object scene (:mod:`roodi_toolkit.synth.scene`), trains it, distils its
instance masks, extracts one partly hidden target with the offline defaults
(:func:`roodi_toolkit.run.extract.extract_objects`: ``files`` masks, the weight-free ``symmetry`` inpainter) in
the preset's occluded variant, where part of the target is never seen in training, and scores it with the paper's
metrics against the target's object-alone views.
:func:`run_prune_demo` plants floaters around a generated surface and prunes them (:mod:`roodi_toolkit.synth.floaters`).

Layout of the extraction demo's ``OUT_DIR``::

    data/                       the generated scene (roodi-toolkit make-scene layout)
    extraction/                 roodi-toolkit extract's folder: scene/ (trained, distilled), object_<ID>/...
    extraction/object_<ID>/object.ply   the extracted object (Inria PLY)
    summary.png                 a training view, the true object, the object before and after refinement, the test
                                view's never-seen part (or what the model lacked) outlined on the last three
    report.json                 settings, stage times, metrics, paths
"""

from __future__ import annotations

import os
import platform
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
import torch
from matplotlib.patches import Rectangle
from scipy.ndimage import binary_erosion

from ..errors import ConfigError
from ..evaluate.metrics import ALPHA_THRESHOLD, Evaluation, zoom_box
from ..gaussians import GaussianCloud
from ..io import files
from ..io.dataset import load_dataset
from ..io.files import read_image
from ..io.ply import read_ply, write_ply
from ..pipeline.extract import ExtractConfig
from ..pipeline.occlusion import FILLED_COLOUR, outlined
from ..pipeline.train import TrainConfig, config_with
from ..progress import ProgressFactory, null_progress
from ..prune.outliers import remove_statistical_outliers
from ..render.renderer import Renderer, resolve_renderer
from ..run.evaluate import evaluate_object, find_target
from ..run.extract import extract_objects
from ..settings import check_settings, documented, setting
from ..viz.figures import new_figure
from .floaters import FloaterMix, planted_floater_cloud, removal_scores
from .objects import PRESETS
from .scene import SceneSettings, build_scene, make_scene
from .tracer import render_views


@dataclass
class DemoResult:
    """Where the demo wrote its files and how well pruning did against the planted truth."""

    out_dir: Path
    files: dict[str, Path]
    scores: dict[str, float]
    input_count: int
    kept_count: int
    seconds: float


def _projection_panel(ax, cloud: GaussianCloud, keep: np.ndarray, axes: tuple[int, int], title: str) -> None:
    rgb = np.clip(cloud.rgb, 0, 1)
    x, y = cloud.means[:, axes[0]], cloud.means[:, axes[1]]
    ax.scatter(x[keep], y[keep], s=0.3, c=rgb[keep], linewidths=0, rasterized=True)
    if (~keep).any():
        ax.scatter(x[~keep], y[~keep], s=2.5, c="red", linewidths=0, rasterized=True, label="removed")
        ax.legend(loc="upper right", markerscale=3, fontsize=8)
    ax.set_title(title, fontsize=9)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def run_prune_demo(out_dir: str | Path, *, seed: int = 0, surface: str = "ant", n_object: int = 20_000,
                   overwrite: bool = False, progress: ProgressFactory = null_progress) -> DemoResult:
    """Return the figures of a prune run on a generated cloud with planted floaters, after writing its files.

    Writes ``with_floaters.ply`` (the input), ``pruned.ply``, ``floaters.ply`` (what was removed), ``report.json`` and
    ``prune_demo.png`` (the cloud before and after, removed Gaussians in red) into ``out_dir``.
    """
    out = files.prepare_output_dir(out_dir, overwrite=overwrite)
    t0 = time.perf_counter()
    planted = planted_floater_cloud(FloaterMix(surface, n_object=n_object), seed=seed)
    paths = {"input": out / "with_floaters.ply", "pruned": out / "pruned.ply", "floaters": out / "floaters.ply",
             "report": out / "report.json", "picture": out / "prune_demo.png"}
    write_ply(planted.cloud, paths["input"])
    pruned, keep, report = remove_statistical_outliers(planted.cloud, progress=progress)
    write_ply(pruned, paths["pruned"])
    if (~keep).any():
        write_ply(planted.cloud.select(~keep), paths["floaters"])
    else:
        del paths["floaters"]
    scores = removal_scores(planted.labels, keep)
    summary = report.to_dict()
    summary["planted_truth"] = {"object_lost": scores["object"], "far_removed": scores["far"],
                                "near_removed": scores["near"]}
    files.write_json(summary, paths["report"])

    # look along the axis in which the object is thinnest, so its outline is clearest
    extent = np.ptp(pruned.means, axis=0)
    thin = int(np.argmin(extent))
    view = tuple(i for i in range(3) if i != thin)
    along = "xyz"[thin]
    fig, axes = new_figure(1, 3, figsize=(12, 4.2))
    _projection_panel(axes[0], planted.cloud, np.ones(len(keep), dtype=bool), view,
                      f"input: {len(keep):,} Gaussians (view along {along})")
    _projection_panel(axes[1], planted.cloud, keep, view, f"flagged by pruning: {(~keep).sum():,}")
    _projection_panel(axes[2], pruned, np.ones(len(pruned), dtype=bool), view, f"pruned: {len(pruned):,}")
    fig.suptitle(f"W2 statistical outlier pruning: far floaters removed {scores['far']:.1%}, near-surface floaters "
                 f"removed {scores['near']:.1%}, object lost {scores['object']:.2%}", fontsize=10)
    files.save_figure(fig, paths["picture"])
    return DemoResult(out, paths, scores, len(keep), int(keep.sum()), time.perf_counter() - t0)


# ------------------------------------------------------------------------------------------------ extraction demo


def _demo_train() -> TrainConfig:
    # 2000 steps with --init depth reach 32.5 dB held-out on the 128x128 bedroom scene in 3.4 min on a quiet 2-core
    # machine (benchmarks/RESULTS.md, "Scene training"; the glossy kitchen: 24.5 dB). A 30,000 cap (15,000 lifted from
    # depth) rather than 40,000 (20,000) took the whole demo from 15.8 to 11.3 min on a shared machine, distillation
    # being the larger share, and scored the kitchen pot better (IoU 0.83 against 0.78; "Extraction demo" in
    # RESULTS.md).
    return config_with(TrainConfig(), iterations=2000, init="depth", init_num_points=15_000, cap_max=30_000,
                       eval_every=0)


@documented
@dataclass(frozen=True)
class ExtractDemoConfig:
    """Settings of the extraction demo; the defaults finish within 20 minutes on 2 CPU cores (benchmarks/RESULTS.md).
    The demo command offers the settings of ``scene`` and ``extract`` it takes through ``Options(within=...)``."""

    # kitchen: glossy pots, bowls and vases on and around a table
    preset: str = setting("kitchen", "Generated scene type.", choices=tuple(PRESETS))
    # kitchen 2: a metal pot by the table, 13% of it hidden by the table top and the bottles on it; not offered by
    # the demo command, whose --seed is also the pruning demo's
    seed: int = setting(2, "Seed of the generated scene.", low=0, high=2 ** 32 - 1, cli=False)
    object_id: Optional[int] = setting(None, "Instance id of the target to extract (default: the target other "
                                             "objects hide most).", option="--object")
    # the test views are the object-alone views scored
    scene: SceneSettings = setting(factory=lambda: SceneSettings(width=128, height=128, train_views=50,
                                                                 test_views=12, occluded=True),
                                   help="Image size and view counts of the generated scene.", prefix="")
    extract: ExtractConfig = setting(factory=lambda: ExtractConfig(train=_demo_train(), inpainter="symmetry"),
                                     help="Every extraction stage: the offline defaults but the scene training, "
                                          "sized for the CPU.", prefix="")

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass
class ExtractDemoResult:
    """What the extraction demo wrote and measured.

    Attributes:
        out_dir: the demo's folder.
        object_id: the extracted target's instance id.
        object_name: its name in scene.json.
        files: name -> path of the outputs (``object_ply``, ``summary``, ``object_picture``, ``debug``, ``report`` ...).
        evaluation: the paper's metrics of the extracted object.
        before: the same metrics of the object after selection and pruning, before inpainting and fine-tuning.
        stages: wall seconds per stage.
        cpu_stages: process CPU seconds per stage, all threads together (``extract``: its four stages).
        gaussians: Gaussian counts (``scene``, ``selected``, ``object``).
        hidden_fraction: fraction of the target's pixels hidden by other objects over the training views.
        scene_psnr: held-out PSNR of the trained scene model (None when it has no held-out views).
        seconds: wall time of the whole demo.
        load_average: the machine's 1-minute load average at the start and at the end.
    """

    out_dir: Path
    object_id: int
    object_name: str
    files: dict[str, Path]
    evaluation: Evaluation
    before: Evaluation
    stages: dict[str, float]
    cpu_stages: dict[str, float]
    gaussians: dict[str, int]
    hidden_fraction: float
    scene_psnr: Optional[float]
    seconds: float
    load_average: tuple[float, float]


class _Clock:
    """Wall and process CPU seconds of named stages."""

    def __init__(self) -> None:
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self._t = (time.perf_counter(), time.process_time())

    def lap(self, name: str) -> None:
        now = (time.perf_counter(), time.process_time())
        self.wall[name] = self.wall.get(name, 0.0) + now[0] - self._t[0]
        self.cpu[name] = self.cpu.get(name, 0.0) + now[1] - self._t[1]
        self._t = now


def run_environment(renderer: Renderer) -> dict[str, Any]:
    """Return what the figures of a run depend on besides its settings: the renderer, PyTorch's and NumPy's versions,
    PyTorch's intra-op threads and the CPU instruction set its kernels were chosen for, and the processor.

    A different float summation order (more threads, another instruction set or BLAS path, another PyTorch) changes
    the trained scene a little, and training amplifies it the way a change of seed does (docs/benchmark.md,
    "Run to run"); a report with these records says which of them differed.
    """
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            cpu = next((line.split(":", 1)[1].strip() for line in fh if line.startswith("model name")), cpu)
    except OSError:
        pass
    return {"renderer": getattr(renderer, "name", "") or type(renderer).__name__, "torch": torch.__version__,
            "numpy": np.__version__, "threads": torch.get_num_threads(),
            "cpu_capability": torch.backends.cpu.get_cpu_capability(), "cpu": cpu}


def _alone_masks(scene: Any, cameras: list, target_ids: list[int]) -> dict[int, np.ndarray]:
    """Return per target ``[V, H, W]`` True where it covers the views' pixel centres when rendered alone."""
    alone = {}
    for tid in target_ids:
        renders = render_views(scene, cameras, object_ids=[tid], with_ground=False, supersample=1)
        alone[tid] = np.stack([r.ids == tid for r in renders])
    return alone


def _outline(mask: np.ndarray) -> np.ndarray:
    return mask & ~binary_erosion(mask)


def _view_scores(view: Any) -> str:
    return "" if view.psnr is None else f"\nPSNR {view.psnr:.1f} dB, IoU {view.iou:.2f}"


def _never_seen(target_dir: Path, view_name: str, truth_alpha: np.ndarray, before: np.ndarray) -> tuple[np.ndarray, str]:
    """Return the region of a test view to outline ``[H, W]`` and what it is: the scene's never-seen mask of that
    view when make-scene wrote one (``test/never_seen/<view>.png`` beside the target's views), else the true
    object's pixels where the object before the fill shows the white background (what the model lacked)."""
    path = target_dir / "test" / "never_seen" / f"{Path(view_name).name}.png"
    if path.is_file():
        mask = np.asarray(read_image(path))
        mask = mask[..., 0] if mask.ndim == 3 else mask
        if mask.shape == truth_alpha.shape:
            return mask > 0.5 * mask.max() if mask.max() > 0 else mask > 0, "never seen in training"
    lacking = (truth_alpha > ALPHA_THRESHOLD) & (np.abs(before - 1.0).max(axis=2) < 0.05)
    return lacking, "missing before the fill"


def _summary_figure(path: Path, train_image: np.ndarray, alone: np.ndarray, visible: np.ndarray, truth: np.ndarray,
                    truth_alpha: np.ndarray, before: np.ndarray, after: np.ndarray, titles: list[str],
                    suptitle: str, never_seen: np.ndarray | None = None) -> None:
    """Write five panels: a training view, its close-up (the target outlined, its hidden part in red), then, zoomed
    in on the object in one test view, the true object and the object before and after refinement, with the
    ``never_seen`` region ``[H, W]`` of that view outlined in red on all three (what the fill had to add)."""
    view = train_image.copy()
    hidden = alone & ~visible
    view[hidden] = 0.45 * view[hidden] + 0.55 * np.array([1.0, 0.0, 0.0])
    view[_outline(alone)] = (1.0, 0.9, 0.0)
    y0, y1, x0, x1 = zoom_box(alone)
    t0, t1, s0, s1 = zoom_box(truth_alpha > ALPHA_THRESHOLD, 2.0)
    tests = (truth, before, after)
    if never_seen is not None and never_seen.any():
        width = max(1, truth.shape[0] // 128)
        tests = tuple(outlined(img, [(never_seen, FILLED_COLOUR)], width=width, tint=0.0) for img in tests)
    test = [img[t0:t1, s0:s1] for img in tests]
    fig, axes = new_figure(1, 5, figsize=(16, 3.9))
    for ax, img, title in zip(axes, [train_image, view[y0:y1, x0:x1], *test], titles):
        ax.imshow(np.clip(img, 0, 1), interpolation="nearest")
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    axes[0].add_patch(Rectangle((x0 - 0.5, y0 - 0.5), x1 - x0, y1 - y0, fill=False, edgecolor=(1.0, 0.9, 0.0),
                                linewidth=1.5))
    fig.suptitle(suptitle, fontsize=10)
    files.save_figure(fig, path)


def _choose_target(scene: Any, dataset: Any, target_ids: list[int],
                   requested: int | None) -> tuple[int, dict[int, np.ndarray], dict[int, int], float]:
    """Return the target to extract (``requested``, or the one other objects hide most: its object-alone
    silhouettes against the scene's instance masks), every target's silhouettes ``[N, H, W]`` and hidden pixels, and
    the hidden share of the chosen one."""
    masks = dataset.masks.numpy()
    alone = _alone_masks(scene, dataset.cameras, target_ids)
    hidden = {tid: int((a & (masks != tid)).sum()) for tid, a in alone.items()}
    if requested is None:
        object_id = max(target_ids, key=lambda t: (hidden[t], int(alone[t].sum())))
    else:
        object_id = int(requested)
    total = int(alone[object_id].sum())
    return object_id, alone, hidden, hidden[object_id] / total if total else 0.0


def _summary_views(evaluation: Any, alone: np.ndarray, visible: np.ndarray) -> tuple[int, int]:
    """Return the summary's test view (the one of median PSNR, a representative one) and training view (the one
    hiding most of the target among those that show at least 30% of it; ``alone``, ``visible`` ``[N, H, W]``)."""
    scored = [i for i, v in enumerate(evaluation.views) if v.psnr is not None] or list(range(len(evaluation.views)))
    j = sorted(scored, key=lambda i: evaluation.views[i].psnr or 0.0)[len(scored) // 2]
    seen = visible.sum(axis=(1, 2)) >= 0.3 * np.maximum(alone.sum(axis=(1, 2)), 1)
    hidden_per_view = np.where(seen, (alone & ~visible).sum(axis=(1, 2)), -1)
    k = int(np.argmax(hidden_per_view)) if seen.any() else int(np.argmax(visible.sum(axis=(1, 2))))
    return j, k


def _draw_summary(path: Path, config: ExtractDemoConfig, data: Path, dataset: Any, object_id: int, name: str,
                  alone: np.ndarray, visible: np.ndarray, hidden_fraction: float, evaluation: Any, before: Any,
                  renders: list, before_renders: list) -> tuple[str, str]:
    """Write ``summary.png`` (a training view, the target in close-up, the true object, before and after) and
    return the names of its training and test views."""
    settings = config.scene
    j, k = _summary_views(evaluation, alone, visible)
    truth = load_dataset(find_target(data, object_id)[0], background=(1.0, 1.0, 1.0))
    vj = evaluation.views[j]
    never_seen, what = _never_seen(find_target(data, object_id)[0], vj.name, truth.alphas[j].numpy(),
                                   np.asarray(before_renders[j]))
    _summary_figure(path, dataset.images[k].numpy(), alone[k], visible[k], truth.images[j].numpy(),
                    truth.alphas[j].numpy(), before_renders[j], renders[j],
                    [f"training view {dataset.cameras[k].name}", f"close-up: {name} outlined,\nits hidden part in red",
                     f"true {name} alone, test view {vj.name} (zoom)\n{what} outlined in red",
                     f"selected + pruned (before inpainting){_view_scores(before.views[j])}",
                     f"extracted (inpainted + fine-tuned){_view_scores(vj)}"],
                    f"ROODI on a generated {config.preset} scene (seed {config.seed}, "
                    f"{settings.width}x{settings.height}): {name}, {hidden_fraction:.0%} of it hidden "
                    "in the training views", never_seen=never_seen)
    return dataset.cameras[k].name, vj.name


def run_extract_demo(out_dir: str | Path, config: ExtractDemoConfig = ExtractDemoConfig(), *,
                     overwrite: bool = False, progress: ProgressFactory = null_progress,
                     renderer: Renderer | None = None) -> ExtractDemoResult:
    """Return the figures of an extraction on a generated scene, after writing the scene, the object and pictures.

    Generates the scene into ``out_dir/data``, extracts the target into ``out_dir/extraction`` (train, distil with
    the scene's own instance masks, select, prune, occlusion-reasoned inpainting with ``config.extract.inpainter``,
    fine-tune), scores the object before and after refinement against the target's object-alone test views, and
    writes ``summary.png`` and ``report.json`` (with :func:`run_environment`).

    Args:
        out_dir: the demo's folder; an existing non-empty one is refused unless ``overwrite`` (then everything is
            regenerated and retrained).
        config: scene, target and extraction settings.
        overwrite: write into an existing folder.
        progress: progress factory (one bar per stage).
        renderer: every rendering of the extraction and its scoring (default: the built-in CPU renderer).

    Raises:
        ConfigError: bad settings, or ``config.object_id`` is not one of the scene's targets.
        OutputError: ``out_dir`` exists and is not empty without ``overwrite``.
    """
    renderer = resolve_renderer(renderer)
    load_start = os.getloadavg()[0]
    t0 = time.perf_counter()
    clock = _Clock()
    settings = config.scene
    # the scene make_scene writes below (occluded variants included: their wraps are objects too, and the ids follow)
    scene = build_scene(config.preset, config.seed, n_objects=settings.n_objects, n_targets=settings.n_targets,
                        occluded=settings.occluded)
    target_ids = [o.id for o in scene.targets]
    if config.object_id is not None and config.object_id not in target_ids:
        listed = ", ".join(f"{o.id} ({o.name})" for o in scene.targets)
        raise ConfigError(f"object {config.object_id} is not a target of the {config.preset} scene with seed "
                          f"{config.seed}; its targets are {listed}")
    out = files.prepare_output_dir(out_dir, overwrite=overwrite)
    data = out / "data"
    make_scene(data, config.preset, config.seed, settings=settings, overwrite=overwrite, progress=progress)
    clock.lap("make_scene")

    dataset = load_dataset(data)
    object_id, alone, hidden, hidden_fraction = _choose_target(scene, dataset, target_ids, config.object_id)
    name = scene.object(object_id).name
    clock.lap("choose_target")

    ex_dir = out / "extraction"
    report = extract_objects(data, ex_dir, [object_id], config=config.extract, overwrite=overwrite, progress=progress,
                             renderer=renderer)
    entry = report["objects"][str(object_id)]
    for stage in ("train", "distill"):
        clock.wall[stage] = report["stages"][f"{stage}_s"]
    clock.wall["select_prune"] = entry["select_s"]
    clock.wall["refine"] = entry["refine_s"]
    clock.lap("extract")  # the CPU seconds of the four stages together; wall seconds kept per stage above
    clock.wall.pop("extract")

    odir = ex_dir / f"object_{object_id}"
    final, selected = read_ply(odir / "object.ply"), read_ply(odir / "selected.ply")
    evaluation, renders = evaluate_object(final, data, object_id, progress=progress, renderer=renderer)
    before, before_renders = evaluate_object(selected, data, object_id, progress=progress, renderer=renderer)
    clock.lap("evaluate")

    paths = {"object_ply": odir / "object.ply", "summary": out / "summary.png", "object_picture": odir / "object.png",
             "debug": odir / "debug", "selected_ply": odir / "selected.ply", "scene_model": ex_dir / "scene",
             "data": data, "overview": data / "overview.png", "report": out / "report.json"}
    train_view, test_view = _draw_summary(paths["summary"], config, data, dataset, object_id, name, alone[object_id],
                                          dataset.masks.numpy() == object_id, hidden_fraction, evaluation, before,
                                          renders, before_renders)
    clock.lap("pictures")

    trained = files.read_json(ex_dir / "scene" / "metrics.json", "training metrics")
    scene_psnr = (trained.get("eval") or {}).get("psnr")
    gaussians = {"scene": int(trained.get("num_gaussians", 0)), "selected": int(entry["gaussians_selected_and_pruned"]),
                 "object": int(entry["gaussians"])}
    seconds = time.perf_counter() - t0
    load = (load_start, os.getloadavg()[0])
    files.write_json({
        "preset": config.preset, "seed": config.seed, "object_id": object_id, "object_name": name,
        "hidden_fraction": hidden_fraction, "hidden_pixels_per_target": {str(t): h for t, h in hidden.items()},
        "metrics": evaluation.to_dict(), "metrics_before_refinement": before.to_dict(),
        "stages_s": clock.wall, "stages_cpu_s": clock.cpu, "seconds": seconds, "load_average_1min": list(load),
        "cpu_count": os.cpu_count(), "gaussians": gaussians, "scene_heldout_psnr": scene_psnr,
        "summary_views": {"train": train_view, "test": test_view},
        "scene_settings": asdict(settings), "extract_config": asdict(config.extract),
        "environment": run_environment(renderer), "files": {key: str(p) for key, p in paths.items()}}, paths["report"])
    return ExtractDemoResult(out, object_id, name, paths, evaluation, before, clock.wall, clock.cpu, gaussians,
                             hidden_fraction, scene_psnr, seconds, load)
