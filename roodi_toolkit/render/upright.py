"""Which way is up in a splat: what orbits, the floater picture and the inspect views stand on.

A 3DGS file stores no up axis, so it is taken, in this order, from:

1. what the user gives (``--up X,Y,Z`` or a dataset / camera file: its cameras' mean up);
2. the cameras the cloud was trained with: a model folder of this toolkit (``cfg.json`` naming its dataset) or of
   the Inria code (``cameras.json`` beside ``point_cloud/``); photographers hold cameras upright, so the mean of
   minus each camera's image-y axis is the scene's up;
3. the format's convention: PlayCanvas files (compressed PLY, SOG) and SPZ (as read, in the PLY axes) are y-down,
   the convention of the 3DGS PLYs they are made from (SuperSplat turns them over on import); nerfstudio's world,
   in which its exported PLYs lie, is z-up (its data parsers turn the mean camera up to +z);
4. the cloud itself: a ground plane under the content (:func:`ground_plane_up`), camera-free;
5. otherwise z up, said as a default the user may correct.

Every answer carries where it came from, which the commands print.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..errors import ConfigError, RoodiError
from ..io.files import read_json
from ..io.other_models import load_inria_cameras
from ..io.ply import ply_info
from ..io.splat import detect_format

Y_DOWN_FORMATS = {"compressed-ply": "PlayCanvas compressed PLY", "sog": "PlayCanvas SOG", "spz": "SPZ"}
"""Formats whose clouds are y-down by convention (:func:`format_up`)."""
GROUND_SAMPLE = 20_000
"""ground_plane_up: at most this many centres (an even, seeded sample) are searched."""
GROUND_MIN_SHARE = 0.1
"""A ground plane holds at least this share of the (robustly bounded) centres within its thickness."""
GROUND_MIN_SUPPORT = 0.97
"""... has at least this share of the content off the plane on one side (the content stands on it) ..."""
GROUND_MIN_FREE = 0.5
"""... and reaches past what stands on it: at least this share of the plane's cells (a 48 x 48 grid over the
cloud's extent in the plane) have nothing above them. A thin object's face (a logo's front, a guitar's body) has its
own back above all of it; a floor reaches out around what stands on it."""
GROUND_PLANES = 3
"""ground_plane_up: the largest planes tried, one after another."""


@dataclass(frozen=True)
class UpAxis:
    """An up direction and where it came from.

    Attributes:
        vector: ``[3]`` unit vector.
        source: what decided it, in words (printed by the commands, recorded in ``render.json``).
        kind: ``given``, ``cameras``, ``format``, ``ground`` or ``default``.
    """

    vector: np.ndarray = field(repr=False)
    source: str
    kind: str

    def describe(self) -> str:
        """Return e.g. ``"up 0, -1, 0: SPZ files are y-down by convention"``."""
        return f"up {', '.join(f'{v:.3g}' for v in self.vector + 0.0)}: {self.source}"


def cameras_up(cameras: Sequence[Any]) -> np.ndarray:
    """Return the unit mean up direction ``[3]`` of cameras: the mean of minus each camera's image y axis.

    Photographers hold cameras upright, so this is the scene's up whatever the file's convention (z up, y down ...).

    Raises:
        ConfigError: no cameras, or their up directions cancel out.
    """
    if not len(cameras):
        raise ConfigError("no cameras to take the up direction from")
    # row 1 of the world-to-camera rotation is the camera's y axis (image down, OpenCV) in world coordinates
    return _mean_up(-np.array([c.world_to_camera[1, :3] for c in cameras]))


def _mean_up(ups: np.ndarray) -> np.ndarray:
    mean = np.asarray(ups, dtype=np.float64).mean(axis=0)
    norm = float(np.linalg.norm(mean))
    if not norm >= 1e-3:
        raise ConfigError("the cameras' up directions cancel out (no common up); give --up X,Y,Z")
    return mean / norm


def model_cameras(ply: str | os.PathLike) -> list[Any] | None:
    """Return the training cameras of the model a PLY belongs to, or None.

    A ``roodi-toolkit train`` output keeps its scene at ``MODEL/point_cloud/iteration_N/point_cloud.ply`` beside
    ``MODEL/cfg.json``, whose ``data_dir`` names the dataset; an Inria output keeps its own cameras in
    ``MODEL/cameras.json`` beside ``cfg_args``; None when there is no such record or the dataset is gone.
    """
    root = _model_root(ply)
    if root is None:
        return None
    if (root / "cfg_args").is_file() and (root / "cameras.json").is_file():
        return _inria_cameras(root / "cameras.json")
    record = root / "cfg.json"
    if not record.is_file():
        return None
    try:
        cfg = read_json(record, "training record")
        data = Path(str(cfg["data_dir"])) if isinstance(cfg, dict) and "data_dir" in cfg else None
        return _dataset_cameras(data) if data is not None and data.exists() else None
    except (RoodiError, OSError):
        return None


def _dataset_cameras(data_dir: str | os.PathLike) -> list[Any]:
    """Return the cameras of the dataset in ``data_dir``."""
    from ..io.dataset import load_cameras  # lazy: the dataset readers import torch; a lone PLY never needs them

    return load_cameras(data_dir)


def _inria_cameras(path: Path) -> list[Any] | None:
    try:
        return load_inria_cameras(path)
    except RoodiError:  # not the file we know: no cameras then
        return None


def _model_root(ply: str | os.PathLike) -> Path | None:
    """Return ``MODEL`` for ``MODEL/point_cloud/iteration_N/*.ply``, else None."""
    p = Path(ply).resolve()
    if p.parent.parent.name != "point_cloud":
        return None
    return p.parent.parent.parent


def inria_cameras_up(ply: str | os.PathLike) -> tuple[np.ndarray, Path] | None:
    """Return the mean camera up ``[3]`` of an Inria model folder's ``cameras.json`` and its path, or None (read by
    :func:`roodi_toolkit.io.other_models.load_inria_cameras`, whose ``rotation`` is camera-to-world)."""
    root = _model_root(ply)
    path = root / "cameras.json" if root is not None else None
    cams = _inria_cameras(path) if path is not None and path.is_file() else None
    return (cameras_up(cams), path) if cams else None


def format_up(path: str | os.PathLike) -> UpAxis | None:
    """Return the up axis the file's format fixes by convention (:data:`Y_DOWN_FORMATS`, nerfstudio PLYs), or None."""
    try:
        fmt = detect_format(path)
    except RoodiError:
        return None
    if fmt in Y_DOWN_FORMATS:
        return UpAxis(np.array([0.0, -1.0, 0.0]), f"{Y_DOWN_FORMATS[fmt]} files are y-down by convention", "format")
    if fmt == "ply":
        try:
            variant = ply_info(path).variant
        except RoodiError:
            return None
        if variant == "nerfstudio":
            return UpAxis(np.array([0.0, 0.0, 1.0]), "a nerfstudio PLY: nerfstudio's world is z-up by convention",
                          "format")
    return None


def ground_plane_up(means: np.ndarray, seed: int = 0) -> tuple[np.ndarray, dict[str, float]] | None:
    """Return the up direction ``[3]`` of a ground plane under the cloud, with its figures, or None when none is found.

    The largest planes among the centres are found by RANSAC (Open3D's ``segment_plane`` on an even sample, inliers
    within 0.5% of the robust box's diagonal), one after another (:data:`GROUND_PLANES`). A plane is a ground when it
    holds :data:`GROUND_MIN_SHARE` of the centres, nearly all the rest lies on one side of it
    (:data:`GROUND_MIN_SUPPORT`) and it reaches out past what stands on it (:data:`GROUND_MIN_FREE`); up is its normal
    towards the content. A standing object without its floor (a statue cut at its feet), a flat object (a logo) or a
    room with its ceiling has none: the caller then says so.

    Args:
        means: ``[N, 3]`` centres.
        seed: the sample's and RANSAC's seed.

    Returns:
        ``(up [3], {"share", "support", "free"})`` or None.
    """
    pts = np.asarray(means, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < 100:
        return None
    rng = np.random.default_rng(seed)
    if len(pts) > GROUND_SAMPLE:
        pts = pts[np.sort(rng.choice(len(pts), GROUND_SAMPLE, replace=False))]
    low, high = np.quantile(pts, 0.005, axis=0), np.quantile(pts, 0.995, axis=0)
    pts = pts[np.all((pts >= low) & (pts <= high), axis=1)]
    diag = float(np.linalg.norm(high - low))
    if len(pts) < 100 or not diag > 0:
        return None
    import open3d as o3d  # lazy: 3 s to import; only the ground-plane guess (no cameras, no format) needs it

    o3d.utility.random.seed(seed)
    thickness = 0.005 * diag
    rest = pts
    for _ in range(GROUND_PLANES):
        if len(rest) < 100:
            break
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(rest))
        (a, b, c, d), _ = cloud.segment_plane(thickness, 3, 500)
        normal = np.array([a, b, c], dtype=np.float64)
        scale = float(np.linalg.norm(normal))
        if not scale > 0:
            break
        normal, d = normal / scale, d / scale
        figures = _ground_figures(pts, normal, d, thickness)
        if figures is not None:
            up, fig = figures
            if (fig["share"] >= GROUND_MIN_SHARE and fig["support"] >= GROUND_MIN_SUPPORT
                    and fig["free"] >= GROUND_MIN_FREE):
                return up, fig
        rest = rest[np.abs(rest @ normal + d) > 2.0 * thickness]
    return None


def _ground_figures(pts: np.ndarray, normal: np.ndarray, d: float,
                    thickness: float) -> tuple[np.ndarray, dict[str, float]] | None:
    """Return the up (the normal towards most content) and the plane's share, support and free figures."""
    h = pts @ normal + d  # [S] signed height above the plane
    on = np.abs(h) <= 2.0 * thickness
    above, below = h > 2.0 * thickness, h < -2.0 * thickness
    side = 1.0 if above.sum() >= below.sum() else -1.0
    h = h * side
    up = normal * side
    off = ~on
    if not off.any():  # everything is on the plane: a flat cloud has no up to tell
        return None
    tall = float(np.quantile(h[off], 0.99)) if (h[off] > 0).any() else 0.0
    # below: beyond a twentieth of the content's height (the ground's own roughness is not content under it)
    under = h < -max(2.0 * thickness, 0.05 * tall)
    over = h > 2.0 * thickness
    support = float(over.sum() / max(int(over.sum() + under.sum()), 1))
    # free: the plane's cells of a grid over the cloud's extent in the plane with nothing standing above them
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(up, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    uv = np.stack([pts @ e1, pts @ e2], axis=1)  # [S, 2]
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    g = 48
    cell = np.clip(np.floor((uv - lo) / np.maximum(hi - lo, 1e-30) * g), 0, g - 1).astype(np.int64)
    index = cell[:, 0] * g + cell[:, 1]
    plane_cells = np.zeros(g * g, dtype=bool)
    plane_cells[index[on]] = True
    covered = np.zeros(g * g, dtype=bool)
    covered[index[h > 4.0 * thickness]] = True
    free = float((plane_cells & ~covered).sum() / max(int(plane_cells.sum()), 1))
    return up, {"share": float(on.mean()), "support": support, "free": free}


def parse_up(spec: str) -> np.ndarray:
    """Return the unit vector of ``"X,Y,Z"``.

    Raises:
        ConfigError: not three finite numbers, or all zero.
    """
    try:
        vec = np.array([float(v) for v in spec.replace(" ", "").split(",") if v])
    except ValueError:
        raise ConfigError(f"--up must be X,Y,Z, auto, or a dataset or camera file; got {spec!r}") from None
    if vec.shape != (3,) or not np.isfinite(vec).all() or np.linalg.norm(vec) == 0:
        raise ConfigError(f"--up must be three finite numbers, not all zero; got {spec!r}")
    return vec / np.linalg.norm(vec)


def check_up(spec: str | None) -> None:
    """Refuse a malformed ``--up`` before any work (``X,Y,Z``, ``auto``, or an existing dataset or camera file).

    Raises:
        ConfigError: not three finite numbers, not all zero, and not an existing path.
    """
    text = "" if spec is None else spec.strip()
    if text and text.lower() != "auto" and not Path(text).exists():
        parse_up(text)


def resolve_up(spec: str | None, path: str | os.PathLike, means: np.ndarray | None = None) -> UpAxis:
    """Return the up axis of the cloud in ``path`` (module docstring for the order).

    Args:
        spec: ``"X,Y,Z"``; a dataset or camera file (its cameras' mean up); ``"auto"`` or None: the cameras, the
            format's convention, the ground plane, z up, in that order.
        path: the splat file (for the model folder it may sit in, and its format).
        means: ``[N, 3]`` the cloud's centres, for the ground plane (None: not looked for).

    Raises:
        ConfigError: a malformed ``spec``.
    """
    text = "" if spec is None else spec.strip()
    if text and text.lower() != "auto":
        if Path(text).exists():
            return UpAxis(cameras_up(_dataset_cameras(text)), f"the mean up of the cameras in {text}", "cameras")
        return UpAxis(parse_up(text), "given", "given")
    cams = model_cameras(path)
    if cams:
        return UpAxis(cameras_up(cams), "the mean up of the model's training cameras", "cameras")
    inria = inria_cameras_up(path)
    if inria is not None:
        return UpAxis(inria[0], f"the mean up of the training cameras in {inria[1]}", "cameras")
    known = format_up(path)
    if known is not None:
        return known
    if means is not None:
        found = ground_plane_up(means)
        if found is not None:
            up, fig = found
            return UpAxis(up, f"estimated from the cloud: a ground plane holding {fig['share']:.0%} of the Gaussians, "
                              "the rest above it", "ground")
        return UpAxis(np.array([0.0, 0.0, 1.0]), "z up by default: no cameras, no convention of the format and no "
                                                 "ground plane in the cloud tell it (give --up X,Y,Z)", "default")
    return UpAxis(np.array([0.0, 0.0, 1.0]), "z up by default (give --up X,Y,Z)", "default")
