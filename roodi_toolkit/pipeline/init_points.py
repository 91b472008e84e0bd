"""Initial Gaussian centres for scene training: from depth maps, sparse SfM points (topped up on their surfaces and on
the views' rays), or colours for random points by projection into the views.

Split from :mod:`roodi_toolkit.pipeline.train` (which calls them from ``Trainer``) to keep modules small.
"""

from __future__ import annotations

import warnings

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from ..errors import DatasetError
from ..gaussians import SH_C0
from ..io.dataset import Dataset


def rgb_to_sh0(rgb: Tensor) -> Tensor:
    """Return the DC SH coefficient whose colour is ``rgb``."""
    return (rgb - 0.5) / SH_C0


def projected_colors(points: np.ndarray, dataset: Dataset, views: list[int], max_views: int = 16) -> np.ndarray:
    """Return ``[P, 3]`` colours in [0, 1]: the median of the pixels each point projects to in the training views.

    Random initial points get the colour of what the cameras see along their rays instead of noise, which saves the
    first few hundred iterations of a CPU-sized run. Points seen by no view get grey.
    """
    chosen = views[:: max(1, len(views) // max_views)][:max_views]
    samples = np.full((len(chosen), len(points), 3), np.nan, dtype=np.float32)
    for j, v in enumerate(chosen):
        cam = dataset.cameras[v]
        uv, z = cam.project(points)
        px = np.floor(uv).astype(np.int64)
        ok = (z > cam.near) & (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
        if dataset.valid is not None:  # a pixel the dataset says to ignore (nerfstudio's masks) gives no colour
            ok[ok] = dataset.valid[v].numpy()[px[ok, 1], px[ok, 0]] > 0.5
        img = dataset.images[v].numpy()
        samples[j, ok] = img[px[ok, 1], px[ok, 0]]
    with np.errstate(all="ignore"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            colors = np.nanmedian(samples, axis=0)
    return np.where(np.isnan(colors), 0.5, colors).astype(np.float32)


def depth_points(dataset: Dataset, views: list[int], n: int, generator: torch.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Return ``n`` points [n, 3] and colours [n, 3] lifted from random pixels of the views' depth maps."""
    if dataset.depths is None:
        raise DatasetError("init 'depth' needs a dataset with depth maps (e.g. one made by make-scene)")
    pts, cols = [], []
    per_view = max(1, -(-n // len(views)))
    for v in views:
        depth = dataset.depths[v]
        ys, xs = torch.nonzero(depth > 0, as_tuple=True)
        if len(ys) == 0:
            continue
        pick = torch.randint(len(ys), (min(per_view, len(ys)),), generator=generator)
        ys, xs = ys[pick].numpy(), xs[pick].numpy()
        z = depth[ys, xs].numpy().astype(np.float64)
        pts.append(dataset.cameras[v].backproject(np.stack([ys, xs], axis=1), z))
        cols.append(dataset.images[v][ys, xs].numpy())
    if not pts:
        raise DatasetError("init 'depth': the depth maps are empty")
    points, colors = np.concatenate(pts), np.concatenate(cols)
    keep = torch.randperm(len(points), generator=generator)[:n].numpy()
    return points[keep], colors[keep]


def densified_points(points: np.ndarray, colors: np.ndarray | None, n: int,
                     generator: torch.Generator) -> tuple[np.ndarray, np.ndarray | None]:
    """Return sparse SfM points ``[P, 3]`` (and colours ``[P, 3]``) topped up to ``n`` points when ``P < n``.

    The added points are copies of randomly drawn SfM points, each moved by a normal offset with the spread of its
    own neighbourhood (the RMS distance to its 3 nearest SfM points) and given its colour: the cloud stays on the
    reconstructed surfaces and densest where SfM found structure, as the points themselves are.
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) >= n or len(pts) < 4:
        return points, colors
    dist, _ = cKDTree(pts).query(pts, k=4)
    spread = np.sqrt((dist[:, 1:] ** 2).mean(axis=1))
    pick = torch.randint(len(pts), (n - len(pts),), generator=generator).numpy()
    noise = torch.randn(n - len(pts), 3, generator=generator, dtype=torch.float64).numpy()
    extra = pts[pick] + noise * spread[pick, None]
    out_colors = None if colors is None else np.concatenate([np.asarray(colors), np.asarray(colors)[pick]])
    return np.concatenate([pts, extra]), out_colors


RAY_DEPTH_RANGE = (0.8, 4.0)
"""Ray-sampled initial points lie between these multiples of the 1st and 99th percentile depths of the SfM points
in their view (a capture's background is usually within a few times the distance of what SfM reconstructed)."""


def ray_points(dataset: Dataset, views: list[int], points: np.ndarray, n: int,
               generator: torch.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Return ``n`` points ``[n, 3]`` on random pixels' rays of the training views, coloured by their pixels.

    SfM reconstructs the textured object a capture is about and little of what lies behind it (the statue's 1,443
    points are all on the statue); MCMC grows new Gaussians only as copies of existing ones, so a background with no
    initial Gaussians stays a blur in every held-out view. Each point is a random pixel of a random training view at
    a depth drawn uniformly in inverse depth over :data:`RAY_DEPTH_RANGE` times the SfM points' depths in that view;
    the ones at a wrong depth are transparent after a few hundred steps, and MCMC relocates them onto the live ones.
    """
    g = generator
    pick = torch.randint(len(views), (n,), generator=g).numpy()
    out = np.zeros((n, 3))
    rgb = np.zeros((n, 3))
    H, W = dataset.height, dataset.width
    pts = np.asarray(points, dtype=np.float64)
    for k, v in enumerate(views):
        rows = np.flatnonzero(pick == k)
        if not len(rows):
            continue
        cam = dataset.cameras[v]
        z = (pts @ cam.world_to_camera[:3, :3].T + cam.world_to_camera[:3, 3])[:, 2]
        z = z[z > 0]
        lo, hi = (np.percentile(z, [1, 99]) if len(z) else (cam.near, 10 * cam.near)) * np.array(RAY_DEPTH_RANGE)
        u = torch.rand(len(rows), 3, generator=g, dtype=torch.float64).numpy()
        rc = np.minimum((u[:, :2] * [H, W]).astype(np.int64), [H - 1, W - 1])
        depth = 1.0 / (1.0 / lo + u[:, 2] * (1.0 / hi - 1.0 / lo))
        out[rows] = cam.backproject(rc, depth)
        rgb[rows] = dataset.images[v].numpy()[rc[:, 0], rc[:, 1]]
    return out, rgb


def sfm_initial_points(dataset: Dataset, views: list[int], n: int,
                       generator: torch.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Return a capture's SfM points ``[P, 3]`` and colours, topped up to ``n`` when fewer: half of the added
    points on the SfM surfaces (:func:`densified_points`), half on the views' rays (:func:`ray_points`)."""
    pts = np.asarray(dataset.points, dtype=np.float64)
    cols = np.asarray(dataset.point_colors if dataset.point_colors is not None else np.full((len(pts), 3), 128))
    cols = cols / 255.0 if cols.max() > 1.0 else cols
    if len(pts) >= n:
        return pts, cols
    on_surfaces = len(pts) + (n - len(pts)) // 2
    pts2, cols2 = densified_points(pts, cols, on_surfaces, generator)
    rays, ray_cols = ray_points(dataset, views, pts, n - len(pts2), generator)
    return np.concatenate([pts2, rays]), np.concatenate([cols2, ray_cols])
