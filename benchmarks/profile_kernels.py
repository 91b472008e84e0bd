"""Where a compiled renderer kernel spends its time, instruction by instruction (issue 33, item 3).

Numba's compiled code has no symbols that ``perf`` can read, so this runs the kernel in a child process that compiles
it afresh (an empty ``NUMBA_CACHE_DIR``), writes the machine code of the kernel's parallel body from memory with its
address, and then calls the kernel in a loop; ``perf record`` (the ``cpu-clock`` software event, which works inside
virtual machines without hardware counters) samples the child, and each sample's address is placed on an instruction
of that code (``objdump``). Prints the share of the samples in each 256-byte stretch of the body and the hottest
instructions; a sample lands on the instruction after one that waited (a load that missed, a division).

Scene: :func:`scene.scene_cloud` as in ``bench_render.py`` (camera at (3, -3, 2), 50 degree field of view, SH 3,
float32), rgb + depth, one thread.

Run: ``.venv/bin/python benchmarks/profile_kernels.py backward --n 500000 --size 800`` (``forward``, ``backward``,
``pairs``, ``project``, ``project_backward``). Needs ``perf`` and ``objdump`` (Debian: linux-perf, binutils).
"""

from __future__ import annotations

import argparse
import bisect
import collections
import ctypes
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
KERNELS = ("forward", "backward", "pairs", "project", "project_backward")


def child(kernel: str, n: int, size: int, folder: Path, calls: int) -> None:
    """Compile and run ``kernel`` ``calls`` times after writing its body's code and symbols into ``folder``."""
    import numpy as np

    sys.path.insert(0, str(HERE))
    from scene import bench_view, projection_grads

    from roodi_toolkit.render import fast, kernels, projection_kernels

    arrays, view, proj, bins, channels = bench_view(n, size)
    f32 = np.float32
    _, t_final, last, _, marks = fast.composite(bins, proj, channels, view, want_marks=True)
    g_out = [np.zeros((n, 3), f32), np.zeros((n, 4), f32), np.zeros((n, 3), f32), np.zeros(n, f32),
             np.zeros(arrays[4].shape, f32)]
    m = len(bins.lists)
    head = (bins.lists, bins.starts, bins.counts, bins.busy, fast.records(proj, channels))
    cam = (view.view, view.center, view.intr, size, size, view.near, view.far, view.eps2d)
    calls_of = {
        "forward": (kernels.composite_forward, lambda: fast.composite(bins, proj, channels, view, want_marks=True)),
        "backward": (kernels.composite_backward, lambda: kernels.composite_backward(
            *head, channels, kernels.channel_groups(4), size, size, view.tile, 1, t_final, last, marks,
            np.ones((size, size, 4), f32), np.zeros((size, size), f32), np.zeros(4), np.zeros((m, 6), f32),
            np.zeros((m, 4), f32), True)),
        "pairs": (kernels.composite_pairs, lambda: fast.compositing_pairs(bins, proj, view)),
        "project": (projection_kernels.project_forward, lambda: fast.project(*arrays, 16, view)),
        "project_backward": (projection_kernels.project_backward, lambda: projection_kernels.project_backward(
            arrays[0], arrays[1], proj.scales, proj.opacities, arrays[4], 16, *cam, proj.ntiles, proj.clamped,
            *projection_grads(n), *g_out, True)),
    }
    dispatcher, call = calls_of[kernel]
    call()
    library = dispatcher.overloads[dispatcher.signatures[0]].library
    symbols = {}
    for fn in library._final_module.functions:
        if not fn.is_declaration:
            try:
                symbols[fn.name] = library.get_pointer_to_function(fn.name)
            except Exception:  # a function the engine did not emit
                continue
    bodies = [name for name in symbols if "parfor_gufunc" in name]
    if not bodies:
        raise SystemExit(f"{kernel}: no parallel body found in the compiled library")
    starts = sorted(symbols.values())
    for i, name in enumerate(bodies):  # the machine code of each parallel body, up to the next function
        after = [a for a in starts if a > symbols[name]]
        size_bytes = min(after[0] - symbols[name] if after else 1 << 17, 1 << 17)
        (folder / f"code{i}.bin").write_bytes(ctypes.string_at(symbols[name], size_bytes))
    (folder / "symbols.json").write_text(json.dumps({"bodies": bodies, "symbols": symbols}))
    print("READY", flush=True)
    for _ in range(calls):
        call()


def report(folder: Path, samples_file: Path, top: int, context: int = 0, span: tuple[int, int] | None = None) -> None:
    """Print the body's share of the samples per 256-byte stretch and its hottest instructions (with the ``context``
    instructions before each of the three hottest: a sample lands after the instruction that waited), and every
    instruction of the body between the offsets ``span`` with its share."""
    meta = json.loads((folder / "symbols.json").read_text())
    starts = sorted(meta["symbols"].values())
    names = {v: k for k, v in meta["symbols"].items()}
    text = subprocess.run(["perf", "script", "-i", str(samples_file), "-F", "ip"], capture_output=True, text=True,
                          check=True).stdout
    ips = [int(x, 16) for x in text.split()]
    where = collections.Counter()
    offsets = collections.defaultdict(collections.Counter)
    for ip in ips:
        i = bisect.bisect_right(starts, ip) - 1
        name = names[starts[i]] if i >= 0 and ip - starts[i] < (1 << 17) else "elsewhere"
        where[name] += 1
        offsets[name][ip - starts[i] if i >= 0 else 0] += 1
    index = max(range(len(meta["bodies"])), key=lambda i: where[meta["bodies"][i]])
    body = meta["bodies"][index]
    at = offsets[body]
    listing = subprocess.run(["objdump", "-D", "-b", "binary", "-m", "i386:x86-64", "--no-show-raw-insn",
                              str(folder / f"code{index}.bin")], capture_output=True, text=True, check=True).stdout
    code = {int(m.group(1), 16): m.group(2) for m in re.finditer(r"^\s*([0-9a-f]+):\s*(.*)$", listing, re.M)}
    total = max(1, len(ips))
    shares = ", ".join(f"{'the parallel body' if k == body else k[:50]} {100 * v / total:.1f}%"
                       for k, v in where.most_common(4))
    print(f"{len(ips)} samples: {shares}")
    stretch = collections.Counter()
    for offset, count in at.items():
        stretch[offset // 256] += count
    print("body by 256-byte stretch (offset: share of all samples)")
    for k in sorted(stretch):
        if stretch[k] / total >= 0.01:
            print(f"  {k * 256:6x}: {100 * stretch[k] / total:5.1f}%")
    print(f"hottest {top} instructions (offset, share, instruction)")
    for offset, count in at.most_common(top):
        print(f"  {offset:6x} {100 * count / total:5.1f}%  {code.get(offset, '?')}")
    ordered = sorted(code)
    for offset, _ in at.most_common(3) if context else ():
        i = bisect.bisect_left(ordered, offset)
        print(f"before {offset:x}:")
        for o in ordered[max(0, i - context):i + 1]:
            print(f"  {o:6x} {100 * at[o] / total:5.1f}%  {code[o]}")
    if span:
        print(f"instructions {span[0]:x}-{span[1]:x}")
        for o in ordered:
            if span[0] <= o < span[1]:
                print(f"  {o:6x} {100 * at[o] / total:5.1f}%  {code[o]}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("kernel", choices=KERNELS)
    ap.add_argument("--n", type=int, default=500_000, help="Gaussians (default 500000)")
    ap.add_argument("--size", type=int, default=800, help="image width and height (default 800)")
    ap.add_argument("--seconds", type=float, default=6.0, help="how long perf samples (default 6)")
    ap.add_argument("--top", type=int, default=20, help="hottest instructions to print (default 20)")
    ap.add_argument("--context", type=int, default=0, help="instructions to print before each of the 3 hottest")
    ap.add_argument("--listing", default=None, metavar="LO-HI",
                    help="print every instruction between these hexadecimal offsets of the body, with its share")
    ap.add_argument("--child", type=Path, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--calls", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None:
        child(args.kernel, args.n, args.size, args.child, args.calls)
        return 0
    missing = [tool for tool in ("perf", "objdump") if shutil.which(tool) is None]
    if missing:
        print(f"profile_kernels: {' and '.join(missing)} not found: install linux-perf and binutils", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        env = dict(os.environ, NUMBA_CACHE_DIR=str(folder / "cache"), ROODI_THREADS="1")
        proc = subprocess.Popen([sys.executable, __file__, args.kernel, "--n", str(args.n), "--size", str(args.size),
                                 "--child", str(folder), "--calls", "1000000"], env=env, stdout=subprocess.PIPE,
                                text=True)
        try:
            if proc.stdout.readline().strip() != "READY":
                print("profile_kernels: the kernel's process stopped before it ran", file=sys.stderr)
                return 1
            time.sleep(1.0)
            samples = folder / "perf.data"
            subprocess.run(["perf", "record", "-q", "-e", "cpu-clock", "-F", "4000", "-p", str(proc.pid), "-o",
                            str(samples), "--", "sleep", str(args.seconds)], check=True, capture_output=True)
        finally:
            proc.kill()
            proc.wait()
        print(f"{args.kernel}: {args.n:,} Gaussians, {args.size}x{args.size}, one thread, {args.seconds:g} s sampled")
        span = tuple(int(x, 16) for x in args.listing.split("-")) if args.listing else None
        report(folder, samples, args.top, args.context, span)
    return 0


if __name__ == "__main__":
    sys.exit(main())
