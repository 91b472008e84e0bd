"""Benchmark: the default compiled renderer against the torch tiled renderer (issue 33), and the torch tiled renderer
against the dense reference (issue 5), forward and forward+backward.

Default (``compare``): for 100k Gaussians at 256x256 and 500k at 800x800 (``--configs``), with 1 and 2 threads
(``--threads``), the median wall-clock time of the ``numba`` renderer (``rasterize_fast``) and of the ``torch`` tiled
renderer (``rasterize``, the path before issue 33) measured alternately in the same process, their ratio, and the
peak memory of each in a process of its own. Run: ``.venv/bin/python benchmarks/bench_render.py --repeats 5``.

``--dense`` (issue 5's table): prints, for 10k, 100k and 300k Gaussians at 128x128, 256x256 and 512x512, the median times of the tiled renderer
(``rasterize``), of the dense reference (``rasterize_dense_reference``: every Gaussian at every pixel) and their
ratios, plus the peak memory of the tiled renderer. Times are wall-clock and process CPU time (user + system, both
threads): on a machine shared with other jobs wall-clock time mostly measures the others; the CPU time of a process
that only computes bounds its wall-clock time on an idle machine from above, and the ratios use CPU time. Every configuration runs in its own process so that peak memory
(the rise of the peak resident set size over the loaded scene) is its own.

The dense reference holds N x pixels pairs, so it is run in pieces of the image of about 16M pairs (forward and
backward per piece, the gradients accumulated: the same work, bounded memory; the projection that every piece
repeats is counted once). Its cost per pixel does not depend on the content (every Gaussian is evaluated at every
pixel), so where the whole image would take longer than ``--dense-budget`` seconds, it is timed on evenly spread
pieces and scaled to the full image; the output marks those figures "extrapolated".

Scene: :func:`scene.scene_cloud` (Gaussians on the surfaces of a ground disc, spheres and boxes, sized to cover the
surfaces about once; median footprint a few pixels at 256x256), camera at (3, -3, 2) looking at (0, 0, 0.3) with a
50 degree horizontal field of view, SH degree 3, float32, loss = sum of RGB + expected depth.

Run: ``.venv/bin/python benchmarks/bench_render.py --dense`` (``--quick`` for a smoke run).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def _rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _peak_mb() -> float:
    """The process's peak resident set (VmHWM, which :func:`_reset_peak` can lower), in MB."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _reset_peak() -> float:
    """Lower the peak resident set to the present one where Linux allows it (``/proc/self/clear_refs``), so that a
    peak measured after it is not the scene generation's (at 500k Gaussians its float64 temporaries peak higher than
    a numba rendering does, which read as a rise of 0 MB); returns the baseline to subtract: the present resident set
    after a reset, else the peak so far."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return _rss_mb()
    except OSError:
        return _peak_mb()


def _setup(n: int, size: int):
    import torch

    sys.path.insert(0, str(HERE))
    from scene import bench_camera, scene_cloud

    splat = os.environ.get("BENCH_SPLAT")
    if splat:  # a real splat (the --splat option), seen from its own scale's orbit
        from roodi_toolkit.io.splat import read_cloud
        from roodi_toolkit.render.views import framing_orbit

        cloud = read_cloud(splat)
        cam = framing_orbit(cloud, 1, width=size, height=size, up=[float(v) for v in
                                                                   os.environ["BENCH_UP"].split(",")])[0]
        t = lambda a: torch.tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
        scene = {"means": t(cloud.means), "quats_wxyz": t(cloud.quats_wxyz), "log_scales": t(cloud.log_scales),
                 "opacity_logits": t(cloud.opacity_logits), "sh": t(cloud.sh)}
        w2c, K = t(cam.world_to_camera), t(cam.K)
    else:
        scene = scene_cloud(n)
        w2c, K = bench_camera(size)
    params = {k: v.clone().requires_grad_() for k, v in scene.items()}
    return params, w2c, K


def _args(params):
    return (params["means"], params["quats_wxyz"], params["log_scales"], params["opacity_logits"], params["sh"])


def run_fast(n: int, size: int, repeats: int, tile_size: int) -> dict:
    import torch

    from roodi_toolkit.render.rasterizer import rasterize

    params, w2c, K = _setup(n, size)
    base = _reset_peak()
    fwd, both, fwd_cpu, both_cpu = [], [], [], []
    for _ in range(repeats + 1):  # the first run warms up and is dropped
        t0, c0 = time.perf_counter(), time.process_time()
        with torch.no_grad():
            out = rasterize(*_args(params), w2c, K, size, size, tile_size=tile_size)
        fwd.append(time.perf_counter() - t0)
        fwd_cpu.append(time.process_time() - c0)
        for p in params.values():
            p.grad = None
        t0, c0 = time.perf_counter(), time.process_time()
        out = rasterize(*_args(params), w2c, K, size, size, tile_size=tile_size)
        (out.rgb.sum() + out.depth.sum()).backward()
        both.append(time.perf_counter() - t0)
        both_cpu.append(time.process_time() - c0)
    return {"fwd": statistics.median(fwd[1:]), "both": statistics.median(both[1:]),
            "fwd_cpu": statistics.median(fwd_cpu[1:]), "both_cpu": statistics.median(both_cpu[1:]),
            "peak_mb": _peak_mb() - base, "visible": int(out.visible.sum()),
            "mean_radius_px": float(out.radii[out.visible].float().mean()),
            "coverage": float(out.alpha.detach().mean())}


def run_dense(n: int, size: int, budget: float, pairs_per_piece: int = 1 << 24) -> dict:
    """Time the dense reference over the whole image, in pieces of about ``pairs_per_piece`` (pixel, Gaussian) pairs.

    Each piece recomputes the projection and SH of all N Gaussians; that overhead (timed on a 1-pixel piece) is
    counted once, not once per piece, so the figure is what one dense pass over the image costs.
    """
    import torch

    from roodi_toolkit.render.rasterizer import rasterize_dense_reference

    params, w2c, K = _setup(n, size)
    px = max(1, pairs_per_piece // n)  # pixels per piece
    pieces = []
    for start in range(0, size * size, px):  # row-major runs of pixels, split into rectangles within a row
        stop = min(size * size, start + px)
        while start < stop:
            r, c = divmod(start, size)
            c_end = min(size, c + (stop - start))
            pieces.append(((r, r + 1), (c, c_end)))
            start += c_end - c

    def one(piece, backward):
        rows, cols = piece
        if backward:
            out = rasterize_dense_reference(*_args(params), w2c, K, size, size, rows=rows, cols=cols)
            (out.rgb.sum() + out.depth.sum()).backward()
        else:
            with torch.no_grad():
                rasterize_dense_reference(*_args(params), w2c, K, size, size, rows=rows, cols=cols)

    result = {}
    for key, backward in (("fwd", False), ("both", True)):
        one(pieces[len(pieces) // 2], backward)  # warm-up
        overhead = []
        for _ in range(3):
            c0 = time.process_time()
            one(((0, 1), (0, 1)), backward)
            overhead.append(time.process_time() - c0)
        overhead = statistics.median(overhead)
        stride = max(1, len(pieces) // 64)
        order = [i for k in range(stride) for i in range(k, len(pieces), stride)]  # evenly spread first
        t0, c0 = time.perf_counter(), time.process_time()
        pixels = done = 0
        for i in order:
            one(pieces[i], backward)
            done += 1
            pixels += pieces[i][1][1] - pieces[i][1][0]
            if time.perf_counter() - t0 > budget:
                break
        elapsed = time.process_time() - c0
        per_pixel = max(elapsed - done * overhead, 0.0) / pixels
        result[key] = per_pixel * size * size + overhead
        result[key + "_extrapolated"] = done < len(pieces)
        result[key + "_fraction"] = pixels / (size * size)
    return result


def run_compare(n: int, size: int, repeats: int, threads: int) -> dict:
    """Median wall-clock times of numba and torch, alternating within one process (same load for both)."""
    import torch

    from roodi_toolkit.render.fast import rasterize_fast
    from roodi_toolkit.render.rasterizer import rasterize

    os.environ["ROODI_THREADS"] = str(threads)  # the compiled kernels' threads
    torch.set_num_threads(threads)
    params, w2c, K = _setup(n, size)
    times: dict[str, list[float]] = {}
    for rep in range(repeats + 1):  # the first round warms up (and compiles) and is dropped
        for name, fn in (("numba", rasterize_fast), ("torch", rasterize)):
            t0 = time.perf_counter()
            with torch.no_grad():
                out = fn(*_args(params), w2c, K, size, size)
            t1 = time.perf_counter()
            for p in params.values():
                p.grad = None
            out = fn(*_args(params), w2c, K, size, size)
            (out.rgb.sum() + out.depth.sum()).backward()
            t2 = time.perf_counter()
            if rep:
                times.setdefault(name + "_fwd", []).append(t1 - t0)
                times.setdefault(name + "_both", []).append(t2 - t1)
    return {k: statistics.median(v) for k, v in times.items()}


def run_peak(kind: str, n: int, size: int, threads: int) -> dict:
    """Peak memory (rise of the peak RSS over the loaded scene) of one renderer, forward + backward."""
    import torch

    from roodi_toolkit.render.fast import rasterize_fast
    from roodi_toolkit.render.rasterizer import rasterize

    os.environ["ROODI_THREADS"] = str(threads)
    torch.set_num_threads(threads)
    params, w2c, K = _setup(n, size)
    fn = rasterize_fast if kind == "numba" else rasterize
    fn(*_args(params), w2c, K, 32, 32)  # compile / warm up small
    base = _reset_peak()
    out = fn(*_args(params), w2c, K, size, size)
    (out.rgb.sum() + out.depth.sum()).backward()
    return {"peak_mb": _peak_mb() - base}


def compare(args) -> None:
    configs = [tuple(int(v) for v in c.split("/")) for c in args.configs.split(",")]
    print(f"numba renderer (default) against the torch tiled renderer, forward and forward+backward (loss = sum RGB "
          f"+ sum depth), median of {args.repeats} alternating rounds after one warm-up; load average at start "
          f"{' '.join(f'{v:.1f}' for v in os.getloadavg())}")
    header = (f"{'N':>7} {'size':>9} {'thr':>3} | {'numba fwd':>9} {'torch fwd':>9} {'x fwd':>6} | {'numba f+b':>9} "
              f"{'torch f+b':>9} {'x f+b':>6} | {'numba MB':>8} {'torch MB':>8}")
    print(header)
    print("-" * len(header))
    for n, size in configs:
        for threads in [int(t) for t in args.threads_list.split(",")]:
            def sub(*extra):
                cmd = [sys.executable, __file__, "--one", *extra, str(n), str(size), "--repeats", str(args.repeats),
                       "--threads", str(threads)]
                return json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)

            t = sub("compare")
            mem = {k: sub("peak-" + k)["peak_mb"] for k in ("numba", "torch")}
            print(f"{n:>7} {size:>4}x{size:<4} {threads:>3} | {t['numba_fwd']:9.3f} {t['torch_fwd']:9.3f} "
                  f"{t['torch_fwd'] / t['numba_fwd']:6.1f} | {t['numba_both']:9.3f} {t['torch_both']:9.3f} "
                  f"{t['torch_both'] / t['numba_both']:6.1f} | {mem['numba']:8.0f} {mem['torch']:8.0f}", flush=True)
    print(f"seconds per frame, wall clock; x = torch / numba in the same process; load average at end "
          f"{' '.join(f'{v:.1f}' for v in os.getloadavg())}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--one", nargs=3, metavar=("KIND", "N", "SIZE"), help=argparse.SUPPRESS)
    ap.add_argument("--dense", action="store_true", help="issue 5's table: torch tiled against the dense reference")
    ap.add_argument("--configs", default="100000/256,500000/800", help="N/SIZE pairs (default 100000/256,500000/800)")
    ap.add_argument("--threads-list", default="1,2", help="thread counts of the comparison (default 1,2)")
    ap.add_argument("--splat", default=None, help="render this real splat (any format) instead of the generated "
                    "scene; N in --configs is then ignored")
    ap.add_argument("--up", default="0,0,1", help="the splat's up axis for its orbit camera (default 0,0,1)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--dense-budget", type=float, default=8.0,
                    help="seconds of measured dense time per configuration before extrapolating (default 8)")
    ap.add_argument("--tile-size", type=int, default=4)
    ap.add_argument("--threads", type=int, default=1,
                    help="torch threads (default 1: its CPU time is not inflated by other jobs' load, and bounds "
                         "the wall-clock time of an idle 2-core run from above)")
    ap.add_argument("--quick", action="store_true", help="10k Gaussians at 128x128 only")
    args = ap.parse_args()
    if args.splat:
        os.environ["BENCH_SPLAT"], os.environ["BENCH_UP"] = str(Path(args.splat).resolve()), args.up
    import torch

    torch.set_num_threads(args.threads)
    if args.one:
        kind, n, size = args.one[0], int(args.one[1]), int(args.one[2])
        if kind == "compare":
            res = run_compare(n, size, args.repeats, args.threads)
        elif kind.startswith("peak-"):
            res = run_peak(kind[5:], n, size, args.threads)
        else:
            res = run_fast(n, size, args.repeats, args.tile_size) if kind == "fast" else run_dense(n, size,
                                                                                                    args.dense_budget)
        print(json.dumps(res))
        return
    if not args.dense:
        compare(args)
        return

    ns = [10_000] if args.quick else [10_000, 100_000, 300_000]
    sizes = [128] if args.quick else [128, 256, 512]
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, tile {args.tile_size}px, "
          f"median of {args.repeats} runs after one warm-up; load average at start "
          f"{' '.join(f'{v:.1f}' for v in os.getloadavg())}")
    header = (f"{'N':>7} {'size':>7} | {'fwd':>6} {'cpu':>6} {'f+b':>6} {'cpu':>6} {'peak MB':>7} {'r px':>5} "
              f"{'cover':>5} | {'dense fwd':>10} {'dense f+b':>10} | {'x fwd':>6} {'x f+b':>6}")
    print(header)
    print("-" * len(header))
    for n in ns:
        for size in sizes:
            def sub(kind):
                cmd = [sys.executable, __file__, "--one", kind, str(n), str(size), "--repeats", str(args.repeats),
                       "--dense-budget", str(args.dense_budget), "--tile-size", str(args.tile_size),
                       "--threads", str(args.threads)]
                return json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)

            fast, dense = sub("fast"), sub("dense")
            mark = lambda k: "*" if dense[k + "_extrapolated"] else " "  # noqa: E731
            print(f"{n:>7} {size:>3}x{size:<3} | {fast['fwd']:6.3f} {fast['fwd_cpu']:6.3f} {fast['both']:6.3f} "
                  f"{fast['both_cpu']:6.3f} {fast['peak_mb']:7.0f} {fast['mean_radius_px']:5.1f} "
                  f"{fast['coverage']:5.2f} | {dense['fwd']:9.1f}{mark('fwd')} {dense['both']:9.1f}{mark('both')} | "
                  f"{dense['fwd'] / fast['fwd_cpu']:6.0f} {dense['both'] / fast['both_cpu']:6.0f}", flush=True)
    print("seconds per frame, median: tiled renderer wall-clock and process CPU time (all threads summed); dense "
          "reference in CPU seconds; ratios = dense CPU / tiled CPU")
    print("* dense time extrapolated from evenly spread pieces of the image (its cost per pixel does not depend on "
          f"the content); budget {args.dense_budget:g} s measured per figure; projection counted once")
    print(f"load average at end {' '.join(f'{v:.1f}' for v in os.getloadavg())} (other processes share the cores)")
    print("peak MB: rise of the peak RSS over the loaded scene (tiled renderer, forward + backward); r px: mean "
          "footprint half-width of visible Gaussians; cover: mean rendered alpha")


if __name__ == "__main__":
    main()
