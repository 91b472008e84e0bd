"""Render a Gaussian cloud from many cameras to image files (what ``roodi-toolkit render`` does).

Depth is written as a 16-bit PNG (``value * depth_scale`` = expected depth in scene units along the camera's z axis;
0 = no surface, i.e. accumulated alpha below ``min_alpha``) plus a coloured preview; ``render.json`` beside the images
records the depth scale and every camera.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import torch

from ..cameras import Camera, orbit_cameras
from ..errors import CloudError, ConfigError
from ..io.files import write_image, write_json
from ..gaussians import GaussianCloud
from ..progress import ProgressFactory, null_progress
from ..params import GaussianParams
from .renderer import Renderer, resolve_renderer

WHATS = ("rgb", "depth", "alpha")


def framing_orbit(cloud: GaussianCloud, n: int, *, elevation_deg: float = 20.0, radius: Optional[float] = None,
                  width: int = 512, height: int = 512, fov_x_deg: float = 50.0,
                  up: Sequence[float] = (0.0, 0.0, 1.0)) -> list[Camera]:
    """Return ``n`` orbit cameras around the cloud's centre that frame it.

    The centre is the per-axis median of the means; without ``radius`` the camera distance makes a sphere holding 95%
    of the means (distance from the centre, 95th percentile) fill the narrower field of view, with 10% margin.
    """
    if len(cloud) == 0:
        raise CloudError("cannot frame an empty cloud; give --radius and a centre, or render a non-empty file")
    finite = np.isfinite(cloud.means).all(axis=1)
    if not finite.any():
        raise CloudError("all Gaussian means are NaN/Inf; nothing to frame")
    means = cloud.means[finite].astype(np.float64)
    center = np.median(means, axis=0)
    if radius is None:
        extent = float(np.percentile(np.linalg.norm(means - center, axis=1), 95))
        extent = max(extent, 1e-6)
        fov_x = math.radians(fov_x_deg)
        fov_min = min(fov_x, 2 * math.atan(math.tan(fov_x / 2) * height / width))
        radius = 1.1 * extent / math.sin(fov_min / 2)
    near = max(1e-4, radius * 1e-3)
    return orbit_cameras(center, radius, n, elevation_deg=elevation_deg, width=width, height=height,
                         fov_x_deg=fov_x_deg, up=up, near=near)


def cameras_up(cameras: Sequence[Camera]) -> np.ndarray:
    """Return the unit mean up direction ``[3]`` of cameras: the mean of minus each camera's image y axis.

    Photographers hold cameras upright, so this is the scene's up whatever the file's convention (z up, y down ...).

    Raises:
        ConfigError: no cameras, or their up directions cancel out.
    """
    if not cameras:
        raise ConfigError("no cameras to take the up direction from")
    # row 1 of the world-to-camera rotation is the camera's y axis (image down, OpenCV) in world coordinates
    mean = -np.mean([c.world_to_camera[1, :3] for c in cameras], axis=0)
    norm = float(np.linalg.norm(mean))
    if norm < 1e-3:
        raise ConfigError("the cameras' up directions cancel out (no common up); give --up X,Y,Z")
    return mean / norm


def model_cameras(ply: str | os.PathLike) -> list[Camera] | None:
    """Return the training cameras of the model a PLY belongs to, or None.

    A ``roodi-toolkit train`` output keeps its scene at ``MODEL/point_cloud/iteration_N/point_cloud.ply`` beside
    ``MODEL/cfg.json``, whose ``data_dir`` names the dataset; an Inria output keeps its cameras in ``cameras.json``;
    None when there is no such record or the dataset is gone.
    """
    from ..errors import RoodiError
    from ..io.dataset import load_cameras
    from ..io.files import read_json

    root = Path(ply).resolve().parent.parent.parent
    inria = (root / "cfg_args").is_file() and (root / "cameras.json").is_file()
    if inria and Path(ply).resolve().parent.parent.name == "point_cloud":  # an Inria model: its own cameras
        from ..io.other_models import load_inria_cameras

        try:
            return load_inria_cameras(root / "cameras.json")
        except RoodiError:
            return None
    record = root / "cfg.json"
    if Path(ply).resolve().parent.parent.name != "point_cloud" or not record.is_file():
        return None
    try:
        cfg = read_json(record, "training record")
        data = Path(str(cfg["data_dir"])) if isinstance(cfg, dict) and "data_dir" in cfg else None
        return load_cameras(data) if data is not None and data.exists() else None
    except (RoodiError, OSError):
        return None


def resolve_up(spec: str | None, ply: str | os.PathLike) -> tuple[np.ndarray, str]:
    """Return the orbit's up direction ``[3]`` and where it came from.

    ``spec``: ``"X,Y,Z"``; a dataset or camera file (its cameras' mean up, :func:`cameras_up`); ``"auto"``: the
    training cameras of the model ``ply`` belongs to, refused when there are none; or None: those cameras when there
    are, else z up.

    ``auto`` makes no guess from the cloud alone: the guesses tried (the direction of least spread of the means,
    pointed away from the denser side) were wrong on both real clouds at hand, the PlayCanvas biker (y down; guessed
    -x) and the 3DGS donut (z up; guessed -z).

    Raises:
        ConfigError: a malformed ``spec``, or ``auto`` without cameras.
    """
    if spec is not None and spec.strip().lower() not in ("", "auto") and not Path(spec).exists():
        try:
            vec = np.array([float(v) for v in spec.replace(" ", "").split(",") if v])
        except ValueError:
            raise ConfigError(f"--up must be X,Y,Z, auto, or a dataset or camera file; got {spec!r}") from None
        if vec.shape != (3,) or not np.isfinite(vec).all() or np.linalg.norm(vec) == 0:
            raise ConfigError(f"--up must be three finite numbers, not all zero; got {spec!r}")
        return vec / np.linalg.norm(vec), "given"
    if spec is not None and Path(spec).exists():
        from ..io.dataset import load_cameras

        return cameras_up(load_cameras(spec)), f"the mean up of the cameras in {spec}"
    cams = model_cameras(ply)
    if cams:
        return cameras_up(cams), "the mean up of the model's training cameras"
    if spec is not None:  # auto
        raise ConfigError(f"--up auto: {ply} is not the scene of a trained model whose dataset is still in place, so "
                          "no cameras tell its up; give --up X,Y,Z or --up DATASET")
    return np.array([0.0, 0.0, 1.0]), "z up (default)"


@dataclass(frozen=True)
class DepthEncoding:
    """How depth maps are stored: ``depth = png_value * scale``; ``png_value == 0`` means no surface."""

    scale: float
    min_alpha: float = 0.5

    def encode(self, depth: np.ndarray, alpha: np.ndarray) -> np.ndarray:
        """Return the uint16 image of a float depth map ``[H, W]`` given its accumulated alpha ``[H, W]``."""
        q = np.clip(np.round(depth / self.scale), 1, 65535)
        return np.where((alpha >= self.min_alpha) & np.isfinite(depth), q, 0).astype(np.uint16)

    def decode(self, png: np.ndarray) -> np.ndarray:
        """Return float depths (NaN where no surface) of an encoded image."""
        return np.where(png > 0, png.astype(np.float64) * self.scale, np.nan)


def depth_encoding_for(cloud: GaussianCloud, cameras: Sequence[Camera], min_alpha: float = 0.5) -> DepthEncoding:
    """Return an encoding whose range covers the farthest in-range Gaussian mean of every camera.

    Expected depth is a weighted mean of the Gaussians' camera-space z, so it never exceeds that bound.
    """
    far = 0.0
    for cam in cameras:
        _, z = cam.project(cloud.means)
        z = z[(z > cam.near) & (z < cam.far) & np.isfinite(z)]
        if z.size:
            far = max(far, float(z.max()))
    return DepthEncoding(scale=(far if far > 0 else 1.0) / 65535.0, min_alpha=min_alpha)


def colorize_depth(depth: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Return an RGB preview ``[H, W, 3]`` float of a depth map: turbo colormap, near = red end, black = no surface."""
    from matplotlib import colormaps

    out = np.zeros(depth.shape + (3,))
    if valid.any():
        lo, hi = float(depth[valid].min()), float(depth[valid].max())
        t = np.clip((depth - lo) / max(hi - lo, 1e-12), 0, 1)
        out = colormaps["turbo"](1.0 - t)[..., :3]
        out[~valid] = 0.0
    return out


def render_views(cloud: GaussianCloud, cameras: Sequence[Camera], out_dir: str | os.PathLike, *, what: str = "rgb",
                 renderer: Renderer | str | None = None, background: Sequence[float] = (0.0, 0.0, 0.0),
                 min_alpha: float = 0.5, progress: ProgressFactory = null_progress,
                 extra: dict | None = None) -> dict:
    """Render every camera and write the images into an existing folder; return the ``render.json`` record.

    Files per view (named after ``camera.name``, else ``view_###``): ``rgb``: ``NAME.png``; ``alpha``:
    ``NAME_alpha.png`` (8-bit); ``depth``: ``NAME_depth.png`` (16-bit, see :class:`DepthEncoding`) and
    ``NAME_depth_preview.png``. ``renderer``: an instance, a registered name, or None for the built-in one.
    ``extra``: more entries for ``render.json`` (e.g. how the views were framed).
    """
    if what not in WHATS:
        raise ConfigError(f"unknown render output {what!r}; choose one of {', '.join(WHATS)}")
    if not cameras:
        raise ConfigError("no cameras to render")
    out = Path(out_dir)
    renderer = resolve_renderer(renderer)
    params = GaussianParams.from_cloud(cloud)
    names = _view_names(cameras)
    encoding = depth_encoding_for(cloud, cameras, min_alpha) if what == "depth" else None
    record: dict = {"what": what, "renderer": type(renderer).__name__, "background": list(background),
                    "gaussians": len(cloud), **(extra or {}), "views": []}
    if encoding is not None:
        record["depth"] = {"scale": encoding.scale, "units": "scene units per PNG step (depth = value * scale)",
                           "invalid_value": 0, "min_alpha": encoding.min_alpha,
                           "definition": "expected (alpha-weighted, normalised) camera-space z"}
    with progress(total=len(cameras), desc=f"rendering {what}") as bar:
        for cam, name in zip(cameras, names):
            with torch.no_grad():
                res = renderer.render(params, cam, background=background)
            files = []
            if what == "rgb":
                files.append(write_image(res.rgb.cpu().numpy(), out / f"{name}.png"))
            elif what == "alpha":
                files.append(write_image(res.alpha[..., 0].cpu().numpy(), out / f"{name}_alpha.png"))
            else:
                depth = res.depth[..., 0].cpu().double().numpy()
                alpha = res.alpha[..., 0].cpu().double().numpy()
                png = encoding.encode(depth, alpha)
                files.append(write_image(png, out / f"{name}_depth.png"))
                files.append(write_image(colorize_depth(depth, png > 0), out / f"{name}_depth_preview.png"))
            record["views"].append({"name": name, "files": [f.name for f in files], "width": cam.width,
                                    "height": cam.height, "world_to_camera": cam.world_to_camera, "K": cam.K,
                                    "near": cam.near, "far": cam.far})
            bar.update(1)
    write_json(record, out / "render.json")
    return record


def _view_names(cameras: Sequence[Camera]) -> list[str]:
    names, seen = [], set()
    for i, cam in enumerate(cameras):
        base = "".join(c if c.isalnum() or c in "-_." else "_" for c in (cam.name or f"view_{i:03d}"))
        name = base if base not in seen else f"{base}_{i:03d}"
        seen.add(name)
        names.append(name)
    return names
