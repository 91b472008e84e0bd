"""Multi-object benchmark scenes in the Blender format, rendered by ray casting meshes (Open3D / Embree).

The paper evaluates on MultiObjectBlender: cluttered scenes of 5 to 20 ShapeNet objects, 3 to 4 of them targets, with
each target also rendered alone so an extraction can be scored where it was hidden. Neither ShapeNet nor that dataset
can be fetched here, so this module builds equivalent scenes from procedural meshes (compositions of Open3D
primitives) and the meshes PyVista bundles with its examples, and renders them with Open3D's ray casting and a
shading model of its own (Lambert + Blinn-Phong, hard shadows by shadow rays, one mirror bounce for glossy
materials). Ground truth therefore never passes through the toolkit's splat renderer.

Why ray casting rather than VTK rasterisation: instance ids and depth come exactly from the hit geometry of each
pixel-centre ray (no anti-aliasing can blend two ids), the same rays are used for every output, shadows and
reflections work without an OpenGL context, and the output is bit-identical from run to run. See docs/datasets.md.

Layout of a generated scene (``OUT_DIR``)::

    scene.json                      objects, ids, names, targets, lights, generator settings
    transforms_train.json           the full scene, Blender format, with mask_path / depth_path per frame
    transforms_test.json            empty frame list (some tools insist on the file); scoring uses the targets
    train/r_000.png ...             RGB renders
    train/masks/r_000.png ...       8-bit instance ids (0 = ground / background, objects 1..N)
    train/depth/r_000.png ...       16-bit z-depth times ``depth_scale`` (0 = nothing hit)
    targets/03_mug/transforms_test.json, test/r_000.png (RGBA on white), test/masks/r_000.png
    overview.png                    a grid of training views with the targets outlined
"""

from __future__ import annotations

import colorsys
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from .._version import __version__
from ..cameras import Camera, intrinsics_from_fov, look_at
from ..errors import ConfigError, DatasetError
from ..io.files import prepare_output_dir, write_image, write_json
from ..progress import ProgressFactory, null_progress

__all__ = [
    "PRESETS",
    "Material",
    "Part",
    "SceneObject",
    "Light",
    "Preset",
    "Scene",
    "SceneSettings",
    "RenderResult",
    "build_scene",
    "training_cameras",
    "target_cameras",
    "TEST_FRAMINGS",
    "render_views",
    "make_scene",
    "overview_image",
    "scene_from_record",
]

SCENE_FORMAT = "roodi-toolkit-scene"
SCENE_FORMAT_VERSION = 1
DEPTH_SCALE = 1e-4  # metres per 16-bit depth unit: 0.1 mm resolution, 6.5 m range (the ground is cut at that range)
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
TEST_FRAMINGS = ("scene", "object")
_NOT_TARGETS = frozenset({"bed", "sofa", "table", "blanket", "bench", "umbrella"})


@dataclass(frozen=True)
class SceneSettings:
    """Generator settings recorded in scene.json; with the preset and seed they reproduce a scene bit for bit.

    Attributes:
        width: image width.
        height: image height.
        train_views: number of full-scene training views.
        test_views: number of views of each target alone.
        fov_x_deg: horizontal field of view of every camera.
        supersample: rays per pixel along each axis for colour and alpha (masks and depth use the centre ray).
        n_targets: number of targets, or None for 3 or 4 drawn from the seed.
        n_objects: number of objects, or None for the preset's range.
        test_framing: how the targets' test cameras frame them: ``"scene"`` (the paper's protocol: cameras on the
            training views' hemisphere, at their distance, aimed at the target, so the object is as large as in
            training and anything kept elsewhere in the scene, such as floaters, shows in the view) or ``"object"``
            (close-ups in which the target fills the frame: a stricter test of the object's detail).
    """

    width: int = 200
    height: int = 200
    train_views: int = 50
    test_views: int = 50
    fov_x_deg: float = 50.0
    supersample: int = 2
    n_targets: int | None = None
    n_objects: int | None = None
    test_framing: str = "scene"

    def __post_init__(self) -> None:
        if not (8 <= self.width <= 8192 and 8 <= self.height <= 8192):
            raise ConfigError(f"image size must be between 8 and 8192 pixels, got {self.width}x{self.height}")
        if self.train_views < 1 or self.test_views < 1:
            raise ConfigError(f"need at least one training and one test view, got {self.train_views} and "
                              f"{self.test_views}")
        if not 10.0 <= self.fov_x_deg <= 120.0:
            raise ConfigError(f"fov_x_deg must be in [10, 120] degrees, got {self.fov_x_deg}")
        if not 1 <= self.supersample <= 4:
            raise ConfigError(f"supersample must be 1 to 4, got {self.supersample}")
        if self.n_targets is not None and not 1 <= self.n_targets <= 4:
            raise ConfigError(f"n_targets must be 1 to 4, got {self.n_targets}")
        if self.n_objects is not None and not 5 <= self.n_objects <= MAX_OBJECTS:
            raise ConfigError(f"n_objects must be 5 to {MAX_OBJECTS}, got {self.n_objects}")
        if self.test_framing not in TEST_FRAMINGS:
            raise ConfigError(f"test_framing must be one of {', '.join(TEST_FRAMINGS)}, got {self.test_framing!r}")


@dataclass
class Scene:
    """A generated scene: objects on a ground, lights and an environment.

    Attributes:
        preset: the preset's name.
        seed: the seed it was built from.
        objects: the objects, ids 1..N in order.
        ground: the ground part (id 0 in masks).
        lights: the lights.
        ambient: linear RGB ambient light.
        sky: (horizon, zenith) sRGB colours of the environment seen by rays that hit nothing.
    """

    preset: str
    seed: int
    objects: list[SceneObject]
    ground: Part = field(repr=False)
    lights: list[Light] = field(repr=False)
    ambient: tuple[float, float, float]
    sky: tuple[tuple[float, float, float], tuple[float, float, float]]

    @property
    def targets(self) -> list[SceneObject]:
        """The target objects."""
        return [o for o in self.objects if o.is_target]

    def object(self, object_id: int) -> SceneObject:
        """Return the object with this id."""
        for o in self.objects:
            if o.id == object_id:
                return o
        raise ConfigError(f"scene has no object with id {object_id}")

    @property
    def bounds(self) -> np.ndarray:
        """``[2, 3]`` box around all objects (not the ground)."""
        b = np.stack([o.bounds for o in self.objects])
        return np.stack([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])


# ------------------------------------------------------------------------------------------------ mesh building


def _o3d():
    import open3d as o3d

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
    from pyvista import examples

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


# ------------------------------------------------------------------------------------------------------ layout


def _footprint(parts: list[Part]) -> tuple[float, float]:
    """Return (radius of the xy footprint around the z axis, height)."""
    v = np.concatenate([p.vertices for p in parts])
    return float(np.linalg.norm(v[:, :2], axis=1).max()), float(v[:, 2].max())


def _transform(parts: list[Part], yaw: float, at: np.ndarray) -> list[Part]:
    R = _rot("z", yaw)
    return [Part(p.vertices @ R.T + at, p.triangles, p.material, p.smooth) for p in parts]


def build_scene(preset: str = "bedroom", seed: int = 0, *, n_objects: int | None = None,
                n_targets: int | None = None) -> Scene:
    """Return a scene of the preset, laid out from the seed (same arguments -> the same scene).

    Targets are placed near the middle and each gets an occluder right beside it, so that in many views of the
    hemisphere around the scene part of every target is hidden.

    Args:
        preset: ``bedroom``, ``kitchen``, ``livingroom`` or ``picnic``.
        seed: random seed of the layout, shapes, colours and lights.
        n_objects: object count (5 to 20), default drawn from the preset's range.
        n_targets: target count (1 to 4), default 3 or 4.

    Raises:
        ConfigError: unknown preset or counts out of range.
    """
    if preset not in PRESETS:
        raise ConfigError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
    P = PRESETS[preset]
    rng = np.random.default_rng([int(seed), sorted(PRESETS).index(preset)])
    n = int(n_objects) if n_objects is not None else int(rng.integers(P.n_objects[0], P.n_objects[1] + 1))
    if not 5 <= n <= MAX_OBJECTS:
        raise ConfigError(f"n_objects must be 5 to {MAX_OBJECTS}, got {n}")
    n_t = int(n_targets) if n_targets is not None else int(rng.integers(3, 5))
    if not 1 <= n_t <= 4:
        raise ConfigError(f"n_targets must be 1 to 4, got {n_t}")

    kinds_all = sorted(P.catalog)
    weights = np.array([P.catalog[k] for k in kinds_all])
    target_kinds = [k for k in kinds_all if k not in _NOT_TARGETS]
    t_weights = np.array([P.catalog[k] for k in target_kinds])

    def draw(pool: list[str], w: np.ndarray, used: list[str]) -> str:
        ok = np.array([not (k in P.at_most_one and k in used) for k in pool], dtype=float) * w
        return pool[int(rng.choice(len(pool), p=ok / ok.sum()))]

    kinds: list[str] = []
    for _ in range(n_t):
        kinds.append(draw(target_kinds, t_weights, kinds))
    for _ in range(n - n_t):
        kinds.append(draw(kinds_all, weights, kinds))

    built = []
    for k in kinds:
        glossy = bool(rng.uniform() < P.glossy_fraction)
        parts = BUILDERS[k](rng, glossy)
        lowest = min(float(p.vertices[:, 2].min()) for p in parts)
        for p in parts:  # stand exactly on z = 0 (no part sinks into the ground or floats above it)
            p.vertices = p.vertices - np.array([0.0, 0.0, lowest])
        built.append(parts)

    # placement: large things first keep the rejection sampling short; targets then occluders near the centre
    placed: list[dict[str, Any]] = []  # x, y, r, h, z, table
    order = list(range(n_t))  # targets
    others = sorted(range(n_t, n), key=lambda i: -_footprint(built[i])[0])
    big = [i for i in others if _footprint(built[i])[0] > 0.3]
    small = [i for i in others if i not in big]
    occluders = small[:n_t] if len(small) >= n_t else small
    rest = big + [i for i in small if i not in occluders]
    positions: dict[int, tuple[np.ndarray, float]] = {}
    infos: dict[int, dict[str, Any]] = {}

    def collides(x: float, y: float, r: float, z: float, h: float) -> bool:
        for q in placed:
            if q["z"] + q["h"] <= z + 1e-6 or z + h <= q["z"] + 1e-6:
                continue  # one stands on something above / below the other
            if math.hypot(x - q["x"], y - q["y"]) < r + q["r"] + P.gap:
                return True
        return False

    def try_table(i: int, r: float, h: float) -> tuple[float, float, float] | None:
        tables = [q for q in placed if q["kind"] == "table"]
        if not tables or r > 0.14 or rng.uniform() >= P.on_table_probability:
            return None
        q = tables[int(rng.integers(len(tables)))]
        for _ in range(30):
            x = q["x"] + rng.uniform(-1, 1) * max(q["top"][0] - r, 0.0)
            y = q["y"] + rng.uniform(-1, 1) * max(q["top"][1] - r, 0.0)
            if not collides(x, y, r, q["h"], h):
                return x, y, q["h"]
        return None

    def place(i: int, center: tuple[float, float], radius: float, allow_table: bool) -> None:
        r, h = _footprint(built[i])
        spot = try_table(i, r, h) if allow_table else None
        if spot is None:
            rad = radius
            for attempt in range(400):
                a, s = rng.uniform(0, 2 * math.pi), rad * math.sqrt(rng.uniform())
                x, y = center[0] + s * math.cos(a), center[1] + s * math.sin(a)
                if not collides(x, y, r, 0.0, h):
                    spot = (x, y, 0.0)
                    break
                if attempt % 40 == 39:
                    rad *= 1.15  # crowded: widen the disc
            if spot is None:
                raise ConfigError(f"could not place object {i} ({kinds[i]}) without collisions; use fewer objects")
        x, y, z = spot
        yaw = float(rng.uniform(0, 2 * math.pi))
        info: dict[str, Any] = {"x": x, "y": y, "z": z, "r": r, "h": h, "kind": kinds[i]}
        if kinds[i] == "table":
            v = np.concatenate([p.vertices for p in built[i]])
            info["top"] = (0.5 * (v[:, 0].max() - v[:, 0].min()) * 0.6, 0.5 * (v[:, 1].max() - v[:, 1].min()) * 0.6)
            info["r"] = r
            yaw = float(rng.choice([0.0, math.pi / 2]))  # axis-aligned so the top's free box stays simple
            info["top"] = info["top"] if yaw == 0.0 else info["top"][::-1]
        placed.append(info)
        infos[i] = info
        positions[i] = (np.array([x, y, z]), yaw)

    R = P.layout_radius
    # big furniture away from the middle so it frames rather than buries the targets
    for i in big:
        if kinds[i] in ("bed", "sofa", "blanket", "umbrella", "bench"):
            place(i, (0.0, 0.0), R, False)
    for i in big:
        if i not in positions:
            place(i, (0.0, 0.0), R * 0.6, False)
    for i in order:
        place(i, (0.0, 0.0), R * 0.45, True)
    for j, i in enumerate(occluders):
        tx, ty, _ = positions[order[j % n_t]][0]
        r_t, r_o = infos[order[j % n_t]]["r"], _footprint(built[i])[0]
        place(i, (tx, ty), r_t + r_o + 0.15, False)
    for i in rest:
        if i not in positions:
            place(i, (0.0, 0.0), R, True)

    objects = []
    counters: dict[str, int] = {}
    for i in range(n):
        counters[kinds[i]] = counters.get(kinds[i], 0) + 1
        at, yaw = positions[i]
        name = f"{kinds[i].replace('pyvista_', '')}_{counters[kinds[i]]}"
        source = f"pyvista:{kinds[i][len('pyvista_'):]}" if kinds[i].startswith("pyvista_") else "procedural"
        objects.append(SceneObject(i + 1, name, kinds[i], _transform(built[i], yaw, at), is_target=i < n_t,
                                   source=source))

    ground, lights, ambient, sky = _environment(P, rng)
    return Scene(preset=preset, seed=int(seed), objects=objects, ground=ground, lights=lights, ambient=ambient, sky=sky)


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


# ------------------------------------------------------------------------------------------------------ cameras


def _cap_directions(n: int, el_range: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """Return ``[n, 3]`` unit directions spread evenly (Fibonacci) over a band of elevations, randomly rotated."""
    lo, hi = (math.sin(math.radians(e)) for e in el_range)
    k = np.arange(n) + 0.5
    z = lo + (hi - lo) * ((k / n + rng.uniform()) % 1.0)
    az = rng.uniform(0, 2 * math.pi) + k * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(az), r * np.sin(az), z], axis=1)


def _scene_frame(scene: Scene, K: np.ndarray, width: int, height: int) -> tuple[np.ndarray, float, float]:
    """Return the training cameras' look-at centre, the scene's radius around it and their distance from it."""
    fov_min = 2 * math.atan(min(width / (2 * K[0, 0]), height / (2 * K[1, 1])))
    b = scene.bounds
    centre = np.array([(b[0, 0] + b[1, 0]) / 2, (b[0, 1] + b[1, 1]) / 2, 0.3 * (b[1, 2] - b[0, 2])])
    v = np.concatenate([o.vertices for o in scene.objects])
    radius = float(np.linalg.norm(v - centre, axis=1).max())
    return centre, radius, radius / math.sin(fov_min / 2) * 0.92  # a little cropping keeps the objects large


# elevation band (degrees) of the full-scene training cameras
TRAIN_ELEVATIONS = (18.0, 65.0)


def training_cameras(scene: Scene, n: int, width: int, height: int, *, fov_x_deg: float = 50.0,
                     seed: int | None = None) -> list[Camera]:
    """Return ``n`` cameras on a hemisphere around the scene, looking at its middle, framing all objects.

    Args:
        scene: the scene.
        n: number of views.
        width: image width.
        height: image height.
        fov_x_deg: horizontal field of view.
        seed: randomness of the positions (default the scene's seed).
    """
    rng = np.random.default_rng([scene.seed if seed is None else int(seed), 1])
    K = intrinsics_from_fov(math.radians(fov_x_deg), width, height)
    centre, radius, dist = _scene_frame(scene, K, width, height)
    dirs = _cap_directions(n, TRAIN_ELEVATIONS, rng)
    cams = []
    for i, d in enumerate(dirs):
        eye = centre + d * dist * rng.uniform(0.95, 1.08)
        aim = centre + rng.uniform(-0.05, 0.05, size=3) * radius
        cams.append(Camera(look_at(eye, aim), K, width, height, near=0.01, far=100.0, name=f"r_{i:03d}"))
    return cams


def target_cameras(scene: Scene, target: SceneObject, n: int, width: int, height: int, *, fov_x_deg: float = 50.0,
                   seed: int | None = None, framing: str = "scene") -> list[Camera]:
    """Return ``n`` test cameras of one object, aimed at it, at positions different from the training cameras.

    Args:
        scene: the scene.
        target: the object to look at.
        n: number of views.
        width: image width.
        height: image height.
        fov_x_deg: horizontal field of view.
        seed: randomness of the positions (default derived from the scene's seed and the object id).
        framing: ``"scene"``: on the training cameras' hemisphere and at their distance (the object as large as in
            training; the paper's object-alone test renders); ``"object"``: close-ups in which the object fills the
            frame.
    """
    if framing not in TEST_FRAMINGS:
        raise ConfigError(f"framing must be one of {', '.join(TEST_FRAMINGS)}, got {framing!r}")
    rng = np.random.default_rng([scene.seed if seed is None else int(seed), 2, target.id])
    K = intrinsics_from_fov(math.radians(fov_x_deg), width, height)
    v = target.vertices
    centre = (v.min(axis=0) + v.max(axis=0)) / 2
    cams = []
    if framing == "object":
        fov_min = 2 * math.atan(min(width / (2 * K[0, 0]), height / (2 * K[1, 1])))
        radius = float(np.linalg.norm(v - centre, axis=1).max())
        dist = radius / math.sin(fov_min / 2) * 1.1
        for i, d in enumerate(_cap_directions(n, (8.0, 70.0), rng)):
            eye = centre + d * dist * rng.uniform(0.97, 1.1)
            cams.append(Camera(look_at(eye, centre), K, width, height, near=0.01, far=100.0, name=f"r_{i:03d}"))
        return cams
    scene_centre, _, dist = _scene_frame(scene, K, width, height)
    for i, d in enumerate(_cap_directions(n, TRAIN_ELEVATIONS, rng)):
        eye = scene_centre + d * dist * rng.uniform(0.95, 1.08)
        cams.append(Camera(look_at(eye, centre), K, width, height, near=0.01, far=100.0, name=f"r_{i:03d}"))
    return cams


# ---------------------------------------------------------------------------------------------------- rendering


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


# ------------------------------------------------------------------------------------------------------ writing


_OUTLINE_COLORS = [(1.0, 0.1, 0.1), (0.1, 0.9, 0.2), (0.15, 0.4, 1.0), (1.0, 0.85, 0.0)]


def _outline(mask: np.ndarray) -> np.ndarray:
    """Return the pixels of ``mask`` that touch a pixel outside it (4-neighbourhood), thickened by one pixel."""
    m = np.pad(mask, 1)
    inner = m[1:-1, 1:-1] & m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2] & m[1:-1, 2:]
    edge = mask & ~inner
    e = np.pad(edge, 1)
    return e[1:-1, 1:-1] | e[:-2, 1:-1] | e[2:, 1:-1] | e[1:-1, :-2] | e[1:-1, 2:]


def overview_image(images: Sequence[np.ndarray], masks: Sequence[np.ndarray], target_ids: Sequence[int], *,
                   columns: int = 4, max_views: int = 12, target_thumbnails: Sequence[np.ndarray] = ()) -> np.ndarray:
    """Return an ``[H', W', 3]`` float32 grid of views with each target's visible outline in its own colour.

    Args:
        images: ``[H, W, 3]`` float views.
        masks: ``[H, W]`` instance ids of the views.
        target_ids: ids to outline (colours: red, green, blue, yellow in this order).
        columns: views per row.
        max_views: views shown, evenly picked.
        target_thumbnails: optional ``[H, W, 3]`` images of each target alone, shown in a last row framed in the
            target's colour.
    """
    if not images:
        raise ConfigError("overview needs at least one view")
    idx = np.unique(np.linspace(0, len(images) - 1, min(max_views, len(images))).round().astype(int))
    H, W = images[0].shape[:2]
    tiles = []
    for i in idx:
        tile = np.asarray(images[i], dtype=np.float32).copy()
        for k, tid in enumerate(target_ids):
            tile[_outline(np.asarray(masks[i]) == tid)] = _OUTLINE_COLORS[k % len(_OUTLINE_COLORS)]
        tiles.append(tile)
    for k, thumb in enumerate(target_thumbnails):
        tile = np.asarray(thumb, dtype=np.float32).copy()
        frame = np.zeros((H, W), dtype=bool)
        frame[:2], frame[-2:], frame[:, :2], frame[:, -2:] = True, True, True, True
        tile[frame] = _OUTLINE_COLORS[k % len(_OUTLINE_COLORS)]
        if k == 0:
            while len(tiles) % columns:
                tiles.append(np.ones((H, W, 3), np.float32))
        tiles.append(tile)
    while len(tiles) % columns:
        tiles.append(np.ones((H, W, 3), np.float32))
    gap = 2
    rows = len(tiles) // columns
    out = np.ones((rows * H + (rows - 1) * gap, columns * W + (columns - 1) * gap, 3), np.float32)
    for j, tile in enumerate(tiles):
        r, c = divmod(j, columns)
        out[r * (H + gap):r * (H + gap) + H, c * (W + gap):c * (W + gap) + W] = tile
    return out


def _depth_png(depth: np.ndarray) -> np.ndarray:
    q = np.round(depth.astype(np.float64) / DEPTH_SCALE)
    return np.clip(q, 0, 65535).astype(np.uint16)


def _object_record(o: SceneObject) -> dict[str, Any]:
    b = o.bounds
    return {"id": o.id, "name": o.name, "kind": o.kind, "source": o.source, "is_target": o.is_target,
            "center": [round(float(x), 6) for x in o.center], "bounds": np.round(b, 6).tolist(),
            "n_vertices": int(sum(len(p.vertices) for p in o.parts)),
            "n_triangles": int(sum(len(p.triangles) for p in o.parts)),
            "materials": [asdict(p.material) for p in o.parts]}


def make_scene(out_dir: str | os.PathLike, preset: str = "bedroom", seed: int = 0, *,
               settings: SceneSettings = SceneSettings(), overwrite: bool = False,
               progress: ProgressFactory = null_progress) -> dict[str, Any]:
    """Generate a benchmark scene in the Blender format and return its scene.json record.

    Args:
        out_dir: the output folder (created; an existing non-empty one needs ``overwrite``).
        preset: ``bedroom``, ``kitchen``, ``livingroom`` or ``picnic``.
        seed: random seed; the same preset, seed and settings give bit-identical files.
        settings: image size, view counts, field of view, anti-aliasing, counts.
        overwrite: write into an existing non-empty folder.
        progress: progress factory (one bar per rendering pass).

    Raises:
        ConfigError: bad preset or settings.
        OutputError: the folder exists and is not empty without ``overwrite``.
    """
    out = prepare_output_dir(out_dir, overwrite=overwrite)
    t0 = time.perf_counter()
    scene = build_scene(preset, seed, n_objects=settings.n_objects, n_targets=settings.n_targets)
    W, H = settings.width, settings.height
    cams = training_cameras(scene, settings.train_views, W, H, fov_x_deg=settings.fov_x_deg)
    renders = render_views(scene, cams, supersample=settings.supersample, progress=progress)
    for sub in ("train", "train/masks", "train/depth", "targets"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    frame_extra = []
    for cam, r in zip(cams, renders):
        write_image(r.rgb, out / "train" / f"{cam.name}.png")
        write_image(r.ids, out / "train" / "masks" / f"{cam.name}.png")
        write_image(_depth_png(r.depth), out / "train" / "depth" / f"{cam.name}.png")
        frame_extra.append({"mask_path": f"train/masks/{cam.name}.png", "depth_path": f"train/depth/{cam.name}.png"})
    bounds = scene.bounds
    pad = 0.05 * (bounds[1] - bounds[0])
    scene_bounds = np.round(np.stack([bounds[0] - pad, bounds[1] + pad]), 6).tolist()
    common = {"background": list(scene.sky[0]),
              "scene_bounds": scene_bounds, "depth_scale": DEPTH_SCALE}
    # the environment is not one colour; "background" is the horizon colour, used only if a tool needs one
    from ..io.blender import write_blender_transforms

    write_blender_transforms(out / "transforms_train.json", cams, [f"train/{c.name}" for c in cams],
                             extra=common, frame_extra=frame_extra)
    write_json({"camera_angle_x": cams[0].fov_x, "frames": [],
                "comment": "no full-scene test views: score extraction with targets/*/transforms_test.json"},
               out / "transforms_test.json")

    target_records = []
    thumbs = []
    for k, obj in enumerate(scene.targets):
        folder = f"targets/{obj.id:02d}_{obj.name}"
        tdir = out / folder
        (tdir / "test" / "masks").mkdir(parents=True, exist_ok=True)
        tcams = target_cameras(scene, obj, settings.test_views, W, H, fov_x_deg=settings.fov_x_deg,
                               framing=settings.test_framing)
        tr = render_views(scene, tcams, object_ids=[obj.id], with_ground=False, supersample=settings.supersample,
                          background=(1.0, 1.0, 1.0), progress=progress)
        extra = []
        for cam, r in zip(tcams, tr):
            write_image(np.concatenate([r.rgb, r.alpha[..., None]], axis=2), tdir / "test" / f"{cam.name}.png")
            write_image(r.ids, tdir / "test" / "masks" / f"{cam.name}.png")
            extra.append({"mask_path": f"test/masks/{cam.name}.png"})
        write_blender_transforms(tdir / "transforms_test.json", tcams, [f"test/{c.name}" for c in tcams],
                                 extra={"background": [1.0, 1.0, 1.0], "scene_bounds": scene_bounds,
                                        "object_id": obj.id, "object_name": obj.name},
                                 frame_extra=extra)
        thumbs.append(np.where(tr[0].alpha[..., None] > 0, tr[0].rgb, 1.0))
        target_records.append({"id": obj.id, "name": obj.name, "path": folder})

    target_ids = [o.id for o in scene.targets]
    write_image(overview_image([r.rgb for r in renders], [r.ids for r in renders], target_ids,
                               target_thumbnails=thumbs), out / "overview.png")
    P = PRESETS[preset]
    record = {
        "format": SCENE_FORMAT, "version": SCENE_FORMAT_VERSION, "generator": f"roodi-toolkit {__version__}",
        "preset": preset, "description": P.description, "seed": int(seed),
        "settings": asdict(settings),
        "renderer": "open3d RaycastingScene (Embree) + Lambert/Blinn-Phong, shadow rays, one mirror bounce",
        "objects": [_object_record(o) for o in scene.objects],
        "targets": target_records,
        "lights": [asdict(li) for li in scene.lights], "ambient": list(scene.ambient), "sky": [list(c) for c in scene.sky],
        "scene_bounds": scene_bounds, "depth_scale": DEPTH_SCALE,
        "files": {"train": "transforms_train.json", "masks": "train/masks (uint8 instance ids, 0 = ground/background)",
                  "depth": "train/depth (uint16 z-depth / depth_scale, 0 = nothing hit)",
                  "targets": "targets/<id>_<name>/transforms_test.json (RGBA on white)", "overview": "overview.png"},
    }
    write_json(record, out / "scene.json")
    record["_seconds"] = time.perf_counter() - t0
    return record


def scene_from_record(record: dict[str, Any]) -> Scene:
    """Return the :class:`Scene` a scene.json record was generated from (rebuilt from preset, seed and counts)."""
    try:
        preset, seed, settings = record["preset"], int(record["seed"]), record.get("settings", {})
    except (KeyError, TypeError, ValueError):
        raise DatasetError("scene.json: missing 'preset' or 'seed'") from None
    scene = build_scene(preset, seed, n_objects=settings.get("n_objects"), n_targets=settings.get("n_targets"))
    names = [o["name"] for o in record.get("objects", [])]
    if names and names != [o.name for o in scene.objects]:
        raise DatasetError("scene.json: the objects rebuilt from its preset and seed differ from the ones it lists "
                           "(generated by another version of the generator?)")
    return scene

