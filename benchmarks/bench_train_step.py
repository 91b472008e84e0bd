"""One training step, compiled against the reference, side by side: what a step costs besides the renderer.

Two trainers start from the same model (a trained PLY, or the random initialisation) on the same dataset; steps
alternate between them, and so do the per-part timings:

- reference: unfused Adam (``torch.optim.Adam`` per parameter, the for-loop implementation), kornia's SSIM with
  autograd, the MCMC position noise through ``[N, 3, 3]`` covariances in torch;
- compiled (what ``Trainer`` does): fused Adam, :func:`roodi_toolkit.pipeline.train_kernels.ssim` and
  :func:`~roodi_toolkit.pipeline.train_kernels.covariance_noise`.

Prints medians of wall and CPU time (the process's, all threads) per step and per part, each part's ratio, and the
load average (the machine may be shared: compare the ratios, taken in one run). The renderer is the same in both.

    .venv/bin/python benchmarks/bench_train_step.py ../shared/data/lego --downscale 4 \\
        --model MODEL/point_cloud/iteration_3000/point_cloud.ply --steps 30
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Callable


def _timed(fn: Callable[[], object]) -> tuple[float, float]:
    w, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w, time.process_time() - c


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("--downscale", type=float, default=4)
    ap.add_argument("--model", type=Path, default=None, help="start from this PLY (default: the initialisation)")
    ap.add_argument("--steps", type=int, default=30, help="steps of each trainer (the first 3 are not timed)")
    ap.add_argument("--at-step", type=int, default=2050, help="the schedule's step to time at (sets the SH degree)")
    args = ap.parse_args(argv)

    import torch

    import roodi_toolkit.pipeline.train as train_module
    from roodi_toolkit.imaging import ssim as kornia_ssim
    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.io.ply import read_ply
    from roodi_toolkit.params import GaussianParams
    from roodi_toolkit.pipeline import strategy as strategy_module
    from roodi_toolkit.pipeline import train_kernels
    from roodi_toolkit.pipeline.train import TrainConfig, Trainer

    torch.set_num_threads(int(os.environ.get("ROODI_THREADS", "1")))
    ds = load_dataset(args.data, args.downscale)
    config = TrainConfig()
    trainers = {}
    for name in ("reference", "compiled"):
        trainer = Trainer(ds, config)
        if args.model is not None:
            cloud = read_ply(args.model)
            trainer.params = GaussianParams.from_cloud(cloud, sh_degree=config.sh_degree, requires_grad=True)
        trainer._make_optimizers(fused=name == "compiled")
        trainer.step = args.at_step
        trainers[name] = trainer
    paths = {"reference": (kornia_ssim, strategy_module.covariance_noise_reference),
             "compiled": (train_kernels.ssim, train_kernels.covariance_noise)}
    n = trainers["compiled"].num_gaussians
    print(f"{ds.width}x{ds.height}, {n:,} Gaussians, SH degree {trainers['compiled'].sh_degree}, "
          f"torch threads {torch.get_num_threads()}, ROODI_THREADS {os.environ.get('ROODI_THREADS', '(all cores)')}",
          flush=True)

    steps: dict[str, list[tuple[float, float]]] = {k: [] for k in trainers}
    parts: dict[str, dict[str, list[tuple[float, float]]]] = {k: {"ssim fwd+bwd": [], "adam": [], "noise": []}
                                                               for k in trainers}
    g = torch.Generator().manual_seed(0)
    image = torch.rand(ds.height, ds.width, 3, generator=g)
    for i in range(args.steps):
        for name, trainer in trainers.items():
            ssim_fn, noise_fn = paths[name]
            train_module.ssim_loss, train_kernels.covariance_noise = ssim_fn, noise_fn
            step = _timed(trainer.train_step)
            # the parts alone, on this trainer's parameters and a rendering-sized image
            render = image.clone().requires_grad_()
            ssim = _timed(lambda: ssim_fn(render, ds.images[0], 11).backward())
            for p in trainer.params.values():
                p.grad = torch.full_like(p, 1e-3)

            def adam() -> None:
                for opt in trainer.optimizers.values():
                    opt.step()
                    opt.zero_grad(set_to_none=True)

            adam_t = _timed(adam)
            noise = _timed(lambda: strategy_module.inject_position_noise(trainer.params, 1e-9, g))
            if i >= 3:
                steps[name].append(step)
                for key, value in (("ssim fwd+bwd", ssim), ("adam", adam_t), ("noise", noise)):
                    parts[name][key].append(value)
    train_module.ssim_loss, train_kernels.covariance_noise = paths["compiled"]

    def med(values: list[tuple[float, float]], i: int) -> float:
        return 1000 * statistics.median(v[i] for v in values)

    print(f"\n{'':14s} {'reference ms':>24s} {'compiled ms':>24s} {'ratio':>14s}")
    print(f"{'':14s} {'wall':>11s} {'cpu':>12s} {'wall':>11s} {'cpu':>12s} {'wall':>6s} {'cpu':>7s}")
    for key in ["whole step", "ssim fwd+bwd", "adam", "noise"]:
        ref = steps["reference"] if key == "whole step" else parts["reference"][key]
        new = steps["compiled"] if key == "whole step" else parts["compiled"][key]
        print(f"{key:14s} {med(ref, 0):11.1f} {med(ref, 1):12.1f} {med(new, 0):11.1f} {med(new, 1):12.1f} "
              f"{med(new, 0) / med(ref, 0):6.2f} {med(new, 1) / med(ref, 1):7.2f}")
    print(f"\nmedians of {args.steps - 3} steps each, alternated; load average {os.getloadavg()[0]:.1f} "
          f"(1 min) on {os.cpu_count()} cores")
    return 0


if __name__ == "__main__":
    sys.exit(main())
