"""The compiled routes issue 33 (item 3) named, side by side on the compositing forward: numba (the renderer's
kernel, ``kernels.composite_forward``) against the same work written for Taichi and for warp-lang.

The compositing is where a render spends its time (``docs/rendering.md``). Each route gets the same input: one view
of :func:`scene.scene_cloud` (the scene of ``bench_render.py``: camera at (3, -3, 2), 50 degree field of view, SH 3,
float32) projected and binned by the renderer, the Gaussians' 64-byte records (mean, conic, opacity, footprint box,
rgb + depth), the tiles' depth-ordered runs. Taichi and warp get the kernel their manuals teach: a thread per pixel
walking its tile's run front to back; Taichi also the renderer's own idea, a thread per 4x4 block of pixels whose
state is 16-lane vectors (``ti.Vector``; warp has no lane-wise comparison or select for its vectors). All use the
renderer's alpha rule (``min(0.99, opacity exp(-sigma))``, blended
where it reaches 1/255 inside the footprint box, a pixel stopped where its transmittance would fall under 1e-4);
numba's kernel is the renderer's own (a 4x4 block of pixels as one vector). Each route's image is checked against
numba's (largest difference printed), then the routes are timed in turn, the order reversed every other round,
the median of ``--repeats`` rounds.

Taichi and warp-lang are not dependencies of the toolkit: install them where this runs (``pip install taichi
warp-lang``). Taichi's CPU thread count is fixed when it starts, so each thread count runs in a process of its own
(``--threads``); warp runs CPU kernels on one thread.

Run: ``python benchmarks/bench_jit_routes.py 100000 256 --threads 1`` (and 500000 800; ``--threads 2``).
"""

# (no ``from __future__ import annotations``: Taichi and warp read their kernels' annotations as types)
import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ALPHA_MIN, ALPHA_MAX, T_MIN = 1.0 / 255.0, 0.99, 1e-4


def inputs(n: int, size: int):
    """The renderer's projected, binned view of ``scene_cloud(n)`` at ``size`` x ``size``: (bins, records, channels,
    view)."""
    sys.path.insert(0, str(HERE))
    from scene import bench_view

    from roodi_toolkit.render import fast

    _, view, proj, bins, channels = bench_view(n, size)
    return bins, fast.records(proj, channels), channels, view


def numba_route(bins, rec, channels, view):
    """The renderer's compositing forward: returns a function of no argument that renders (rgb + depth, T)."""
    from roodi_toolkit.render import fast

    proj = type("P", (), {})()  # :func:`fast.composite` reads the records given, nothing else of the projection

    def render():
        out, t_final, *_ = fast.composite(bins, proj, channels, view, rec=rec)
        return out, t_final

    return render


def _taichi_pixels(ti, tile: int, tiles_x: int, W: int, H: int):
    """The Taichi kernel of a thread per pixel, each walking its tile's run."""

    @ti.kernel
    def composite(lists: ti.types.ndarray(), starts: ti.types.ndarray(), counts: ti.types.ndarray(),
                  busy: ti.types.ndarray(), rec: ti.types.ndarray(), out: ti.types.ndarray(),
                  t_final: ti.types.ndarray()):
        for b, q in ti.ndrange(busy.shape[0], tile * tile):
            t = busy[b]
            px = (t % tiles_x) * tile + q % tile
            py = (t // tiles_x) * tile + q // tile
            if px < W and py < H:
                x = ti.f32(px) + 0.5
                y = ti.f32(py) + 0.5
                T = ti.f32(1.0)
                c = ti.Vector([0.0, 0.0, 0.0, 0.0], dt=ti.f32)
                s = starts[t]
                for e in range(counts[t]):
                    g = lists[s + e]
                    if rec[g, 6] < x and x < rec[g, 7] and rec[g, 8] < y and y < rec[g, 9]:
                        dx = x - rec[g, 0]
                        dy = y - rec[g, 1]
                        sigma = 0.5 * rec[g, 2] * dx * dx + rec[g, 3] * dx * dy + 0.5 * rec[g, 4] * dy * dy
                        alpha = ti.min(ALPHA_MAX, rec[g, 5] * ti.exp(-sigma))
                        if alpha >= ALPHA_MIN:
                            tn = T * (1.0 - alpha)
                            if tn < T_MIN:
                                break
                            w = alpha * T
                            for ch in ti.static(range(4)):
                                c[ch] += w * rec[g, 10 + ch]
                            T = tn
                for ch in ti.static(range(4)):
                    out[py, px, ch] = c[ch]
                t_final[py, px] = T

    return composite


def _taichi_blocks(ti, tile: int, tiles_x: int, W: int, H: int):
    """The Taichi kernel of a thread per 4x4 block, its 16 pixels' state as ``ti.Vector``s (Taichi's vectors are
    unrolled into scalars, which LLVM may combine into vector instructions), each testing every entry of its
    tile's run against the block (the renderer lists each block's entries instead)."""

    @ti.kernel
    def composite_blocks(lists: ti.types.ndarray(), starts: ti.types.ndarray(), counts: ti.types.ndarray(),
                         busy: ti.types.ndarray(), rec: ti.types.ndarray(), out: ti.types.ndarray(),
                         t_final: ti.types.ndarray()):
        for b, k in ti.ndrange(busy.shape[0], (tile // 4) ** 2):  # a 4x4 block a thread, its pixels in vectors
            t = busy[b]
            bx = (t % tiles_x) * tile + (k % (tile // 4)) * 4
            by = (t // tiles_x) * tile + (k // (tile // 4)) * 4
            x = ti.Vector([ti.f32(bx + q % 4) + 0.5 for q in ti.static(range(16))], dt=ti.f32)
            y = ti.Vector([ti.f32(by + q // 4) + 0.5 for q in ti.static(range(16))], dt=ti.f32)
            T = ti.Vector([1.0 if bx + q % 4 < W and by + q // 4 < H else -1.0 for q in ti.static(range(16))],
                          dt=ti.f32)
            c0 = ti.Vector([0.0] * 16, dt=ti.f32)
            c1 = ti.Vector([0.0] * 16, dt=ti.f32)
            c2 = ti.Vector([0.0] * 16, dt=ti.f32)
            c3 = ti.Vector([0.0] * 16, dt=ti.f32)
            s = starts[t]
            for e in range(counts[t]):
                g = lists[s + e]
                if rec[g, 6] < bx + 4 and bx < rec[g, 7] and rec[g, 8] < by + 4 and by < rec[g, 9]:
                    dx = x - rec[g, 0]
                    dy = y - rec[g, 1]
                    sigma = 0.5 * rec[g, 2] * dx * dx + rec[g, 3] * dx * dy + 0.5 * rec[g, 4] * dy * dy
                    alpha = ti.min(ALPHA_MAX, rec[g, 5] * ti.exp(-sigma))
                    inside = (rec[g, 6] < x) & (x < rec[g, 7]) & (rec[g, 8] < y) & (y < rec[g, 9])
                    ok = (alpha >= ALPHA_MIN) & (T > 0.0) & inside
                    tn = T * (1.0 - alpha)
                    blend = ok & (tn >= T_MIN)
                    stop = ok & (tn < T_MIN)
                    w = ti.select(blend, alpha * T, 0.0)
                    c0 += w * rec[g, 10]
                    c1 += w * rec[g, 11]
                    c2 += w * rec[g, 12]
                    c3 += w * rec[g, 13]
                    T = ti.select(blend, tn, ti.select(stop, -T, T))
                    if T.max() <= 0.0:
                        break
            for q in ti.static(range(16)):
                px = bx + q % 4
                py = by + q // 4
                if px < W and py < H:
                    out[py, px, 0] = c0[q]
                    out[py, px, 1] = c1[q]
                    out[py, px, 2] = c2[q]
                    out[py, px, 3] = c3[q]
                    t_final[py, px] = ti.abs(T[q])

    return composite_blocks


def taichi_route(bins, rec, view, threads: int):
    """The compositing as Taichi kernels on ``threads`` CPU threads: returns the renders of a thread per pixel
    (:func:`_taichi_pixels`) and of a thread per 4x4 block (:func:`_taichi_blocks`)."""
    import taichi as ti

    ti.init(arch=ti.cpu, cpu_max_num_threads=threads, default_fp=ti.f32, offline_cache=True, log_level=ti.WARN)
    tile, W, H = view.tile, view.width, view.height
    tiles_x = (W + tile - 1) // tile
    composite = _taichi_pixels(ti, tile, tiles_x, W, H)
    composite_blocks = _taichi_blocks(ti, tile, tiles_x, W, H)

    def render(kernel=composite):
        out = np.zeros((H, W, 4), np.float32)
        t_final = np.ones((H, W), np.float32)
        kernel(bins.lists, bins.starts, bins.counts, bins.busy, rec, out, t_final)
        ti.sync()
        return out, t_final

    return render, lambda: render(composite_blocks)


def warp_route(bins, rec, view):
    """The compositing as a warp-lang kernel on its CPU device, a thread per pixel (``wp.launch`` over busy tiles
    times their pixels)."""
    import warp as wp

    wp.config.quiet = True
    wp.init()
    tile, W, H = view.tile, view.width, view.height
    tiles_x = (W + tile - 1) // tile

    @wp.kernel
    def composite(lists: wp.array(dtype=wp.int32), starts: wp.array(dtype=wp.int64),
                  counts: wp.array(dtype=wp.int64), busy: wp.array(dtype=wp.int64),
                  rec: wp.array2d(dtype=wp.float32), tile: int, tiles_x: int, W: int, H: int,
                  out: wp.array3d(dtype=wp.float32), t_final: wp.array2d(dtype=wp.float32)):
        i = wp.tid()
        t = busy[i // (tile * tile)]
        q = i % (tile * tile)
        px = int(t % wp.int64(tiles_x)) * tile + q % tile
        py = int(t // wp.int64(tiles_x)) * tile + q // tile
        if px < W and py < H:
            x = float(px) + 0.5
            y = float(py) + 0.5
            T = float(1.0)
            c0 = float(0.0)
            c1 = float(0.0)
            c2 = float(0.0)
            c3 = float(0.0)
            s = starts[int(t)]
            for e in range(int(counts[int(t)])):
                g = lists[int(s) + e]
                if rec[g, 6] < x and x < rec[g, 7] and rec[g, 8] < y and y < rec[g, 9]:
                    dx = x - rec[g, 0]
                    dy = y - rec[g, 1]
                    sigma = 0.5 * rec[g, 2] * dx * dx + rec[g, 3] * dx * dy + 0.5 * rec[g, 4] * dy * dy
                    alpha = wp.min(float(ALPHA_MAX), rec[g, 5] * wp.exp(-sigma))
                    if alpha >= float(ALPHA_MIN):
                        tn = T * (1.0 - alpha)
                        if tn < float(T_MIN):
                            break
                        w = alpha * T
                        c0 += w * rec[g, 10]
                        c1 += w * rec[g, 11]
                        c2 += w * rec[g, 12]
                        c3 += w * rec[g, 13]
                        T = tn
            out[py, px, 0] = c0
            out[py, px, 1] = c1
            out[py, px, 2] = c2
            out[py, px, 3] = c3
            t_final[py, px] = T

    args = [wp.array(a, device="cpu") for a in (bins.lists, bins.starts, bins.counts, bins.busy)]
    rec_wp = wp.array(np.ascontiguousarray(rec), dtype=wp.float32, device="cpu")

    def render():
        out = wp.zeros((H, W, 4), dtype=wp.float32, device="cpu")
        t_final = wp.full((H, W), 1.0, dtype=wp.float32, device="cpu")
        wp.launch(composite, dim=len(bins.busy) * tile * tile, inputs=[*args, rec_wp, tile, tiles_x, W, H, out,
                                                                           t_final], device="cpu")
        wp.synchronize()
        return out.numpy(), t_final.numpy()

    return render


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("n", type=int, help="Gaussians")
    parser.add_argument("size", type=int, help="image width and height in pixels")
    parser.add_argument("--threads", type=int, default=1, help="threads for numba and Taichi (warp: one)")
    parser.add_argument("--repeats", type=int, default=11)
    parser.add_argument("--routes", default="taichi,warp", help="comma-separated: taichi, warp")
    args = parser.parse_args(argv)
    os.environ["ROODI_THREADS"] = str(args.threads)  # the renderer's thread count (``render.cores.workers``)
    bins, rec, channels, view = inputs(args.n, args.size)
    routes = {"numba": numba_route(bins, rec, channels, view)}
    for name in [r for r in args.routes.split(",") if r]:
        try:
            if name == "taichi":
                routes["taichi"], routes["taichi-4x4"] = taichi_route(bins, rec, view, args.threads)
            elif name == "warp":
                routes["warp"] = warp_route(bins, rec, view)
        except ImportError as exc:
            print(f"{name}: not installed ({exc}); pip install taichi warp-lang", file=sys.stderr)
    first = {}
    for name, render in routes.items():  # compile (Taichi and warp at their first call) and check the images
        t0 = time.perf_counter()
        first[name] = render()
        print(f"{name}: first call {time.perf_counter() - t0:.2f} s", flush=True)
    ref, ref_t = first["numba"]
    for name, (img, t_final) in first.items():
        if name != "numba":
            print(f"{name}: image vs numba max |diff| {np.abs(img - ref).max():.2e} (rgb + depth), "
                  f"transmittance {np.abs(t_final - ref_t).max():.2e}")
    times = {name: [] for name in routes}
    for r in range(args.repeats):
        for name in (list(routes) if r % 2 == 0 else list(routes)[::-1]):
            t0 = time.perf_counter()
            routes[name]()
            times[name].append(time.perf_counter() - t0)
    print(f"{args.n:,} Gaussians, {args.size}x{args.size}, {len(bins.lists):,} (tile, Gaussian) pairs, "
          f"{args.threads} thread(s) (warp: 1), compositing forward, median of {args.repeats} rounds")
    base = statistics.median(times["numba"])
    for name, ts in times.items():
        med = statistics.median(ts)
        print(f"  {name:10s} {med * 1e3:9.2f} ms   {med / base:6.2f}x numba's time")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
