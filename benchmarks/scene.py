"""A scene-like synthetic Gaussian cloud for the benchmarks (stands in for a trained 3DGS scene).

Gaussians lie on surfaces: a ground disc of radius 3, four spheres and two boxes. Each is a flat disc tangent to its
surface, with tangential standard deviation ``0.6 * sqrt(area / N)`` times a log-normal factor (sigma 0.3) and normal
standard deviation a tenth of that, so the surfaces are covered about once, as after 3DGS training; opacities are
sigmoid(N(2, 1)) (median 0.88); colours are SH degree 3 with a random DC term and small higher coefficients.
"""

from __future__ import annotations

import math

import numpy as np
import torch


def _frame_quats(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Quaternions (w,x,y,z) rotating z onto each normal, with a random spin about it."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    a = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t1 = np.cross(n, a)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    phi = rng.uniform(0, 2 * math.pi, len(n))[:, None]
    u = np.cos(phi) * t1 + np.sin(phi) * t2
    v = np.cross(n, u)
    R = np.stack([u, v, n], axis=2)  # columns
    from scipy.spatial.transform import Rotation

    xyzw = Rotation.from_matrix(R).as_quat()
    return np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)


def scene_cloud(n: int, seed: int = 0, dtype=torch.float32) -> dict[str, torch.Tensor]:
    """Return raw tensors (means, quats_wxyz, log_scales, opacity_logits, sh [N, 16, 3]) of ``n`` surface Gaussians."""
    rng = np.random.default_rng(seed)
    spheres = [((-1.0, -0.8, 0.6), 0.6), ((1.1, -0.5, 0.5), 0.5), ((0.2, 1.0, 0.8), 0.8), ((-1.6, 1.2, 0.3), 0.3)]
    boxes = [((0.9, 1.6, 0.35), (0.7, 0.5, 0.7)), ((-0.2, -1.8, 0.25), (1.0, 0.4, 0.5))]
    areas = [math.pi * 9.0] + [4 * math.pi * r * r for _, r in spheres]
    areas += [2 * (s[0] * s[1] + s[1] * s[2] + s[0] * s[2]) for _, s in boxes]
    total = sum(areas)
    counts = rng.multinomial(n, np.array(areas) / total)
    pts, nrm = [], []
    # ground disc
    r = 3.0 * np.sqrt(rng.uniform(0, 1, counts[0]))
    th = rng.uniform(0, 2 * math.pi, counts[0])
    pts.append(np.stack([r * np.cos(th), r * np.sin(th), np.zeros_like(r)], 1))
    nrm.append(np.tile([0.0, 0.0, 1.0], (counts[0], 1)))
    for (c, rad), k in zip(spheres, counts[1:5]):
        d = rng.normal(size=(k, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        pts.append(np.asarray(c) + rad * d)
        nrm.append(d)
    for (c, size), k in zip(boxes, counts[5:]):
        face = rng.integers(0, 6, k)
        axis, sign = face // 2, np.where(face % 2 == 0, 1.0, -1.0)
        p = rng.uniform(-0.5, 0.5, (k, 3)) * np.asarray(size)
        p[np.arange(k), axis] = sign * 0.5 * np.asarray(size)[axis]
        nn = np.zeros((k, 3))
        nn[np.arange(k), axis] = sign
        pts.append(np.asarray(c) + p)
        nrm.append(nn)
    means = np.concatenate(pts)
    normals = np.concatenate(nrm)
    sigma_t = 0.6 * math.sqrt(total / n) * np.exp(rng.normal(0, 0.3, (n, 2)))
    scales = np.concatenate([sigma_t, 0.1 * sigma_t.mean(1, keepdims=True)], 1)
    sh = np.zeros((n, 16, 3))
    sh[:, 0] = rng.normal(0, 1.0, (n, 3))
    sh[:, 1:] = rng.normal(0, 0.05, (n, 15, 3))
    t = lambda a: torch.as_tensor(a, dtype=dtype)  # noqa: E731
    return {"means": t(means), "quats_wxyz": t(_frame_quats(normals, rng)), "log_scales": t(np.log(scales)),
            "opacity_logits": t(rng.normal(2.0, 1.0, n)), "sh": t(sh)}


def bench_camera(size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The renderer benchmarks' camera on :func:`scene_cloud`: at (3, -3, 2) looking at (0, 0, 0.3), a 50 degree
    horizontal field of view, ``size`` x ``size`` pixels. Returns (world-to-camera [4, 4], K [3, 3]), float32."""
    from roodi_toolkit.cameras import intrinsics_from_fov, look_at

    return (torch.tensor(look_at([3.0, -3.0, 2.0], [0.0, 0.0, 0.3]), dtype=torch.float32),
            torch.tensor(intrinsics_from_fov(math.radians(50.0), size, size), dtype=torch.float32))


def cloud_arrays(n: int) -> list[np.ndarray]:
    """:func:`scene_cloud` ``(n)`` as the numpy arrays the compiled renderer's functions take: means, quaternions
    (w, x, y, z), log-scales, opacity logits, SH coefficients [N, 16, 3]."""
    scene = scene_cloud(n)
    return [scene[k].numpy() for k in ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh")]


def bench_view(n: int, size: int):
    """:func:`cloud_arrays` ``(n)`` in :func:`bench_camera` ``(size)`` as the compiled renderer prepares it for the
    compositing: (arrays, view, projected, bins, channels: rgb + depth)."""
    from roodi_toolkit.render import fast

    arrays = cloud_arrays(n)
    view = fast.make_view(*bench_camera(size), size, size)
    proj = fast.project(*arrays, 16, view)
    return arrays, view, proj, fast.bin_gaussians(proj, view), fast.channels_of(proj, None)


def projection_grads(n: int) -> tuple[np.ndarray, ...]:
    """Random gradients of the projection's outputs for ``n`` Gaussians, as ``projection_kernels.project_backward``
    takes them (float32, C order): means2d [N, 2], conics [N, 3], opacities [N], rgb [N, 3], depths [N]."""
    grads = np.random.default_rng(0).standard_normal((n, 10)).astype(np.float32)
    return tuple(np.ascontiguousarray(grads[:, cols]) for cols in (slice(0, 2), slice(2, 5), 5, slice(6, 9), 9))
