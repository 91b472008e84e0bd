"""Extraction of a real object from a capture without masks (issue 20): time `extract --click` end to end from a
trained model, and score the object's alpha from the held-out cameras against hand-drawn polygon masks.

    .venv/bin/python benchmarks/bench_real_extract.py MODEL_DIR OUT_DIR --click 520,560 --view DSC_5284 \
        [--negative-click X,Y ...] [--polygons tests/data/statue_masks/polygons.json] [EXTRA extract OPTIONS]

Runs ``roodi-toolkit extract OUT_DIR --model MODEL_DIR --click ...`` (skipped with ``--score-only``), then renders
``OUT_DIR/object_1/object.ply`` and the whole scene from the cameras of the polygons' views (the held-out photos) and
prints, per view, the alpha IoU (alpha >= 0.5) against the polygon mask, for the object and, as the reference of
selecting nothing, for the whole scene. Writes ``OUT_DIR/bench_real_extract.png`` (per view: the photo with the
polygon outlined, the object's render on black, the object's alpha outlined in the photo) and
``OUT_DIR/bench_real_extract.json``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _outline(mask: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    return mask & ~ndimage.binary_erosion(mask)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model_dir")
    ap.add_argument("out_dir")
    ap.add_argument("--click", action="append", default=[])
    ap.add_argument("--negative-click", action="append", default=[])
    ap.add_argument("--view", default=None)
    ap.add_argument("--polygons", default=str(ROOT / "tests" / "data" / "statue_masks" / "polygons.json"))
    ap.add_argument("--score-only", action="store_true", help="score an existing OUT_DIR, do not run extract")
    args, extra = ap.parse_known_args(argv)  # the rest goes to extract as it is

    from roodi_toolkit.evaluate.polygons import polygon_masks
    from roodi_toolkit.io.polygons import read_polygons
    from roodi_toolkit.imaging import mask_iou
    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.io.files import write_image, write_json
    from roodi_toolkit.io.model import find_model
    from roodi_toolkit.io.ply import read_ply
    from roodi_toolkit.render.renderer import render_cloud

    out = Path(args.out_dir)
    seconds = None
    if not args.score_only:
        cmd = [str(Path(sys.executable).parent / "roodi-toolkit"), "extract", str(out), "--model", args.model_dir, "-q"]
        for c in args.click:
            cmd += ["--click", c]
        for c in args.negative_click:
            cmd += ["--negative-click", c]
        if args.view:
            cmd += ["--view", args.view]
        cmd += [a for a in extra if a != "--"]
        print("$", " ".join(cmd), flush=True)
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True)
        seconds = time.perf_counter() - t0
        print(f"extract: {seconds / 60:.1f} min end to end", flush=True)

    model = find_model(args.model_dir)
    ds = load_dataset(model.config["data_dir"], float(model.config.get("downscale", 1) or 1))
    masks = polygon_masks(ds, read_polygons(args.polygons))
    obj = read_ply(out / "object_1" / "object.ply")
    scene = read_ply(model.ply_path)
    rows, tiles = [], []
    for name, truth in masks.items():
        cam = ds.cameras[ds.names.index(name)]
        r_obj = render_cloud(obj, cam)
        a_obj = r_obj.alpha[..., 0].numpy() >= 0.5
        a_scene = render_cloud(scene, cam).alpha[..., 0].numpy() >= 0.5
        rows.append({"view": name, "object_iou": mask_iou(a_obj, truth), "scene_iou": mask_iou(a_scene, truth),
                     "truth_pixels": int(truth.sum()), "object_pixels": int(a_obj.sum())})
        photo = ds.images[ds.names.index(name)].numpy().copy()
        with_truth = photo.copy()
        with_truth[_outline(truth)] = (1.0, 0.0, 0.0)
        with_obj = photo * 0.35
        with_obj[a_obj] = photo[a_obj]
        with_obj[_outline(truth)] = (1.0, 0.0, 0.0)
        tiles.append(np.concatenate([with_truth, r_obj.rgb.clamp(0, 1).numpy(), with_obj], axis=1))
    mean = float(np.mean([r["object_iou"] for r in rows]))
    print(f"{'view':<12} {'object IoU':>10} {'scene IoU':>10}")
    for r in rows:
        print(f"{r['view']:<12} {r['object_iou']:>10.4f} {r['scene_iou']:>10.4f}")
    print(f"{'mean':<12} {mean:>10.4f} {np.mean([r['scene_iou'] for r in rows]):>10.4f}")
    write_image(np.concatenate(tiles, axis=0), out / "bench_real_extract.png")
    write_json({"extract_seconds": seconds, "views": rows, "mean_object_iou": mean, "object_gaussians": len(obj),
                "scene_gaussians": len(scene), "clicks": args.click, "negative_clicks": args.negative_click,
                "view": args.view}, out / "bench_real_extract.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
