"""The benchmark's run (:mod:`roodi_toolkit.evaluate.benchmark` has its methods, sizes and tables): every method on
every preset scene into ``OUT``, each stage's result kept there and reused by a re-run (the scenes, trained models,
extracted objects and scores), ``results.json``, ``results.md`` and a picture grid per scene.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import numpy as np

from ..errors import ConfigError, RoodiError
from ..evaluate.baselines import feature_similarity, gaussian_grouping
from ..evaluate.benchmark import (BASELINES, GG_RULE, MACHINE_SIZE, METHODS, MODEL_OF, PRESETS, SHORT, BenchmarkSize,
                                  TargetTruth, _average, _method_order, checks, empty_scores,
                                  extract_config, method_config, results_markdown, scene_name, score_object)
from ..evaluate.metrics import ALPHA_THRESHOLD, zoom_box
from ..io import files
from ..io.dataset import load_dataset, split_views
from ..io.generated import read_scene_record
from ..io.lpips_weights import read_lpips
from ..io.ply import read_ply, write_ply
from ..pipeline.extract import ExtractConfig
from ..pipeline.segment import FilesSegmenter, SegmentPrompt
from ..lpips import LPIPSUnavailable
from ..progress import ProgressFactory, null_progress
from ..render.renderer import Renderer, resolve_renderer
from ..viz.figures import new_figure
from .distill import load_distillation
from .evaluate import load_truth
from .extract import extract_objects


# Generates a missing scene: ``make_scene(folder, preset, seed, size, occluded, progress)``; the scene generator is on
# the floor above this one (roodi_toolkit.synth), so its caller passes it: synth.scene.make_benchmark_scene.
SceneMaker = Callable[[Path, str, int, BenchmarkSize, bool, ProgressFactory], Any]


class _Truths:
    """A scene's record and its targets' true views, each read once for every method and the picture grid."""

    def __init__(self, data: Path) -> None:
        self.data = data
        self.record = read_scene_record(data)
        self.targets = [{"id": int(t["id"]), "name": str(t["name"]),
                         **({"never_seen_share": float(t["never_seen_share"])} if "never_seen_share" in t else {})}
                        for t in self.record["targets"]]
        self._views: dict[int, TargetTruth] = {}

    def __getitem__(self, object_id: int) -> TargetTruth:
        if object_id not in self._views:
            self._views[object_id] = load_truth(self.data, object_id)
        return self._views[object_id]


class _LPIPS:
    """The LPIPS network, read when the run first scores an object and kept for the rest of it."""

    def __init__(self) -> None:
        self._read: tuple[Any, str] | None = None

    def get(self) -> tuple[Any, str]:
        """Return the network and ``"ok"``, or None and why it is unavailable."""
        if self._read is None:
            try:
                self._read = read_lpips(), "ok"
            except LPIPSUnavailable as exc:
                self._read = None, f"unavailable: {exc}"
        return self._read


def _missing_scenes(root: Path, presets: Sequence[str], occluded: bool) -> list[Path]:
    """Return the folders of ``presets``' scenes in ``root`` that hold no scene.json (to be generated)."""
    folders = [root / scene_name(p, occluded) for p in presets]
    return [f for f in folders if not (f / "scene.json").is_file()]


def _scene(root: Path, preset: str, seed: int, size: BenchmarkSize, progress: ProgressFactory,
           occluded: bool = False, make_scene: SceneMaker | None = None) -> Path:
    data = root / scene_name(preset, occluded)
    if (data / "scene.json").is_file():  # reused as it is; its own settings are reported in results["scene_settings"]
        return data
    if data.exists() and any(data.iterdir()):
        raise ConfigError(f"{data} exists but holds no scene.json; remove it or choose another ROOT (the benchmark "
                          "generates its scenes there and never writes over other files)")
    if make_scene is None:
        raise ConfigError(f"{data}: no scene.json, and no make_scene to generate it")
    make_scene(data, preset, seed, size, occluded, progress)
    return data


def _extract_one(method: str, data: Path, out: Path, object_id: int, config: ExtractConfig, model: Optional[Path],
                 progress: ProgressFactory, renderer: Renderer) -> Path:
    """Extract one object; a method that starts from another's run reuses its scene and distillation (read only)."""
    distill = None if model is None else model.parent / "distill"
    extract_objects(data, out, [object_id], model_dir=model, distill_dir=distill,
                    config=method_config(method, config), progress=progress, renderer=renderer)
    return out / f"object_{object_id}" / "object.ply"


def _baseline_one(method: str, data: Path, out: Path, object_id: int, model: Path,
                  loaded: dict[str, Any], renderer: Renderer) -> tuple[Path, bool]:
    """Write one baseline extraction and return its path and whether it was made now (False: an earlier run's,
    made with the same selection rule, is reused); ``loaded`` keeps the scene's distillation, dataset and masks for
    the next target of the same scene."""
    path = out / f"object_{object_id}" / "object.ply"
    record = path.parent / "selection.json"
    if path.is_file() and record.is_file():
        if method not in GG_RULE or files.read_json(record, "baseline selection").get("rule") == GG_RULE[method]:
            return path, False
    if "cloud" not in loaded:
        loaded["distillation"], loaded["cloud"], loaded["classifier"] = load_distillation(model.parent / "distill")
    settings, cloud = loaded["distillation"].record, loaded["cloud"]
    if method in GG_RULE:
        sel = gaussian_grouping(cloud, loaded["classifier"], object_id, rule=GG_RULE[method])
    else:
        if "dataset" not in loaded:
            loaded["dataset"] = load_dataset(data, float(settings.get("downscale", 1) or 1))
            loaded["masks"] = FilesSegmenter().segment(loaded["dataset"], SegmentPrompt()).masks
            loaded["views"] = split_views(loaded["dataset"], int(settings.get("holdout_every", 8)))[0]
        sel = feature_similarity(cloud, loaded["dataset"], loaded["masks"], object_id, views=loaded["views"],
                                 renderer=renderer)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_ply(sel.cloud, path)
    files.write_json({**sel.details, "model": str(model)}, record)  # last: it marks the extraction as complete
    return path, True


def _fingerprint(ply: Path, data: Path, renderer: Renderer) -> str:
    """Return what a score depends on, as a digest: the object PLY's bytes, the scene record and the renderer; a
    cached score is reused only for an equal one."""
    digest = hashlib.sha256()
    for part in (ply, data / "scene.json"):
        with open(part, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
    digest.update(type(renderer).__qualname__.encode())
    return digest.hexdigest()[:32]


def _stale_score(cache: dict[str, Any], key: str, scored: str, target: dict[str, Any]) -> str | None:
    """Return why the cached score under ``key`` is not this extraction's (None: it is, or there is none)."""
    if key in cache and cache[key].get("scored") != scored:
        return "the object or scene differs from the one scored before"  # other settings since
    if key in cache and "never_seen_share" in target and "ns_iou" not in cache[key]:
        return "scored before the never-seen region was"
    return None


def _score_target(method: str, key: str, target: dict[str, Any], truths: _Truths, mout: Path, model: Optional[Path],
                  config: ExtractConfig, cache: dict[str, Any], loaded: dict[str, dict[str, Any]],
                  recomputed: dict[str, str], lpips: _LPIPS, progress: ProgressFactory,
                  renderer: Renderer) -> tuple[dict[str, Any], Optional[np.ndarray]]:
    """Return one target's scores by one method and the render of its first test view (None where it failed):
    extracted (or selected, for a baseline) into ``mout`` and scored, or the score ``cache`` holds for the same
    object, scene and renderer. A failed extraction scores as an empty one, with its message."""
    t = time.perf_counter()
    data = truths.data
    try:
        if method in BASELINES:
            path, fresh = _baseline_one(method, data, mout, target["id"], model,
                                        loaded.setdefault(MODEL_OF[method], {}), renderer)
            if fresh:  # an earlier score belongs to an earlier extraction
                cache.pop(key, None)
        else:
            path = _extract_one(method, data, mout, target["id"], config, model, progress, renderer)
        cloud = read_ply(path)
        scored = _fingerprint(path, data, renderer)
        stale = _stale_score(cache, key, scored, target)
        if stale is not None:
            recomputed[key] = stale
            cache.pop(key)
        if key in cache:  # scored by an earlier run: render the picture's view only
            return cache[key], score_object(cloud, truths[target["id"]], max_views=1, renderer=renderer)[1][0]
        lpips_model, lpips_status = lpips.get()
        ev, renders = score_object(cloud, truths[target["id"]], lpips_model=lpips_model, lpips_status=lpips_status,
                                   progress=progress, renderer=renderer)
        return {**ev.to_dict(per_view=False), "gaussians": len(cloud), "ply": str(path),
                "seconds": time.perf_counter() - t, "scored": scored}, renders[0]
    except RoodiError as exc:
        return cache.get(key) or {**empty_scores(truths[target["id"]]), "failed": str(exc), "gaussians": 0,
                                  "seconds": time.perf_counter() - t}, None


def run_benchmark(root: str | Path, out_dir: str | Path, *, presets: Sequence[str] = PRESETS, seed: int = 0,
                  size: BenchmarkSize = MACHINE_SIZE, methods: Sequence[str] = tuple(METHODS),
                  config: ExtractConfig | None = None, overwrite: bool = False,
                  progress: ProgressFactory = null_progress, renderer: Renderer | None = None,
                  occluded: bool = False, make_scene: SceneMaker | None = None) -> dict[str, Any]:
    """Run every method on every preset scene; write ``results.json``, ``results.md`` and a picture grid per scene
    into ``out_dir``; return the results.

    Args:
        root: where the scenes are found (a ``ROOT/<preset>/scene.json`` is reused as it is) or generated.
        out_dir: models, extracted objects, scores and the tables; an existing one is reused stage by stage.
        presets: scenes to run.
        seed: the scenes' and trainings' seed.
        size: scene and training size (:data:`MACHINE_SIZE` by default, :data:`PAPER_SIZE` for paper-sized runs).
        methods: which of :data:`METHODS` to run (``full`` is always run: the others start from its model;
            ``gaussian_grouping`` also runs ``no_two_stage``, whose jointly trained model it selects from).
        config: the full method's settings (default :func:`extract_config` at ``size``); the methods change it.
        overwrite: start afresh in ``out_dir``.
        progress: progress factory.
        renderer: every rendering of every method, training included (default: the built-in CPU renderer).
        occluded: run on the presets' occluded variants (``ROOT/<preset>_occluded``) and score the never-seen
            region too.
        make_scene: generates a scene missing from ``root`` (:data:`SceneMaker`; the generator's is
            :func:`roodi_toolkit.synth.scene.make_benchmark_scene`); None: every scene must be in ``root``.

    Raises:
        ConfigError: a scene is missing from ``root`` and no ``make_scene`` was given (before anything is written).
    """
    methods, run_order = _method_order(presets, methods)
    missing = [] if make_scene is not None else _missing_scenes(Path(root), presets, occluded)
    if missing:
        raise ConfigError(f"{missing[0]}: no scene.json; generate the benchmark's scenes into {root} first "
                          "(roodi-toolkit make-scene) or pass make_scene (synth.scene.make_benchmark_scene)")
    root, out = Path(root), files.prepare_output_dir(out_dir, overwrite=overwrite, allow_existing=True)
    root.mkdir(parents=True, exist_ok=True)
    # scores are kept per scene, so that runs of different presets (--preset) can go side by side; an older
    # OUT_DIR/scores.json (one file for all scenes) is still read
    legacy = out / "scores.json"
    cache: dict[str, Any] = files.read_json(legacy, "scores") if legacy.is_file() and not overwrite else {}
    config = config or extract_config(size, seed)
    renderer = resolve_renderer(renderer)
    lpips = _LPIPS()
    results: dict[str, Any] = {"root": str(root), "seed": seed, "size": asdict(size), "methods": methods,
                               "iterations": config.train.iterations, "labels": {m: METHODS[m] for m in methods},
                               "scenes": {}, "inpainter": config.inpainter}
    if occluded:
        results["occluded"] = True
    names = [scene_name(p, occluded) for p in presets]
    recomputed: dict[str, str] = {}
    results["recomputed"] = recomputed
    t_all = time.perf_counter()
    for preset, name in zip(presets, names):
        data = _scene(root, preset, seed, size, progress, occluded, make_scene)
        truths = _Truths(data)
        scene_out = out / name
        scene_out.mkdir(parents=True, exist_ok=True)
        scores_path = scene_out / "scores.json"
        if scores_path.is_file() and not overwrite:
            cache.update(files.read_json(scores_path, "scores"))
        per_method: dict[str, Any] = {}
        loaded: dict[str, dict[str, Any]] = {}  # per model: its distillation, read once for the scene's baselines
        pictures: dict[str, dict[int, np.ndarray]] = {}
        for method in run_order:
            model = scene_out / MODEL_OF[method] / "scene" if method in MODEL_OF else None
            rows = []
            pictures[method] = {}
            for target in truths.targets:
                key = f"{name}/{method}/{target['id']}"
                row, picture = _score_target(method, key, target, truths, scene_out / method, model, config, cache,
                                             loaded, recomputed, lpips, progress, renderer)
                if picture is not None:
                    pictures[method][target["id"]] = picture
                if "never_seen_share" in target:
                    row["never_seen_share"] = target["never_seen_share"]
                cache[key] = row
                rows.append(row)
                files.write_json({k: v for k, v in cache.items() if k.startswith(f"{name}/")}, scores_path)
            # seconds of the first run that computed each object (training included where the method trains)
            per_method[method] = {"objects": rows, "mean": _average(rows),
                                  "seconds": float(sum(r.get("seconds", 0.0) for r in rows))}
        results["scenes"][name] = {m: per_method[m] for m in methods}
        results.setdefault("scene_settings", {})[name] = truths.record["settings"]
        results["scenes"][name]["_picture"] = str(_scene_grid(truths, name, methods, pictures, out))
    results["mean"] = {m: _average([results["scenes"][p][m]["mean"] for p in names]) for m in methods}
    results["checks"] = checks(results["mean"])
    results["seconds"] = time.perf_counter() - t_all
    files.write_json(results, out / "results.json")
    (out / "results.md").write_text(results_markdown(results))
    return results


def _scene_grid(truths: _Truths, preset: str, methods: Sequence[str], pictures: dict[str, dict[int, np.ndarray]],
                out: Path) -> Path:
    """Write the scene's picture grid (paper Fig. 5): per target a training view, then the truth and every method's
    render of the first test view, full frame (floaters anywhere show) and zoomed in on the true object."""
    scene = load_dataset(truths.data)
    targets = truths.targets
    cols = ["training view", "ground truth", *methods]
    rows = 2 * len(targets)
    fig, axes = new_figure(rows, len(cols), figsize=(1.6 * len(cols), 1.7 * rows), squeeze=False)
    for r, target in enumerate(targets):
        areas = [int((m == target["id"]).sum()) for m in scene.masks] if scene.masks is not None else [0]
        truth = truths[target["id"]].dataset
        images = [scene.images[int(np.argmax(areas))].numpy(), truth.images[0].numpy()]
        images += [pictures.get(m, {}).get(target["id"], np.ones_like(images[1])) for m in methods]
        y0, y1, x0, x1 = zoom_box(truth.alphas[0].numpy() > ALPHA_THRESHOLD, 2.0)
        for c, (img, title) in enumerate(zip(images, cols)):
            for k, view in enumerate((img, img[y0:y1, x0:x1] if c else None)):
                ax = axes[2 * r + k, c]
                ax.set_xticks([])
                ax.set_yticks([])
                if view is None:
                    ax.axis("off")
                    continue
                ax.imshow(np.clip(view, 0, 1), interpolation="nearest")
                if r == 0 and k == 0:
                    ax.set_title(SHORT.get(title, title), fontsize=7)
                if c == 1:
                    ax.set_ylabel("zoom" if k else "full view", fontsize=6)
            if c == 0:
                axes[2 * r, 0].set_ylabel(target["name"], fontsize=7)
    fig.tight_layout()
    return files.save_figure(fig, out / f"{preset}.png", dpi=130)
