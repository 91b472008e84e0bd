"""Scenes trained by other tools, read as they wrote them: the Inria 3DGS code's output folder, gsplat's trainer
checkpoints (read by :mod:`.gsplat`, which imports torch), and a nerfstudio (splatfacto) export with its
``dataparser_transforms.json``.

**Inria** (``graphdeco-inria/gaussian-splatting``, ``train.py -s DATA -m MODEL``)::

    point_cloud/iteration_N/point_cloud.ply   the scene, in the data's own frame (COLMAP's or Blender's)
    cfg_args                                  Python's repr of its arguments: Namespace(source_path=..., images=...,
                                              resolution=..., eval=..., white_background=..., sh_degree=...)
    cameras.json                              its cameras: img_name, width, height, position (centre), rotation
                                              (camera-to-world, OpenCV axes), fx, fy (at the photos' size)

``cfg_args`` is parsed as literals (never run). ``cameras.json`` is compared with the dataset's cameras of the same
names: a model and a dataset in different frames (another reconstruction of the same photos) are refused, naming the
camera that disagrees most. Resolution: ``images_N`` and ``resolution`` 1/2/4/8 give the downscale; -1 reduces photos
wider than 1600 px to 1600 (as the Inria loader does); ``eval`` holds out every 8th image.

**gsplat** (``examples/simple_trainer.py``): ``RESULT/ckpts/ckpt_STEP_rankR.pt`` holds ``{"step", "splats": {means,
quats (w,x,y,z), scales (log), opacities (logit), sh0 [N,1,3], shN [N,K,3]}}`` (or ``features``/``colors`` with
appearance optimisation), read with ``torch.load(weights_only=True)``: no pickled code runs. ``RESULT/cfg.yml``
(its config, with Python tags that are skipped) names ``data_dir``, ``data_factor``, ``test_every`` and
``normalize_world_space``. With normalisation (gsplat's default) the Gaussians lie in a normalised world computed from
the COLMAP data (``examples/datasets/normalize.py``: ``similarity_from_cameras`` then ``align_principal_axes``, and
since gsplat 1.5.2 half a turn about x when the points' median height is above their mean); the same transform is
computed here from the data and undone. Where the versions differ the photos decide (:func:`gsplat_frames`).

**nerfstudio** (``ns-export gaussian-splat``): ``splat.ply`` lies in the data parser's frame;
``dataparser_transforms.json`` holds ``{"transform": [3, 4], "scale": s}`` with ``export = s * (T @ original)``,
``original`` being the world before ``ns-process-data``'s ``applied_transform``. Undone, and ``applied_transform``
re-applied when the data is a ``transforms.json`` capture.
"""

from __future__ import annotations

import ast
import json
import math
import re
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..cameras import Camera, invert_rigid
from ..errors import ModelError, RoodiError
from ..gaussians import GaussianCloud
from ..similarity import Similarity
from .files import read_json

INRIA_ARGS = "cfg_args"
INRIA_CAMERAS = "cameras.json"
GSPLAT_CONFIG = "cfg.yml"
GSPLAT_CKPT = re.compile(r"ckpt_(\d+)_rank(\d+)\.pt")
INRIA_AUTO_WIDTH = 1600
"""The Inria loader's ``resolution -1``: photos wider than this are reduced to it."""

CAMERA_POSITION_TOLERANCE = 1e-3
"""Largest camera-centre difference between ``cameras.json`` and the dataset, as a fraction of the cameras' spread
(both are read from the same reconstruction: they agree to about 1e-12)."""
CAMERA_ANGLE_TOLERANCE = 0.1
"""Largest camera-rotation difference in degrees between ``cameras.json`` and the dataset."""


def _model_error(msg: str) -> Exception:
    return ModelError(msg)


# ------------------------------------------------------------------------------------------------------------ Inria
def read_cfg_args(path: Path) -> dict[str, Any]:
    """Return the arguments an Inria run recorded in ``cfg_args`` (``Namespace(key=literal, ...)``), parsed as
    literals only.

    Raises:
        ModelError: unreadable, or not a ``Namespace(...)`` of literal values (the message names the argument).
    """
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise _model_error(f"{path}: cannot read ({exc})") from None
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except (SyntaxError, ValueError, RecursionError, MemoryError):
        raise _model_error(f"{path}: not an Inria cfg_args file (expected Namespace(source_path=..., ...))") from None
    call = tree.body
    if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Name) and call.func.id == "Namespace"
            and not call.args):
        raise _model_error(f"{path}: not an Inria cfg_args file (expected Namespace(source_path=..., ...))")
    out: dict[str, Any] = {}
    for kw in call.keywords:
        if kw.arg is None:
            raise _model_error(f"{path}: not an Inria cfg_args file (a **argument)")
        try:
            out[kw.arg] = ast.literal_eval(kw.value)
        except (ValueError, TypeError, SyntaxError, RecursionError, MemoryError):
            raise _model_error(f"{path}: argument {kw.arg!r} is not a literal value") from None
    return out


def is_inria_cameras_file(path: Path) -> bool:
    """Whether ``path`` is an Inria ``cameras.json`` (a JSON list whose entries have ``img_name`` and ``position``)."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096).lstrip()
        if not head.startswith(b"["):
            return False
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError, UnicodeDecodeError, RecursionError):
        return False
    return isinstance(data, list) and bool(data) and isinstance(data[0], dict) and "img_name" in data[0] \
        and "position" in data[0]


def _number(path: Path, i: int, key: str, value: Any, positive: bool = False) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError, OverflowError):
        raise _model_error(f"{path}: camera {i}: '{key}' must be a number, got {value!r}") from None
    if not math.isfinite(out) or (positive and out <= 0):
        raise _model_error(f"{path}: camera {i}: '{key}' must be a finite{' positive' if positive else ''} number, "
                           f"got {value!r}")
    return out


def load_inria_cameras(path: Path) -> list[Camera]:
    """Return the cameras of an Inria ``cameras.json`` (centred principal points, at the photos' own size).

    Raises:
        ModelError: not a list of cameras, or a camera with a missing or malformed field (named).
    """
    try:
        data = read_json(path, "Inria cameras file")
    except RoodiError as exc:
        raise _model_error(str(exc)) from None
    if not isinstance(data, list) or not data:
        raise _model_error(f"{path}: expected a JSON list of cameras")
    cams = []
    for i, entry in enumerate(data):
        if not isinstance(entry, dict):
            raise _model_error(f"{path}: camera {i} is not a JSON object")
        for key in ("img_name", "width", "height", "position", "rotation", "fx", "fy"):
            if key not in entry:
                raise _model_error(f"{path}: camera {i} has no '{key}'")
        w = _number(path, i, "width", entry["width"], True)
        h = _number(path, i, "height", entry["height"], True)
        fx = _number(path, i, "fx", entry["fx"], True)
        fy = _number(path, i, "fy", entry["fy"], True)
        try:
            pos = np.asarray(entry["position"], dtype=np.float64)
            rot = np.asarray(entry["rotation"], dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise _model_error(f"{path}: camera {i}: 'position' and 'rotation' must be numbers") from None
        if pos.shape != (3,) or rot.shape != (3, 3) or not (np.isfinite(pos).all() and np.isfinite(rot).all()):
            raise _model_error(f"{path}: camera {i}: 'position' must be 3 numbers and 'rotation' 3x3")
        c2w = np.eye(4)
        c2w[:3, :3], c2w[:3, 3] = rot, pos
        K = np.array([[fx, 0.0, w / 2.0], [0.0, fy, h / 2.0], [0.0, 0.0, 1.0]])
        try:
            cams.append(Camera(invert_rigid(c2w), K, int(round(w)), int(round(h)), name=str(entry["img_name"])))
        except RoodiError as exc:
            raise _model_error(f"{path}: camera {i} ({entry['img_name']}): {exc}") from None
    return cams


def inria_settings(root: Path, args: dict[str, Any], photo_width: int | None) -> dict[str, Any]:
    """Return this toolkit's record keys (``downscale``, ``holdout_every``, ``background``, ``sh_degree``) for an
    Inria run's arguments; ``photo_width``: the photos' width (for ``resolution`` -1 and a target width)."""
    where = root / INRIA_ARGS
    images = str(args.get("images", "images") or "images")
    m = re.fullmatch(r"images_(\d+)", images)
    folder_factor = float(m.group(1)) if m else 1.0
    try:
        res = float(args.get("resolution", -1))
    except (TypeError, ValueError):
        raise _model_error(f"{where}: 'resolution' must be a number, got {args.get('resolution')!r}") from None
    if res in (1.0, 2.0, 4.0, 8.0):
        factor = res
    elif photo_width is None or res == -1 and photo_width / folder_factor <= INRIA_AUTO_WIDTH:
        factor = 1.0
    elif res == -1:
        factor = photo_width / folder_factor / INRIA_AUTO_WIDTH
    elif res > 0:
        factor = photo_width / folder_factor / res  # a target width
    else:
        raise _model_error(f"{where}: 'resolution' {res:g} is not one the Inria code takes (1, 2, 4, 8, -1 or a "
                           "width)")
    return {"downscale": max(1.0, folder_factor * factor), "holdout_every": 8 if args.get("eval") else 0,
            "background": [1.0, 1.0, 1.0] if args.get("white_background") else [0.0, 0.0, 0.0],
            "sh_degree": args.get("sh_degree"), "images": images}


def check_inria_cameras(cameras_path: Path, data_cameras: Sequence[Camera], data_dir: Path) -> int:
    """Check that an Inria model's ``cameras.json`` agrees with the dataset's cameras of the same names; return how
    many were compared.

    Raises:
        ModelError: no camera names match, or one is elsewhere, turned or of another focal length: the model was
            trained on another reconstruction (another frame) than this dataset's.
    """
    theirs = load_inria_cameras(cameras_path)
    ours = {c.name: c for c in data_cameras}
    for c in data_cameras:  # the Inria loader names an image by its name up to the first dot
        ours.setdefault(c.name.split(".")[0], c)
    pairs = [(t, ours[t.name]) for t in theirs if t.name in ours]
    if not pairs:
        raise _model_error(f"{cameras_path}: none of its {len(theirs)} cameras ({theirs[0].name}, ...) names an image "
                           f"of the dataset {data_dir}; give the data folder the model was trained on")
    centres = np.stack([c.center for c in data_cameras])
    spread = float(np.median(np.linalg.norm(centres - centres.mean(axis=0), axis=1))) or 1.0
    worst = (0.0, 0.0, 0.0, "")
    for t, o in pairs:
        dist = float(np.linalg.norm(t.center - o.center)) / spread
        cos = (np.trace(t.world_to_camera[:3, :3] @ o.world_to_camera[:3, :3].T) - 1.0) / 2.0
        angle = math.degrees(math.acos(max(-1.0, min(1.0, cos))))
        focal = abs(t.K[0, 0] / t.width - o.K[0, 0] / o.width) / (o.K[0, 0] / o.width)
        if (dist, angle, focal) > worst[:3]:
            worst = (dist, angle, focal, t.name)
    dist, angle, focal, name = worst
    if dist > CAMERA_POSITION_TOLERANCE or angle > CAMERA_ANGLE_TOLERANCE:
        raise _model_error(f"{cameras_path}: camera {name} is {dist:.3g} of the cameras' spread from the dataset's "
                           f"and turned {angle:.3g} degrees from it: the model and {data_dir} are in different frames "
                           "(trained on another reconstruction of the photos?); give the data folder it was trained "
                           "on")
    if focal > 0.01:
        raise _model_error(f"{cameras_path}: camera {name}'s focal length differs from the dataset's by "
                           f"{100 * focal:.3g}%: the model was trained on other intrinsics than {data_dir}'s")
    return len(pairs)


# ------------------------------------------------------------------------------------------------------- nerfstudio
def read_dataparser_transforms(path: Path) -> Similarity:
    """Return the similarity nerfstudio's ``dataparser_transforms.json`` describes: data (before ``ns-process-data``'s
    ``applied_transform``) to the trained model's frame, ``export = scale * (T @ p)``.

    Raises:
        ModelError: not that file (the message names the missing or malformed field).
    """
    try:
        data = read_json(path, "nerfstudio dataparser transforms file")
    except RoodiError as exc:
        raise _model_error(str(exc)) from None
    if not isinstance(data, dict) or "transform" not in data or "scale" not in data:
        raise _model_error(f"{path}: expected nerfstudio's dataparser_transforms.json with 'transform' (3x4) and "
                           "'scale'")
    try:
        scale = float(data["scale"])
    except (TypeError, ValueError, OverflowError):
        raise _model_error(f"{path}: 'scale' must be a number, got {data['scale']!r}") from None
    if not (math.isfinite(scale) and scale > 0):
        raise _model_error(f"{path}: 'scale' must be a finite number > 0, got {data['scale']!r}")
    try:
        T = Similarity.from_matrix(data["transform"], f"{path}: 'transform'")
    except RoodiError as exc:
        raise _model_error(str(exc)) from None
    return T.then(Similarity(scale=scale))


# ---------------------------------------------------------------------------------------------- frame agreement
def seen_fraction(cloud: GaussianCloud, cameras: Sequence[Camera], samples: int = 20000, max_cameras: int = 64,
                  seed: int = 0) -> float:
    """Return the fraction of the cloud's Gaussians (a seeded sample of their means) that at least one of the cameras
    sees (in front of it, inside its image): near 1 for a scene in the cameras' frame, low for one in another."""
    means = cloud.means[np.isfinite(cloud.means).all(axis=1)].astype(np.float64)
    if not len(means) or not cameras:
        return 0.0
    rng = np.random.default_rng(seed)
    if len(means) > samples:
        means = means[rng.choice(len(means), samples, replace=False)]
    cams = list(cameras)
    if len(cams) > max_cameras:
        cams = [cams[int(i)] for i in np.linspace(0, len(cams) - 1, max_cameras).round()]
    seen = np.zeros(len(means), dtype=bool)
    for cam in cams:
        uv, z = cam.project(means)
        with np.errstate(invalid="ignore"):
            seen |= (z > cam.near) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & \
                (uv[:, 1] < cam.height)
    return float(seen.mean())
