"""The kernels' threading layer: numba's OpenMP layer (the default since 2026-11-28) against its ``workqueue`` (the
default before), side by side.

The layer is chosen once per process, so each measurement is a fresh process with ``NUMBA_THREADING_LAYER`` set;
processes alternate between the layers for ``--rounds`` rounds, so both see the same load. Each measures the start of
an empty parallel region (median over 2,000, in microseconds) and one view of ``bench_render.py``'s scene, forward
and forward+backward (its loss: sum of RGB and depth), with the kernels on ``--threads`` threads and PyTorch on
``--torch-threads`` (default the same, as ``bench_render.py`` runs them), median of ``--repeats`` after a warm-up.
Prints each layer's medians over the rounds and the ratio of ``workqueue``'s times to each layer's. TBB is measured
too where it is installed. With ``--train DATA``, a training step too (``Trainer`` with the default settings on DATA
at ``--downscale``, from its initialisation, the steps after 3 of warm-up).

    .venv/bin/python benchmarks/bench_layers.py 100000 256 --threads 2
    .venv/bin/python benchmarks/bench_layers.py 500000 800 --threads 2 --rounds 3
    .venv/bin/python benchmarks/bench_layers.py 100000 256 --threads 2 --train ../shared/data/lego
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
LAYERS = ("workqueue", "omp", "tbb")


def train_step(data: Path, downscale: float, steps: int) -> float:
    """Median seconds of a training step (after 3 of warm-up)."""
    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.pipeline.train import TrainConfig, Trainer

    trainer = Trainer(load_dataset(data, downscale), TrainConfig())
    times = []
    for i in range(steps + 3):
        t0 = time.perf_counter()
        trainer.train_step()
        if i >= 3:
            times.append(time.perf_counter() - t0)
    return statistics.median(times)


def child(n: int, size: int, threads: int, torch_threads: int, repeats: int, train: Path | None,
          downscale: float) -> dict:
    """Measure in this process (its layer set by the environment)."""
    os.environ["ROODI_THREADS"] = str(threads)
    import numba
    import numpy as np
    import torch

    torch.set_num_threads(torch_threads)
    sys.path.insert(0, str(HERE))
    import bench_render

    from roodi_toolkit.render import cores
    from roodi_toolkit.render.fast import rasterize_fast

    layer = cores.layer()
    cores.set_workers()

    @numba.njit(parallel=True)
    def empty(a, w):
        for i in numba.prange(w):
            a[i] += 1.0

    a = np.zeros(threads)
    empty(a, threads)
    starts = []
    for _ in range(2000):
        t0 = time.perf_counter()
        empty(a, threads)
        starts.append(time.perf_counter() - t0)

    params, w2c, K = bench_render._setup(n, size)
    times: dict[str, list[float]] = {"fwd": [], "both": []}
    for rep in range(repeats + 1):
        t0 = time.perf_counter()
        with torch.no_grad():
            rasterize_fast(*bench_render._args(params), w2c, K, size, size)
        t1 = time.perf_counter()
        for p in params.values():
            p.grad = None
        out = rasterize_fast(*bench_render._args(params), w2c, K, size, size)
        (out.rgb.sum() + out.depth.sum()).backward()
        t2 = time.perf_counter()
        if rep:
            times["fwd"].append(t1 - t0)
            times["both"].append(t2 - t1)
    step = {"step": train_step(train, downscale, 4 * repeats)} if train is not None else {}
    return {"layer": layer, "start_us": 1e6 * statistics.median(starts),
            **{k: statistics.median(v) for k, v in times.items()}, **step}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("n", type=int, help="Gaussians")
    ap.add_argument("size", type=int, help="image width and height in pixels")
    ap.add_argument("--threads", type=int, default=2, help="the kernels' threads")
    ap.add_argument("--torch-threads", type=int, default=None, help="PyTorch's threads (default: --threads)")
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--train", type=Path, default=None, help="a dataset: time a training step on it too")
    ap.add_argument("--downscale", type=float, default=4)
    ap.add_argument("--child", choices=LAYERS, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    torch_threads = args.threads if args.torch_threads is None else args.torch_threads
    if args.child:
        print(json.dumps(child(args.n, args.size, args.threads, torch_threads, args.repeats, args.train,
                               args.downscale)))
        return 0

    results: dict[str, list[dict]] = {}
    for r in range(args.rounds):
        for layer in (LAYERS if r % 2 == 0 else LAYERS[::-1]):
            env = {**os.environ, "NUMBA_THREADING_LAYER": layer}
            cmd = [sys.executable, __file__, str(args.n), str(args.size), "--threads", str(args.threads),
                   "--torch-threads", str(torch_threads), "--repeats", str(args.repeats), "--child", layer,
                   "--downscale", str(args.downscale)] + (["--train", str(args.train)] if args.train else [])
            proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
            if proc.returncode != 0:  # TBB not installed, or no OpenMP runtime: that layer is left out
                results.setdefault(layer, [])
                continue
            results.setdefault(layer, []).append(json.loads(proc.stdout.strip().splitlines()[-1]))
    print(f"{args.n} Gaussians, {args.size}x{args.size}, kernels on {args.threads} thread(s), PyTorch on "
          f"{torch_threads}; medians over {args.rounds} processes a layer; load average {os.getloadavg()[0]:.1f}")
    keys = ("start_us", "fwd", "both") + (("step",) if args.train else ())
    print(f"{'layer':10} {'start us':>9} {'fwd s':>8} {'f+b s':>8} {'x fwd':>6} {'x f+b':>6}"
          + (f" {'step s':>7} {'x step':>6}" if args.train else ""))
    base = {k: statistics.median(r[k] for r in results["workqueue"]) for k in keys}
    for layer, rows in results.items():
        if not rows:
            print(f"{layer:10} not available")
            continue
        m = {k: statistics.median(r[k] for r in rows) for k in keys}
        print(f"{layer:10} {m['start_us']:9.1f} {m['fwd']:8.4f} {m['both']:8.4f} {base['fwd'] / m['fwd']:6.2f} "
              f"{base['both'] / m['both']:6.2f}" + (f" {m['step']:7.3f} {base['step'] / m['step']:6.2f}"
                                                    if args.train else ""))
    print("x = workqueue's time / the layer's (the default before 2026-11-28 against each)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
