"""The on-disk layout of a trained model folder and of a distillation folder, in one place; and the scenes other
tools trained, opened as models (:func:`open_model`).

A trained model folder (``roodi-toolkit train`` output, the layout the Inria 3DGS code and its viewers read)::

    point_cloud/iteration_N/point_cloud.ply   the scene (Inria PLY); the highest N is the model
    checkpoints/latest.pt                     the resumable training state
    cfg.json                                  the training run's record (data_dir, downscale, holdout_every, ...)

Scenes trained by other tools open as models too (:func:`open_model`; the formats in
:mod:`roodi_toolkit.io.other_models`): an Inria output folder (``cfg_args`` names the data; ``cameras.json`` is checked
against it), a gsplat result folder or checkpoint (its normalised world undone from the data), a nerfstudio export with
its ``dataparser_transforms.json``, or any splat file with the data folder given.

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
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from ..errors import ConfigError, InputWarning, ModelError, RoodiError  # ModelError: importable from here as before
from ..similarity import Similarity, transform_cloud
from . import gsplat, other_models as om
from .dataset import _find_colmap_sparse, detect_format, load_cameras
from .files import atomic_path, load_checkpoint, read_json, save_checkpoint, write_image, write_json
from .gsplat import read_gsplat_checkpoint
from .nerfstudio import _applied_transform as applied, _json_path, _read_meta
from .other_models import GSPLAT_CKPT, seen_fraction
from .records import MODEL_RECORD, model_record  # noqa: F401 (importable from here as before)
from .splat import read_cloud

if TYPE_CHECKING:
    from ..cameras import Camera
    from ..gaussians import GaussianCloud

MODEL_PLY = "point_cloud.ply"
CHECKPOINT = Path("checkpoints") / "latest.pt"

FEATURES_FILE = "features.npy"
CLASSIFIER_FILE = "object_classifier.pt"
DISTILL_RECORD = "distill.json"
MASKS_DIR = "object_masks"
DISTILL_PICTURE = "distill.png"


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


MODEL_KINDS = ("roodi", "inria", "gsplat", "nerfstudio", "splat")
"""What trained a model: this toolkit, the Inria code, gsplat's trainer, nerfstudio (an export with its data parser's
transform), or an unknown tool (a splat file given with its data folder)."""

SEEN_MIN = 0.3
"""A model from another tool must have at least this share of its Gaussians in view of the dataset's cameras, or it
lies in another frame (measured in tests: its own data's cameras see 0.9-1.0 of a trained scene)."""


@dataclass
class ModelFolder:
    """A trained model.

    Attributes:
        root: the folder (the file itself for a splat file given alone).
        ply_path: the file the scene is read from: ``point_cloud/iteration_N/point_cloud.ply`` with the highest N, a
            gsplat checkpoint, or the splat file given; distillations record its digest.
        iteration: that N (the checkpoint's step; 0 for a splat file).
        config: the record in this toolkit's keys (data_dir, downscale, holdout_every ...): ``cfg.json``, or what the
            other tool's own record says; empty if nothing says.
        kind: one of :data:`MODEL_KINDS`.
        to_data: what moves the file's Gaussians into the data's frame, or None when they are in it.
        frames: for a gsplat checkpoint whose normalisation differs between gsplat versions, every candidate (the
            photos pick one: :func:`roodi_toolkit.pipeline.model_frame.settle_model_frame`); else empty.
        notes: what was read and assumed, for the report.
    """

    root: Path
    ply_path: Path
    iteration: int
    config: dict[str, Any]
    kind: str = "roodi"
    to_data: "Similarity | None" = None
    frames: list = field(default_factory=list)
    notes: list = field(default_factory=list)

    def read_cloud(self) -> "GaussianCloud":
        """Return the scene in the data's frame."""
        return read_scene(self.ply_path, self.to_data)

    def record(self) -> dict[str, Any]:
        """Return what a distillation records to read this scene again (:meth:`Distillation.read_scene`)."""
        return {"model_kind": self.kind,
                "model_to_data": None if self.to_data is None else self.to_data.matrix().tolist()}


def read_scene(path: str | Path, to_data: "Similarity | None" = None) -> "GaussianCloud":
    """Return the Gaussians of a model's scene file (a splat file of any readable format, or a gsplat checkpoint),
    moved by ``to_data`` when given."""
    p = Path(path)
    cloud = read_gsplat_checkpoint([p]) if GSPLAT_CKPT.fullmatch(p.name) else read_cloud(p)
    if to_data is not None and not to_data.is_identity():
        cloud = transform_cloud(cloud, to_data)
    return cloud


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


def _quiet_cameras(data_dir: Path) -> "list[Camera]":
    """Return a dataset's cameras for checking a model against, without repeating the loader's warnings (the dataset
    itself is loaded and warns later)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InputWarning)
        return load_cameras(data_dir)


def _recorded_data(root: Path, value: Any, record: Path, data_dir: str | Path | None) -> Path:
    """Return the data folder: the one given, else the one the record names (relative names tried against the
    model folder's parent too)."""
    if data_dir is not None:
        return Path(data_dir)
    if not value:
        raise ModelError(f"{record} names no data folder; give DATA_DIR")
    p = Path(str(value))
    for cand in (p, root / p, root.parent / p):
        if cand.exists():
            return cand
    raise ModelError(f"the data folder {p} that {record} names is not here; give DATA_DIR")


def open_model(path: str | Path, data_dir: str | Path | None = None, *,
               dataparser_transforms: str | Path | None = None,
               data_cameras: "Sequence[Camera] | None" = None) -> ModelFolder:
    """Return the trained model at ``path``, whatever trained it, with its scene in the data's frame.

    ``path``: a roodi-toolkit train output folder (:func:`find_model`); an Inria output folder (``cfg_args``,
    ``cameras.json``) or a PLY inside one; a gsplat result folder, its ``ckpts`` folder or one ``ckpt_N_rank0.pt``; or
    any splat file (with ``data_dir``; with ``dataparser_transforms``, a nerfstudio export). ``data_dir`` defaults to
    the one the model's record names; ``data_cameras`` spares reading the cameras again.

    Raises:
        ModelError: nothing readable as a model, a record naming no data folder that is here, a model in another
            frame than the data (cameras that disagree, Gaussians the cameras do not see), a malformed file.
    """
    p = Path(path)
    if not p.exists():
        raise ModelError(f"{p}: model folder not found (give a roodi-toolkit train output folder, an Inria or gsplat "
                         "output folder, a gsplat checkpoint, or a splat file together with the data folder)")
    if dataparser_transforms is not None:
        if p.is_dir():
            raise ModelError(f"{p}: --dataparser-transforms goes with the exported splat file (ns-export's "
                             "splat.ply), not a folder")
        return _nerfstudio_model(p, data_dir, Path(dataparser_transforms), data_cameras)
    root = _enclosing_folder(p)
    if root is not None and (root / om.INRIA_ARGS).is_file() and not (root / MODEL_RECORD).is_file():
        return _inria_model(root, p if p.is_file() else None, data_dir, data_cameras)
    if root is not None:
        model = find_model(root)
        if p.is_file():
            found = {v.resolve(): k for k, v in model_iterations(root).items()}
            model = ModelFolder(root, p, found.get(p.resolve(), model.iteration), model.config)
        if data_dir is not None:
            model.config = {**model.config, "data_dir": str(data_dir)}
        return model
    ckpts = gsplat.find_gsplat_checkpoints(p)
    if ckpts is not None:
        return _gsplat_model(*ckpts, data_dir, data_cameras)
    if p.is_dir():
        raise ModelError(f"{p}: not a model folder: no point_cloud/iteration_N/point_cloud.ply (roodi-toolkit or "
                         "Inria) and no ckpts/ckpt_N_rank0.pt (gsplat)")
    if data_dir is None:
        raise ModelError(f"{p}: a splat file as the model needs the data folder it was trained on; give DATA_DIR")
    model = ModelFolder(p, p, 0, {"data_dir": str(data_dir)}, kind="splat",
                        notes=[f"{p.name}: a splat file, taken to be in {data_dir}'s frame"])
    _check_seen(model, data_cameras if data_cameras is not None else _quiet_cameras(Path(data_dir)), Path(data_dir))
    return model


def _enclosing_folder(p: Path) -> Path | None:
    """Return the roodi-toolkit or Inria model folder ``p`` is, or whose ``point_cloud/iteration_N/x.ply`` it is."""
    if p.is_dir():
        return p if model_iterations(p) or (p / MODEL_RECORD).is_file() and (p / "point_cloud").is_dir() else None
    folder = p.resolve().parent
    if re.fullmatch(r"iteration_\d+", folder.name) and folder.parent.name == "point_cloud":
        return folder.parent.parent
    return None


def _check_seen(model: ModelFolder, cameras: "Sequence[Camera]", data_dir: Path, hint: str = "") -> float:
    seen = seen_fraction(model.read_cloud(), cameras)
    if seen < SEEN_MIN:
        raise ModelError(f"{model.ply_path}: only {100 * seen:.0f}% of its Gaussians lie in view of the cameras of "
                         f"{data_dir}: the model and the data are in different frames{hint}")
    model.notes.append(f"{100 * seen:.0f}% of its Gaussians in view of the data's cameras")
    return seen


def _inria_model(root: Path, ply: Path | None, data_dir: str | Path | None,
                 data_cameras: "Sequence[Camera] | None") -> ModelFolder:
    args = om.read_cfg_args(root / om.INRIA_ARGS)
    data = _recorded_data(root, args.get("source_path"), root / om.INRIA_ARGS, data_dir)
    found = model_iterations(root)
    if not found and ply is None:
        raise ModelError(f"{root}: no point_cloud/iteration_N/point_cloud.ply in the Inria output folder")
    iteration = max(found) if ply is None else {v.resolve(): k for k, v in found.items()}.get(ply.resolve(), 0)
    cams = list(data_cameras) if data_cameras is not None else _quiet_cameras(data)
    notes = [f"Inria output folder, iteration {iteration}"]
    width = None
    if (root / om.INRIA_CAMERAS).is_file():
        n = om.check_inria_cameras(root / om.INRIA_CAMERAS, cams, data)
        notes.append(f"its cameras.json agrees with {n} of the dataset's cameras")
    else:
        notes.append("no cameras.json to check the frame against")
    if cams:
        width = max(c.width for c in cams)
    settings = om.inria_settings(root, args, width)
    config = {"data_dir": str(data), **settings}
    return ModelFolder(root, ply if ply is not None else found[iteration], iteration, config, kind="inria",
                       notes=notes)


def _gsplat_model(root: Path, step: int, files: list[Path], data_dir: str | Path | None,
                  data_cameras: "Sequence[Camera] | None") -> ModelFolder:
    if len(files) > 1:
        raise ModelError(f"{root}: step {step} is split over {len(files)} ranks' checkpoints ({files[0].name}, ...); "
                         "this reads a single-GPU run's ckpt_N_rank0.pt")
    cfg = gsplat.read_gsplat_config(root)
    record = root / om.GSPLAT_CONFIG
    data = _recorded_data(root, cfg.get("data_dir"), record, data_dir) if data_dir is not None or cfg else None
    if data is None:
        raise ModelError(f"{files[0]}: no {om.GSPLAT_CONFIG} beside its ckpts folder names the data; give DATA_DIR")
    settings = gsplat.gsplat_settings(cfg, record)
    normalize = settings.pop("normalize")
    config = {"data_dir": str(data), **settings}
    notes = [f"gsplat checkpoint, step {step}" + ("" if cfg else f" (no {om.GSPLAT_CONFIG}: gsplat's defaults "
                                                                  "taken, normalize_world_space on)")]
    model = ModelFolder(root, files[0], step, config, kind="gsplat", notes=notes)
    cloud = model.read_cloud()  # a broken checkpoint is named before anything else is looked at
    cams = list(data_cameras) if data_cameras is not None else _quiet_cameras(data)
    if normalize:
        sparse = _find_colmap_sparse(data) if data.is_dir() else None
        if sparse is None:
            raise ModelError(f"{files[0]}: gsplat normalised its world from a COLMAP capture, but {data} has no "
                             "sparse/0; give the COLMAP data folder it was trained on")
        frames = [f.inverse() for f in gsplat.gsplat_frames(sparse)]
        seen = [om.seen_fraction(transform_cloud(cloud, f), cams) for f in frames]
        keep = [f for f, s in zip(frames, seen) if s >= SEEN_MIN]
        if not keep:
            raise ModelError(f"{files[0]}: with gsplat's normalisation of {data} undone, only {100 * max(seen):.0f}% "
                             "of its Gaussians lie in view of the cameras: it was trained on other data (give that "
                             "DATA_DIR)")
        model.to_data = keep[0]
        model.frames = keep if len(keep) > 1 else []
        model.notes.append("gsplat's normalised world undone" + (" (two gsplat versions differ here: the photos "
                                                                   "decide)" if len(keep) > 1 else ""))
    else:
        _check_seen(model, cams, data)
    return model


def _nerfstudio_model(p: Path, data_dir: str | Path | None, transforms: Path,
                      data_cameras: "Sequence[Camera] | None") -> ModelFolder:
    if data_dir is None:
        raise ModelError(f"{p}: a nerfstudio export needs the data folder it was trained on; give DATA_DIR")
    data = Path(data_dir)
    to_model = om.read_dataparser_transforms(transforms)
    to_data = to_model.inverse()
    applied = _applied_transform(data)
    note = "nerfstudio export: its data parser's transform undone"
    if applied is not None:
        to_data = to_data.then(Similarity.from_matrix(applied, f"{data}: applied_transform"))
        note += ", then the capture's applied_transform applied"
    model = ModelFolder(p, p, 0, {"data_dir": str(data)}, kind="nerfstudio", to_data=to_data, notes=[note])
    _check_seen(model, data_cameras if data_cameras is not None else _quiet_cameras(data), data,
                " (is --dataparser-transforms the one of this training run?)")
    return model


def _applied_transform(data: Path) -> list | None:
    """Return the ``applied_transform`` of a nerfstudio capture (as its data parser takes it), None for other data."""
    if detect_format(data) != "nerfstudio":
        return None
    json_path = _json_path(data)
    return applied(json_path, _read_meta(json_path))


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

    def read_scene(self) -> "GaussianCloud":
        """Return the scene the features belong to, in the data's frame (a model from another tool is moved as it
        was when distilled)."""
        matrix = self.record.get("model_to_data")
        move = None
        if matrix is not None:
            try:
                move = Similarity.from_matrix(matrix, f"{self.root / DISTILL_RECORD}: model_to_data")
            except RoodiError as exc:
                raise ModelError(str(exc)) from None
        return read_scene(self.model_ply, move)


def write_distillation(out_dir: str | Path, *, model_ply: Path, features: np.ndarray,
                       classifier_state: dict[str, Any], record: dict[str, Any],
                       masks: dict[str, np.ndarray] | None = None, picture: np.ndarray | None = None) -> Path:
    """Write a distillation folder (every file atomically, the record last: it marks the folder complete); return
    the record's path. ``record`` gains the model file's path, size and SHA-256."""
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
