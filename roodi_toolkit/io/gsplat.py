"""gsplat's trainer output (``examples/simple_trainer.py``), as :mod:`.other_models` describes it: checkpoints read
with ``torch.load(weights_only=True)``, its ``cfg.yml``, and the normalised world it trains in (computed here from the
COLMAP data and undone). Imports torch: the light readers of model folders (:mod:`.other_models`) do not."""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
import yaml

from ..cameras import invert_rigid
from ..errors import RoodiError
from ..gaussians import SH_C0, GaussianCloud, sigmoid
from ..similarity import Similarity
from .colmap import read_colmap_model
from .other_models import GSPLAT_CKPT, GSPLAT_CONFIG, _model_error


def find_gsplat_checkpoints(path: Path) -> tuple[Path, int, list[Path]] | None:
    """Return (result folder, step, the step's checkpoint files of every rank) for a gsplat result folder, its
    ``ckpts`` folder or one checkpoint file (the highest step when a folder is given); None when it is none of these."""
    path = Path(path)
    if path.is_file():
        m = GSPLAT_CKPT.fullmatch(path.name)
        if m is None:
            return None
        folder = path.parent
        step = int(m.group(1))
    else:
        folder = path / "ckpts" if (path / "ckpts").is_dir() else path
        steps = [int(m.group(1)) for p in folder.glob("ckpt_*_rank*.pt") if (m := GSPLAT_CKPT.fullmatch(p.name))]
        if not steps:
            return None
        step = max(steps)
    files = sorted((p for p in folder.glob(f"ckpt_{step}_rank*.pt") if GSPLAT_CKPT.fullmatch(p.name)),
                   key=lambda p: int(GSPLAT_CKPT.fullmatch(p.name).group(2)))  # type: ignore[union-attr]
    root = folder.parent if folder.name == "ckpts" else folder
    return root, step, files


def read_gsplat_checkpoint(files: Sequence[Path]) -> GaussianCloud:
    """Return the Gaussians of a gsplat checkpoint (the ranks' ``splats`` joined), read with
    ``torch.load(weights_only=True)``.

    Raises:
        ModelError: not a checkpoint that loads as plain tensors, no ``splats``, or tensors of the wrong shapes (the
            message names the file and the tensor).
    """
    parts = []
    for f in files:
        try:
            state = torch.load(f, map_location="cpu", weights_only=True)
        except (RuntimeError, pickle.UnpicklingError, EOFError, OSError, ValueError, TypeError, AttributeError,
                ImportError, KeyError, IndexError, MemoryError, UnicodeDecodeError, OverflowError) as exc:
            raise _model_error(f"{f}: not a gsplat checkpoint that loads as plain tensors "
                               f"({type(exc).__name__}: {' '.join(str(exc).split())[:160]})") from None
        splats = state.get("splats") if isinstance(state, dict) else None
        if not isinstance(splats, dict):
            raise _model_error(f"{f}: no 'splats' in the checkpoint (is it a gsplat simple_trainer checkpoint?)")
        parts.append(_splats_cloud(f, splats))
    return GaussianCloud.concatenate(parts) if len(parts) > 1 else parts[0]


def _splats_cloud(f: Path, splats: dict[str, Any]) -> GaussianCloud:
    def get(name: str, shape_tail: tuple[int, ...]) -> np.ndarray:
        t = splats.get(name)
        if not isinstance(t, torch.Tensor):
            raise _model_error(f"{f}: the checkpoint's splats have no '{name}' tensor")
        if t.ndim != 1 + len(shape_tail) or tuple(t.shape[1:]) != shape_tail:
            want = "[N" + "".join(f", {s}" for s in shape_tail) + "]"
            raise _model_error(f"{f}: splats '{name}' has shape {list(t.shape)}, expected {want}")
        if not t.is_floating_point():
            raise _model_error(f"{f}: splats '{name}' holds {t.dtype}, expected floating point")
        return t.detach().to(torch.float32).numpy()

    means = get("means", (3,))
    n = len(means)
    quats, scales, opac = get("quats", (4,)), get("scales", (3,)), get("opacities", ())
    if "sh0" in splats:
        sh0 = get("sh0", (1, 3))[:, 0]
        rest_t = splats.get("shN")
        rest = get("shN", tuple(rest_t.shape[1:])) if isinstance(rest_t, torch.Tensor) and rest_t.ndim == 3 \
            else np.zeros((n, 0, 3), np.float32)
    elif "colors" in splats:  # appearance optimisation: per-Gaussian logit colours (+ a network this reader skips)
        sh0 = ((sigmoid(get("colors", (3,))) - 0.5) / SH_C0).astype(np.float32)
        rest = np.zeros((n, 0, 3), np.float32)
    else:
        raise _model_error(f"{f}: the checkpoint's splats have neither 'sh0' nor 'colors'")
    for name, arr in (("quats", quats), ("scales", scales), ("opacities", opac), ("sh0", sh0), ("shN", rest)):
        if len(arr) != n:
            raise _model_error(f"{f}: splats '{name}' has {len(arr)} rows but 'means' has {n}")
    try:
        return GaussianCloud(means, quats, scales, opac, sh0, rest)
    except RoodiError as exc:
        raise _model_error(f"{f}: {exc}") from None


def read_gsplat_config(root: Path) -> dict[str, Any]:
    """Return a gsplat result folder's ``cfg.yml`` (its Python-tagged values as plain mappings), or {} if absent.

    Raises:
        ModelError: the file is there but is not YAML of a mapping.
    """
    path = Path(root) / GSPLAT_CONFIG
    if not path.is_file():
        return {}
    class _Loader(yaml.SafeLoader):
        """A safe loader that reads ``!!python/...`` tagged nodes as plain values instead of building objects."""

    def plain(loader: yaml.SafeLoader, suffix: str, node: yaml.Node) -> Any:
        if isinstance(node, yaml.MappingNode):
            return loader.construct_mapping(node, deep=True)
        if isinstance(node, yaml.SequenceNode):
            return loader.construct_sequence(node, deep=True)
        return loader.construct_scalar(node)

    _Loader.add_multi_constructor("tag:yaml.org,2002:python/", plain)
    _Loader.add_multi_constructor("!", plain)
    try:
        data = yaml.load(path.read_text(), Loader=_Loader)  # noqa: S506 - a SafeLoader subclass
    except (yaml.YAMLError, OSError, UnicodeDecodeError, RecursionError, ValueError, TypeError) as exc:
        raise _model_error(f"{path}: not a readable gsplat config ({' '.join(str(exc).split())[:160]})") from None
    if not isinstance(data, dict):
        raise _model_error(f"{path}: not a gsplat config (expected a mapping of settings)")
    return data


def gsplat_settings(cfg: dict[str, Any], record: Path) -> dict[str, Any]:
    """Return this toolkit's record keys (``downscale``, ``holdout_every``, ``sh_degree``) and ``normalize`` from a
    gsplat ``cfg.yml`` (gsplat's defaults for the keys it lacks: factor 1 here, every 8th held out, normalised).

    Raises:
        ModelError: a value of the wrong kind (named).
    """
    numbers = {}
    for key, default in (("data_factor", 1), ("test_every", 8)):
        value = cfg.get(key, default)
        try:
            numbers[key] = float(value)
        except (TypeError, ValueError, OverflowError):
            raise _model_error(f"{record}: '{key}' must be a number, got {value!r}") from None
        if not (0 <= numbers[key] < 1e6) or numbers[key] != int(numbers[key]):
            raise _model_error(f"{record}: '{key}' must be a whole number >= 0, got {value!r}")
    normalize = cfg.get("normalize_world_space", True)
    if not isinstance(normalize, bool):
        raise _model_error(f"{record}: 'normalize_world_space' must be true or false, got {normalize!r}")
    return {"downscale": max(1.0, numbers["data_factor"]), "holdout_every": int(numbers["test_every"]),
            "sh_degree": cfg.get("sh_degree"), "normalize": normalize}


def _similarity_from_cameras(c2w: np.ndarray) -> np.ndarray:
    """gsplat's ``similarity_from_cameras`` (centre ``focus``, median scaling): the ``[4, 4]`` normalising matrix."""
    t = c2w[:, :3, 3]
    R = c2w[:, :3, :3]
    world_up = (R @ np.array([0.0, -1.0, 0.0])).mean(axis=0)
    world_up /= np.linalg.norm(world_up)
    up_cam = np.array([0.0, -1.0, 0.0])
    c = float(up_cam @ world_up)
    cross = np.cross(world_up, up_cam)
    skew = np.array([[0.0, -cross[2], cross[1]], [cross[2], 0.0, -cross[0]], [-cross[1], cross[0], 0.0]])
    R_align = np.eye(3) + skew + skew @ skew / (1.0 + c) if c > -1 else np.diag([-1.0, 1.0, 1.0])
    R = R_align @ R
    fwds = R @ np.array([0.0, 0.0, 1.0])
    t = t @ R_align.T
    nearest = t + ((fwds * -t).sum(-1))[:, None] * fwds
    translate = -np.median(nearest, axis=0)
    transform = np.eye(4)
    transform[:3, 3] = translate
    transform[:3, :3] = R_align
    transform[:3, :] *= 1.0 / np.median(np.linalg.norm(t + translate, axis=-1))
    return transform


def _align_principal_axes(points: np.ndarray) -> np.ndarray:
    """gsplat's ``align_principal_axes``: the ``[4, 4]`` rigid matrix putting the points' median at the origin and
    their principal axes on x, y, z (z the smallest)."""
    centroid = np.median(points, axis=0)
    values, vectors = np.linalg.eigh(np.cov(points - centroid, rowvar=False))
    vectors = vectors[:, values.argsort()[::-1]]
    if np.linalg.det(vectors) < 0:
        vectors[:, 0] *= -1
    transform = np.eye(4)
    transform[:3, :3] = vectors.T
    transform[:3, 3] = -vectors.T @ centroid
    return transform


def gsplat_frames(sparse_dir: Path) -> list[Similarity]:
    """Return the similarities gsplat's COLMAP parser (``normalize=True``) applies to the data at ``sparse_dir``: one,
    or two when gsplat versions differ on this data (1.5.2 and later turn the world half a turn about x when the
    points' median height is above their mean; earlier versions do not). Each maps the data's frame to the
    checkpoint's.

    Raises:
        ModelError: the model has too few images or points to normalise.
    """
    model = read_colmap_model(sparse_dir)
    if len(model.images) < 2 or len(model.points.ids) < 4:
        raise _model_error(f"{sparse_dir}: gsplat's normalisation needs the COLMAP model's images and points, and "
                           f"it has {len(model.images)} images and {len(model.points.ids)} points")
    c2w = np.stack([invert_rigid(img.world_to_camera()) for img in model.images.values()])
    points = model.points.xyz[np.argsort(model.points.ids)].astype(np.float32)  # gsplat keeps them float32
    T1 = _similarity_from_cameras(c2w)
    p1 = points @ T1[:3, :3].T + T1[:3, 3]
    T2 = _align_principal_axes(p1)
    p2 = p1 @ T2[:3, :3].T + T2[:3, 3]
    base = T2 @ T1
    frames = [Similarity.from_matrix(base, f"{sparse_dir}: gsplat normalisation")]
    if np.median(p2[:, 2]) > np.mean(p2[:, 2]):
        flipped = np.diag([1.0, -1.0, -1.0, 1.0]) @ base
        frames.append(Similarity.from_matrix(flipped, f"{sparse_dir}: gsplat normalisation"))
    return frames


