"""Distillation and selection on a generated scene: held-out class-map IoU, click-segmenter mask IoU, object alpha IoU.

Usage:
    .venv/bin/python benchmarks/bench_distill.py MODEL_DIR DATA_DIR [--iterations 500] [--click-view r_000]
        [--no-click | --click-only]

MODEL_DIR is a `roodi-toolkit train` output of the generated scene DATA_DIR (`roodi-toolkit make-scene`); it is
copied, never modified. Prints one JSON summary.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("model_dir")
    ap.add_argument("data_dir")
    ap.add_argument("--iterations", type=int, default=500)
    ap.add_argument("--click-view", default=None, help="view to click each target in (default: where it is largest)")
    ap.add_argument("--no-click", action="store_true")
    ap.add_argument("--click-only", action="store_true", help="skip distillation; measure the click segmenter only")
    args = ap.parse_args()
    import os

    import torch

    torch.set_num_threads(int(os.environ.get("ROODI_THREADS", "1")))  # as the CLI does; 2 threads are slower here

    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.io.files import read_json
    from roodi_toolkit.io.model import find_model
    from roodi_toolkit.io.ply import read_ply
    from roodi_toolkit.evaluate.metrics import alpha_iou
    from roodi_toolkit.pipeline.distill import DistillConfig
    from roodi_toolkit.run.distill import load_distillation, run_distill
    from roodi_toolkit.pipeline.select import select_object

    data = Path(args.data_dir)
    record = read_json(data / "scene.json")
    if args.click_only:
        found = find_model(Path(args.model_dir))
        scale = float(found.config.get("downscale", 1) or 1)
        ds = load_dataset(data, scale)
        scene = read_ply(found.ply_path)
        out = {"model": args.model_dir, "gaussians": len(scene), "targets": {}}
        for t in record["targets"]:
            tid = int(t["id"])
            out["targets"][f"{tid}_{t['name']}"] = {"click": _click_scores(ds, tid, scene, args.click_view)}
        print(json.dumps(out, indent=1))
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        model = Path(args.model_dir)  # only read: the distillation goes to a folder of its own
        t0 = time.perf_counter()
        summary = run_distill(model, data, Path(tmp) / "distill", config=DistillConfig(iterations=args.iterations))
        total = time.perf_counter() - t0
        _, cloud, classifier = load_distillation(Path(tmp) / "distill")
        out = {"model": args.model_dir, "gaussians": len(cloud), "iterations": args.iterations,
               "distill_seconds_optimisation": round(summary["seconds"], 1), "distill_seconds_command": round(total, 1),
               "held_out_views": len(summary["held_out"]["views"]),
               "held_out_mean_iou": round(summary["held_out"]["mean_iou"], 4),
               "held_out_per_object": {k: round(v, 3) for k, v in summary["held_out"]["per_object"].items()},
               "targets": {}}
        ds = load_dataset(data, float(summary["downscale"]))
        for t in record["targets"]:
            tid = int(t["id"])
            tds = load_dataset(data / t["path"], float(summary["downscale"]))
            res = {}
            for prune in (False, True):
                sel = select_object(cloud, classifier, tid, prune=prune)
                ious = alpha_iou(sel.cloud, tds.cameras, tds.alphas)
                res["pruned" if prune else "unpruned"] = {"gaussians": len(sel.cloud),
                                                           "alpha_iou": round(float(np.mean(ious)), 4)}
            held = summary["held_out"]["per_object"].get(str(tid))
            res["held_out_class_iou"] = None if held is None else round(held, 4)
            if not args.no_click:
                res["click"] = _click_scores(ds, tid, read_ply(find_model(model).ply_path), args.click_view)
            out["targets"][f"{tid}_{t['name']}"] = res
    print(json.dumps(out, indent=1))
    return 0


def _click_scores(ds, tid: int, scene, click_view) -> dict:
    """Return the click segmenter's mask IoU against the true masks of target ``tid`` over the views that show it."""
    from roodi_toolkit.imaging import mask_iou
    from roodi_toolkit.pipeline.segment import Click, SegmentPrompt, get_segmenter

    areas = (ds.masks == tid).flatten(1).sum(1)
    v = int(areas.argmax()) if click_view is None else ds.names.index(click_view)
    ys, xs = np.nonzero((ds.masks[v] == tid).numpy())
    k = int(np.argmin((ys - ys.mean()) ** 2 + (xs - xs.mean()) ** 2))  # the mask pixel nearest its centroid
    click = Click(ds.names[v], xs[k] + 0.5, ys[k] + 0.5)
    t1 = time.perf_counter()
    masks = get_segmenter("click").segment(ds, SegmentPrompt((click,)), scene=scene)
    secs = time.perf_counter() - t1
    ious = [mask_iou(masks.masks[i] == 1, ds.masks[i] == tid) for i in range(len(ds)) if (ds.masks[i] == tid).any()]
    return {"click": f"{click.view}:{click.x:g},{click.y:g}", "mean_iou": round(float(np.mean(ious)), 4),
            "median_iou": round(float(np.median(ious)), 4), "views": len(ious), "seconds": round(secs, 1)}


if __name__ == "__main__":
    sys.exit(main())
