"""The on-disk layout of a trained model folder and of a distillation folder, in one place.

A trained model folder (``roodi-toolkit train`` output, the layout the Inria 3DGS code and its viewers read)::

    point_cloud/iteration_N/point_cloud.ply   the scene (Inria PLY); the highest N is the model
    checkpoints/latest.pt                     the resumable training state
    cfg.json                                  the training run's record (data_dir, downscale, holdout_every, ...)

A distillation folder (``roodi-toolkit distill`` output; never inside the model folder, which is an input)::

    features.npy            per-Gaussian object features [N, F] float32, in the model PLY's row order
    object_classifier.pt    the 1x1 classifier (a weights-only torch checkpoint)
    distill.json            the record: which model file (path, size, SHA-256), data folder, settings, scores
    object_masks/<view>.png the segmenter's masks
    distill.png             rendered classes beside the masks
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, InputError

MODEL_PLY = "point_cloud.ply"
CHECKPOINT = Path("checkpoints") / "latest.pt"
MODEL_RECORD = "cfg.json"

FEATURES_FILE = "features.npy"
CLASSIFIER_FILE = "object_classifier.pt"
DISTILL_RECORD = "distill.json"
MASKS_DIR = "object_masks"
DISTILL_PICTURE = "distill.png"


class ModelError(InputError):
    """A model or distillation folder is missing, malformed or does not belong to its model."""


def iteration_ply(root: str | Path, iteration: int) -> Path:
    """Return where iteration ``iteration``'s scene PLY lives in a model folder.

    Example:
        >>> iteration_ply("m", 30000).as_posix()
        'm/point_cloud/iteration_30000/point_cloud.ply'
    """
    return Path(root) / "point_cloud" / f"iteration_{int(iteration)}" / MODEL_PLY


def checkpoint_file(root: str | Path) -> Path:
    """Return the resumable training checkpoint's path in a model folder."""
    return Path(root) / CHECKPOINT


@dataclass
class ModelFolder:
    """A trained model folder.

    Attributes:
        root: the folder.
        ply_path: ``point_cloud/iteration_N/point_cloud.ply`` with the highest N.
        iteration: that N.
        config: ``cfg.json`` (data_dir, downscale, holdout_every ...), empty if absent.
    """

    root: Path
    ply_path: Path
    iteration: int
    config: dict[str, Any]


def model_iterations(root: str | Path) -> dict[int, Path]:
    """Return the scene PLYs of a model folder by iteration (empty if it has none)."""
    found: dict[int, Path] = {}
    pc = Path(root) / "point_cloud"
    if pc.is_dir():
        for d in pc.iterdir():
            m = re.fullmatch(r"iteration_(\d+)", d.name)
            if m and (d / MODEL_PLY).is_file():
                found[int(m.group(1))] = d / MODEL_PLY
    return found


def find_model(model_dir: str | Path) -> ModelFolder:
    """Return the trained model in ``model_dir`` (the highest ``point_cloud/iteration_N``).

    Raises:
        ModelError: not a folder, or no ``point_cloud/iteration_N/point_cloud.ply`` in it.
    """
    from .files import read_json

    root = Path(model_dir)
    if not root.is_dir():
        raise ModelError(f"{root}: model folder not found (give a roodi-toolkit train output folder)")
    found = model_iterations(root)
    if not found:
        raise ModelError(f"{root}: no point_cloud/iteration_N/point_cloud.ply; is it a roodi-toolkit train output "
                         "folder?")
    iteration = max(found)
    cfg_path = root / MODEL_RECORD
    config = read_json(cfg_path, "training record") if cfg_path.is_file() else {}
    if not isinstance(config, dict):
        raise ModelError(f"{cfg_path}: not a training record (a JSON object is expected)")
    return ModelFolder(root, found[iteration], iteration, config)


def file_digest(path: str | Path, chunk: int = 1 << 22) -> str:
    """Return the SHA-256 of a file (hex): how a distillation recognises the exact model file it was made from."""
    h = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            while block := f.read(chunk):
                h.update(block)
    except OSError as exc:
        raise ModelError(f"{path}: cannot read ({exc.strerror})") from None
    return h.hexdigest()


# ---------------------------------------------------------------------------------------------------- distillations


@dataclass
class Distillation:
    """A distillation folder as read from disk.

    Attributes:
        root: the folder.
        record: ``distill.json``.
        features: per-Gaussian object features. [N, F]
        classifier_state: the classifier checkpoint (a dict of tensors and labels).
        model_ply: the scene PLY the features belong to.
    """

    root: Path
    record: dict[str, Any]
    features: np.ndarray
    classifier_state: dict[str, Any]
    model_ply: Path

    @property
    def masks_dir(self) -> Path:
        return self.root / MASKS_DIR


def write_distillation(out_dir: str | Path, *, model_ply: Path, features: np.ndarray,
                       classifier_state: dict[str, Any], record: dict[str, Any],
                       masks: dict[str, np.ndarray] | None = None, picture: np.ndarray | None = None) -> Path:
    """Write a distillation folder (every file atomically, the record last: it marks the folder complete); return
    the record's path. ``record`` gains the model file's path, size and SHA-256."""
    from .files import save_checkpoint, write_image, write_json

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    features = np.ascontiguousarray(features, dtype=np.float32)
    if features.ndim != 2:
        raise ConfigError(f"features must be [N, F], got {list(features.shape)}")
    _save_npy(features, out / FEATURES_FILE)
    save_checkpoint(classifier_state, out / CLASSIFIER_FILE)
    if masks:
        (out / MASKS_DIR).mkdir(exist_ok=True)
        for name, mask in masks.items():
            write_image(mask, out / MASKS_DIR / f"{name}.png")
    if picture is not None:
        write_image(picture, out / DISTILL_PICTURE)
    full = {**record, "model_ply": str(Path(model_ply).resolve()), "model_ply_bytes": Path(model_ply).stat().st_size,
            "model_ply_sha256": file_digest(model_ply), "num_gaussians": int(features.shape[0]),
            "feature_dim": int(features.shape[1]), "features": FEATURES_FILE, "classifier": CLASSIFIER_FILE}
    return write_json(full, out / DISTILL_RECORD)


def read_distillation(distill_dir: str | Path) -> Distillation:
    """Return a distillation folder's record, features and classifier state, checked against its model file.

    Raises:
        ModelError: not a distillation folder, a missing or changed model file, or features of the wrong size.
    """
    from .files import load_checkpoint, read_json

    root = Path(distill_dir)
    rec_path = root / DISTILL_RECORD
    if not rec_path.is_file():
        hint = (" (it is a model folder: distil it into a folder of its own with roodi-toolkit distill MODEL_DIR "
                "DATA_DIR OUT_DIR)" if model_iterations(root) else "")
        raise ModelError(f"{root}: not a distillation folder, no {DISTILL_RECORD}{hint}")
    record = read_json(rec_path, "distillation record")
    if not isinstance(record, dict) or "model_ply" not in record:
        raise ModelError(f"{rec_path}: not a roodi-toolkit distillation record")
    model_ply = Path(record["model_ply"])
    if not model_ply.is_file():
        raise ModelError(f"{rec_path}: its model file {model_ply} is gone; distil the model again")
    if record.get("model_ply_sha256") and file_digest(model_ply) != record["model_ply_sha256"]:
        raise ModelError(f"{model_ply} changed since it was distilled into {root}; run roodi-toolkit distill again")
    features = _load_npy(root / FEATURES_FILE)
    if features.ndim != 2 or features.shape[0] != int(record.get("num_gaussians", features.shape[0])):
        raise ModelError(f"{root / FEATURES_FILE}: features of shape {list(features.shape)} do not match the record "
                         f"({record.get('num_gaussians')} Gaussians)")
    state = load_checkpoint(root / CLASSIFIER_FILE)
    if not isinstance(state, dict):
        raise ModelError(f"{root / CLASSIFIER_FILE}: not a roodi-toolkit object classifier")
    return Distillation(root, record, features, state, model_ply)


def _save_npy(array: np.ndarray, path: Path) -> None:
    from .files import atomic_path

    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.save(f, array, allow_pickle=False)


def _load_npy(path: Path) -> np.ndarray:
    try:
        return np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise ModelError(f"{path}: missing; the distillation folder is incomplete, run roodi-toolkit distill "
                         "again") from None
    except (OSError, ValueError) as exc:
        raise ModelError(f"{path}: not a feature array ({exc})") from None
