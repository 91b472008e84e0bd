"""Planted-floater Gaussian clouds: an object's surface covered in small flat Gaussians, plus labelled floaters.

Used to measure pruning rules (``benchmarks/bench_floaters.py``, the tests), for the README demo and wherever a
cloud with known ground truth helps. Everything is generated from a seed; no file is read except PyVista's bundled
example meshes (shipped inside the pyvista wheel).

Labels: :data:`OBJECT` (on the surface), :data:`FAR` (isolated floaters away from the object) and :data:`NEAR`
(oversized, diffuse floaters whose centres sit on the surface: the case the paper's motivation names, invisible to
a centre-distance filter). The object is scaled to a bounding radius of 1; ``spacing`` is the mean distance between
neighbouring surface Gaussians, sqrt(area / n_object).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..errors import ConfigError
from ..gaussians import GaussianCloud

OBJECT, FAR, NEAR = 0, 1, 2
LABEL_NAMES = {OBJECT: "object", FAR: "far", NEAR: "near"}
SURFACES = ("sphere", "torus", "box", "ant")


@dataclass(frozen=True)
class FloaterMix:
    """How a planted-floater cloud is made.

    Attributes:
        surface: one of :data:`SURFACES`.
        n_object: surface Gaussians.
        far_fraction: far floaters as a fraction of n_object.
        near_fraction: near-surface oversized floaters as a fraction of n_object.
        near_size: range of the near floaters' scales, in surface spacings.
        far_size: range of the far floaters' scales, in surface spacings.
        far_gap: minimum distance of a far floater from the surface, in object radii.
        far_extent: far floaters lie within a cube of this half-size (object radii).
    """

    surface: str = "sphere"
    n_object: int = 20_000
    far_fraction: float = 0.01
    near_fraction: float = 0.01
    near_size: tuple[float, float] = (4.0, 12.0)
    far_size: tuple[float, float] = (0.5, 3.0)
    far_gap: float = 0.1
    far_extent: float = 2.5

    @property
    def name(self) -> str:
        return (f"{self.surface} n={self.n_object} far={self.far_fraction:.1%} near={self.near_fraction:.1%} "
                f"near_size={self.near_size[0]:g}-{self.near_size[1]:g}")


@dataclass(frozen=True)
class PlantedCloud:
    """A cloud with ground-truth labels.

    Attributes:
        cloud: the Gaussians, object and floaters shuffled together.
        labels: ``[N]`` int8, OBJECT, FAR or NEAR per Gaussian.
        spacing: mean distance between neighbouring surface Gaussians.
        mix: the recipe.
    """

    cloud: GaussianCloud
    labels: np.ndarray
    spacing: float
    mix: FloaterMix


def _unit_mesh(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Return vertices ``[V, 3]`` and triangles ``[F, 3]`` of a bundled mesh, centred, bounding radius 1."""
    from pyvista import examples  # lazy: pyvista takes 2 s to import; only the ant surface reads a mesh

    if name == "ant":
        mesh = examples.load_ant()
    else:  # pragma: no cover - guarded by the caller
        raise ConfigError(f"unknown mesh {name!r}")
    mesh = mesh.triangulate().clean()
    faces = np.asarray(mesh.faces).reshape(-1, 4)[:, 1:]
    v = np.asarray(mesh.points, dtype=np.float64)
    v = v - 0.5 * (v.min(axis=0) + v.max(axis=0))
    v /= np.linalg.norm(v, axis=1).max()
    return v, faces


def sample_mesh_surface(vertices: np.ndarray, faces: np.ndarray, n: int,
                        rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float]:
    """Return n points ``[n, 3]`` uniform by area on a triangle mesh, their unit normals ``[n, 3]`` and the area."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    cross = np.cross(b - a, c - a)
    areas = 0.5 * np.linalg.norm(cross, axis=1)
    keep = areas > 0
    a, b, c, cross, areas = a[keep], b[keep], c[keep], cross[keep], areas[keep]
    tri = rng.choice(len(areas), size=n, p=areas / areas.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    pts = a[tri] + u[:, None] * (b[tri] - a[tri]) + v[:, None] * (c[tri] - a[tri])
    normals = cross[tri] / np.linalg.norm(cross[tri], axis=1, keepdims=True)
    return pts, normals, float(areas.sum())


def sample_surface(surface: str, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float]:
    """Return n points uniform by area on a named surface (bounding radius 1), unit normals and the surface area."""
    if surface == "sphere":
        p = rng.normal(size=(n, 3))
        p /= np.linalg.norm(p, axis=1, keepdims=True)
        return p, p.copy(), 4 * np.pi
    if surface == "torus":
        big, small = 0.7, 0.3
        # rejection sampling of the tube angle so the density is uniform by area
        out = np.empty((0, 2))
        while len(out) < n:
            th = rng.uniform(0, 2 * np.pi, 2 * n)
            ok = rng.uniform(0, big + small, 2 * n) < big + small * np.cos(th)
            out = np.concatenate([out, np.stack([th[ok], rng.uniform(0, 2 * np.pi, ok.sum())], axis=1)])
        th, ph = out[:n, 0], out[:n, 1]
        normal = np.stack([np.cos(th) * np.cos(ph), np.cos(th) * np.sin(ph), np.sin(th)], axis=1)
        centre = np.stack([big * np.cos(ph), big * np.sin(ph), np.zeros(n)], axis=1)
        return centre + small * normal, normal, 4 * np.pi**2 * big * small
    if surface == "box":
        half = np.array([0.8, 0.5, 0.3])
        half = half / np.linalg.norm(half)
        areas = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]]) * 4
        face_areas = np.repeat(areas, 2)
        face = rng.choice(6, size=n, p=face_areas / face_areas.sum())
        axis, sign = face // 2, np.where(face % 2 == 0, 1.0, -1.0)
        p = rng.uniform(-1, 1, size=(n, 3)) * half
        p[np.arange(n), axis] = sign * half[axis]
        normal = np.zeros((n, 3))
        normal[np.arange(n), axis] = sign
        return p, normal, float(face_areas.sum())
    if surface == "ant":
        v, f = _unit_mesh("ant")
        return sample_mesh_surface(v, f, n, rng)
    raise ConfigError(f"unknown surface {surface!r}; choose one of {', '.join(SURFACES)}")


def _quat_from_z(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Return unit quaternions ``[n, 4]`` (w,x,y,z) whose rotation maps the z axis onto each normal, with a random
    spin about the normal."""
    n = np.asarray(normals, dtype=np.float64)
    z = np.array([0.0, 0.0, 1.0])
    dot = n @ z
    axis = np.cross(np.broadcast_to(z, n.shape), n)
    w = 1.0 + dot
    q = np.concatenate([w[:, None], axis], axis=1)
    anti = w < 1e-9  # normal = -z: rotate 180 degrees about x
    q[anti] = [0.0, 1.0, 0.0, 0.0]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    spin = rng.uniform(0, 2 * np.pi, len(n))
    s = np.stack([np.cos(spin / 2), np.zeros(len(n)), np.zeros(len(n)), np.sin(spin / 2)], axis=1)
    return _quat_mul(q, s)


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = a.T
    bw, bx, by, bz = b.T
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], axis=1)


def _random_quats(n: int, rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def surface_cloud(surface: str, n: int, rng: np.random.Generator) -> tuple[GaussianCloud, float, np.ndarray]:
    """Return n small flat Gaussians lying along a surface, the spacing, and the unit normals ``[n, 3]``.

    Tangential scales are the spacing times a log-normal factor (sigma 0.25); the normal scale is 5-15% of that;
    opacities 0.6-0.99; colours random. This is what a trained 3DGS surface looks like up to texture.
    """
    pts, normals, area = sample_surface(surface, n, rng)
    spacing = float(np.sqrt(area / n))
    tangential = spacing * np.exp(rng.normal(0.0, 0.25, size=(n, 2))) * 0.6
    thickness = tangential.min(axis=1) * rng.uniform(0.05, 0.15, n)
    scales = np.column_stack([tangential, thickness])
    cloud = GaussianCloud.from_activated(pts, scales=scales, opacities=rng.uniform(0.6, 0.99, n),
                                         rgb=rng.uniform(0.1, 0.9, (n, 3)), quats_wxyz=_quat_from_z(normals, rng))
    return cloud, spacing, normals


def planted_floater_cloud(mix: FloaterMix = FloaterMix(), seed: int = 0) -> PlantedCloud:
    """Return a surface cloud with far and near-surface oversized floaters planted, shuffled, with labels.

    Example:
        >>> planted = planted_floater_cloud(FloaterMix("sphere", n_object=2000, far_fraction=0.01,
        ...                                            near_fraction=0.02), seed=0)
        >>> len(planted.cloud), int((planted.labels == FAR).sum()), int((planted.labels == NEAR).sum())
        (2060, 20, 40)
    """
    if mix.surface not in SURFACES:
        raise ConfigError(f"unknown surface {mix.surface!r}; choose one of {', '.join(SURFACES)}")
    rng = np.random.default_rng(seed)
    obj, h, _ = surface_cloud(mix.surface, mix.n_object, rng)
    n_far = int(round(mix.far_fraction * mix.n_object))
    n_near = int(round(mix.near_fraction * mix.n_object))

    tree = cKDTree(obj.means)
    far_pts = np.empty((0, 3))
    while len(far_pts) < n_far:
        cand = rng.uniform(-mix.far_extent, mix.far_extent, size=(4 * n_far + 16, 3))
        # only "is anything closer than far_gap" matters: a bounded query answers it without a full search
        gap, _ = tree.query(cand, distance_upper_bound=mix.far_gap)
        far_pts = np.concatenate([far_pts, cand[np.isinf(gap)]])
    far_pts = far_pts[:n_far]
    far = GaussianCloud.from_activated(
        far_pts, scales=h * rng.uniform(*mix.far_size, (n_far, 1)) * np.exp(rng.normal(0, 0.3, (n_far, 3))),
        opacities=rng.uniform(0.05, 0.9, n_far), rgb=rng.uniform(0, 1, (n_far, 3)),
        quats_wxyz=_random_quats(n_far, rng))

    anchor = rng.integers(0, mix.n_object, n_near)
    base_pts = obj.means[anchor].astype(np.float64)
    # offset along the local normal (estimated from the anchor's flattest axis) by up to 2 spacings
    rot = obj.rotations()[anchor]
    near_pts = base_pts + rot[:, :, 2] * rng.uniform(-2 * h, 2 * h, (n_near, 1))
    near = GaussianCloud.from_activated(
        near_pts, scales=h * rng.uniform(*mix.near_size, (n_near, 1)) * np.exp(rng.normal(0, 0.2, (n_near, 3))),
        opacities=rng.uniform(0.02, 0.3, n_near), rgb=rng.uniform(0, 1, (n_near, 3)),
        quats_wxyz=_random_quats(n_near, rng))

    cloud = GaussianCloud.concatenate([obj, far, near])
    labels = np.concatenate([np.full(mix.n_object, OBJECT), np.full(n_far, FAR), np.full(n_near, NEAR)]).astype(np.int8)
    perm = rng.permutation(len(cloud))
    return PlantedCloud(cloud.select(perm), labels[perm], h, mix)


def removal_scores(labels: np.ndarray, keep: np.ndarray) -> dict[str, float]:
    """Return the fraction removed of each label: ``{"object": lost fraction, "far": ..., "near": ...}``."""
    out = {}
    for label, name in LABEL_NAMES.items():
        sel = labels == label
        out[name] = float((~keep[sel]).mean()) if sel.any() else float("nan")
    return out


STANDARD_MIXES: tuple[FloaterMix, ...] = tuple(
    FloaterMix(surface, n_object=n, far_fraction=far, near_fraction=near, near_size=size)
    for surface in SURFACES
    for n, far, near, size in (
        (20_000, 0.01, 0.01, (4.0, 12.0)),     # both kinds, 1% each
        (20_000, 0.002, 0.02, (4.0, 12.0)),    # a few far floaters, many near ones
        (20_000, 0.03, 0.005, (3.0, 8.0)),     # many far floaters, few smaller near ones
        (20_000, 0.01, 0.01, (2.0, 5.0)),      # hard: near floaters only 3-8x a surface Gaussian's size
        (60_000, 0.01, 0.01, (4.0, 12.0)),     # denser surface
        (20_000, 0.0, 0.02, (4.0, 12.0)),      # near floaters only
        (20_000, 0.02, 0.0, (4.0, 12.0)),      # far floaters only
    ))
"""The mixes the floater benchmark and the target test run (several seeds each)."""


SPECK, BLOB = 3, 4
"""Labels of :func:`plant_floaters` (real content is :data:`OBJECT`)."""
REAL_LABEL_NAMES = {OBJECT: "real", SPECK: "speck", BLOB: "blob"}


def scene_extent(cloud: GaussianCloud) -> tuple[np.ndarray, float, float]:
    """Return a real cloud's centre ``[3]`` (median of the centres), its 90% radius and its median Gaussian size.

    The size of a Gaussian is the geometric mean of its three scales (the radius of the sphere of equal volume),
    so flat and round Gaussians compare by how much space they fill.
    """
    means = cloud.means.astype(np.float64)
    centre = np.median(means, axis=0)
    r90 = float(np.quantile(np.linalg.norm(means - centre, axis=1), 0.9))
    size = float(np.exp(np.median(cloud.log_scales.astype(np.float64).mean(axis=1))))
    return centre, r90, size


def plant_floaters(cloud: GaussianCloud, seed: int = 0, *, n_specks: int = 300, n_blobs: int = 300,
                   speck_radius: tuple[float, float] = (1.4, 2.5), blob_size: tuple[float, float] = (10.0, 20.0)
                   ) -> tuple[GaussianCloud, np.ndarray]:
    """Return a real cloud with far specks and oversized near-surface blobs planted into it, and labels ``[N]``.

    The recipe of issue 19, scaled to the scene (:func:`scene_extent`):

    - specks: the log-scales of randomly drawn real Gaussians (so the size of the scene's own), centred
      ``speck_radius`` x the 90% radius from the scene's centre in a uniformly random direction;
    - blobs: round-ish Gaussians ``blob_size`` x the median Gaussian size (each axis jittered by exp(N(0, 0.2))),
      centred on a randomly drawn real Gaussian (the surface), random rotation;
    - both: random colour (SH DC, higher bands zero), opacity logit N(1, 1).

    The real Gaussians keep their order and come first; labels are :data:`OBJECT`, :data:`SPECK`, :data:`BLOB`.

    Example:
        >>> base = surface_cloud("sphere", 2000, np.random.default_rng(0))[0]
        >>> planted, labels = plant_floaters(base, seed=0, n_specks=10, n_blobs=20)
        >>> len(planted), int((labels == SPECK).sum()), int((labels == BLOB).sum())
        (2030, 10, 20)
    """
    rng = np.random.default_rng(seed)
    n = len(cloud)
    if n == 0:
        raise ConfigError("plant_floaters needs a non-empty cloud")
    finite = np.flatnonzero(~cloud.nonfinite_rows())
    centre, r90, size = scene_extent(cloud.select(finite))
    direction = rng.normal(size=(n_specks, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    speck_means = centre + direction * (r90 * rng.uniform(*speck_radius, (n_specks, 1)))
    speck_scales = np.exp(cloud.log_scales[rng.choice(finite, n_specks)].astype(np.float64))
    blob_means = cloud.means[rng.choice(finite, n_blobs)].astype(np.float64)
    blob_scales = size * rng.uniform(*blob_size, (n_blobs, 1)) * np.exp(rng.normal(0, 0.2, (n_blobs, 3)))

    def make(means: np.ndarray, scales: np.ndarray) -> GaussianCloud:
        m = len(means)
        part = GaussianCloud.from_activated(means, scales=scales, opacities=np.full(m, 0.5),
                                            rgb=rng.uniform(0, 1, (m, 3)), quats_wxyz=_random_quats(m, rng),
                                            sh_degree=cloud.sh_degree)
        logits = rng.normal(1.0, 1.0, m).astype(np.float32)
        extras = {name: np.zeros((m,) + v.shape[1:], dtype=v.dtype) for name, v in cloud.extras.items()}
        normals = None if cloud.normals is None else np.zeros((m, 3), dtype=cloud.normals.dtype)
        return part.with_fields(opacity_logits=logits, extras=extras, normals=normals)

    out = GaussianCloud.concatenate([cloud, make(speck_means, speck_scales), make(blob_means, blob_scales)])
    labels = np.concatenate([np.full(n, OBJECT), np.full(n_specks, SPECK), np.full(n_blobs, BLOB)]).astype(np.int8)
    return out, labels
