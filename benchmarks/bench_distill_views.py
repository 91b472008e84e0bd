"""What distilling from fewer views loses: the object selected after distilling its true masks from K training views
spread round the scene (``DistillConfig.max_views``), from the first K in file order, and from all of them.

The scene is a folder of ``benchmarks/scale_scene.py`` (``data/``, ``model/``, ``truth.npz``). Each view's mask is
the true object's share of its rendered alpha (> 0.5, at the working size), so that what differs between the runs is
the views alone, not a segmenter's mistakes. Every run caches all its views' weights (``cache_mb`` 9000: all 90 views
of a 650k scene hold 5.7 GB), so the times compare the steps, not the cache's reach. The selection (probability
> 0.3, then the default outlier removal) is scored as ``bench_scale.py`` scores an extraction: IoU of alpha > 0.5 and
PSNR of the colours against the true object, from the held-out cameras at full size.

    .venv/bin/python benchmarks/bench_distill_views.py /tmp/scale/biker500 --runs spread:16,spread:32,first:32,all
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))


def true_masks(cloud, truth: np.ndarray, cameras) -> np.ndarray:
    """Return ``[V, H, W]`` uint8: 1 where the true object holds more than half of the rendered alpha."""
    import torch

    from roodi_toolkit.params import GaussianParams
    from roodi_toolkit.pipeline.distill import render_features

    params = GaussianParams.from_cloud(cloud, sh_degree=0)
    both = torch.from_numpy(np.stack([truth, np.ones_like(truth)], 1).astype(np.float32))
    out = []
    with torch.no_grad():
        for cam in cameras:
            r = render_features(params, both, cam).numpy()
            out.append(((r[..., 0] > 0.5 * r[..., 1]) & (r[..., 1] > 1 / 255)).astype(np.uint8))
    return np.stack(out)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("--runs", default="spread:32,first:32,all",
                    help="comma-separated: spread:K (K views spread round the scene), first:K, all")
    ap.add_argument("--iterations", type=int, default=500)
    args = ap.parse_args(argv)

    import torch

    from bench_scale import object_scores
    from roodi_toolkit.cameras import spread_cameras
    from roodi_toolkit.io.dataset import load_cameras, load_dataset
    from roodi_toolkit.io.model import find_model
    from roodi_toolkit.io.ply import read_ply
    from roodi_toolkit.pipeline.distill import DistillConfig, distill_object_features, with_features
    from roodi_toolkit.pipeline.resolution import working_dataset
    from roodi_toolkit.pipeline.segment import ViewMasks
    from roodi_toolkit.pipeline.select import select_object

    cloud = read_ply(find_model(args.scene / "model").ply_path)
    truth = np.load(args.scene / "truth.npz")["object"]
    work, _ = working_dataset(load_dataset(args.scene / "data"), DistillConfig().max_pixels)
    masks = ViewMasks(torch.from_numpy(true_masks(cloud, truth, work.cameras)), work.names, "binary", 2)
    test = load_cameras(args.scene / "data", splits=["test"])
    train = work.train_indices
    for run in args.runs.split(","):
        how, _, k = run.partition(":")
        if how == "all":
            views = train
        elif how == "spread":
            views = [train[i] for i in spread_cameras([work.cameras[v] for v in train], int(k))]
        elif how == "first":
            views = train[:int(k)]
        else:
            raise SystemExit(f"unknown run {run!r}: spread:K, first:K or all")
        t0 = time.perf_counter()
        result = distill_object_features(cloud, work, masks, DistillConfig(iterations=args.iterations, max_views=0,
                                                                           cache_mb=9000), train_views=views)
        seconds = time.perf_counter() - t0
        sel = select_object(with_features(cloud, result.features), result.classifier, 1)
        iou, psnr = object_scores(sel.cloud, cloud.select(truth), test)
        print(json.dumps({"run": run, "views": len(views), "of": len(train), "cached": result.cached_views,
                          "cache_mb": round(result.cache_mb), "seconds": round(seconds, 1),
                          "final_loss": round(result.history[-1]["loss"], 4), "selected": len(sel.cloud),
                          "iou": round(iou, 4), "psnr": round(psnr, 2)}), flush=True)


if __name__ == "__main__":
    main()
