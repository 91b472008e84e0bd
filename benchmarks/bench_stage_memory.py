"""Benchmark: the peak memory of one rendering and its backward pass against the estimate the stages check before they
start (``roodi_toolkit/pipeline/budget.py``, issue 33 item 6).

Each case runs in a process of its own: it renders a 50-Gaussian cloud first (compiling the kernels), builds the
parameters, then measures the rise of the peak resident set size over the resident size just before one rendering and
its backward (loss = sum of RGB + depth). Cases: random Gaussians (SH 0, scale e^-4 around a unit ball) at
1M and 2M on a 32x32 view (the per-Gaussian share), 2,000 at 2000x2000 (the per-pixel share), 500k at 800x800 (a deep
view), the same rendering 16 features of frozen geometry (distillation's pass), a training step (SH 3, Adam) at 1M
Gaussians on 32x32 and 300k on 800x800, and with ``--splat``
a real splat seen from its orbit camera at 800x800 (tile lists of a real view). Prints the measured rise, the
estimate (``budget.render_pass_bytes``) and their ratio (estimate / measured: at least 1 is what the checks need).

Run: ``.venv/bin/python benchmarks/bench_stage_memory.py --splat /tmp/splats/playbot0/meta.json``
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FEATURES = 16


def one(kind: str, n: int, size: int) -> dict:
    import gc
    import resource

    import numpy as np
    import torch

    sys.path.insert(0, str(ROOT))
    from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
    from roodi_toolkit.gaussians import GaussianCloud
    from roodi_toolkit.params import GaussianParams
    from roodi_toolkit.pipeline.budget import render_pass_bytes
    from roodi_toolkit.render.renderer import get_renderer

    def random_cloud(m: int) -> GaussianCloud:
        rng = np.random.default_rng(0)
        return GaussianCloud.from_activated(rng.normal(size=(m, 3)) * 0.5, scales=np.exp(rng.normal(-4.0, 0.3, (m, 3))),
                                            opacities=rng.uniform(0.05, 0.6, m), rgb=rng.uniform(0, 1, (m, 3)),
                                            quats_wxyz=rng.normal(size=(m, 4)))

    r = get_renderer("numba")
    features = kind == "features"  # distillation's pass: 16 features of frozen geometry, their gradient only
    if kind == "train":
        return one_training_step(n, size)
    if kind in ("random", "features"):
        cloud = random_cloud(n)
        cam = Camera(look_at([0, -3, 1], [0, 0, 0]), intrinsics_from_fov(math.radians(50), size, size), size, size)
    else:
        from roodi_toolkit.io.splat import read_cloud
        from roodi_toolkit.render.views import framing_orbit

        cloud = read_cloud(kind)
        cam = framing_orbit(cloud, 1, width=size, height=size, up=(0.0, -1.0, 0.0))[0]
    warm = GaussianParams.from_cloud(random_cloud(50), requires_grad=True)
    out = r.render(warm, cam)
    out.rgb.sum().backward()
    g = GaussianParams.from_cloud(cloud, requires_grad=True)
    del out, warm
    gc.collect()
    with open("/proc/self/statm") as fh:
        before = int(fh.read().split()[1]) * 4096
    if features:
        g = GaussianParams.from_cloud(cloud)
        feats = torch.zeros(len(cloud), FEATURES, requires_grad=True)
        gc.collect()
        with open("/proc/self/statm") as fh:
            before = int(fh.read().split()[1]) * 4096
        image, _ = r.render_features(g, feats, cam)
        image.sum().backward()
    else:
        out = r.render(g, cam)
        (out.rgb.sum() + out.depth.sum()).backward()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    estimate = render_pass_bytes(len(cloud), cam.width * cam.height, sh_coeffs=(g.sh_degree + 1) ** 2,
                                 channels=FEATURES if features else 3)
    return {"case": kind if kind in ("random", "features") else Path(kind).parent.name, "gaussians": len(cloud),
            "size": f"{cam.width}x{cam.height}", "sh_degree": g.sh_degree, "measured_mb": (peak - before) / 2**20,
            "estimate_mb": estimate / 2**20, "ratio": estimate / max(1.0, peak - before)}


def one_training_step(n: int, size: int) -> dict:
    """The peak of a training step at ``n`` Gaussians of SH degree 3 (what densification grows to): the parameters,
    their gradients, one fused Adam per parameter as the trainer makes them, and a rendering with its backward."""
    import gc
    import resource

    import numpy as np
    import torch

    sys.path.insert(0, str(ROOT))
    from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
    from roodi_toolkit.pipeline.budget import train_bytes
    from roodi_toolkit.render.fast import rasterize_fast

    cam = Camera(look_at([0, -3, 1], [0, 0, 0]), intrinsics_from_fov(math.radians(50), size, size), size, size)

    def params(m: int, requires_grad: bool) -> dict:
        rng = np.random.default_rng(0)
        t = lambda a: torch.tensor(a, dtype=torch.float32, requires_grad=requires_grad)  # noqa: E731
        return {"means": t(rng.normal(size=(m, 3)) * 0.5), "quats_wxyz": t(rng.normal(size=(m, 4))),
                "log_scales": t(rng.normal(-4.0, 0.3, (m, 3))), "opacity_logits": t(rng.normal(-1.0, 1.0, m)),
                "sh": t(rng.normal(0, 0.2, (m, 16, 3)))}

    def step(p: dict, opts: list) -> None:
        out = rasterize_fast(p["means"], p["quats_wxyz"], p["log_scales"], p["opacity_logits"], p["sh"],
                             torch.tensor(cam.world_to_camera, dtype=torch.float32),
                             torch.tensor(cam.K, dtype=torch.float32), size, size)
        (out.rgb.sum() + out.depth.sum()).backward()
        for o in opts:
            o.step()
            o.zero_grad(set_to_none=False)

    warm = params(50, True)
    step(warm, [torch.optim.Adam([v], lr=1e-3, eps=1e-15, fused=True) for v in warm.values()])
    del warm
    gc.collect()
    with open("/proc/self/statm") as fh:
        before = int(fh.read().split()[1]) * 4096
    p = params(n, True)
    step(p, [torch.optim.Adam([v], lr=1e-3, eps=1e-15, fused=True) for v in p.values()])
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    estimate = train_bytes(n, size * size)
    return {"case": "train", "gaussians": n, "size": f"{size}x{size}", "sh_degree": 3,
            "measured_mb": (peak - before) / 2**20, "estimate_mb": estimate / 2**20,
            "ratio": estimate / max(1.0, peak - before)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--splat", default=None, help="a real splat file (any format) rendered at 800x800")
    ap.add_argument("--one", nargs=3, metavar=("KIND", "N", "SIZE"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(one(args.one[0], int(args.one[1]), int(args.one[2]))))
        return
    cases = [("random", 1_000_000, 32), ("random", 2_000_000, 32), ("random", 2_000, 2000), ("random", 500_000, 800),
             ("features", 500_000, 800), ("train", 1_000_000, 32), ("train", 300_000, 800)]
    if args.splat:
        cases.append((args.splat, 0, 800))
    print("| case | Gaussians | view | SH | measured | estimate | estimate / measured |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for kind, n, size in cases:
        res = subprocess.run([sys.executable, __file__, "--one", kind, str(n), str(size)], check=True,
                             capture_output=True, text=True)
        r = json.loads(res.stdout.strip().splitlines()[-1])
        print(f"| {r['case']} | {r['gaussians']:,} | {r['size']} | {r['sh_degree']} | {r['measured_mb']:.0f} MB | "
              f"{r['estimate_mb']:.0f} MB | {r['ratio']:.2f} |", flush=True)


if __name__ == "__main__":
    main()
