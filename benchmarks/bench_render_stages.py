"""Per-stage times of the default renderer's kernels, optionally side by side with another checkout's kernels.

For one view of :func:`scene.scene_cloud` (the scene of ``bench_render.py``: camera at (3, -3, 2) looking at
(0, 0, 0.3), 50 degree field of view, SH 3, float32) it times each stage of a forward and backward pass: projection
(with SH colours and footprints) and its backward, depth order, tile binning, compositing forward, compositing
backward (geometry and channels) and the per-Gaussian reduction of the pair gradients. ``--against CHECKOUT`` loads
that checkout's ``roodi_toolkit/render/kernels.py`` and ``projection_kernels.py`` (copied to the temporary folder, so
nothing is written into it) and runs its projection and compositing kernels on the same Gaussians (the compositing on
the same projected, binned ones), alternating with this checkout's in every round, each going first every other
round (the first of two identical kernels read 0.88x against the second when this checkout always went first): the
two columns see the same load, and the ratio is what counts on a shared machine. It also checks that both give the
same image (largest difference printed). The ratio of the fastest rounds is printed beside the medians' ratio:
on a machine whose other tenants take a core now and then, it moves less between runs.

``--channels 4`` composites rgb + depth (rendering, training); ``--channels 16`` 16 features alone (distillation).
Gradients: the loss is the sum of every channel (what ``bench_render.py`` uses).

``--processes K`` (with ``--against``) runs the comparison in K processes of its own and prints each stage's median
ratio over them with their range: where a process's memory lies moves the compositing's ratio of two kernels by up
to 1.4x either way between processes (both kernels see the same load, but not the same placement of their stack
arrays and code against the data). Half the processes run with address-space randomisation off (``setarch -R``,
where installed) and the stack shifted by a different padding in the environment each, so their layouts are fixed
and different; the other half run as a user's process would, randomised.

Run:
    .venv/bin/python benchmarks/bench_render_stages.py 500000 800 --threads 1 --against /path/to/main
    .venv/bin/python benchmarks/bench_render_stages.py 100000 256 --against /path/to/main --processes 16
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def load_kernels(checkout: Path):
    """Return ``checkout``'s kernels module and its projection kernels module, loaded from a copy in the temporary
    folder (numba caches its compiled code beside the file; a folder named by the content lets later runs reuse it).
    The kernels, the block helpers and vector operations they import (``lanes.py``, ``vectors.py`` and ``simd.py``,
    where the checkout has them) and the projection kernels (their package imports made absolute: the constants come
    from this checkout's package) are copied as a package of their own."""
    render = checkout / "roodi_toolkit" / "render"
    names = ("kernels.py", "lanes.py", "vectors.py", "simd.py", "projection_kernels.py")
    files = {name: (render / name).read_bytes() for name in names if (render / name).exists()}
    files["projection_kernels.py"] = files["projection_kernels.py"].replace(
        b"from ..gaussians import", b"from roodi_toolkit.gaussians import").replace(
        b"from ..sh import", b"from roodi_toolkit.sh import")
    digest = hashlib.sha1(b"".join(files.values())).hexdigest()[:12]
    package = f"kernels_against_{digest}"
    folder = Path(tempfile.gettempdir()) / "bench_kernels" / package
    folder.mkdir(parents=True, exist_ok=True)
    for name, source in {**files, "__init__.py": b""}.items():
        if not (folder / name).exists():
            (folder / name).write_bytes(source)
    sys.path.insert(0, str(folder.parent))  # importable by name: numba's cache finds the module again
    return importlib.import_module(f"{package}.kernels"), importlib.import_module(f"{package}.projection_kernels")


def parameters(kernel) -> tuple[str, ...]:
    """The names of a compiled kernel's parameters (its code's first names; the rest are its locals)."""
    code = kernel.py_func.__code__
    return code.co_varnames[:code.co_argcount]


def make_records(mod, proj, channels):
    """The Gaussians' records for ``mod``'s compositing kernels (as ``fast.records`` makes them), by its own
    ``lanes.fill_records``."""
    from roodi_toolkit.render.fast import record_buffer

    rec = record_buffer(len(proj.opacities), proj.opacities.dtype)
    lanes = importlib.import_module(mod.__name__.rsplit(".", 1)[0] + ".lanes")
    lanes.fill_records(proj.bounds, proj.means2d, proj.conics, proj.opacities, channels,
                       4 if channels.shape[1] <= 4 else 0, rec)
    return rec


def reduce(mod, lists, pair_arrays, n, workers):
    """``mod``'s per-Gaussian sums of each of ``pair_arrays``: into arrays of the caller's since 2026-11-28."""
    import numpy as np

    for values in pair_arrays:
        if "out" in parameters(mod.reduce_pairs):
            mod.reduce_pairs(lists, values, np.empty((n, values.shape[1]), values.dtype), workers)
        else:
            mod.reduce_pairs(lists, values, n, workers)


def across_processes(argv: list[str], count: int) -> int:
    """Run this benchmark ``count`` times, each in a process of its own (see the module's docstring), and print each
    stage's median ratio with the ratios' range, for the fixed layouts and the randomised ones apart."""
    import re
    import shutil
    import subprocess

    setarch = shutil.which("setarch")
    ratios: dict[tuple[str, str], list[float]] = {}
    for k in range(count):
        fixed = setarch is not None and k % 2 == 0
        env = dict(os.environ, BENCH_STACK_PAD="x" * ((448 + 512 * (k // 2)) % 4096 if fixed else 0))
        prefix = [setarch, os.uname().machine, "-R"] if fixed else []
        run = subprocess.run(prefix + [sys.executable, __file__, *argv], env=env, capture_output=True, text=True)
        if run.returncode != 0:
            print(run.stdout + run.stderr, file=sys.stderr)
            return run.returncode
        if k == 0:
            print(run.stdout.splitlines()[0])
        for m in re.finditer(r"^\s+(\S+ \S+)\s+this .* ratio ([\d.]+)x", run.stdout, re.M):
            ratios.setdefault((m.group(1), "fixed" if fixed else "randomised"), []).append(float(m.group(2)))
    print(f"against / this over {count} processes: median (range)")
    for (stage, layout), values in sorted(ratios.items()):
        print(f"  {stage:<22} {layout:<10} {statistics.median(values):.2f}x ({min(values):.2f}-{max(values):.2f}, "
              f"{len(values)} processes)")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("n", type=int, help="Gaussians")
    ap.add_argument("size", type=int, help="image width and height in pixels")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--channels", type=int, default=4, help="4: rgb + depth; else that many features alone")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--tile-size", type=int, default=None, help="tile edge in pixels (default: the renderer's)")
    ap.add_argument("--against", type=Path, default=None, help="another checkout whose kernels run beside these")
    ap.add_argument("--processes", type=int, default=0, help="with --against: this many processes, median ratios")
    args = ap.parse_args(argv)
    if args.processes:
        if args.against is None:
            ap.error("--processes needs --against")
        rest = list(sys.argv[1:] if argv is None else argv)
        at = next(i for i, a in enumerate(rest) if a.startswith("--processes"))
        return across_processes(rest[:at] + rest[at + (1 if "=" in rest[at] else 2):], args.processes)
    os.environ["ROODI_THREADS"] = str(args.threads)

    import numpy as np
    import torch

    sys.path.insert(0, str(HERE))
    from scene import bench_camera, cloud_arrays

    from roodi_toolkit.render import cores, fast, kernels, projection_kernels, tiles

    torch.set_num_threads(1)
    arrays = cloud_arrays(args.n)
    view = fast.make_view(*bench_camera(args.size), args.size, args.size, tile=args.tile_size or fast.TILE_SIZE)
    W = H = args.size
    workers = cores.set_workers()
    rng = np.random.default_rng(0)
    sides = {"this": (kernels, projection_kernels)}
    if args.against is not None:
        sides["against"] = load_kernels(args.against)

    times: dict[str, list[float]] = {}

    def clock(key, fn):
        t0 = time.perf_counter()
        result = fn()
        times.setdefault(key, []).append(time.perf_counter() - t0)
        return result

    n = args.n
    grads = rng.standard_normal((n, 10)).astype(np.float32)  # dL/d(means2d, conic, opacity, rgb, depth)

    f32 = np.float32
    buffers = {}  # per side: the projection's outputs and gradients, allocated once (page faults are not the code's)
    clamped = {}

    def project_both(name, pk):
        """Time ``pk``'s projection forward and backward (SH 3, every gradient) as the renderer calls them, into
        arrays that are written once before (fresh arrays' page faults weigh the same for both sides, and swing a
        backward by 2x between rounds on this machine)."""
        if name not in buffers:
            # the colours' array: rgb and depth since 2026-11-28 (``chan``), rgb alone before
            colours = 4 if "chan" in parameters(pk.project_forward) else 3
            buffers[name] = ((np.empty((n, 2), f32), np.empty((n, 3), f32), np.empty(n, f32),
                              np.empty((n, colours), f32),
                              np.empty(n, f32), np.zeros((n, 4), np.int32), np.zeros((n, 2), np.int32),
                              np.zeros(n, np.int64)),
                             (np.zeros((n, 3), f32), np.zeros((n, 4), f32), np.zeros((n, 3), f32), np.zeros(n, f32),
                              np.zeros(arrays[4].shape, f32)))
            clamped[name] = np.zeros(n, np.uint8)
        outs, g_out = buffers[name]
        for a in g_out:
            a.fill(0)
        cam = (view.view, view.center, view.intr, W, H, view.near, view.far, view.eps2d)
        if "scales" in parameters(pk.project_forward)[:3]:  # the activations made outside, timed
            # the SH clamp's flags, which the backward reads (since 2026-11-28)
            flags = (clamped[name],) if "clamped" in parameters(pk.project_forward) else ()
            t0 = time.perf_counter()
            scales, opacities, r2 = pk.activations(arrays[2], arrays[3])
            pk.project_forward(arrays[0], arrays[1], scales, opacities, r2, arrays[4], 16, *cam, view.tile,
                               *outs[:4], *outs[5:], *flags)
            t1 = time.perf_counter()
            pk.project_backward(arrays[0], arrays[1], scales, opacities, arrays[4], 16, *cam, outs[7], *flags,
                                *grads_in, *g_out, True)
        else:  # a checkout before 2026-11-28: the kernels take the log-scales and logits
            t0 = time.perf_counter()
            pk.project_forward(*arrays, 16, *cam, view.tile, *outs)
            t1 = time.perf_counter()
            pk.project_backward(*arrays, 16, *cam, outs[7], *grads_in, *g_out, True)
        t2 = time.perf_counter()
        return t1 - t0, t2 - t1

    grads_in = [np.ascontiguousarray(grads[:, a:b]) for a, b in ((0, 2), (2, 5))] + \
        [np.ascontiguousarray(grads[:, 5]), np.ascontiguousarray(grads[:, 6:9]), np.ascontiguousarray(grads[:, 9])]

    images = {}
    for rnd in range(args.repeats + 1):  # round 0 compiles and warms up; dropped
        proj = fast.project(*arrays, 16, view)
        turn = list(sides.items())[::-1 if rnd % 2 else 1]  # each side goes first every other round
        for name, (_, pk) in turn:
            fwd, bwd = project_both(name, pk)
            times.setdefault(f"{name} projection fwd", []).append(fwd)
            times.setdefault(f"{name} projection bwd", []).append(bwd)
        order = clock("depth order", lambda: tiles.depth_order(proj.ntiles, proj.depths, workers))
        lists, starts, counts = clock("binning", lambda: tiles.bin_tiles(order, proj.bounds, W, H, view.tile,
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
        for name, (mod, _) in turn:
            out = np.zeros((H, W, C), np.float32)
            t_final = np.ones((H, W), np.float32)
            last = np.zeros((H, W), np.int32)
            top = np.full((0, 0), -1, np.int32)
            extra = (mod.channel_groups(C),) if hasattr(mod, "channel_groups") else ()  # kernels before 4x4 blocks
            # the Gaussians' records made by the caller, once a render, since 2026-11-28 (the forward's time
            # includes them: the kernels made their own before); before, the kernels took the four arrays
            records = "rec" in parameters(mod.composite_forward)
            geometry = [None] if records else [proj.bounds, proj.means2d, proj.conics, proj.opacities]

            def forward():
                if records:
                    geometry[0] = make_records(mod, proj, channels)
                return mod.composite_forward(lists, starts, counts, busy, *geometry, channels, *extra, W, H,
                                             view.tile, workers, out, t_final, last, top, *marks)

            # the forward's marks of the blocks each pair blended in, which the backward walks (since 2026-11-28)
            marks = (np.zeros(fast.marks_shape(len(lists), view.tile), np.uint64),) \
                if "marks" in parameters(mod.composite_forward) else ()
            clock(f"{name} fwd", forward)
            pair_geom = np.zeros((len(lists), 6), np.float32)
            pair_chan = np.zeros((len(lists), C), np.float32)
            clock(f"{name} bwd", lambda: mod.composite_backward(lists, starts, counts, busy, *geometry, channels,
                                                                *extra, W, H, view.tile, workers, t_final, last,
                                                                *marks, g_out, g_alpha, bg, pair_geom, pair_chan, True))
            clock(f"{name} reduce", lambda: reduce(mod, lists, (pair_geom, pair_chan), args.n, workers))
            images[name] = (out, t_final)
        if rnd == 0:
            times.clear()
    print(f"{args.n} Gaussians, {W}x{H}, tile {view.tile}, {C} channels, {workers} thread(s); "
          f"{len(lists):,} (tile, Gaussian) pairs; median of {args.repeats} rounds (seconds); "
          f"load average {' '.join(f'{v:.1f}' for v in os.getloadavg())}")
    for key in ("depth order", "binning"):
        print(f"  {key:<22} {statistics.median(times[key]):.3f}")
    for stage in ("projection fwd", "projection bwd", "compositing fwd", "compositing bwd", "compositing reduce"):
        key = stage.replace("compositing ", "")
        row = "  " + stage.ljust(22)
        for name in sides:
            row += f" {name} {statistics.median(times[f'{name} {key}']):.3f}"
        if "against" in sides:
            ratio = statistics.median(times[f"against {key}"]) / statistics.median(times[f"this {key}"])
            best = min(times[f"against {key}"]) / min(times[f"this {key}"])
            row += f"  ratio {ratio:.2f}x (fastest rounds {best:.2f}x)"
        print(row)
    if "against" in sides:
        (a, ta), (b, tb) = images["this"], images["against"]
        print(f"  image difference (max |this - against|): colours {np.abs(a - b).max():.2e}, "
              f"transmittance {np.abs(ta - tb).max():.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
