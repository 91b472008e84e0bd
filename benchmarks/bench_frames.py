"""Whole frames of the default renderer: this checkout against another, in alternating processes (issue 33, item 3).

A kernel's time moves with where a process's memory lies (``bench_render_stages.py --processes``), and a frame's with
the host's load: so each measurement is a fresh process, alternating between the two checkouts (``PYTHONPATH`` set
to each, so every module of the renderer is that checkout's, its numba cache its own) for ``--processes`` pairs, the
first side swapped every other pair. Each process renders ``bench_render.py``'s scene (or ``--splat``'s) with
``rasterize_fast``: ``--repeats`` frames forward (``torch.no_grad()``) and forward+backward (its loss: sum of RGB and
depth), after three of warm-up, on ``--threads`` threads (kernels and PyTorch). Prints each side's median frame and
the median and range of the per-pair ratios (other / this: above 1, this checkout is faster).

    git worktree add /tmp/start <commit> --detach
    .venv/bin/python benchmarks/bench_frames.py 100000 256 --against /tmp/start --processes 8 --repeats 15
    .venv/bin/python benchmarks/bench_frames.py 500000 800 --threads 2 --against /tmp/start --processes 6 --repeats 5
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def frames(n: int, size: int, repeats: int, threads: int) -> dict:
    """Median seconds of a forward and of a forward+backward frame in this process."""
    import torch

    sys.path.insert(0, str(HERE))
    from bench_render import _args, _setup

    from roodi_toolkit.render.fast import rasterize_fast

    torch.set_num_threads(threads)
    params, w2c, K = _setup(n, size)

    def both():
        for p in params.values():
            p.grad = None
        out = rasterize_fast(*_args(params), w2c, K, size, size)
        (out.rgb.sum() + out.depth.sum()).backward()

    def forward():
        with torch.no_grad():
            rasterize_fast(*_args(params), w2c, K, size, size)

    for _ in range(3):
        both()
    fwd, full = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        forward()
        t1 = time.perf_counter()
        both()
        fwd.append(t1 - t0)
        full.append(time.perf_counter() - t1)
    return {"fwd": statistics.median(fwd), "both": statistics.median(full)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("n", type=int, help="Gaussians")
    ap.add_argument("size", type=int, help="image width and height")
    ap.add_argument("--against", type=Path, help="the other checkout (a git worktree)")
    ap.add_argument("--processes", type=int, default=8, help="pairs of processes (default 8)")
    ap.add_argument("--repeats", type=int, default=15, help="frames a process (default 15)")
    ap.add_argument("--threads", type=int, default=1, help="kernel and PyTorch threads (default 1)")
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(frames(args.n, args.size, args.repeats, args.threads)))
        return 0
    if args.against is None or not (args.against / "roodi_toolkit").is_dir():
        ap.error("--against must name a checkout of the project (a folder holding roodi_toolkit/)")
    sides = {"this": ROOT, "other": args.against.resolve()}
    results: dict[str, list[dict]] = {name: [] for name in sides}
    for k in range(args.processes):
        for name in (("this", "other") if k % 2 == 0 else ("other", "this")):
            env = dict(os.environ, PYTHONPATH=str(sides[name]), ROODI_THREADS=str(args.threads))
            cmd = [sys.executable, str(HERE / "bench_frames.py"), str(args.n), str(args.size), "--one", "--repeats",
                   str(args.repeats), "--threads", str(args.threads)]
            run = subprocess.run(cmd, env=env, cwd=sides[name], capture_output=True, text=True)
            if run.returncode:
                print(f"bench_frames: the {name} checkout's process failed:\n{run.stderr[-2000:]}", file=sys.stderr)
                return 1
            results[name].append(json.loads(run.stdout.strip().splitlines()[-1]))
    print(f"{args.n} Gaussians, {args.size}x{args.size}, {args.threads} thread(s); {args.processes} pairs of processes "
          f"of {args.repeats} frames; load average {' '.join(f'{v:.1f}' for v in os.getloadavg())}")
    for key, label in (("fwd", "forward"), ("both", "forward+backward")):
        mine = [r[key] for r in results["this"]]
        other = [r[key] for r in results["other"]]
        ratios = sorted(o / m for o, m in zip(other, mine))
        print(f"  {label:<17} this {statistics.median(mine):.4f} s  other {statistics.median(other):.4f} s  "
              f"other / this {statistics.median(ratios):.2f}x ({ratios[0]:.2f}-{ratios[-1]:.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
