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
from ..io.files import file_stems, write_image, write_json
from ..gaussians import GaussianCloud
from ..progress import ProgressFactory, null_progress
from ..params import GaussianParams
from .pictures import colour_map
from .renderer import Renderer, resolve_renderer
from .upright import cameras_up, model_cameras  # noqa: F401 - their home before upright.py
from .upright import resolve_up as resolve_upright

WHATS = ("rgb", "depth", "alpha")


INSIDE_DEPTH = 0.25
"""framing_orbit: a view is inside the content when the Gaussians nearer than this fraction of its distance to the
orbit's centre cover more than :data:`INSIDE_COVER` of its image."""
INSIDE_COVER = 0.3
INSIDE_STEPS = 6
"""framing_orbit: the radius is raised 1.5x at most this many times to get every view out of the content."""


def framing_orbit(cloud: GaussianCloud, n: int, *, elevation_deg: float = 20.0, radius: Optional[float] = None,
                  width: int = 512, height: int = 512, fov_x_deg: float = 50.0,
                  up: Sequence[float] = (0.0, 0.0, 1.0), azimuth0_deg: float = 0.0) -> list[Camera]:
    """Return ``n`` orbit cameras around the cloud's centre that frame it.

    The centre is the per-axis median of the means; without ``radius`` the camera distance makes a sphere holding 95%
    of the means (distance from the centre, 95th percentile) fill the narrower field of view, with 10% margin, raised
    (1.5x at a time, :data:`INSIDE_STEPS` times at most) while a view starts inside the content
    (:func:`views_inside`): a wall, a plinth or a floor beside the object, which the 95% sphere leaves out, covering
    the view.
    """
    if len(cloud) == 0:
        raise CloudError("cannot frame an empty cloud; give --radius and a centre, or render a non-empty file")
    finite = np.isfinite(cloud.means).all(axis=1)
    if not finite.any():
        raise CloudError("all Gaussian means are NaN/Inf; nothing to frame")
    means = cloud.means[finite].astype(np.float64)
    center = np.median(means, axis=0)
    fixed = radius is not None
    if radius is None:
        extent = float(np.percentile(np.linalg.norm(means - center, axis=1), 95))
        extent = max(extent, 1e-6)
        fov_x = math.radians(fov_x_deg)
        fov_min = min(fov_x, 2 * math.atan(math.tan(fov_x / 2) * height / width))
        radius = 1.1 * extent / math.sin(fov_min / 2)

    def circle(r: float) -> list[Camera]:
        return orbit_cameras(center, r, n, elevation_deg=elevation_deg, width=width, height=height,
                             fov_x_deg=fov_x_deg, up=up, near=max(1e-4, r * 1e-3), azimuth0_deg=azimuth0_deg)

    cams = circle(radius)
    if fixed:
        return cams
    sample = np.flatnonzero(finite)[::max(1, int(finite.sum()) // 200_000)]  # the check needs shares, not all
    near = cloud.select(sample)
    for _ in range(INSIDE_STEPS):
        if not views_inside(cams, near, center).any():
            break
        radius *= 1.5
        cams = circle(radius)
    return cams


def views_inside(cameras: Sequence[Camera], cloud: GaussianCloud, center: Sequence[float]) -> np.ndarray:
    """Return ``[V]`` whether each camera starts inside the content: the Gaussians of ``cloud`` nearer than
    :data:`INSIDE_DEPTH` times its distance to ``center`` cover more than :data:`INSIDE_COVER` of its image (each
    a disc of twice its largest scale, weighted by its opacity)."""
    out = np.zeros(len(cameras), dtype=bool)
    means = cloud.means.astype(np.float64)
    sigma = np.exp(cloud.log_scales.astype(np.float64).max(axis=1))  # [N]
    alpha = cloud.opacities.astype(np.float64)
    for i, cam in enumerate(cameras):
        near = INSIDE_DEPTH * float(np.linalg.norm(cam.center - np.asarray(center, dtype=np.float64)))
        px, z = cam.project(means)
        close = (z > cam.near) & (z < near)
        if not close.any():
            continue
        area = float(cam.width * cam.height)
        r = cam.K[0, 0] * 2.0 * sigma[close] / z[close]  # footprint radius in pixels
        u, v = px[close, 0], px[close, 1]
        seen = (u > -r) & (u < cam.width + r) & (v > -r) & (v < cam.height + r)
        cover = float((alpha[close][seen] * np.minimum(np.pi * r[seen] ** 2, area)).sum())
        out[i] = cover > INSIDE_COVER * area
    return out


def resolve_up(spec: str | None, ply: str | os.PathLike, means: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """Return the orbit's up direction ``[3]`` and where it came from (:func:`~roodi_toolkit.render.upright.resolve_up`:
    ``spec`` ``X,Y,Z`` or a dataset or camera file; ``auto`` or None: the training cameras, the format's convention,
    a ground plane among ``means``, z up).

    Raises:
        ConfigError: a malformed ``spec``.
    """
    up = resolve_upright(spec, ply, means)
    return up.vector, up.source


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
    out = np.zeros(depth.shape + (3,))
    if valid.any():
        lo, hi = float(depth[valid].min()), float(depth[valid].max())
        t = np.clip((depth - lo) / max(hi - lo, 1e-12), 0, 1)
        out = colour_map("turbo")(1.0 - t)[..., :3]
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
    names = file_stems([cam.name for cam in cameras])
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
