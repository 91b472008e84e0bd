"""Scoring an extracted object against a generated scene's target, read from the scene folder (``roodi-toolkit
evaluate``, the demo, the benchmark): the folder's target, true views and never-seen masks are read here, once; the
scores are :func:`roodi_toolkit.evaluate.benchmark.score_object`'s, in memory."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import DatasetError, RoodiError
from ..gaussians import GaussianCloud
from ..io.dataset import load_dataset
from ..io.files import read_image
from ..io.generated import read_scene_record
from ..io.lpips_weights import read_lpips
from ..lpips import LPIPSUnavailable
from ..evaluate.benchmark import TargetTruth, score_object
from ..evaluate.metrics import Evaluation
from ..progress import ProgressFactory, null_progress
from ..render.renderer import Renderer


def find_target(data_dir: str | Path, object_id: int) -> tuple[Path, str]:
    """Return the folder of target ``object_id``'s object-alone test views and the object's name.

    Raises:
        DatasetError: no scene.json, or no such target (the message lists the targets).
    """
    root = Path(data_dir)
    record = read_scene_record(root)
    targets = {int(t["id"]): t for t in record.get("targets", [])}
    if object_id not in targets:
        listed = ", ".join(f"{i} ({t['name']})" for i, t in sorted(targets.items())) or "none"
        raise DatasetError(f"{root}: object {object_id} is not an extraction target; targets: {listed}")
    folder = root / targets[object_id]["path"]
    if not (folder / "transforms_test.json").is_file():
        raise DatasetError(f"{folder}: missing transforms_test.json of the target's views")
    return folder, str(targets[object_id]["name"])


def load_never_seen(data_dir: str | Path, object_id: int, names: Sequence[str]) -> np.ndarray | None:
    """Return ``[N, H, W]`` bool never-seen masks of target ``object_id``'s test views ``names``, or None when the
    scene has none (made without ``--occluded`` / ``--never-seen``).

    Raises:
        DatasetError: scene.json names masks that are missing or unreadable.
    """
    root = Path(data_dir)
    target = {int(t["id"]): t for t in read_scene_record(root).get("targets", [])}.get(int(object_id))
    if target is None or "never_seen" not in target:
        return None
    folder = root / target["path"] / str(target["never_seen"])
    masks = []
    for name in names:
        path = folder / f"{Path(name).name}.png"
        try:
            m = read_image(path)
        except (RoodiError, OSError) as exc:
            raise DatasetError(f"{path}: cannot read the never-seen mask named by scene.json ({exc}); regenerate the "
                               "scene with make-scene") from None
        masks.append(np.asarray(m).reshape(m.shape[0], m.shape[1], -1)[..., 0] > 127)
    return np.stack(masks)


def load_truth(data_dir: Path, object_id: int) -> TargetTruth:
    """Return target ``object_id``'s true object-alone test views and never-seen masks, read from the scene folder.

    Raises:
        DatasetError: no such target, views without alpha, or never-seen masks of another size than the views.
    """
    folder, name = find_target(data_dir, object_id)
    truth = load_dataset(folder, background=(1.0, 1.0, 1.0))
    if truth.alphas is None:
        raise DatasetError(f"{folder}: the target's views have no alpha; cannot score IoU")
    never_seen = load_never_seen(data_dir, object_id, truth.names)
    if never_seen is not None and never_seen.shape[1:] != (truth.height, truth.width):
        raise DatasetError(f"{folder}: the never-seen masks are {never_seen.shape[2]}x{never_seen.shape[1]} but the "
                           f"test views {truth.width}x{truth.height}; regenerate the scene")
    return TargetTruth(int(object_id), name, truth, never_seen)


def evaluate_object(cloud: GaussianCloud, data_dir: str | Path, object_id: int, *, renderer: Renderer | None = None,
                    lpips_weights: str | None = None, max_views: int | None = None,
                    progress: ProgressFactory = null_progress) -> tuple[Evaluation, np.ndarray]:
    """Return the paper's metrics of an extracted object against its true object-alone views in a scene folder, and
    the renders ``[N, H, W, 3]`` on white.

    Args:
        cloud: the extracted object.
        data_dir: a scene made by ``roodi-toolkit make-scene``.
        object_id: the target's instance id.
        renderer: draws the object (default: the built-in CPU renderer).
        lpips_weights: local LPIPS weights (default: found by :func:`roodi_toolkit.io.lpips_weights.read_lpips`).
        max_views: evaluate on the first this many test views only.
        progress: progress factory.
    """
    truth = load_truth(Path(data_dir), object_id)
    lpips_model, status = None, "ok"
    try:
        lpips_model = read_lpips(lpips_weights)
    except LPIPSUnavailable as exc:
        status = f"unavailable: {exc}"
    return score_object(cloud, truth, lpips_model=lpips_model, lpips_status=status, renderer=renderer,
                        max_views=max_views, progress=progress)
