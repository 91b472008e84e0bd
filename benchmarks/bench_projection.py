"""The projection kernels' time by SH degree, beside the memory's pace for the same coefficients (issue 33, item 3).

The projection (``projection_kernels.project_forward`` and ``project_backward``: geometry, footprints, SH colours and
their gradients, per Gaussian) reads each drawn Gaussian's SH coefficients, and its backward writes their gradients:
at SH 3, 192 bytes each way a Gaussian. This times both kernels on one view of :func:`scene.scene_cloud` (the scene
of ``bench_render.py``) at SH degrees 0 to 3, the backward with and without the geometry's gradients, and beside them
numpy reading the same coefficients (a sum) and reading and writing them (a product into a second array): what
the SH terms add over degree 0 against what moving their bytes costs on this machine. Medians of ``--repeats``
rounds, every case once a round, in turn.

Run: ``.venv/bin/python benchmarks/bench_projection.py 100000 256 --threads 1``
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("n", type=int, help="Gaussians")
    ap.add_argument("size", type=int, help="image width and height")
    ap.add_argument("--threads", type=int, default=1, help="kernel threads (default 1)")
    ap.add_argument("--repeats", type=int, default=15, help="rounds (default 15)")
    args = ap.parse_args()
    os.environ["ROODI_THREADS"] = str(args.threads)
    from scene import bench_view, projection_grads

    from roodi_toolkit.render import projection_kernels as pk
    from roodi_toolkit.render.cores import set_workers

    arrays, view, proj, _, _ = bench_view(args.n, args.size)
    set_workers()
    n, f32 = args.n, np.float32
    scales, opacities, r2 = pk.activations(arrays[2], arrays[3])
    cam = (view.view, view.center, view.intr, args.size, args.size, view.near, view.far, view.eps2d)
    g_in = projection_grads(n)
    drawn = int((proj.ntiles > 0).sum())

    def case_of(degree: int):
        sh = np.ascontiguousarray(arrays[4][:, :(degree + 1) ** 2])
        outs = [np.empty((n, 2), f32), np.empty((n, 3), f32), np.empty(n, f32), np.empty((n, 4), f32),
                np.zeros((n, 4), np.int32), np.zeros((n, 2), np.int32), np.zeros(n, np.int64), np.zeros(n, np.uint8)]
        g_out = [np.empty((n, 3), f32), np.empty((n, 4), f32), np.empty((n, 3), f32), np.empty(n, f32),
                 np.empty(sh.shape, f32)]

        def forward():
            pk.project_forward(arrays[0], arrays[1], scales, opacities, r2, sh, len(sh[0]), *cam, view.tile, *outs)

        def backward(geometry: bool):
            pk.project_backward(arrays[0], arrays[1], scales, opacities, sh, len(sh[0]), *cam, outs[6], outs[7],
                                *g_in, *g_out, geometry)

        return sh, forward, lambda: backward(True), lambda: backward(False)

    cases = {d: case_of(d) for d in range(4)}
    sh3 = cases[3][0]
    copy = np.empty_like(sh3)
    numpy_cases = {"numpy read": lambda: sh3.sum(), "numpy read+write": lambda: np.multiply(sh3, f32(2), out=copy)}
    calls = {(d, k): c for d, fns in cases.items() for k, c in zip(("fwd", "bwd", "bwd colours"), fns[1:])}
    calls.update(numpy_cases)
    for call in calls.values():  # compile, warm
        call()
    times: dict = {key: [] for key in calls}
    for _ in range(args.repeats):
        for key, call in calls.items():
            t = time.perf_counter()
            call()
            times[key].append(time.perf_counter() - t)
    med = {key: statistics.median(v) * 1e3 for key, v in times.items()}
    print(f"{n:,} Gaussians ({drawn:,} drawn), {args.size}x{args.size}, {args.threads} thread(s), float32; median of "
          f"{args.repeats} rounds (ms)")
    print("SH degree | forward | backward | backward, colours only | SH MB a frame (each way)")
    for d in range(4):
        mb = cases[d][0].nbytes / 1e6
        print(f"{d:9d} | {med[(d, 'fwd')]:7.2f} | {med[(d, 'bwd')]:8.2f} | {med[(d, 'bwd colours')]:22.2f} | "
              f"{mb:.1f}")
    extra_f = med[(3, "fwd")] - med[(0, "fwd")]
    extra_b = med[(3, "bwd")] - med[(0, "bwd")]
    print(f"numpy over the SH 3 coefficients ({sh3.nbytes / 1e6:.1f} MB): read {med['numpy read']:.2f} ms, read and "
          f"write {med['numpy read+write']:.2f} ms")
    print(f"SH 3 over SH 0: forward +{extra_f:.2f} ms ({extra_f / med['numpy read']:.2f}x numpy's read), backward "
          f"+{extra_b:.2f} ms ({extra_b / med['numpy read+write']:.2f}x numpy's read and write)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
