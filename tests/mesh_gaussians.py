"""Gaussian models of generated scenes made straight from their meshes (no training), for occlusion and fine-tuning
tests: surface points sampled uniformly by area, one small isotropic Gaussian each, in the part's base colour."""

from __future__ import annotations

import numpy as np

from roodi_toolkit.gaussians import GaussianCloud
from roodi_toolkit.synth.floaters import sample_mesh_surface


def mesh_cloud(objects, per_area: float = 60000.0, seed: int = 0, opacity: float = 0.95) -> GaussianCloud:
    """Return Gaussians on the surfaces of ``objects``: ``per_area`` per square metre, scale 0.6 x their spacing."""
    rng = np.random.default_rng(seed)
    pts, cols = [], []
    for o in objects:
        for p in o.parts:
            v, t = p.vertices, p.triangles
            area = 0.5 * np.linalg.norm(np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]), axis=1).sum()
            n = max(1, int(area * per_area))
            pts.append(sample_mesh_surface(v, t, n, rng)[0])
            cols.append(np.tile(p.material.color, (n, 1)))
    points = np.concatenate(pts)
    scale = 0.6 / per_area ** 0.5
    return GaussianCloud.from_activated(points, scales=np.full((len(points), 3), scale),
                                        opacities=np.full(len(points), opacity), rgb=np.concatenate(cols))


def nearby(scene, target, reach: float):
    """Return the objects other than ``target`` whose bounding boxes come within ``reach`` of its centre."""
    c = target.center
    out = []
    for o in scene.objects:
        if o.id == target.id:
            continue
        lo, hi = o.bounds
        if np.linalg.norm(np.maximum(lo - c, 0) + np.maximum(c - hi, 0)) <= reach:
            out.append(o)
    return out


def hidden_truth(scene, target, cameras):
    """Return ``[V, H, W]`` bool: the target is seen when rendered alone but not in the full scene (mesh ray casting)."""
    from roodi_toolkit.synth.tracer import render_views

    alone = render_views(scene, cameras, object_ids=[target.id], with_ground=False, supersample=1)
    full = render_views(scene, cameras, supersample=1)
    return np.stack([(a.ids == target.id) & (f.ids != target.id) for a, f in zip(alone, full)])
