"""Per-stage times of the default renderer's kernels, optionally side by side with another checkout's kernels.

For one view of :func:`scene.scene_cloud` (the scene of ``bench_render.py``: camera at (3, -3, 2) looking at
(0, 0, 0.3), 50 degree field of view, SH 3, float32) it times each stage of a forward and backward pass: projection
(with SH colours and footprints), depth order, tile binning, compositing forward, compositing backward (geometry and
channels) and the per-Gaussian reduction of the pair gradients. ``--against CHECKOUT`` loads that checkout's
``roodi_toolkit/render/kernels.py`` (copied to the temporary folder, so nothing is written into it) and runs its
compositing kernels on the same projected, binned Gaussians, alternating with this checkout's in every round: the
two columns see the same load, and the ratio is what counts on a shared machine. It also checks that both give the
same image (largest difference printed).

``--channels 4`` composites rgb + depth (rendering, training); ``--channels 16`` 16 features alone (distillation).
Gradients: the loss is the sum of every channel (what ``bench_render.py`` uses).

Run:
    .venv/bin/python benchmarks/bench_render_stages.py 500000 800 --threads 1 --against /path/to/main
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import math
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def load_kernels(checkout: Path):
    """Return ``checkout``'s kernels module, loaded from a copy in the temporary folder (numba caches its compiled
    code beside the file; a folder named by the content lets later runs reuse it). The kernels and the block helpers
    they import (``lanes.py``, where the checkout has it) are copied as a package of their own."""
    render = checkout / "roodi_toolkit" / "render"
    files = {name: (render / name).read_bytes() for name in ("kernels.py", "lanes.py") if (render / name).exists()}
    digest = hashlib.sha1(b"".join(files.values())).hexdigest()[:12]
    package = f"kernels_against_{digest}"
    folder = Path(tempfile.gettempdir()) / "bench_kernels" / package
    folder.mkdir(parents=True, exist_ok=True)
    for name, source in {**files, "__init__.py": b""}.items():
        if not (folder / name).exists():
            (folder / name).write_bytes(source)
    sys.path.insert(0, str(folder.parent))  # importable by name: numba's cache finds the module again
    return importlib.import_module(f"{package}.kernels")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("n", type=int, help="Gaussians")
    ap.add_argument("size", type=int, help="image width and height in pixels")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--channels", type=int, default=4, help="4: rgb + depth; else that many features alone")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--tile-size", type=int, default=16)
    ap.add_argument("--against", type=Path, default=None, help="another checkout whose kernels run beside these")
    args = ap.parse_args(argv)
    os.environ["ROODI_THREADS"] = str(args.threads)

    import numpy as np
    import torch

    sys.path.insert(0, str(HERE))
    from scene import scene_cloud

    from roodi_toolkit.cameras import intrinsics_from_fov, look_at
    from roodi_toolkit.render import fast, kernels

    torch.set_num_threads(1)
    scene = scene_cloud(args.n)
    w2c = torch.tensor(look_at([3.0, -3.0, 2.0], [0.0, 0.0, 0.3]), dtype=torch.float32)
    K = torch.tensor(intrinsics_from_fov(math.radians(50.0), args.size, args.size), dtype=torch.float32)
    arrays = [scene[k].numpy() for k in ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh")]
    view = fast.make_view(w2c, K, args.size, args.size, tile=args.tile_size)
    W = H = args.size
    workers = fast.workers()
    rng = np.random.default_rng(0)
    sides = {"this": kernels}
    if args.against is not None:
        sides["against"] = load_kernels(args.against)

    times: dict[str, list[float]] = {}

    def clock(key, fn):
        t0 = time.perf_counter()
        result = fn()
        times.setdefault(key, []).append(time.perf_counter() - t0)
        return result

    images = {}
    for rnd in range(args.repeats + 1):  # round 0 compiles and warms up; dropped
        proj = clock("projection", lambda: fast.project(*arrays, 16, view))
        order = clock("depth order", lambda: kernels.depth_order(proj.ntiles, proj.depths))
        lists, starts, counts = clock("binning", lambda: kernels.bin_tiles(order, proj.bounds, W, H, view.tile,
                                                                            workers))
        busy = np.flatnonzero(counts > 0)
        if args.channels == 4:
            channels = fast.channels_of(proj, None)
        else:
            channels = rng.standard_normal((args.n, args.channels)).astype(np.float32)
        C = channels.shape[1]
        g_out = np.ones((H, W, C), np.float32)
        g_alpha = np.zeros((H, W), np.float32)
        bg = np.zeros(C)
        for name, mod in sides.items():
            out = np.zeros((H, W, C), np.float32)
            t_final = np.ones((H, W), np.float32)
            last = np.zeros((H, W), np.int32)
            top = np.full((0, 0), -1, np.int32)
            extra = (mod.channel_groups(C),) if hasattr(mod, "channel_groups") else ()  # kernels before 4x4 blocks
            head = (lists, starts, counts, busy, proj.bounds, proj.means2d, proj.conics, proj.opacities, channels,
                    *extra, W, H, view.tile, workers)
            clock(f"{name} fwd", lambda: mod.composite_forward(*head, out, t_final, last, top))
            pair_geom = np.zeros((len(lists), 6), np.float32)
            pair_chan = np.zeros((len(lists), C), np.float32)
            clock(f"{name} bwd", lambda: mod.composite_backward(*head, t_final, last, g_out, g_alpha, bg, pair_geom,
                                                                pair_chan, True))
            clock(f"{name} reduce", lambda: (mod.reduce_pairs(lists, pair_geom, args.n, workers),
                                             mod.reduce_pairs(lists, pair_chan, args.n, workers)))
            images[name] = (out, t_final)
        if rnd == 0:
            times.clear()
    print(f"{args.n} Gaussians, {W}x{H}, tile {view.tile}, {C} channels, {workers} thread(s); "
          f"{len(lists):,} (tile, Gaussian) pairs; median of {args.repeats} rounds (seconds); "
          f"load average {' '.join(f'{v:.1f}' for v in os.getloadavg())}")
    for key in ("projection", "depth order", "binning"):
        print(f"  {key:<22} {statistics.median(times[key]):.3f}")
    for stage in ("fwd", "bwd", "reduce"):
        row = "  " + f"compositing {stage}".ljust(22)
        for name in sides:
            row += f" {name} {statistics.median(times[f'{name} {stage}']):.3f}"
        if "against" in sides:
            row += f"  ratio {statistics.median(times[f'against {stage}']) / statistics.median(times[f'this {stage}']):.2f}x"
        print(row)
    if "against" in sides:
        (a, ta), (b, tb) = images["this"], images["against"]
        print(f"  image difference (max |this - against|): colours {np.abs(a - b).max():.2e}, "
              f"transmittance {np.abs(ta - tb).max():.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
