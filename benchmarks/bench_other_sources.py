"""Captures and models as people bring them, on the real statue: its COLMAP capture written as ns-process-data writes
it, a scene trained here given back as another tool's model (a bare PLY, an Inria folder, a gsplat checkpoint, a
nerfstudio export), each checked against the data's cameras and photos in the right frame and in a wrong one.

    .venv/bin/python benchmarks/bench_other_sources.py OUT [--model MODEL_DIR] [--iterations 300] [--downscale 8]

OUT gets the nerfstudio capture (its images a link to the statue's) and, without --model, a model trained here
(COLMAP, at 1/downscale). Prints one line per case: kind, data, share of Gaussians in view, squared error of the renders
against an empty picture's (the ratio must be < 0.1), and the decision with its reason.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

STATUE = ROOT.parent / "shared" / "data" / "statue"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--iterations", type=int, default=300)
    ap.add_argument("--downscale", type=float, default=8.0)
    args = ap.parse_args()
    warnings.simplefilter("ignore")

    from roodi_toolkit.errors import RoodiError
    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.io.model import ModelFolder, find_model, open_model
    from roodi_toolkit.io.gsplat import gsplat_frames
    from roodi_toolkit.io.other_models import seen_fraction
    from roodi_toolkit.io.ply import write_ply
    from roodi_toolkit.run.distill import check_model_frame
    from roodi_toolkit.pipeline.train import TrainConfig
    from roodi_toolkit.run.train import train_scene
    from roodi_toolkit.similarity import Similarity, transform_cloud
    from tests.io.test_nerfstudio import ns_process_data
    from tests.io.test_other_models import write_gsplat, write_inria

    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    ns = out / "statue_ns"
    if not ns.exists():
        ns_process_data(STATUE, ns)
    applied = Similarity.from_matrix(json.loads((ns / "transforms.json").read_text())["applied_transform"])

    t = time.perf_counter()
    ds_colmap = load_dataset(STATUE, 4)
    t_colmap = time.perf_counter() - t
    t = time.perf_counter()
    ds_ns = load_dataset(ns, 4)
    t_ns = time.perf_counter() - t
    same = bool((ds_colmap.images == ds_ns.images).all())
    print(f"load at 1/4: COLMAP {t_colmap:.2f} s, nerfstudio {t_ns:.2f} s; identical pixels: {same}; "
          f"points moved by applied_transform: max {np.abs(ds_ns.points - applied.apply(ds_colmap.points)).max():.2g}")

    render_equivalence(ns, applied)

    model_dir = args.model
    if model_dir is None:
        model_dir = out / "model"
        if not (model_dir / "cfg.json").is_file():
            from roodi_toolkit.pipeline.strategy import MCMCStrategy

            t = time.perf_counter()
            train_scene(STATUE, model_dir, TrainConfig(iterations=args.iterations, eval_every=0,
                                                       init_num_points=8000, strategy=MCMCStrategy(cap_max=20000)),
                        downscale=args.downscale)
            print(f"trained {args.iterations} steps at 1/{args.downscale:g} in {time.perf_counter() - t:.0f} s")
    scene = find_model(model_dir).read_cloud()
    ds8 = {"colmap": load_dataset(STATUE, args.downscale), "nerfstudio": load_dataset(ns, args.downscale)}
    data = {"colmap": STATUE, "nerfstudio": ns}

    def case(label: str, make) -> None:
        try:
            model = make()
            which = "nerfstudio" if str(model.config.get("data_dir", "")).startswith(str(ns)) else "colmap"
            cams = ds8[which].cameras
            seen = seen_fraction(model.read_cloud(), cams)
            report = check_model_frame(model, ds8[which])
            ratio = report["model_check_error"] / report["model_check_empty"]
            print(f"{label}: accepted; {100 * seen:.0f}% in view, error {ratio:.4f} of an empty picture's")
        except RoodiError as exc:
            print(f"{label}: refused: {exc}")

    ply = out / "scene_colmap.ply"
    write_ply(scene, ply)
    ply_ns = out / "scene_ns.ply"
    write_ply(transform_cloud(scene, applied), ply_ns)
    case("bare PLY, COLMAP frame, COLMAP data", lambda: open_model(ply, data["colmap"]))
    case("bare PLY moved by applied_transform, nerfstudio data", lambda: open_model(ply_ns, data["nerfstudio"]))
    case("bare PLY, COLMAP frame, nerfstudio data", lambda: open_model(ply, data["nerfstudio"]))
    inria = out / "inria"
    if not inria.exists():
        write_inria(inria, STATUE, scene)
    case("Inria folder, its data (cfg_args)", lambda: open_model(inria))
    case("Inria folder, nerfstudio data", lambda: open_model(inria, data["nerfstudio"]))
    gs = out / "gsplat"
    if not gs.exists():
        write_gsplat(gs, scene, gsplat_frames(STATUE / "sparse" / "0")[0], STATUE)
    case("gsplat checkpoint, its data (cfg.yml)", lambda: open_model(gs))
    back = open_model(gs).read_cloud()
    print(f"gsplat round trip: means within {np.abs(back.means - scene.means).max():.2g} of the trained scene")
    # a nerfstudio export: the data parser's transform of nerfstudio's defaults (orient 'up', centre 'poses', scale)
    from roodi_toolkit.similarity import rotation_between

    c2w = np.stack([np.linalg.inv(c.world_to_camera) for c in ds8["nerfstudio"].cameras])
    up = -c2w[:, :3, 1].mean(0)  # the OpenCV y axis points down: nerfstudio's up is the mean of -y
    R = rotation_between(up, (0.0, 0.0, 1.0))
    t = -R @ c2w[:, :3, 3].mean(0)
    orient = Similarity(R, t)
    scale = 1.0 / np.abs(orient.apply(c2w[:, :3, 3])).max()
    export = transform_cloud(transform_cloud(scene, applied), orient.then(Similarity(scale=scale)))
    write_ply(export, out / "splat.ply")
    (out / "dataparser_transforms.json").write_text(json.dumps(
        {"transform": (orient.matrix() @ applied.matrix())[:3].tolist(), "scale": scale}))
    case("nerfstudio export with its dataparser_transforms.json, nerfstudio data",
         lambda: open_model(out / "splat.ply", data["nerfstudio"],
                            dataparser_transforms=out / "dataparser_transforms.json"))
    case("nerfstudio export without its transform, nerfstudio data",
         lambda: open_model(out / "splat.ply", data["nerfstudio"]))


def render_equivalence(ns: Path, applied) -> None:
    """Render an SH-3 cloud on the statue from all 23 cameras at 200 px in the COLMAP frame and, moved by
    ``applied_transform``, from the nerfstudio cameras; and the same cloud with its means nudged by 1e-7 (float32
    rounding alone) in the COLMAP frame."""
    from roodi_toolkit.io.colmap import read_colmap_model
    from roodi_toolkit.io.dataset import load_cameras
    from roodi_toolkit.render.renderer import render_cloud
    from roodi_toolkit.similarity import transform_cloud
    from tests.conftest import make_cloud

    colmap = {c.name: c for c in load_cameras(STATUE)}
    pts = read_colmap_model(STATUE / "sparse" / "0").points.xyz
    cloud = make_cloud(3000, sh_degree=3, seed=4)
    rng = np.random.default_rng(4)
    cloud.means[:] = pts[rng.integers(0, len(pts), 3000)] + rng.normal(0, 0.02, (3000, 3))
    cloud.log_scales[:] = np.log(0.01)
    cloud.sh_rest *= 0.3
    moved = transform_cloud(cloud, applied)
    nudged = cloud.copy()
    nudged.means = (nudged.means.astype(np.float64) * (1 + 1e-7)).astype(np.float32)
    worst = nudge = 0.0
    flipped = 0
    for cam in load_cameras(ns / "transforms.json"):
        ref = colmap[cam.name]
        size = (200, round(200 * ref.height / ref.width))
        a = render_cloud(cloud, ref.with_size(*size), sh_degree=3).rgb
        d = (a - render_cloud(moved, cam.with_size(*size), sh_degree=3).rgb).abs()
        worst, flipped = max(worst, float(d.max())), flipped + int((d > 1e-4).sum())
        nudge = max(nudge, float((a - render_cloud(nudged, ref.with_size(*size), sh_degree=3).rgb).abs().max()))
    print(f"23 views at 200 px, COLMAP frame against nerfstudio frame: largest difference {worst:.2g}, "
          f"{flipped} pixel values over 1e-4; means nudged by 1e-7 in the COLMAP frame: largest difference "
          f"{nudge:.2g}")


if __name__ == "__main__":
    main()
