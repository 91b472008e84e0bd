"""Scene training on the CPU: time per iteration and held-out PSNR over time, on a generated scene or a real dataset.

Issue 7's target: a generated scene at 128x128 trains to at least 27 dB PSNR on its held-out full-scene views within
15 minutes on 2 cores. Issue 20's: the statue capture (COLMAP) at 1/4 resolution to 23 dB within 20 minutes, lego at
200x200 to 30 dB (white background) within 15 minutes. Prints the PSNR curve (held-out views, every --eval-every
iterations) with the training time, and the median seconds per iteration.

    .venv/bin/python benchmarks/bench_train.py --preset bedroom --size 128 --minutes 15
    .venv/bin/python benchmarks/bench_train.py --data ../shared/data/statue --downscale 4 --minutes 20
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="bedroom")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--minutes", type=float, default=15.0, help="wall-clock budget for training")
    ap.add_argument("--iterations", type=int, default=30000, help="schedule length (the budget usually ends first)")
    ap.add_argument("--data", type=Path, default=None, help="train this dataset (COLMAP, Blender) instead")
    ap.add_argument("--downscale", type=float, default=1.0)
    ap.add_argument("--threads", type=int, default=1, help="torch threads (the CLI's default: 1)")
    ap.add_argument("--init", default=None, help="[depth for generated scenes, auto for --data]")
    ap.add_argument("--init-points", type=int, default=20000)
    ap.add_argument("--cap-max", type=int, default=60000)
    ap.add_argument("--eval-every", type=int, default=250)
    ap.add_argument("--scene", type=Path, default=None, help="reuse a generated scene folder")
    ap.add_argument("--json", type=Path, default=None, help="write the curve here")
    args = ap.parse_args(argv)

    import torch

    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.synth.scene import SceneSettings, make_scene
    from roodi_toolkit.pipeline.train import TrainConfig, Trainer, config_with

    torch.set_num_threads(args.threads)
    scene = args.data or args.scene
    init = args.init or ("auto" if args.data else "depth")
    if args.data is None and (scene is None or not (scene / "transforms_train.json").exists()):
        scene = scene or Path(tempfile.mkdtemp()) / args.preset
        t = time.perf_counter()
        make_scene(scene, args.preset, args.seed,
                   settings=SceneSettings(width=args.size, height=args.size, test_views=1))
        print(f"generated {scene} in {time.perf_counter() - t:.1f} s", flush=True)
    ds = load_dataset(scene, args.downscale)
    cfg = config_with(TrainConfig(), iterations=args.iterations, init=init, init_num_points=args.init_points,
                      cap_max=args.cap_max)
    trainer = Trainer(ds, cfg)
    print(f"{len(trainer.train_indices)} training views, {len(trainer.eval_indices)} held-out views, "
          f"{ds.width}x{ds.height}, init {init} ({trainer.num_gaussians} Gaussians), cap_max {args.cap_max}, "
          f"random background {trainer.config.random_background}", flush=True)
    budget = args.minutes * 60
    step_times: list[float] = []
    curve = []
    t0 = time.perf_counter()
    train_time = 0.0
    cpu_time = 0.0  # the process's CPU time in training steps (all threads): on a shared machine the wall time is not
    # the work; with ROODI_THREADS=1 it is the time the steps take on one idle core
    while trainer.step < cfg.iterations and train_time < budget:
        s, c = time.perf_counter(), time.process_time()
        trainer.train_step()
        dt = time.perf_counter() - s
        cpu_time += time.process_time() - c
        step_times.append(dt)
        train_time += dt
        if trainer.step % args.eval_every == 0:
            ev = trainer.evaluate()
            curve.append({"step": trainer.step, "train_seconds": round(train_time, 1),
                          "train_cpu_seconds": round(cpu_time, 1), "psnr": round(ev["psnr"], 2),
                          "ssim": round(ev["ssim"], 4), "gaussians": trainer.num_gaussians})
            print(f"step {trainer.step:6d}  {train_time / 60:5.1f} min ({cpu_time / 60:5.1f} CPU min)  held-out PSNR "
                  f"{ev['psnr']:6.2f} dB  SSIM {ev['ssim']:.3f}  {trainer.num_gaussians:,} Gaussians  "
                  f"{statistics.median(step_times[-args.eval_every:]) * 1000:.0f} ms/it", flush=True)
    ev = trainer.evaluate()
    curve.append({"step": trainer.step, "train_seconds": round(train_time, 1), "train_cpu_seconds": round(cpu_time, 1),
                  "psnr": round(ev["psnr"], 2), "ssim": round(ev["ssim"], 4), "gaussians": trainer.num_gaussians})
    print(f"final: {trainer.step} iterations in {train_time / 60:.1f} min of training, {cpu_time / 60:.1f} CPU min "
          f"({(time.perf_counter() - t0) / 60:.1f} min with evaluation), held-out PSNR {ev['psnr']:.2f} dB, "
          f"SSIM {ev['ssim']:.3f}, median {statistics.median(step_times) * 1000:.0f} ms/iteration, "
          f"{trainer.num_gaussians:,} Gaussians; load average {os.getloadavg()[0]:.1f} at the end")
    if args.json:
        args.json.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "curve": curve}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
