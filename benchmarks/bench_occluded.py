"""ROODI against "w/o inpainting" and the SAGA- and Gaussian Grouping-style baselines on the occluded scenes (issue 22).

Each preset's occluded variant (``make-scene --occluded``: every target stands in a wrap touching it, which hides its
lower part from every training view) is generated into ``ROOT/<preset>_occluded`` at a small size, and
:func:`roodi_toolkit.evaluate.benchmark.run_benchmark` runs the methods on it: the paper's box metrics and the same
metrics inside each test view's never-seen region, with the issue's checks. ``--inpainter`` picks the inpainter plugin
of the methods that inpaint, so the run can be repeated with other fills (give each its own OUT).

Usage: nice -n 10 .venv/bin/python benchmarks/bench_occluded.py ROOT OUT [--preset kitchen ...] [--seed 0]
       [--size 64] [--iterations 1500] [--inpainter opencv] [--method full --method no_inpaint ...]

Writes OUT/results.md and OUT/results.json (the tables), OUT/<preset>_occluded.png (pictures) and prints the
never-seen share of every target and the tables' means.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from roodi_toolkit.evaluate.benchmark import (MACHINE_SIZE, METHODS, PRESETS, SHORT, extract_config,  # noqa: E402
                                              run_benchmark)
from roodi_toolkit.plugins import load_plugin  # noqa: E402

DEFAULT_METHODS = ("full", "no_inpaint", "feature_similarity", "gaussian_grouping")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("root", help="where the occluded scenes are generated (or reused)")
    ap.add_argument("out", help="models, objects, scores and tables")
    ap.add_argument("--preset", action="append", choices=PRESETS, help="repeat; default all four")
    ap.add_argument("--method", action="append", choices=tuple(METHODS),
                    help=f"repeat; default {', '.join(DEFAULT_METHODS)}")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", type=int, default=MACHINE_SIZE.size, help="image side of the scenes (default 64)")
    ap.add_argument("--train-views", type=int, default=MACHINE_SIZE.train_views)
    ap.add_argument("--test-views", type=int, default=MACHINE_SIZE.test_views)
    ap.add_argument("--iterations", type=int, default=MACHINE_SIZE.iterations)
    ap.add_argument("--inpainter", default="opencv", help="inpainter plugin of the methods that inpaint")
    args = ap.parse_args(argv)

    # one PyTorch thread unless $ROODI_THREADS says otherwise, as the CLI runs (two threads on a busy 2-core
    # machine made every training step ~10x slower, and the thread count changes float summation order)
    torch.set_num_threads(int(os.environ.get("ROODI_THREADS", "1")))
    load_plugin("inpainters", args.inpainter)  # fail before training on an unknown name
    size = replace(MACHINE_SIZE, size=args.size, train_views=args.train_views, test_views=args.test_views,
                   iterations=args.iterations)
    config = replace(extract_config(size, args.seed), inpainter=args.inpainter)
    t0 = time.perf_counter()
    results = run_benchmark(args.root, args.out, presets=args.preset or PRESETS, seed=args.seed, size=size,
                            methods=args.method or DEFAULT_METHODS, config=config, occluded=True)
    for scene, per in results["scenes"].items():
        shares = ", ".join(f"{o['object_name']} {100 * o['never_seen_share']:.1f}%"
                           for o in per["full"]["objects"] if "never_seen_share" in o)
        print(f"{scene}: never seen in training: {shares}")
    print(f"{'method':<48} {'PSNR':>6} {'SSIM':>6} {'IoU':>6} | never-seen: {'PSNR':>6} {'SSIM':>6} {'IoU':>6}")

    def f(v: float | None, d: int) -> str:
        return "n/a" if v is None else f"{v:.{d}f}"

    for m, s in results["mean"].items():
        print(f"{SHORT[m]:<48} {f(s['psnr'], 2):>6} {f(s['ssim'], 3):>6} {f(s['iou'], 3):>6} | "
              f"{'':>11} {f(s.get('ns_psnr'), 2):>6} {f(s.get('ns_ssim'), 3):>6} {f(s.get('ns_iou'), 3):>6}")
    for c in results["checks"]:
        print(f"{'info' if c['met'] is None else 'met' if c['met'] else 'NOT met'}: {c['check']} ({c['value']:+.3f})")
    print(f"tables: {args.out}/results.md ({(time.perf_counter() - t0) / 60:.1f} min)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
