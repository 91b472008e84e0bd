"""PyTorch intra-op threads: training-step time with 1 thread against N threads, side by side, in one run.

The CLI runs PyTorch on one thread by default (``--threads`` / ``$ROODI_THREADS``). This measures why: the renderer
is many small tensor operations, and OpenMP threads that spin while another process holds a core cost far more than
they save. Run it on the machine you care about (quiet and busy give different answers):

    .venv/bin/python benchmarks/bench_threads.py --scene SCENE_DIR --threads 1 2
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path


def step_times(scene: Path, threads: int, gaussians: int, warmup: int, rounds: int, steps: int) -> list[float]:
    import torch

    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.pipeline.strategy import MCMCStrategy
    from roodi_toolkit.pipeline.train import TrainConfig, Trainer

    torch.set_num_threads(threads)
    ds = load_dataset(scene)
    trainer = Trainer(ds, TrainConfig(iterations=100_000, init="depth", init_num_points=gaussians, eval_every=0,
                                      strategy=MCMCStrategy(cap_max=gaussians)))
    for _ in range(warmup):
        trainer.train_step()
    out = []
    for _ in range(rounds):
        t = time.perf_counter()
        for _ in range(steps):
            trainer.train_step()
        out.append((time.perf_counter() - t) / steps)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", type=Path, required=True, help="a generated (or any Blender/COLMAP) scene folder")
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--gaussians", type=int, default=9000)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--steps", type=int, default=20)
    args = ap.parse_args(argv)
    import os

    medians = {}
    for n in args.threads:
        times = step_times(args.scene, n, args.gaussians, 10, args.rounds, args.steps)
        medians[n] = statistics.median(times)
        print(f"threads {n}: median {1000 * medians[n]:.1f} ms/step over {args.rounds} rounds of {args.steps}")
    base = medians[args.threads[0]]
    for n in args.threads[1:]:
        print(f"threads {n} / threads {args.threads[0]}: {medians[n] / base:.2f}x the time per step")
    print(f"load average at the end: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
