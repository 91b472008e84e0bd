"""The objects of the generated benchmark scenes: materials, mesh parts, object builders and scene presets.

Objects are compositions of Open3D primitives (procedural furniture, tableware, toys, plants) and the meshes PyVista
bundles with its examples; every builder draws its sizes and materials from a seeded generator, so a preset and a seed
give the same objects bit for bit. :mod:`roodi_toolkit.synth.scene` places them, :mod:`roodi_toolkit.synth.tracer`
renders them.

Example:
    >>> sorted(PRESETS)
    ['bedroom', 'kitchen', 'livingroom', 'picnic']
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import open3d as o3d
from pyvista import examples


__all__ = ["PRESETS", "BUILDERS", "MAX_OBJECTS", "Material", "Part", "SceneObject", "Light", "Preset", "box", "cylinder",
           "sphere", "cone", "torus"]

MAX_OBJECTS = 20  # the paper: 5 to 20 objects per scene; ids fit an 8-bit mask


# ----------------------------------------------------------------------------------------------------- data model


@dataclass(frozen=True)
class Material:
    """Surface appearance for the shading model.

    Attributes:
        color: base colour, sRGB in [0, 1].
        color2: second colour of the pattern, sRGB in [0, 1].
        pattern: ``plain``, ``stripes``, ``checker``, ``noise``, ``planks``, ``grass``, ``tiles`` or ``gingham``.
        pattern_scale: pattern frequency in cycles per metre.
        diffuse: Lambert weight.
        specular: Blinn-Phong weight.
        shininess: Blinn-Phong exponent.
        reflectivity: fraction of the colour taken from one mirror bounce (0 = matte).
        metallic: tint highlights and reflections by the base colour (metals) rather than white (dielectrics).
    """

    color: tuple[float, float, float]
    color2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    pattern: str = "plain"
    pattern_scale: float = 10.0
    diffuse: float = 0.9
    specular: float = 0.1
    shininess: float = 16.0
    reflectivity: float = 0.0
    metallic: bool = False


@dataclass
class Part:
    """A triangle mesh with one material.

    Attributes:
        vertices: ``[V, 3]`` float64 positions (object-local before placement, world after).
        triangles: ``[T, 3]`` int64 vertex indices.
        material: its material.
        smooth: interpolate normals across edges sharper than nothing (curved primitives) or keep creases.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    material: Material
    smooth: bool = True


@dataclass
class SceneObject:
    """One object of a scene.

    Attributes:
        id: instance id in the masks, 1..N.
        name: unique readable name, e.g. ``"mug_3"``.
        kind: what it is (``"mug"``, ``"table"``, ``"pyvista_airplane"`` ...).
        parts: its meshes in world coordinates.
        is_target: whether it is an extraction target (rendered alone for scoring).
        source: ``"procedural"`` or ``"pyvista:<example>"``.
    """

    id: int
    name: str
    kind: str
    parts: list[Part] = field(repr=False)
    is_target: bool = False
    source: str = "procedural"

    @property
    def vertices(self) -> np.ndarray:
        """``[V, 3]`` all vertices of all parts."""
        return np.concatenate([p.vertices for p in self.parts])

    @property
    def bounds(self) -> np.ndarray:
        """``[2, 3]`` axis-aligned box (min row, max row)."""
        v = self.vertices
        return np.stack([v.min(axis=0), v.max(axis=0)])

    @property
    def center(self) -> np.ndarray:
        """``[3]`` centre of the bounding box."""
        return self.bounds.mean(axis=0)


@dataclass(frozen=True)
class Light:
    """A light of the shading model.

    Attributes:
        kind: ``"point"`` (at ``position``) or ``"directional"`` (light travels along ``-direction``).
        vector: position of a point light, or the unit direction towards a directional light.
        color: linear RGB intensity.
        shadows: whether it casts shadows.
    """

    kind: str
    vector: tuple[float, float, float]
    color: tuple[float, float, float]
    shadows: bool = True


@dataclass(frozen=True)
class Preset:
    """What distinguishes the four scene types of the paper.

    Attributes:
        name: preset name.
        n_objects: inclusive range of the object count.
        catalog: object kind -> sampling weight.
        at_most_one: kinds that appear at most once.
        layout_radius: objects are placed in a disc of this radius (smaller = more overlap in the images).
        gap: minimal clearance between footprints in metres.
        glossy_fraction: share of objects with glossy, reflective materials.
        on_table_probability: chance that a small object stands on a table when one has room.
        outdoor: sky and sun instead of a room.
    """

    name: str
    n_objects: tuple[int, int]
    catalog: dict[str, float]
    at_most_one: tuple[str, ...]
    layout_radius: float
    gap: float
    glossy_fraction: float
    on_table_probability: float
    outdoor: bool
    description: str = ""


PRESETS: dict[str, Preset] = {
    "bedroom": Preset(
        "bedroom", (8, 13),
        {"bed": 1.0, "table": 0.8, "chair": 1.0, "lamp": 1.0, "books": 1.5, "teddy": 1.5, "ball": 1.0, "plant": 1.0,
         "mug": 0.7, "vase": 0.7, "crate": 1.0, "cushion": 1.0, "pyvista_airplane": 0.8, "pyvista_ant": 0.8,
         "pyvista_globe": 0.6},
        ("bed",), 1.0, 0.03, 0.2, 0.35, False,
        "general indoor scene: furniture, toys and small items under ceiling lights"),
    "kitchen": Preset(
        "kitchen", (10, 16),
        {"table": 1.0, "pot": 1.5, "kettle": 1.2, "pan": 1.0, "mug": 1.5, "bowl": 1.5, "bottle": 1.5, "glass": 1.0,
         "vase": 0.6, "apple": 0.8, "pyvista_nut": 0.5, "pyvista_globe": 0.5},
        (), 0.55, 0.015, 0.75, 0.6, False,
        "many glossy and reflective objects (metal pots, ceramics, glass) under bright lights"),
    "livingroom": Preset(
        "livingroom", (13, 20),
        {"sofa": 1.0, "table": 0.8, "chair": 1.0, "lamp": 1.0, "plant": 1.2, "books": 1.5, "vase": 1.0,
         "cushion": 1.2, "crate": 1.0, "ball": 0.8, "mug": 0.6, "teddy": 0.6, "pyvista_ant": 0.6,
         "pyvista_globe": 0.6},
        ("sofa",), 0.7, 0.01, 0.25, 0.5, False,
        "heavy overlap: many objects packed tightly, targets behind and between others"),
    "picnic": Preset(
        "picnic", (6, 12),
        {"blanket": 1.0, "basket": 1.2, "apple": 1.2, "bottle": 1.0, "plate": 0.8, "bowl": 0.8, "ball": 1.0,
         "bench": 0.8, "umbrella": 0.8, "table": 0.6, "mug": 0.6, "crate": 0.8, "pyvista_airplane": 0.6},
        ("blanket", "umbrella"), 1.1, 0.03, 0.15, 0.4, True,
        "outdoor: low sun with strong hard shadows on grass, sky background"),
}

# kinds that cannot be targets: furniture and flat things that are scenery rather than objects to extract
_NOT_TARGETS = frozenset({"bed", "sofa", "table", "blanket", "bench", "umbrella"})


# ------------------------------------------------------------------------------------------------ mesh building


def _o3d():
    return o3d


def _mesh_arrays(mesh: Any) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(mesh.vertices, dtype=np.float64).copy(), np.asarray(mesh.triangles, dtype=np.int64).copy()


def _rot(axis: str, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _part(v: np.ndarray, t: np.ndarray, mat: Material, smooth: bool, *, scale: Sequence[float] = (1, 1, 1),
          R: np.ndarray | None = None, at: Sequence[float] = (0, 0, 0)) -> Part:
    v = v * np.asarray(scale, dtype=np.float64)
    if R is not None:
        v = v @ np.asarray(R).T
    return Part(v + np.asarray(at, dtype=np.float64), t, mat, smooth)


def box(size: Sequence[float], mat: Material, at: Sequence[float] = (0, 0, 0), **kw: Any) -> Part:
    """Return a box part of ``size`` (x, y, z) whose bottom face is centred at ``at``."""
    v, t = _mesh_arrays(_o3d().geometry.TriangleMesh.create_box(1.0, 1.0, 1.0))
    v = v - np.array([0.5, 0.5, 0.0])
    return _part(v, t, mat, False, scale=size, at=at, **kw)


def cylinder(radius: float, height: float, mat: Material, at: Sequence[float] = (0, 0, 0), *, top_scale: float = 1.0,
             resolution: int = 40, **kw: Any) -> Part:
    """Return a cylinder (a frustum if ``top_scale`` != 1) standing on ``at``."""
    v, t = _mesh_arrays(_o3d().geometry.TriangleMesh.create_cylinder(1.0, 1.0, resolution, 1))
    top = v[:, 2] > 0
    v[top, :2] *= top_scale
    v[:, 2] += 0.5
    return _part(v, t, mat, False, scale=(radius, radius, height), at=at, **kw)


def sphere(radius: float, mat: Material, at: Sequence[float] = (0, 0, 0), *, scale: Sequence[float] = (1, 1, 1),
           resolution: int = 16, lower_half: bool = False, **kw: Any) -> Part:
    """Return a sphere (ellipsoid with ``scale``; an open lower hemisphere shell with ``lower_half``) centred at ``at``."""
    v, t = _mesh_arrays(_o3d().geometry.TriangleMesh.create_sphere(1.0, resolution))
    if lower_half:
        keep = (v[t][:, :, 2] <= 1e-9).all(axis=1)
        t = t[keep]
    return _part(v, t, mat, True, scale=np.asarray(scale) * radius, at=at, **kw)


def cone(radius: float, height: float, mat: Material, at: Sequence[float] = (0, 0, 0), *, resolution: int = 32,
         **kw: Any) -> Part:
    """Return a cone with its base centred on ``at`` and its apex ``height`` above (before rotation ``R``)."""
    v, t = _mesh_arrays(_o3d().geometry.TriangleMesh.create_cone(1.0, 1.0, resolution, 1))
    return _part(v, t, mat, False, scale=(radius, radius, height), at=at, **kw)


def torus(radius: float, tube: float, mat: Material, at: Sequence[float] = (0, 0, 0), **kw: Any) -> Part:
    """Return a torus in the xy plane (before rotation ``R``) centred at ``at``."""
    v, t = _mesh_arrays(_o3d().geometry.TriangleMesh.create_torus(radius, tube, 24, 12))
    return _part(v, t, mat, True, at=at, **kw)


def _pyvista_mesh(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Return (vertices, triangles) of a mesh bundled with PyVista's examples (no download)."""
    loaders = {"airplane": examples.load_airplane, "ant": examples.load_ant, "nut": examples.load_nut,
               "globe": examples.load_globe}
    mesh = loaders[name]().triangulate()  # bundled PolyData surfaces
    faces = np.asarray(mesh.faces).reshape(-1, 4)[:, 1:]
    return np.asarray(mesh.points, dtype=np.float64), faces.astype(np.int64)


# ------------------------------------------------------------------------------------------------- materials


def _hsv(h: float, s: float, v: float) -> tuple[float, float, float]:
    r, g, b = colorsys.hsv_to_rgb(h % 1.0, min(max(s, 0.0), 1.0), min(max(v, 0.0), 1.0))
    return (round(r, 4), round(g, 4), round(b, 4))


def _random_color(rng: np.random.Generator, sat: tuple[float, float] = (0.35, 0.85),
                  val: tuple[float, float] = (0.45, 0.95)) -> tuple[float, float, float]:
    return _hsv(rng.uniform(0, 1), rng.uniform(*sat), rng.uniform(*val))


def _matte(color: tuple[float, float, float], **kw: Any) -> Material:
    return Material(color=color, **{"specular": 0.08, "shininess": 12.0, **kw})


def _glossy(color: tuple[float, float, float], rng: np.random.Generator, metallic: bool = False, **kw: Any) -> Material:
    """Return a glossy material: sharp highlight and a mirror bounce (stronger for metals)."""
    refl = rng.uniform(0.35, 0.6) if metallic else rng.uniform(0.12, 0.3)
    return Material(color=color, specular=0.8 if metallic else 0.6, shininess=float(rng.uniform(60, 140)),
                    reflectivity=round(float(refl), 4), metallic=metallic, diffuse=0.55 if metallic else 0.8, **kw)


def _body_material(rng: np.random.Generator, glossy: bool, *, metal_ok: bool = False,
                   color: tuple[float, float, float] | None = None) -> Material:
    c = color if color is not None else _random_color(rng)
    if glossy:
        metallic = metal_ok and rng.uniform() < 0.5
        if metallic:
            c = _hsv(rng.uniform(0.05, 0.15), rng.uniform(0.0, 0.3), rng.uniform(0.6, 0.9))
        return _glossy(c, rng, metallic)
    pattern = str(rng.choice(["plain", "plain", "stripes", "checker", "noise"]))
    c2 = _hsv(*colorsys.rgb_to_hsv(*c)[:2], colorsys.rgb_to_hsv(*c)[2] * 0.55)
    return _matte(c, color2=c2, pattern=pattern, pattern_scale=float(rng.uniform(12, 30)))


def _wood(rng: np.random.Generator) -> Material:
    base = _hsv(rng.uniform(0.06, 0.1), rng.uniform(0.45, 0.7), rng.uniform(0.45, 0.75))
    dark = _hsv(*colorsys.rgb_to_hsv(*base)[:2], colorsys.rgb_to_hsv(*base)[2] * 0.7)
    return _matte(base, color2=dark, pattern="noise", pattern_scale=float(rng.uniform(15, 30)))


# ---------------------------------------------------------------------------------------------- object builders
# Each builder returns the parts of one object in local coordinates: standing on z = 0, centred on the z axis.

Builder = Callable[[np.random.Generator, bool], list[Part]]


def _table(rng: np.random.Generator, glossy: bool) -> list[Part]:
    w, d, h = rng.uniform(0.5, 0.7), rng.uniform(0.4, 0.55), rng.uniform(0.32, 0.42)
    top = _glossy(_random_color(rng, val=(0.3, 0.8)), rng) if glossy else _wood(rng)
    leg = _matte(_hsv(0, 0, rng.uniform(0.15, 0.5)))
    th, lr = 0.03, 0.022
    parts = [box((w, d, th), top, at=(0, 0, h - th))]
    for sx in (-1, 1):
        for sy in (-1, 1):
            parts.append(cylinder(lr, h - th, leg, at=(sx * (w / 2 - 0.05), sy * (d / 2 - 0.05), 0), resolution=16))
    return parts


def _chair(rng: np.random.Generator, glossy: bool) -> list[Part]:
    s, h = rng.uniform(0.28, 0.36), rng.uniform(0.2, 0.26)
    mat = _wood(rng) if rng.uniform() < 0.5 else _body_material(rng, glossy)
    parts = [box((s, s, 0.03), mat, at=(0, 0, h))]
    for sx in (-1, 1):
        for sy in (-1, 1):
            parts.append(box((0.03, 0.03, h), mat, at=(sx * (s / 2 - 0.02), sy * (s / 2 - 0.02), 0)))
    parts.append(box((s, 0.03, rng.uniform(0.2, 0.3)), mat, at=(0, s / 2 - 0.015, h + 0.03)))
    return parts


def _bed(rng: np.random.Generator, glossy: bool) -> list[Part]:
    w, ln = rng.uniform(0.6, 0.75), rng.uniform(0.85, 1.0)
    frame = _wood(rng)
    sheet = _matte(_random_color(rng, sat=(0.1, 0.5), val=(0.7, 0.95)), color2=_random_color(rng), pattern="stripes",
                   pattern_scale=12.0)
    return [box((w, ln, 0.12), frame, at=(0, 0, 0)),
            box((w * 0.96, ln * 0.96, 0.08), sheet, at=(0, 0, 0.12)),
            box((w, 0.05, 0.38), frame, at=(0, ln / 2 - 0.025, 0)),
            sphere(1.0, _matte((0.95, 0.95, 0.92)), at=(0, ln / 2 - 0.15, 0.23), scale=(w * 0.35, 0.08, 0.04))]


def _sofa(rng: np.random.Generator, glossy: bool) -> list[Part]:
    w, d = rng.uniform(0.8, 1.0), rng.uniform(0.35, 0.42)
    cloth = _matte(_random_color(rng, sat=(0.2, 0.6), val=(0.35, 0.8)), pattern="noise",
                   color2=_random_color(rng, val=(0.3, 0.5)), pattern_scale=40.0)
    return [box((w, d, 0.16), cloth),
            box((w, 0.1, 0.36), cloth, at=(0, d / 2 - 0.05, 0)),
            box((0.09, d, 0.25), cloth, at=(-w / 2 + 0.045, 0, 0)),
            box((0.09, d, 0.25), cloth, at=(w / 2 - 0.045, 0, 0))]


def _bench(rng: np.random.Generator, glossy: bool) -> list[Part]:
    w = rng.uniform(0.7, 0.9)
    mat = _wood(rng)
    return [box((w, 0.22, 0.03), mat, at=(0, 0, 0.2)),
            box((0.04, 0.2, 0.2), mat, at=(-w / 2 + 0.06, 0, 0)),
            box((0.04, 0.2, 0.2), mat, at=(w / 2 - 0.06, 0, 0))]


def _lamp(rng: np.random.Generator, glossy: bool) -> list[Part]:
    h = rng.uniform(0.35, 0.55)
    metal = _glossy(_hsv(0.1, 0.2, rng.uniform(0.5, 0.8)), rng, metallic=True)
    shade = _matte(_random_color(rng, sat=(0.1, 0.5), val=(0.8, 1.0)))
    return [cylinder(0.07, 0.02, metal), cylinder(0.012, h, metal, resolution=12),
            cylinder(0.1, 0.12, shade, at=(0, 0, h - 0.06), top_scale=0.55)]


def _books(rng: np.random.Generator, glossy: bool) -> list[Part]:
    parts, z = [], 0.0
    for _ in range(int(rng.integers(2, 5))):
        w, d, t = rng.uniform(0.14, 0.22), rng.uniform(0.1, 0.15), rng.uniform(0.02, 0.045)
        R = _rot("z", rng.uniform(-0.35, 0.35))
        parts.append(box((w, d, t), _matte(_random_color(rng)), at=(rng.uniform(-0.01, 0.01), 0, z), R=R))
        z += t
    return parts


def _teddy(rng: np.random.Generator, glossy: bool) -> list[Part]:
    s = rng.uniform(0.8, 1.2)
    fur = _matte(_hsv(rng.uniform(0.05, 0.11), rng.uniform(0.4, 0.7), rng.uniform(0.4, 0.75)), pattern="noise",
                 color2=_hsv(0.08, 0.5, 0.3), pattern_scale=60.0)
    dark = _matte((0.1, 0.07, 0.05))
    return [sphere(0.09 * s, fur, at=(0, 0, 0.09 * s), scale=(1, 0.85, 1.1)),
            sphere(0.065 * s, fur, at=(0, -0.01 * s, 0.235 * s)),
            sphere(0.025 * s, fur, at=(-0.05 * s, 0, 0.29 * s)),
            sphere(0.025 * s, fur, at=(0.05 * s, 0, 0.29 * s)),
            sphere(0.025 * s, dark, at=(0, -0.065 * s, 0.23 * s)),
            sphere(0.035 * s, fur, at=(-0.09 * s, -0.02 * s, 0.13 * s), scale=(1, 1, 1.6)),
            sphere(0.035 * s, fur, at=(0.09 * s, -0.02 * s, 0.13 * s), scale=(1, 1, 1.6)),
            sphere(0.04 * s, fur, at=(-0.05 * s, -0.06 * s, 0.035 * s), scale=(1, 1.5, 0.9)),
            sphere(0.04 * s, fur, at=(0.05 * s, -0.06 * s, 0.035 * s), scale=(1, 1.5, 0.9))]


def _ball(rng: np.random.Generator, glossy: bool) -> list[Part]:
    r = rng.uniform(0.06, 0.11)
    mat = Material(color=_random_color(rng), color2=_random_color(rng), pattern="stripes", pattern_scale=1.5 / r,
                   specular=0.5, shininess=40.0, reflectivity=0.1 if glossy else 0.0)
    return [sphere(r, mat, at=(0, 0, r), resolution=20)]


def _plant(rng: np.random.Generator, glossy: bool) -> list[Part]:
    pot = _matte(_hsv(rng.uniform(0.02, 0.08), 0.6, rng.uniform(0.45, 0.7)))
    parts = [cylinder(0.07, 0.1, pot, top_scale=1.3)]
    for _ in range(int(rng.integers(3, 6))):
        leaf = _matte(_hsv(rng.uniform(0.22, 0.38), rng.uniform(0.5, 0.8), rng.uniform(0.3, 0.6)), pattern="noise",
                      color2=_hsv(0.3, 0.7, 0.2), pattern_scale=50.0)
        parts.append(sphere(rng.uniform(0.05, 0.08), leaf, at=(rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05),
                                                               rng.uniform(0.14, 0.3))))
    return parts


def _mug(rng: np.random.Generator, glossy: bool) -> list[Part]:
    r, h = rng.uniform(0.04, 0.055), rng.uniform(0.09, 0.12)
    mat = _body_material(rng, glossy)
    return [cylinder(r, h, mat),
            torus(0.028, 0.007, mat, at=(r + 0.012, 0, h * 0.55), R=_rot("x", math.pi / 2))]


def _glass(rng: np.random.Generator, glossy: bool) -> list[Part]:
    mat = _glossy(_hsv(rng.uniform(0.45, 0.6), rng.uniform(0.05, 0.3), rng.uniform(0.75, 0.95)), rng)
    return [cylinder(rng.uniform(0.03, 0.04), rng.uniform(0.1, 0.14), mat, top_scale=1.15)]


def _bowl(rng: np.random.Generator, glossy: bool) -> list[Part]:
    r = rng.uniform(0.07, 0.11)
    mat = _body_material(rng, glossy)
    return [sphere(r, mat, at=(0, 0, r * 0.6), scale=(1, 1, 0.6), lower_half=True)]


def _plate(rng: np.random.Generator, glossy: bool) -> list[Part]:
    r = rng.uniform(0.08, 0.12)
    mat = _body_material(rng, glossy)
    return [cylinder(r * 0.7, 0.01, mat), cylinder(r, 0.012, mat, at=(0, 0, 0.01), top_scale=1.0)]


def _bottle(rng: np.random.Generator, glossy: bool) -> list[Part]:
    r, h = rng.uniform(0.03, 0.045), rng.uniform(0.15, 0.22)
    mat = _glossy(_hsv(rng.uniform(0.25, 0.45), rng.uniform(0.4, 0.8), rng.uniform(0.3, 0.6)), rng)
    cap = _matte(_random_color(rng))
    return [cylinder(r, h, mat), cylinder(r, 0.04, mat, at=(0, 0, h), top_scale=0.35),
            cylinder(r * 0.35, 0.05, mat, at=(0, 0, h + 0.04), resolution=16),
            cylinder(r * 0.4, 0.015, cap, at=(0, 0, h + 0.09), resolution=16)]


def _vase(rng: np.random.Generator, glossy: bool) -> list[Part]:
    r = rng.uniform(0.05, 0.08)
    mat = _body_material(rng, glossy)
    return [sphere(r, mat, at=(0, 0, r * 1.2), scale=(1, 1, 1.2)),
            cylinder(r * 0.4, r * 1.3, mat, at=(0, 0, r * 2.0), top_scale=1.5, resolution=24)]


def _pot(rng: np.random.Generator, glossy: bool) -> list[Part]:
    r, h = rng.uniform(0.08, 0.11), rng.uniform(0.08, 0.12)
    mat = _body_material(rng, glossy, metal_ok=True)
    return [cylinder(r, h, mat), torus(r, 0.006, mat, at=(0, 0, h)),
            box((0.04, 0.02, 0.015), mat, at=(r + 0.015, 0, h * 0.8)),
            box((0.04, 0.02, 0.015), mat, at=(-r - 0.015, 0, h * 0.8)),
            sphere(r * 0.98, mat, at=(0, 0, h), scale=(1, 1, 0.25))]


def _kettle(rng: np.random.Generator, glossy: bool) -> list[Part]:
    r = rng.uniform(0.07, 0.09)
    mat = _body_material(rng, glossy, metal_ok=True)
    return [sphere(r, mat, at=(0, 0, r * 0.8), scale=(1, 1, 0.8)),
            cone(0.02, r * 0.9, mat, at=(r * 0.7, 0, r * 0.6), R=_rot("y", 0.9)),
            torus(r * 0.55, 0.008, mat, at=(0, 0, r * 1.55), R=_rot("x", math.pi / 2)),
            sphere(0.015, _matte((0.1, 0.1, 0.1)), at=(0, 0, r * 1.62))]


def _pan(rng: np.random.Generator, glossy: bool) -> list[Part]:
    r = rng.uniform(0.08, 0.11)
    mat = _body_material(rng, glossy, metal_ok=True)
    handle = _matte((0.08, 0.08, 0.08))
    return [cylinder(r, 0.035, mat, top_scale=1.1), box((0.16, 0.025, 0.015), handle, at=(r + 0.075, 0, 0.02))]


def _apple(rng: np.random.Generator, glossy: bool) -> list[Part]:
    r = rng.uniform(0.035, 0.05)
    skin = Material(color=_hsv(rng.choice([0.0, 0.02, 0.25]), rng.uniform(0.6, 0.9), rng.uniform(0.5, 0.85)),
                    color2=_hsv(0.12, 0.7, 0.8), pattern="noise", pattern_scale=80.0, specular=0.4, shininess=30.0)
    return [sphere(r, skin, at=(0, 0, r * 0.9), scale=(1, 1, 0.9)),
            cylinder(0.004, 0.02, _matte((0.3, 0.2, 0.1)), at=(0, 0, r * 1.75), resolution=8)]


def _basket(rng: np.random.Generator, glossy: bool) -> list[Part]:
    r, h = rng.uniform(0.1, 0.13), rng.uniform(0.1, 0.14)
    wicker = _matte(_hsv(0.09, 0.55, rng.uniform(0.55, 0.75)), color2=_hsv(0.08, 0.6, 0.35), pattern="checker",
                    pattern_scale=60.0)
    return [cylinder(r, h, wicker, top_scale=1.15),
            torus(r * 0.95, 0.008, wicker, at=(0, 0, h), R=_rot("x", math.pi / 2), scale=(1, 1, 1))]


def _crate(rng: np.random.Generator, glossy: bool) -> list[Part]:
    s = rng.uniform(0.14, 0.24)
    mat = _wood(rng) if rng.uniform() < 0.6 else _body_material(rng, glossy)
    return [box((s, s * rng.uniform(0.8, 1.2), s * rng.uniform(0.7, 1.1)), mat, R=_rot("z", rng.uniform(0, 1.5)))]


def _cushion(rng: np.random.Generator, glossy: bool) -> list[Part]:
    s = rng.uniform(0.12, 0.17)
    mat = _matte(_random_color(rng), color2=_random_color(rng), pattern="checker", pattern_scale=25.0)
    return [sphere(s, mat, at=(0, 0, s * 0.35), scale=(1, 1, 0.35))]


def _blanket(rng: np.random.Generator, glossy: bool) -> list[Part]:
    mat = _matte(_hsv(rng.choice([0.0, 0.6, 0.33]), 0.75, 0.75), color2=(0.95, 0.95, 0.95), pattern="gingham",
                 pattern_scale=8.0)
    return [box((rng.uniform(0.8, 1.0), rng.uniform(0.7, 0.9), 0.008), mat)]


def _umbrella(rng: np.random.Generator, glossy: bool) -> list[Part]:
    h = rng.uniform(0.7, 0.85)
    canopy = _matte(_random_color(rng), color2=(0.95, 0.95, 0.95), pattern="stripes", pattern_scale=10.0)
    return [cylinder(0.012, h, _matte((0.85, 0.85, 0.85)), resolution=12),
            cone(0.45, 0.15, canopy, at=(0, 0, h - 0.1), resolution=24),
            cylinder(0.07, 0.03, _matte((0.3, 0.3, 0.3)))]


def _pyvista_builder(name: str, size: tuple[float, float]) -> Builder:
    def build(rng: np.random.Generator, glossy: bool) -> list[Part]:
        v, t = _pyvista_mesh(name)
        v = v - (v.min(axis=0) + v.max(axis=0)) / 2
        v = v / np.abs(v).max() * rng.uniform(*size) / 2
        v[:, 2] -= v[:, 2].min()
        return [Part(v, t, _body_material(rng, glossy), True)]

    return build


BUILDERS: dict[str, Builder] = {
    "table": _table, "chair": _chair, "bed": _bed, "sofa": _sofa, "bench": _bench, "lamp": _lamp, "books": _books,
    "teddy": _teddy, "ball": _ball, "plant": _plant, "mug": _mug, "glass": _glass, "bowl": _bowl, "plate": _plate,
    "bottle": _bottle, "vase": _vase, "pot": _pot, "kettle": _kettle, "pan": _pan, "apple": _apple,
    "basket": _basket, "crate": _crate, "cushion": _cushion, "blanket": _blanket, "umbrella": _umbrella,
    "pyvista_airplane": _pyvista_builder("airplane", (0.3, 0.4)),
    "pyvista_ant": _pyvista_builder("ant", (0.15, 0.22)),
    "pyvista_nut": _pyvista_builder("nut", (0.1, 0.14)),
    "pyvista_globe": _pyvista_builder("globe", (0.12, 0.18)),
}


def _environment(P: Preset, rng: np.random.Generator) -> tuple[Part, list[Light], tuple, tuple]:
    """Return the ground, lights, ambient light and sky colours of a preset."""
    ground_radius = 5.5
    gv, gt = _mesh_arrays(_o3d().geometry.TriangleMesh.create_cylinder(1.0, 1.0, 64, 1))
    keep = (gv[gt][:, :, 2] > 0).all(axis=1)  # the top cap only: a disc
    gv[:, 2] = 0.0
    gv[:, :2] *= ground_radius
    if P.outdoor:
        mat = _matte(_hsv(rng.uniform(0.22, 0.28), rng.uniform(0.55, 0.75), rng.uniform(0.45, 0.6)),
                     color2=_hsv(0.2, 0.6, 0.3), pattern="grass", pattern_scale=6.0)
        az, el = rng.uniform(0, 2 * math.pi), math.radians(rng.uniform(30, 45))
        sun = (math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el))
        lights = [Light("directional", tuple(round(c, 6) for c in sun), (2.6, 2.45, 2.1), True)]
        ambient = (0.22, 0.26, 0.34)
        sky = ((0.78, 0.87, 0.96), (0.35, 0.58, 0.9))
    else:
        if P.name == "kitchen":
            mat = _matte((0.85, 0.85, 0.82), color2=(0.35, 0.38, 0.42), pattern="tiles", pattern_scale=4.0,
                         specular=0.3, shininess=40.0)
        elif P.name == "livingroom":
            mat = _matte(_random_color(rng, sat=(0.2, 0.5), val=(0.4, 0.7)), color2=_random_color(rng, val=(0.3, 0.5)),
                         pattern="noise", pattern_scale=12.0)
        else:
            mat = _wood(rng)
            mat = Material(**{**asdict(mat), "pattern": "planks", "pattern_scale": 6.0})
        lights = []
        for k in range(2):
            a = rng.uniform(0, 2 * math.pi)
            pos = (round(1.2 * math.cos(a), 6), round(1.2 * math.sin(a), 6), round(rng.uniform(2.2, 2.8), 6))
            lights.append(Light("point", pos, (0.9, 0.85, 0.78) if k == 0 else (0.45, 0.45, 0.5), True))
        ambient = (0.32, 0.31, 0.3)
        sky = ((0.72, 0.7, 0.66), (0.9, 0.89, 0.86))
    return Part(gv, gt[keep], mat, False), lights, ambient, sky
