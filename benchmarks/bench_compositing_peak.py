"""The compositing kernels' cost per 4x4 block and Gaussian when nothing else counts: data in cache, every box hit.

``G`` Gaussians cover the whole ``SIZE`` x ``SIZE`` image (a conic of 1e-7: the Gaussian is above 0.99 everywhere)
with an opacity of 0.0041, just over the 1/255 cut: every 4x4 block of every tile evaluates every Gaussian (no box
misses, no early stop: the transmittance after 2000 of them is 2.8e-4, above the 1e-4 stop), and each tile's run fits
in the cache. The time per block and Gaussian is then the inner loop's own cost, which the real scenes' figures
(``bench_render_stages.py``) add box tests, cache misses and early stops to. Read the assembly of the kernels with
``NUMBA_CACHE_DIR`` set to an empty folder (compiled code loaded from the cache cannot be inspected) and
``--asm FILE``.

    .venv/bin/python benchmarks/bench_compositing_peak.py [--gaussians 2000] [--size 256] [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gaussians", type=int, default=2000)
    ap.add_argument("--size", type=int, default=256, help="image width and height (a multiple of 16)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--asm", default=None, help="write the forward kernel's assembly to this new file")
    args = ap.parse_args(argv)
    if args.asm and os.path.lexists(args.asm):
        print(f"bench_compositing_peak: --asm {args.asm} exists; give a new path", file=sys.stderr)
        return 2
    os.environ.setdefault("ROODI_THREADS", "1")

    import numpy as np

    from roodi_toolkit.render import fast, kernels, lanes, tiles

    G, S = args.gaussians, args.size
    f32 = np.float32
    rng = np.random.default_rng(0)
    means2d = (rng.random((G, 2)) * S).astype(f32)
    conics = np.tile(np.array([1e-7, 0.0, 1e-7], f32), (G, 1))
    opacities = np.full(G, 0.0041, f32)
    bounds = np.tile(np.array([0, S - 1, 0, S - 1], np.int32), (G, 1))
    ntiles = np.full(G, ((S + 15) // 16) ** 2, np.int64)
    order = tiles.depth_order(ntiles, np.arange(G, dtype=f32), 1)
    lists, starts, counts = tiles.bin_tiles(order, bounds, S, S, 16, 1)
    busy = np.flatnonzero(counts > 0)
    channels = rng.random((G, 4)).astype(f32)
    rec = fast.record_buffer(G, f32)  # the kernels' records, on cache lines as fast.records makes them
    lanes.fill_records(bounds, means2d, conics, opacities, channels, 4, rec)
    head = (lists, starts, counts, busy, rec, channels, kernels.channel_groups(4), S, S, 16, 1)
    evaluations = (S // 4) ** 2 * G
    fwd, bwd = [], []
    for rnd in range(args.repeats + 1):  # round 0 compiles (or loads) the kernels and is dropped
        out = np.zeros((S, S, 4), f32)
        t_final = np.ones((S, S), f32)
        last = np.zeros((S, S), np.int32)
        marks = np.zeros(fast.marks_shape(len(lists), 16), np.uint64)
        t0 = time.perf_counter()
        kernels.composite_forward(*head, out, t_final, last, np.full((0, 0), -1, np.int32), marks)
        t1 = time.perf_counter()
        pair_geom = np.zeros((len(lists), 6), f32)
        pair_chan = np.zeros((len(lists), 4), f32)
        t2 = time.perf_counter()
        kernels.composite_backward(*head, t_final, last, marks, np.ones((S, S, 4), f32), np.zeros((S, S), f32),
                                   np.zeros(4), pair_geom, pair_chan, True)
        t3 = time.perf_counter()
        if rnd:
            fwd.append(t1 - t0)
            bwd.append(t3 - t2)
    assert int(last.min()) == G, "every pixel must walk every Gaussian"
    print(f"{G} Gaussians over {S}x{S}, one thread: {evaluations / 1e6:.1f}M block-Gaussian evaluations; median of "
          f"{args.repeats}; load average {' '.join(f'{v:.1f}' for v in os.getloadavg())}")
    for name, times in (("forward", fwd), ("backward", bwd)):
        t = statistics.median(times)
        print(f"  {name:<9} {t:.3f} s  {t / evaluations * 1e9:.1f} ns per block and Gaussian")
    if args.asm:
        asm = kernels.composite_forward.inspect_asm(kernels.composite_forward.signatures[-1])
        try:
            with open(args.asm, "x") as fh:  # never replaces a file
                fh.write(asm)
        except FileExistsError:  # it appeared while the kernels ran
            print(f"bench_compositing_peak: --asm {args.asm} exists; give a new path", file=sys.stderr)
            return 2
        calls = sum(1 for line in asm.splitlines() if "call" in line and "memcpy" in line)
        print(f"  forward assembly -> {args.asm} ({len(asm.splitlines())} lines, {calls} memcpy calls)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
