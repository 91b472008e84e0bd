"""The default renderer's frames at two or more tile sizes, side by side (issue 33, item 3: ``fast.TILE_SIZE`` and
``fast.FEATURE_TILE_SIZE``).

The image is the same at any tile size (the compositing walks 4x4 blocks, each through the entries of its tile's run
that touch it); what changes is the number of (tile, Gaussian) pairs to bin, copy and give gradients to, against the
length of the runs each worker holds. For the scene of ``bench_render.py`` (``--n``, default 100,000 Gaussians) or a
real splat (``--splat FILE``, seen from four orbit cameras), it times in one process, the tile sizes alternating in
every round: a forward (no gradient), a forward and backward of rgb + depth (loss = their sum: training, fine-tuning),
and a forward and backward of 16 features alone of frozen geometry (distillation). Prints medians and each size's
ratio against the first (above 1: faster than the first).

Run:
    .venv/bin/python benchmarks/bench_tiles.py --size 256 --sizes 16,32
    .venv/bin/python benchmarks/bench_tiles.py --splat model/point_cloud.ply --size 800 --threads 2
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=100_000, help="Gaussians of the benchmark scene (default 100,000)")
    ap.add_argument("--splat", type=Path, help="a splat file to render instead of the benchmark scene")
    ap.add_argument("--size", type=int, default=256, help="image width and height (default 256)")
    ap.add_argument("--sizes", default="16,32", help="tile sizes, comma-separated (default 16,32)")
    ap.add_argument("--threads", type=int, default=1, help="kernel and PyTorch threads (default 1)")
    ap.add_argument("--repeats", type=int, default=5, help="rounds (default 5)")
    args = ap.parse_args()
    os.environ["ROODI_THREADS"] = str(args.threads)
    import torch

    from roodi_toolkit.render.fast import rasterize_features, rasterize_fast

    torch.set_num_threads(args.threads)
    tiles = [int(t) for t in args.sizes.split(",")]
    size = args.size
    if args.splat:
        from roodi_toolkit.io.splat import read_cloud
        from roodi_toolkit.params import GaussianParams
        from roodi_toolkit.render.views import framing_orbit

        cloud = read_cloud(str(args.splat))
        g = GaussianParams.from_cloud(cloud)
        raw = [g.means, g.quats_wxyz, g.log_scales, g.opacity_logits, g.colors]
        cams = [(torch.as_tensor(c.world_to_camera, dtype=torch.float32), torch.as_tensor(c.K, dtype=torch.float32))
                for c in framing_orbit(cloud, 4, width=size, height=size, up=(0.0, -1.0, 0.0))]
        label = f"{args.splat} ({len(cloud):,} Gaussians), four orbit views"
    else:
        from scene import bench_camera, scene_cloud

        sc = scene_cloud(args.n)
        raw = [sc[k] for k in ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh")]
        cams = [bench_camera(size)]
        label = f"the benchmark scene ({args.n:,} Gaussians)"
    params = [t.detach().clone().contiguous().requires_grad_(True) for t in raw]
    feats = torch.zeros(len(params[0]), 16, requires_grad=True)

    def frame(kind: str, tile: int, cam) -> float:
        for p in params + [feats]:
            p.grad = None
        t = time.perf_counter()
        if kind == "forward":
            with torch.no_grad():
                rasterize_fast(*params, *cam, size, size, tile_size=tile)
        elif kind == "forward+backward":
            out = rasterize_fast(*params, *cam, size, size, tile_size=tile)
            (out.rgb.sum() + out.depth.sum()).backward()
        else:
            image, _ = rasterize_features(*(p.detach() for p in params[:4]), feats, *cam, size, size, tile_size=tile)
            image.sum().backward()
        return time.perf_counter() - t

    print(f"{label}, {size}x{size}, {args.threads} thread(s); median of {args.repeats} rounds over {len(cams)} "
          f"view(s), tile sizes alternating (ms)")
    for kind in ("forward", "forward+backward", "16 features, f+b"):
        for tile in tiles:
            frame(kind, tile, cams[0])
        times: dict = {tile: [] for tile in tiles}
        for _ in range(args.repeats):
            for cam in cams:
                for tile in tiles:
                    times[tile].append(frame(kind, tile, cam))
        med = {tile: statistics.median(v) * 1e3 for tile, v in times.items()}
        cells = "  ".join(f"{tile} px {med[tile]:.1f} ({med[tiles[0]] / med[tile]:.2f}x)" for tile in tiles)
        print(f"{kind:18s} {cells}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
