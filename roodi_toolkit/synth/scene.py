"""Multi-object benchmark scenes in the Blender format: cameras, and the scene folder written to disk.

The paper evaluates on MultiObjectBlender: cluttered scenes of 5 to 20 ShapeNet objects, 3 to 4 of them targets, with
each target also rendered alone so an extraction can be scored where it was hidden. Neither ShapeNet nor that dataset
can be fetched here, so this package builds equivalent scenes from procedural meshes
(:mod:`roodi_toolkit.synth.objects`), lays them out (:mod:`roodi_toolkit.synth.layout`, whose :func:`build_scene`
this module re-exports) and renders them by ray casting (:mod:`roodi_toolkit.synth.tracer`).

Layout of a generated scene (``OUT_DIR``)::

    scene.json                      objects, ids, names, targets, lights, generator settings
    transforms_train.json           the full scene, Blender format, with mask_path / depth_path per frame
    transforms_test.json            empty frame list (some tools insist on the file); scoring uses the targets
    train/r_000.png ...             RGB renders
    train/masks/r_000.png ...       8-bit instance ids (0 = ground / background, objects 1..N)
    train/depth/r_000.png ...       16-bit z-depth times ``depth_scale`` (0 = nothing hit)
    targets/03_mug/transforms_test.json, test/r_000.png (RGBA on white), test/masks/r_000.png
    targets/03_mug/test/never_seen/r_000.png   with --occluded or --never-seen: 255 where no training view sees
                                    the target's surface (:mod:`roodi_toolkit.synth.visibility`)
    overview.png                    a grid of training views with the targets outlined
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .._version import __version__
from ..cameras import Camera, intrinsics_from_fov, look_at
from ..errors import ConfigError, DatasetError
from ..io.blender import write_blender_transforms
from ..io.files import prepare_output_dir, write_image, write_json
from ..io.generated import SCENE_FILE, SCENE_FORMAT, SCENE_FORMAT_VERSION
from ..progress import ProgressFactory, null_progress
from ..settings import check_settings, documented, parse_image_size, setting, write_image_size
from .layout import build_scene
from .objects import MAX_OBJECTS, PRESETS, SceneObject
from .overview import overview_image
from .tracer import _Tracer, render_views
from .visibility import NEVER_SEEN_DIR, never_seen_record, write_never_seen
from .world import Scene

if TYPE_CHECKING:
    from ..evaluate.benchmark import BenchmarkSize

__all__ = [
    "Scene",
    "SceneSettings",
    "build_scene",
    "training_cameras",
    "target_cameras",
    "TEST_FRAMINGS",
    "make_scene",
    "make_benchmark_scene",
    "overview_image",
    "scene_from_record",
]

DEPTH_SCALE = 1e-4  # metres per 16-bit depth unit: 0.1 mm resolution, 6.5 m range (the ground is cut at that range)

# kinds that cannot be targets: furniture and flat things that are scenery rather than objects to extract
TEST_FRAMINGS = ("scene", "object")


MAX_VIEWS = 1000
"""The most views of a scene (training, or test views of each target) make-scene generates."""
MIN_SIDE, MAX_SIDE = 8, 8192
"""The smallest and largest image side of a generated scene, in pixels."""


def _parse_size(text: str) -> tuple[int, int]:
    """Return (width, height) of ``--size`` text (``WIDTHxHEIGHT`` or one number), each within the sides allowed."""
    return parse_image_size(text, MIN_SIDE, MAX_SIDE)


@documented
@dataclass(frozen=True)
class SceneSettings:
    """Generator settings recorded in scene.json; with the preset and seed they reproduce a scene bit for bit."""

    width: int = setting(200, "Image size WIDTHxHEIGHT (or one number).", low=MIN_SIDE, high=MAX_SIDE,
                         option="--size", joins=("height",), parse=_parse_size, write=write_image_size)
    height: int = setting(200, "Image height in pixels.", low=MIN_SIDE, high=MAX_SIDE, cli=False)
    train_views: int = setting(50, "Views of the full scene.", low=1, high=MAX_VIEWS)
    test_views: int = setting(50, "Views of each target alone.", low=1, high=MAX_VIEWS)
    fov_x_deg: float = setting(50.0, "Horizontal field of view of every camera, in degrees.", low=10.0, high=120.0,
                               cli=False)
    supersample: int = setting(2, "Anti-aliasing rays per pixel along each axis (masks and depth always use the "
                                  "pixel centre).", low=1, high=4)
    n_targets: int | None = setting(None, "Number of targets (default: 3 or 4).", low=1, high=4, option="--targets")
    n_objects: int | None = setting(None, "Number of objects (default: drawn from the preset's range).", low=5,
                                    high=MAX_OBJECTS, option="--objects")
    # "scene": on the training views' hemisphere, so anything kept elsewhere in the scene (floaters) shows in the
    # view; "object": a stricter test of the object's detail
    test_framing: str = setting("scene", "Test cameras: 'scene' = at the training cameras' distance, aimed at the "
                                         "target (the paper's protocol); 'object' = close-ups in which the target "
                                         "fills the frame.", choices=TEST_FRAMINGS)
    # the wraps are build_scene's; implies never_seen
    occluded: bool = setting(False, "The occluded variant: 4 targets (default), each standing in a wrap that touches "
                                    "it (a box or sleeve open at the top, or a bowl) and hides its lower part from "
                                    "every training view; writes the never-seen masks.")
    # the masks are roodi_toolkit.synth.visibility's
    never_seen: bool = setting(False, "Write each target's never-seen masks (test-view pixels no training view "
                                      "sees) and their share (always on with --occluded).")

    @property
    def writes_never_seen(self) -> bool:
        """Whether make-scene computes and writes the never-seen masks."""
        return self.occluded or self.never_seen

    def record(self) -> dict[str, Any]:
        """Return the settings as scene.json records them: the variant flags only when set, so a scene of the plain
        presets keeps the record (and the bytes) it had before they existed."""
        return {k: v for k, v in asdict(self).items() if v or k not in ("occluded", "never_seen")}

    def __post_init__(self) -> None:
        check_settings(self)


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


# ------------------------------------------------------------------------------------------------------ writing


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
    scene = build_scene(preset, seed, n_objects=settings.n_objects, n_targets=settings.n_targets,
                        occluded=settings.occluded)
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
    write_blender_transforms(out / "transforms_train.json", cams, [f"train/{c.name}" for c in cams],
                             extra=common, frame_extra=frame_extra)
    write_json({"camera_angle_x": cams[0].fov_x, "frames": [],
                "comment": "no full-scene test views: score extraction with targets/*/transforms_test.json"},
               out / "transforms_test.json")

    target_records = []
    thumbs = []
    full_tracer = None
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
        never_seen: dict[str, Any] = {}
        if settings.writes_never_seen:  # the masks, and each frame's never_seen_path in ``extra``
            full_tracer = full_tracer or _Tracer(scene, None, True)
            never_seen = write_never_seen(tdir, scene, obj.id, tcams, tr, cams, extra, full_tracer)
        write_blender_transforms(tdir / "transforms_test.json", tcams, [f"test/{c.name}" for c in tcams],
                                 extra={"background": [1.0, 1.0, 1.0], "scene_bounds": scene_bounds,
                                        "object_id": obj.id, "object_name": obj.name},
                                 frame_extra=extra)
        thumbs.append(np.where(tr[0].alpha[..., None] > 0, tr[0].rgb, 1.0))
        target_records.append({"id": obj.id, "name": obj.name, "path": folder, **never_seen})

    target_ids = [o.id for o in scene.targets]
    write_image(overview_image([r.rgb for r in renders], [r.ids for r in renders], target_ids,
                               target_thumbnails=thumbs), out / "overview.png")
    P = PRESETS[preset]
    record = {
        "format": SCENE_FORMAT, "version": SCENE_FORMAT_VERSION, "generator": f"roodi-toolkit {__version__}",
        "preset": preset, "description": P.description, "seed": int(seed),
        "settings": settings.record(),
        "renderer": "open3d RaycastingScene (Embree) + Lambert/Blinn-Phong, shadow rays, one mirror bounce",
        "objects": [_object_record(o) for o in scene.objects],
        "targets": target_records,
        "lights": [asdict(li) for li in scene.lights], "ambient": list(scene.ambient), "sky": [list(c) for c in scene.sky],
        "scene_bounds": scene_bounds, "depth_scale": DEPTH_SCALE,
        "files": {"train": "transforms_train.json", "masks": "train/masks (uint8 instance ids, 0 = ground/background)",
                  "depth": "train/depth (uint16 z-depth / depth_scale, 0 = nothing hit)",
                  "targets": "targets/<id>_<name>/transforms_test.json (RGBA on white)", "overview": "overview.png"},
    }
    if settings.writes_never_seen:
        record["files"]["never_seen"] = (f"targets/<id>_<name>/{NEVER_SEEN_DIR} (uint8, 255 = the target's surface "
                                         "at this pixel is seen by no training view)")
        record["never_seen"] = never_seen_record()
    write_json(record, out / SCENE_FILE)
    record["_seconds"] = time.perf_counter() - t0
    return record


def make_benchmark_scene(out_dir: str | os.PathLike, preset: str, seed: int, size: "BenchmarkSize",
                         occluded: bool = False, progress: ProgressFactory = null_progress) -> dict[str, Any]:
    """Generate the scene the benchmark runs on at ``size`` (its image side, view counts and anti-aliasing) and
    return its scene.json record: the ``make_scene`` that :func:`roodi_toolkit.evaluate.benchmark.run_benchmark`
    is given by its callers (``roodi-toolkit benchmark``), the generator being on the floor above the benchmark's."""
    settings = SceneSettings(width=size.size, height=size.size, train_views=size.train_views,
                             test_views=size.test_views, supersample=size.supersample, occluded=occluded)
    return make_scene(out_dir, preset, seed, settings=settings, progress=progress)


def scene_from_record(record: dict[str, Any]) -> Scene:
    """Return the :class:`Scene` a scene.json record was generated from (rebuilt from preset, seed and counts)."""
    try:
        preset, seed, settings = record["preset"], int(record["seed"]), record.get("settings", {})
    except (KeyError, TypeError, ValueError):
        raise DatasetError("scene.json: missing 'preset' or 'seed'") from None
    scene = build_scene(preset, seed, n_objects=settings.get("n_objects"), n_targets=settings.get("n_targets"),
                        occluded=bool(settings.get("occluded", False)))
    names = [o["name"] for o in record.get("objects", [])]
    if names and names != [o.name for o in scene.objects]:
        raise DatasetError("scene.json: the objects rebuilt from its preset and seed differ from the ones it lists "
                           "(generated by another version of the generator?)")
    return scene
