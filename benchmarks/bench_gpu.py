"""Benchmark: the gsplat (CUDA) renderer plugin against the built-in numba renderer on one scene (issue 33 item 7).

``agree SCENE`` takes a capture built by ``benchmarks/scale_scene.py`` and, for its held-out cameras, renders the
model (the real splat) with both renderers, as the pipeline calls them (parameters on the CPU, results back on the
CPU). It prints their agreement: PSNR of gsplat's RGB against numba's, the largest and mean absolute differences of
RGB and alpha, the IoU of alpha > 0.5, and the median wall-clock times of a forward and of a forward+backward render
(loss = sum of RGB), numba on all the machine's cores and gsplat with the GPU synchronised, side by side in one
process. The extraction itself runs through ``bench_scale.py run SCENE --renderer gsplat``; ``benchmarks/gpu/run.sh``
does both on a GPU machine.

Run (on a machine with CUDA and gsplat):
    python3 benchmarks/bench_gpu.py agree /tmp/p500 --repeats 5
(``--against torch`` runs the same comparison on a CPU-only machine.)
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _timed(fn, repeats: int, sync) -> float:
    times = []
    for _ in range(repeats):
        sync()
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _depth_rel(a, b) -> float:
    """The largest relative difference of the expected depths where both alphas exceed 0.5."""
    both = (a.alpha[..., 0] > 0.5) & (b.alpha[..., 0] > 0.5)
    if not bool(both.any()):
        return 0.0
    da, db = a.depth[..., 0][both], b.depth[..., 0][both]
    return float(((da - db).abs() / da.abs().clamp_min(1e-6)).max())


def agree(scene: Path, repeats: int, cameras: int, other: str = "gsplat") -> dict:
    sys.path.insert(0, str(ROOT))
    import numba
    import torch

    from roodi_toolkit.imaging import mask_iou
    from roodi_toolkit.io.dataset import load_cameras
    from roodi_toolkit.io.model import find_model
    from roodi_toolkit.io.ply import read_ply
    from roodi_toolkit.params import GaussianParams
    from roodi_toolkit.render.renderer import get_renderer

    cloud = read_ply(find_model(scene / "model").ply_path)
    test = load_cameras(scene / "data", splits=["test"])[:cameras]
    renderers = {"numba": get_renderer("numba"), other: get_renderer(other)}
    gpu = torch.cuda.is_available()
    sync = {"numba": lambda: None, other: torch.cuda.synchronize if gpu else (lambda: None)}
    g = GaussianParams.from_cloud(cloud)
    rows = []
    with torch.no_grad():
        for cam in test:
            out = {k: r.render(g, cam) for k, r in renderers.items()}
            a, b = out["numba"], out[other]
            mse = float(((a.rgb.clamp(0, 1) - b.rgb.clamp(0, 1)) ** 2).mean())
            rows.append({"camera": cam.name,
                         "psnr_rgb": 10 * np.log10(1.0 / max(mse, 1e-20)),
                         "max_rgb": float((a.rgb - b.rgb).abs().max()),
                         "mean_rgb": float((a.rgb - b.rgb).abs().mean()),
                         "max_alpha": float((a.alpha - b.alpha).abs().max()),
                         "mean_alpha": float((a.alpha - b.alpha).abs().mean()),
                         "iou_alpha": mask_iou(a.alpha[..., 0].numpy() > 0.5, b.alpha[..., 0].numpy() > 0.5),
                         "max_depth_rel": _depth_rel(a, b)})
    cam = test[0]
    times = {}
    for name, r in renderers.items():
        with torch.no_grad():
            r.render(g, cam)  # warm up (compilation, CUDA context)
            fwd = _timed(lambda: r.render(g, cam), repeats, sync[name])

        def fwd_bwd(r=r):
            p = GaussianParams.from_cloud(cloud, requires_grad=True)
            out = r.render(p, cam)
            out.rgb.sum().backward()

        fwd_bwd()
        times[name] = {"fwd_s": fwd, "fwd_bwd_s": _timed(fwd_bwd, repeats, sync[name])}
    result = {"gaussians": len(cloud), "size": [cam.width, cam.height], "cameras": len(rows),
              "threads": torch.get_num_threads(), "numba_threads": numba.get_num_threads(), "gpu": torch.cuda.get_device_name(0) if gpu else None,
              "against": other,
              "agreement": {k: (min if k.startswith("psnr") or k.startswith("iou") else max)(r[k] for r in rows)
                            for k in rows[0] if k != "camera"},
              "per_camera": rows, "times": times,
              "ratio_fwd": times["numba"]["fwd_s"] / times[other]["fwd_s"],
              "ratio_fwd_bwd": times["numba"]["fwd_bwd_s"] / times[other]["fwd_bwd_s"]}
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("agree", help="render the held-out cameras with numba and gsplat; agreement and times")
    a.add_argument("scene", type=Path)
    a.add_argument("--repeats", type=int, default=5)
    a.add_argument("--cameras", type=int, default=12)
    a.add_argument("--against", default="gsplat", help="the registered renderer compared with numba (default gsplat)")
    args = ap.parse_args()
    res = agree(args.scene, args.repeats, args.cameras, args.against)
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
