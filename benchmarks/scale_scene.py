"""Build a capture at the size people bring from a real splat: copies side by side, photos rendered from it.

The splat stands for the trained scene (``--model``) and the photos are rendered from it, so model and photos agree
exactly and what an extraction gets right or wrong is the extraction's. One object of the scene is marked as the
truth: the Gaussians a rule selects in one chosen copy (``--object above:H`` for Gaussians higher than ``H`` along
``--up``: the PlayCanvas playbot's robot floats over its ground slab, ``above:0.177`` with its y-down ``--up 0,-1,0``;
no Gaussian lies between 0.148 and 0.177).

Writes ``OUT/data`` (Blender layout: ``transforms_train.json`` with ``--views`` photos on rings around the scene,
``transforms_test.json`` with ``--test-views`` held-out cameras between them), ``OUT/model`` (the splat as a
roodi-toolkit model folder: ``point_cloud/iteration_0/point_cloud.ply`` and ``cfg.json``) and ``OUT/truth.npz``
(``object``: the object's Gaussians [N] bool; ``up``: the scene's up vector).

Run: ``.venv/bin/python benchmarks/scale_scene.py /tmp/splats/playbot0/meta.json /tmp/scale/p500 --views 90
--size 800 --object above:0.177`` (``--copies 3`` for 1.5M Gaussians). The playbot comes from
github.com/playcanvas/engine, ``examples/assets/splats/playbot/0_0``.

``--place SPLAT`` sets another real splat down on the scene's ground as the object instead (turned so that its
``--place-up`` is the scene's up, ``--place-size`` across, its foot at ``--place-at`` on the surface there): an object
resting on a surface, where a click's depth fill runs on from the object onto what it stands on, unlike the floating
robot. ``--place ../shared/data/donut/point_cloud.ply`` puts the real donut (45,624 Gaussians, z up) on the playbot's
ground beside the robot. ``--neighbour-at X,Y,Z`` (repeatable) sets down more copies of it there, not part of the
object: look-alikes that touch it, which a click must leave out.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np


def tile(cloud, copies: int, gap: float = 0.1):
    """Return ``copies`` of ``cloud`` side by side along x (the middle one at the original place) and the index of the
    first Gaussian of that middle copy."""
    from roodi_toolkit.gaussians import GaussianCloud

    if copies == 1:
        return cloud, 0
    width = float(np.ptp(cloud.means[:, 0])) + gap * float(np.ptp(cloud.means[:, 0]))
    parts = []
    for k in range(copies):
        c = cloud.copy()
        c.means = c.means + np.array([(k - copies // 2) * width, 0.0, 0.0], np.float32)
        parts.append(c)
    return GaussianCloud.concatenate(parts), (copies // 2) * len(cloud)


def place_on_ground(obj, scene, up: np.ndarray, args):
    """Return the splat ``obj`` turned so that its ``--place-up`` is the scene's up, scaled to ``--place-size`` across
    and set down with its foot (its lowest 1% along up) on the scene's surface at ``--place-at`` (the 90th percentile
    height of the scene's Gaussians under its footprint), with the scene's SH degree (higher bands zero) and columns."""
    from roodi_toolkit.gaussians import GaussianCloud
    from roodi_toolkit.similarity import Similarity, rotation_between, transform_cloud

    R = rotation_between([float(v) for v in args.place_up.split(",")], up)
    turned = transform_cloud(obj, Similarity(R, np.zeros(3), 1.0))
    h = turned.means @ up
    across = turned.means - np.outer(h, up)
    scale = args.place_size / float(np.max(np.percentile(across, 99, axis=0) - np.percentile(across, 1, axis=0)))
    at = np.array([float(v) for v in args.place_at.split(",")])
    at_across = at - up * (at @ up)
    scene_h = scene.means @ up
    under = np.linalg.norm(scene.means - np.outer(scene_h, up) - at_across, axis=1) < args.place_size / 2
    if not under.any():
        raise SystemExit(f"--place-at {args.place_at}: no scene Gaussian under the object")
    ground = float(np.percentile(scene_h[under], 90))
    centre = np.median(across, axis=0)
    foot = float(np.percentile(h, 1))
    shift = at_across - scale * centre + up * (ground - scale * foot)
    placed = transform_cloud(turned, Similarity(np.eye(3), shift, scale))
    k = scene.sh_rest.shape[1]
    rest = np.zeros((len(placed), k, 3), placed.sh_rest.dtype)
    rest[:, :min(k, placed.sh_rest.shape[1])] = placed.sh_rest[:, :k]
    return GaussianCloud(placed.means.astype(scene.means.dtype), placed.quats_wxyz.astype(scene.quats_wxyz.dtype),
                         placed.log_scales.astype(scene.log_scales.dtype),
                         placed.opacity_logits.astype(scene.opacity_logits.dtype),
                         placed.sh_dc.astype(scene.sh_dc.dtype), rest.astype(scene.sh_rest.dtype),
                         {k: np.zeros(len(placed), v.dtype) for k, v in scene.extras.items()},
                         None if scene.normals is None else np.zeros((len(placed), 3), scene.normals.dtype))


def ring_cameras(center, radius, n, *, elevations, width, height, fov_deg, up, offset=0.0):
    """Return ``n`` cameras on rings at the given elevations (degrees) around ``center``, looking at it."""
    from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at

    up = np.asarray(up, float)
    ref = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    e1 = ref - up * (ref @ up)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    K = intrinsics_from_fov(math.radians(fov_deg), width, height)
    cams = []
    for i in range(n):
        elev = math.radians(elevations[i % len(elevations)])
        az = 2 * math.pi * (i + offset) / n
        d = math.cos(elev) * (math.cos(az) * e1 + math.sin(az) * e2) + math.sin(elev) * up
        eye = np.asarray(center) + radius * d
        cams.append(Camera(look_at(eye, center, up), K, width, height, 0.01, 1e4, f"r_{i}"))
    return cams


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("splat")
    ap.add_argument("out", type=Path)
    ap.add_argument("--copies", type=int, default=1)
    ap.add_argument("--gaussians", type=int, default=None,
                    help="instead of --copies: this many Gaussians (copies side by side, or a random subset)")
    ap.add_argument("--views", type=int, default=90)
    ap.add_argument("--test-views", type=int, default=12)
    ap.add_argument("--size", type=int, default=800, help="photo width and height in pixels")
    ap.add_argument("--object", default="above:0.177", help="above:H: the Gaussians higher than H along --up")
    ap.add_argument("--up", default="0,-1,0")
    ap.add_argument("--fov", type=float, default=50.0)
    ap.add_argument("--distance", type=float, default=1.6, help="camera distance in scene radii of one copy")
    ap.add_argument("--place", default=None,
                    help="another splat set down on the scene's ground as the object (instead of --object): an object "
                         "resting on a surface, the case people click most")
    ap.add_argument("--place-up", default="0,0,1", help="the placed splat's up")
    ap.add_argument("--place-at", default="0.7,0,0.55", help="where (a point of the scene) its foot goes")
    ap.add_argument("--place-size", type=float, default=0.4, help="its width across the ground, scene units")
    ap.add_argument("--neighbour-at", action="append", default=[],
                    help="a copy of the placed splat set down here too, not part of the object (repeatable): a "
                         "look-alike touching the object, as two cups side by side on a table")
    args = ap.parse_args()
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    import torch
    from PIL import Image

    from roodi_toolkit.io.blender import write_blender_transforms
    from roodi_toolkit.io.ply import write_ply
    from roodi_toolkit.gaussians import GaussianCloud
    from roodi_toolkit.io.splat import read_cloud
    from roodi_toolkit.params import GaussianParams
    from roodi_toolkit.render.renderer import NumbaRenderer

    t0 = time.perf_counter()
    one = read_cloud(args.splat)
    kind, value = args.object.split(":")
    if kind != "above":
        raise SystemExit(f"--object {args.object}: only above:Y is known")
    up = np.array([float(v) for v in args.up.split(",")])
    up /= np.linalg.norm(up)
    if args.gaussians is not None and args.gaussians < len(one):
        one = one.select(np.sort(np.random.default_rng(0).choice(len(one), args.gaussians, replace=False)))
    elif args.gaussians is not None:
        args.copies = max(1, round(args.gaussians / len(one)))
    marked = (one.means @ up) > float(value)
    cloud, start = tile(one, args.copies)
    truth = np.zeros(len(cloud), bool)
    truth[start:start + len(one)] = marked
    if args.place is not None:
        source = read_cloud(args.place)
        placed = place_on_ground(source, cloud, up, args)
        others = [place_on_ground(source, cloud, up, argparse.Namespace(**{**vars(args), "place_at": at}))
                  for at in args.neighbour_at]
        cloud = GaussianCloud.concatenate([cloud, placed, *others])
        truth = np.concatenate([np.zeros(len(truth), bool), np.ones(len(placed), bool),
                                np.zeros(sum(len(o) for o in others), bool)])
    # the cameras look at the chosen copy's object from the distance that frames its copy
    centre = cloud.means[truth].mean(axis=0)
    radius = float(np.linalg.norm(np.ptp(one.means, axis=0))) / 2 * args.distance
    train = ring_cameras(centre, radius, args.views, elevations=(15, 35, 55), width=args.size, height=args.size,
                         fov_deg=args.fov, up=up)
    test = ring_cameras(centre, radius, args.test_views, elevations=(25, 45), width=args.size, height=args.size,
                        fov_deg=args.fov, up=up, offset=0.5)
    data = args.out / "data"
    for split, cams in (("train", train), ("test", test)):
        (data / split).mkdir(parents=True, exist_ok=True)
        params = GaussianParams.from_cloud(cloud)
        renderer = NumbaRenderer()
        for cam in cams:
            with torch.no_grad():
                rgb = renderer.render(params, cam, background=(0.0, 0.0, 0.0)).rgb.numpy()
            Image.fromarray((np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8)).save(data / split / f"{cam.name}.png")
        write_blender_transforms(data / f"transforms_{split}.json", cams, [f"./{split}/{c.name}" for c in cams])
    model = args.out / "model"
    (model / "point_cloud" / "iteration_0").mkdir(parents=True, exist_ok=True)
    write_ply(cloud, model / "point_cloud" / "iteration_0" / "point_cloud.ply")
    (model / "cfg.json").write_text(json.dumps({"data_dir": str(data.resolve()), "downscale": 1,
                                                "holdout_every": 8, "source": str(args.splat),
                                                "copies": args.copies}))
    np.savez(args.out / "truth.npz", object=truth, up=up)
    print(f"{len(cloud):,} Gaussians ({args.copies} x {len(one):,}), object {int(truth.sum()):,}; "
          f"{len(train)} + {len(test)} views of {args.size} px in {time.perf_counter() - t0:.0f} s -> {args.out}")


if __name__ == "__main__":
    main()
