"""The mesh ray tracer that renders the generated scenes: colour, alpha, instance ids and depth per view.

Open3D's ray casting (Embree) and a shading model of its own (Lambert + Blinn-Phong, hard shadows by shadow rays, one
mirror bounce for glossy materials). Ground truth therefore never passes through the toolkit's splat renderer.

Why ray casting rather than VTK rasterisation: instance ids and depth come exactly from the hit geometry of each
pixel-centre ray (no anti-aliasing can blend two ids), the same rays are used for every output, shadows and
reflections work without an OpenGL context, and the output is bit-identical from run to run. See docs/datasets.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..cameras import Camera
from ..errors import ConfigError
from ..progress import ProgressFactory, null_progress
from .objects import Material, Part, _o3d
from .world import Scene

__all__ = ["RenderResult", "render_views"]


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    return np.power(np.clip(c, 0.0, 1.0), 2.2)


def _linear_to_srgb(c: np.ndarray) -> np.ndarray:
    return np.power(np.clip(c, 0.0, 1.0), 1.0 / 2.2)


def _hash01(ix: np.ndarray, iy: np.ndarray, salt: int) -> np.ndarray:
    """Return deterministic pseudo-random values in [0, 1) for integer lattice points."""
    h = (ix.astype(np.int64).astype(np.uint64) * np.uint64(73856093)) ^ \
        (iy.astype(np.int64).astype(np.uint64) * np.uint64(19349663)) ^ np.uint64(salt * 83492791 + 12345)
    h ^= h >> np.uint64(13)
    h *= np.uint64(0x5BD1E995)
    h ^= h >> np.uint64(15)
    return (h & np.uint64(0xFFFF)).astype(np.float64) / 65536.0


def _value_noise(x: np.ndarray, y: np.ndarray, salt: int) -> np.ndarray:
    """Return smooth value noise in [0, 1) at real coordinates (bilinear with smoothstep between lattice values)."""
    ix, iy = np.floor(x), np.floor(y)
    fx, fy = x - ix, y - iy
    fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    a, b = _hash01(ix, iy, salt), _hash01(ix + 1, iy, salt)
    c, d = _hash01(ix, iy + 1, salt), _hash01(ix + 1, iy + 1, salt)
    return (a * (1 - fx) + b * fx) * (1 - fy) + (c * (1 - fx) + d * fx) * fy


def _pattern_weight(pattern: str, p: np.ndarray, s: float) -> np.ndarray:
    """Return per-point weights in [0, 1] of the second colour of a procedural pattern at world points ``p``."""
    x, y, z = p[:, 0] * s, p[:, 1] * s, p[:, 2] * s
    if pattern == "stripes":
        return (np.sin(2 * math.pi * (x + 0.7 * y + 1.3 * z)) > 0).astype(np.float64)
    if pattern == "checker":
        return ((np.floor(x) + np.floor(y) + np.floor(z)) % 2).astype(np.float64)
    if pattern == "noise":
        return 0.6 * _value_noise(x + z, y - z, 1) + 0.4 * _value_noise(2.1 * x, 2.1 * y + 1.7 * z, 2)
    if pattern == "planks":
        row = np.floor(y)
        grain = _value_noise(x * 6 + 13.7 * row, y * 0.5, 3)
        seam = ((y - row) < 0.04).astype(np.float64)
        return np.clip(0.55 * grain + 0.3 * _hash01(row, np.floor(x * 0.5 + row * 0.37), 4) + seam, 0, 1)
    if pattern == "grass":
        return np.clip(0.5 * _value_noise(x, y, 5) + 0.3 * _value_noise(4 * x, 4 * y, 6)
                       + 0.2 * _value_noise(16 * x, 16 * y, 7), 0, 1)
    if pattern == "tiles":
        fx, fy = x - np.floor(x), y - np.floor(y)
        grout = ((fx < 0.04) | (fy < 0.04)).astype(np.float64)
        return np.maximum(grout, 0.15 * ((np.floor(x) + np.floor(y)) % 2))
    if pattern == "gingham":
        return 0.5 * ((np.floor(2 * x) % 2) + (np.floor(2 * y) % 2))
    return np.zeros(len(p))


def _corner_normals(vertices: np.ndarray, triangles: np.ndarray, smooth: bool,
                    crease_deg: float = 50.0) -> np.ndarray:
    """Return ``[T, 3, 3]`` per-corner shading normals: faces meeting at less than ``crease_deg`` are smoothed."""
    tri = vertices[triangles]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length = 2 * area: area weighting
    unit = fn / np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-20)
    T = len(triangles)
    if not smooth or T == 0:
        return np.repeat(unit[:, None, :], 3, axis=1)
    corner_v = triangles.reshape(-1)  # corner c = 3 t + k
    corner_t = np.repeat(np.arange(T), 3)
    order = np.argsort(corner_v, kind="stable")
    counts = np.bincount(corner_v, minlength=len(vertices))
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    deg = counts[corner_v]
    pair_corner = np.repeat(np.arange(3 * T), deg)
    offs = np.arange(len(pair_corner)) - np.repeat(np.cumsum(deg) - deg, deg)
    pair_face = corner_t[order[starts[corner_v[pair_corner]] + offs]]
    keep = (unit[pair_face] * unit[corner_t[pair_corner]]).sum(axis=1) > math.cos(math.radians(crease_deg))
    acc = np.zeros((3 * T, 3))
    np.add.at(acc, pair_corner[keep], fn[pair_face[keep]])
    acc /= np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-20)
    return acc.reshape(T, 3, 3)


@dataclass
class RenderResult:
    """One rendered view.

    Attributes:
        rgb: ``[H, W, 3]`` float32 sRGB in [0, 1] (straight colour: where alpha is 0 it is the background).
        alpha: ``[H, W]`` float32 coverage of the rendered geometry (1 where the ground fills the pixel).
        ids: ``[H, W]`` uint8 instance id of the pixel-centre ray's hit (0 = ground or nothing).
        depth: ``[H, W]`` float32 z-depth of the pixel-centre ray's hit (0 = nothing hit).
    """

    rgb: np.ndarray
    alpha: np.ndarray
    ids: np.ndarray
    depth: np.ndarray


class _Tracer:
    """A ray-casting scene of some of the scene's parts, with everything shading needs per triangle."""

    CHUNK = 1 << 18

    def __init__(self, scene: Scene, object_ids: Sequence[int] | None, with_ground: bool) -> None:
        o3d = _o3d()
        self.scene = scene
        self.rc = o3d.t.geometry.RaycastingScene()
        parts: list[tuple[Part, int]] = []
        if with_ground:
            parts.append((scene.ground, 0))
        wanted = None if object_ids is None else set(int(i) for i in object_ids)
        for obj in scene.objects:
            if wanted is None or obj.id in wanted:
                parts.extend((p, obj.id) for p in obj.parts)
        if not parts:
            raise ConfigError("nothing to render: no objects selected and no ground")
        offsets, normals, mat_idx, obj_idx = [], [], [], []
        self.materials: list[Material] = []
        total = 0
        for k, (part, oid) in enumerate(parts):
            gid = self.rc.add_triangles(o3d.core.Tensor(part.vertices.astype(np.float32)),
                                        o3d.core.Tensor(part.triangles.astype(np.uint32)))
            if gid != k:
                raise RuntimeError("Open3D returned geometry ids out of order")
            offsets.append(total)
            total += len(part.triangles)
            normals.append(_corner_normals(part.vertices, part.triangles, part.smooth))
            self.materials.append(part.material)
            mat_idx.append(np.full(len(part.triangles), k, dtype=np.int64))
            obj_idx.append(np.full(len(part.triangles), oid, dtype=np.int64))
        self.offsets = np.array(offsets, dtype=np.int64)
        self.normals = np.concatenate(normals)
        self.tri_part = np.concatenate(mat_idx)
        self.tri_object = np.concatenate(obj_idx)
        m = self.materials
        self.m_color = _srgb_to_linear(np.array([x.color for x in m], dtype=np.float64))
        self.m_color2 = _srgb_to_linear(np.array([x.color2 for x in m], dtype=np.float64))
        self.m_diffuse = np.array([x.diffuse for x in m])
        self.m_specular = np.array([x.specular for x in m])
        self.m_shininess = np.array([x.shininess for x in m])
        self.m_reflect = np.array([x.reflectivity for x in m])
        self.m_metallic = np.array([x.metallic for x in m], dtype=np.float64)
        self.sky = [_srgb_to_linear(np.array(c)) for c in scene.sky]
        self.ambient = np.array(scene.ambient)

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return (t_hit [M] with inf for misses, global triangle [M] with -1 for misses, barycentrics [M, 2])."""
        o3d = _o3d()
        rays = np.concatenate([origins, dirs], axis=1).astype(np.float32)
        out = self.rc.cast_rays(o3d.core.Tensor(rays), nthreads=0)
        t = out["t_hit"].numpy().astype(np.float64)
        gid = out["geometry_ids"].numpy().astype(np.int64)
        pid = out["primitive_ids"].numpy().astype(np.int64)
        hit = np.isfinite(t)
        tri = np.full(len(t), -1, dtype=np.int64)
        tri[hit] = self.offsets[gid[hit]] + pid[hit]
        return t, tri, out["primitive_uvs"].numpy().astype(np.float64)

    def occluded(self, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """Return [M] whether anything lies between origin and origin + dir (t in (0, 1))."""
        o3d = _o3d()
        rays = np.concatenate([origins, dirs], axis=1).astype(np.float32)
        return self.rc.test_occlusions(o3d.core.Tensor(rays), tnear=0.0, tfar=1.0).numpy().astype(bool)

    def environment(self, dirs: np.ndarray) -> np.ndarray:
        """Return linear RGB seen along directions that hit nothing: a horizon-to-zenith gradient."""
        d = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        w = np.clip(d[:, 2], 0.0, 1.0)[:, None] ** 0.6
        return self.sky[0] * (1 - w) + self.sky[1] * w

    def shade(self, origins: np.ndarray, dirs: np.ndarray, bounce: int = 1) -> tuple[np.ndarray, np.ndarray,
                                                                                       np.ndarray]:
        """Return (linear RGB [M, 3], hit [M] bool, t [M]) of rays; misses get the environment."""
        t, tri, uv = self.cast(origins, dirs)
        hit = tri >= 0
        color = self.environment(dirs)
        if not hit.any():
            return color, hit, t
        d = dirs[hit]
        th, trh, uvh = t[hit], tri[hit], uv[hit]
        p = origins[hit] + th[:, None] * d
        cn = self.normals[trh]
        n = (1 - uvh[:, :1] - uvh[:, 1:]) * cn[:, 0] + uvh[:, :1] * cn[:, 1] + uvh[:, 1:] * cn[:, 2]
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)
        n_geo = cn.mean(axis=1)
        view = -d / np.linalg.norm(d, axis=1, keepdims=True)
        flip = (n * view).sum(axis=1) < 0  # two-sided surfaces (open shells, the ground seen from below)
        n[flip] = -n[flip]
        geo_flip = (n_geo * view).sum(axis=1) < 0
        n_geo[geo_flip] = -n_geo[geo_flip]
        n_geo /= np.maximum(np.linalg.norm(n_geo, axis=1, keepdims=True), 1e-20)
        part = self.tri_part[trh]
        albedo = self.m_color[part].copy()
        for k, mat in enumerate(self.materials):
            if mat.pattern == "plain":
                continue
            sel = np.nonzero(part == k)[0]
            if len(sel):
                w = _pattern_weight(mat.pattern, p[sel], mat.pattern_scale)[:, None]
                albedo[sel] = albedo[sel] * (1 - w) + self.m_color2[k] * w
        metallic = self.m_metallic[part][:, None]
        spec_tint = metallic * albedo + (1 - metallic)
        lit = self.ambient * albedo
        p_off = p + n_geo * 1e-4
        for light in self.scene.lights:
            if light.kind == "point":
                to_l = np.asarray(light.vector) - p
            else:
                to_l = np.broadcast_to(np.asarray(light.vector) * 50.0, p.shape)
            ldir = to_l / np.linalg.norm(to_l, axis=1, keepdims=True)
            ndl = np.clip((n * ldir).sum(axis=1), 0.0, None)
            vis = (ndl > 0).astype(np.float64)
            if light.shadows and (ndl > 0).any():
                idx = np.nonzero(ndl > 0)[0]
                vis[idx] = ~self.occluded(p_off[idx], to_l[idx])
            h = ldir + view
            h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-20)
            spec = np.clip((n * h).sum(axis=1), 0.0, None) ** self.m_shininess[part] * self.m_specular[part]
            lc = np.asarray(light.color)
            lit += vis[:, None] * lc * (self.m_diffuse[part][:, None] * albedo * ndl[:, None]
                                        + spec[:, None] * spec_tint)
        refl = self.m_reflect[part]
        if bounce > 0 and (refl > 0).any():
            idx = np.nonzero(refl > 0)[0]
            r = d[idx] - 2 * (d[idx] * n[idx]).sum(axis=1, keepdims=True) * n[idx]
            rc, _, _ = self.shade(p_off[idx], r, bounce - 1)
            lit[idx] = lit[idx] * (1 - refl[idx, None]) + refl[idx, None] * rc * spec_tint[idx]
        color[hit] = lit
        return color, hit, t

    def render(self, camera: Camera, supersample: int, background: np.ndarray | None) -> RenderResult:
        """Return one view; ``background`` (sRGB) replaces the environment where nothing is hit (alpha views)."""
        W, H = camera.width, camera.height
        R = camera.world_to_camera[:3, :3]
        origin = camera.center
        Kinv = np.linalg.inv(camera.K)

        # centre rays: ids and depth. Directions have camera z = 1, so t_hit is the z-depth.
        vv, uu = np.meshgrid(np.arange(H, dtype=np.float64) + 0.5, np.arange(W, dtype=np.float64) + 0.5,
                             indexing="ij")
        ids = np.zeros(H * W, dtype=np.uint8)
        depth = np.zeros(H * W, dtype=np.float32)
        pix = np.stack([uu.reshape(-1), vv.reshape(-1), np.ones(H * W)], axis=1)
        dirs_c = (pix @ Kinv.T) @ R  # camera -> world: R^T d, row-vector form
        for s in range(0, len(pix), self.CHUNK):
            sl = slice(s, s + self.CHUNK)
            t, tri, _ = self.cast(np.broadcast_to(origin, dirs_c[sl].shape), dirs_c[sl])
            hit = tri >= 0
            ids[sl][hit] = self.tri_object[tri[hit]].astype(np.uint8)
            depth[sl][hit] = t[hit].astype(np.float32)
        # colour and coverage: a regular ss x ss grid of rays per pixel (deterministic anti-aliasing)
        ss = int(supersample)
        sub = (np.arange(ss) + 0.5) / ss
        acc = np.zeros((H * W, 3))
        cov = np.zeros(H * W)
        bg = None if background is None else _srgb_to_linear(np.asarray(background, dtype=np.float64))
        for oy in sub:
            for ox in sub:
                p2 = np.stack([uu.reshape(-1) - 0.5 + ox, vv.reshape(-1) - 0.5 + oy, np.ones(H * W)], axis=1)
                dirs = (p2 @ Kinv.T) @ R
                for s in range(0, len(p2), self.CHUNK):
                    sl = slice(s, s + self.CHUNK)
                    col, hit, _ = self.shade(np.broadcast_to(origin, dirs[sl].shape).copy(), dirs[sl])
                    if bg is not None:
                        col[~hit] = 0.0
                    acc[sl] += col
                    cov[sl] += hit
        n_sub = ss * ss
        alpha = cov / n_sub
        if bg is not None:
            # straight (not premultiplied) colour of the covered part; the background where nothing was hit
            rgb = np.where(cov[:, None] > 0, acc / np.maximum(cov, 1)[:, None], bg)
        else:
            rgb = acc / n_sub
        rgb = _linear_to_srgb(rgb).astype(np.float32).reshape(H, W, 3)
        return RenderResult(rgb=rgb, alpha=alpha.astype(np.float32).reshape(H, W), ids=ids.reshape(H, W),
                            depth=depth.reshape(H, W))


def render_views(scene: Scene, cameras: Sequence[Camera], *, object_ids: Sequence[int] | None = None,
                 with_ground: bool = True, supersample: int = 2, background: Sequence[float] | None = None,
                 progress: ProgressFactory = null_progress) -> list[RenderResult]:
    """Return renders of the scene (or of some objects alone) from each camera.

    Args:
        scene: the scene.
        cameras: the views.
        object_ids: render only these objects (default all).
        with_ground: include the ground (id 0 in ``ids``).
        supersample: rays per pixel along each axis for colour and alpha.
        background: sRGB colour where nothing is hit (an object alone on white: ``(1, 1, 1)``); default the
            environment (sky or room).
        progress: progress factory.
    """
    tracer = _Tracer(scene, object_ids, with_ground)
    out = []
    with progress(total=len(cameras), desc="render") as bar:
        for cam in cameras:
            out.append(tracer.render(cam, supersample, None if background is None else np.asarray(background)))
            bar.update(1)
    return out
