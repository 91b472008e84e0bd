"""ROODI against "w/o inpainting" and the SAGA- and Gaussian Grouping-style baselines on the occluded scenes (issues
22 and 37), over several seeds.

Each preset's occluded variant (``make-scene --occluded``: every target stands in a wrap touching it, which hides its
lower part from every training view) is generated into ``ROOT/seed_<S>/<preset>_occluded`` at a small size, and
:func:`roodi_toolkit.evaluate.benchmark.run_benchmark` runs the methods on it into ``OUT/seed_<S>``: the paper's box
metrics and the same metrics inside each test view's never-seen region, with the issue's checks. Every seed gives
new scenes (the generator's seed) and new trainings (the training seed). ``--inpainter`` picks the inpainter plugin
of the methods that inpaint, so the run can be repeated with other fills (give each its own OUT).

Usage: nice -n 10 .venv/bin/python benchmarks/bench_occluded.py ROOT OUT [--seed 0 --seed 1 ...] [--preset kitchen ...]
       [--size 64] [--iterations 1500] [--inpainter symmetry] [--method full --method no_inpaint ...]

Writes per seed ``OUT/seed_<S>/results.md``, ``results.json`` and ``<preset>_occluded.png`` (pictures), and over the
seeds ``OUT/results.md`` and ``OUT/results.json``: every method's mean over the seeds with the sample standard
deviation and the range of the seeds' figures (a seed's figure is the mean over its scenes), and the issue's checks
on every seed and on the means. PyTorch runs on ``$ROODI_THREADS`` threads (default 1, as the CLI runs).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Optional

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from roodi_toolkit.evaluate.benchmark import (MACHINE_SIZE, METHODS, PRESETS, SHORT, checks,  # noqa: E402
                                              extract_config, run_benchmark)
from roodi_toolkit.io.files import atomic_path, write_json  # noqa: E402
from roodi_toolkit.plugins import load_plugin  # noqa: E402
from roodi_toolkit.synth.scene import make_benchmark_scene  # noqa: E402

DEFAULT_METHODS = ("full", "no_inpaint", "feature_similarity", "gaussian_grouping")
DEFAULT_SEEDS = (0, 1, 2)
KEYS = ("psnr", "ssim", "iou", "ns_psnr", "ns_ssim", "ns_iou")


def spread(values: list[Optional[float]]) -> dict[str, Any]:
    """Return the mean, sample standard deviation (None for one value), minimum, maximum and the values themselves.

    Example:
        >>> s = spread([1.0, 2.0, 3.0])
        >>> s["mean"], s["std"], s["min"], s["max"]
        (2.0, 1.0, 1.0, 3.0)
    """
    vals = [v for v in values if v is not None and not math.isnan(v)]
    if not vals:
        return {"mean": None, "std": None, "min": None, "max": None, "values": values}
    return {"mean": float(np.mean(vals)), "std": float(np.std(vals, ddof=1)) if len(vals) > 1 else None,
            "min": float(min(vals)), "max": float(max(vals)), "values": values}


def over_seeds(per_seed: dict[int, dict[str, Any]]) -> dict[str, Any]:
    """Return the methods' figures over the seeds (:func:`spread` of each metric), the issue's checks on every seed
    and on the means over the seeds (a check is met on every seed when each seed meets it)."""
    methods = [m for m in METHODS if any(m in r["mean"] for r in per_seed.values())]
    table = {m: {k: spread([r["mean"].get(m, {}).get(k) for r in per_seed.values()]) for k in KEYS}
             for m in methods}
    on_mean = checks({m: {k: s["mean"] for k, s in table[m].items()} for m in methods})
    rows = []
    for c in on_mean:
        seeds = {s: next((x for x in r["checks"] if x["check"] == c["check"]), None) for s, r in per_seed.items()}
        every = None if c["met"] is None or any(x is None for x in seeds.values()) \
            else all(x["met"] for x in seeds.values())
        rows.append({**c, "seeds": {s: None if x is None else x["value"] for s, x in seeds.items()},
                     "met_every_seed": every})
    return {"seeds": list(per_seed), "methods": table, "checks": rows}


def markdown(summary: dict[str, Any], inpainter: str) -> str:
    def f(s: dict[str, Any], d: int) -> str:
        if s["mean"] is None:
            return "n/a"
        sd = "" if s["std"] is None else f" ± {s['std']:.{d}f}"
        return f"{s['mean']:.{d}f}{sd} [{s['min']:.{d}f}, {s['max']:.{d}f}]"

    seeds = ", ".join(str(s) for s in summary["seeds"])
    lines = [f"# Occluded scenes over seeds {seeds} (inpainter `{inpainter}`)", "",
             "Mean over the seeds ± sample standard deviation [lowest, highest seed]; a seed's figure is the mean "
             "over its scenes, a scene's the mean over its targets. Per seed: `seed_<S>/results.md`.", "",
             "| Method | PSNR | SSIM | IoU | never-seen PSNR | never-seen SSIM | never-seen IoU |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for m, t in summary["methods"].items():
        lines.append(f"| {SHORT[m]} | " + " | ".join(f(t[k], 3 if k.endswith(("ssim", "iou")) else 2)
                                                   for k in KEYS) + " |")
    lines += ["", "| Check | on the means | seeds | met (means / every seed) |", "| --- | --- | --- | --- |"]
    for c in summary["checks"]:
        per = ", ".join("n/a" if v is None else f"{v:+.3f}" for v in c["seeds"].values())
        met = "info" if c["met"] is None else f"{'yes' if c['met'] else 'NO'} / " \
            f"{'n/a' if c['met_every_seed'] is None else 'yes' if c['met_every_seed'] else 'NO'}"
        lines.append(f"| {c['check']} | {c['value']:+.3f} | {per} | {met} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("root", help="where the occluded scenes are generated (or reused), one folder per seed")
    ap.add_argument("out", help="models, objects, scores and tables, one folder per seed, and the tables over them")
    ap.add_argument("--preset", action="append", choices=PRESETS, help="repeat; default all four")
    ap.add_argument("--method", action="append", choices=tuple(METHODS),
                    help=f"repeat; default {', '.join(DEFAULT_METHODS)}")
    ap.add_argument("--seed", type=int, action="append",
                    help=f"repeat; default {' '.join(str(s) for s in DEFAULT_SEEDS)}")
    ap.add_argument("--size", type=int, default=MACHINE_SIZE.size, help="image side of the scenes (default 64)")
    ap.add_argument("--train-views", type=int, default=MACHINE_SIZE.train_views)
    ap.add_argument("--test-views", type=int, default=MACHINE_SIZE.test_views)
    ap.add_argument("--iterations", type=int, default=MACHINE_SIZE.iterations)
    ap.add_argument("--inpainter", default="symmetry", help="inpainter plugin of the methods that inpaint")
    args = ap.parse_args(argv)

    # one PyTorch thread unless $ROODI_THREADS says otherwise, as the CLI runs (two threads on a busy 2-core
    # machine made every training step ~10x slower, and the thread count changes float summation order)
    torch.set_num_threads(int(os.environ.get("ROODI_THREADS", "1")))
    load_plugin("inpainters", args.inpainter)  # fail before training on an unknown name
    size = replace(MACHINE_SIZE, size=args.size, train_views=args.train_views, test_views=args.test_views,
                   iterations=args.iterations)
    t0 = time.perf_counter()
    per_seed = {}
    for seed in args.seed or DEFAULT_SEEDS:
        config = replace(extract_config(size, seed), inpainter=args.inpainter)
        out = Path(args.out) / f"seed_{seed}"
        per_seed[seed] = results = run_benchmark(Path(args.root) / f"seed_{seed}", out,
                                                 presets=args.preset or PRESETS, seed=seed, size=size,
                                                 methods=args.method or DEFAULT_METHODS, config=config,
                                                 occluded=True, make_scene=make_benchmark_scene)
        print(f"seed {seed}:")
        for scene, per in results["scenes"].items():
            shares = ", ".join(f"{o['object_name']} {100 * o['never_seen_share']:.1f}%"
                               for o in per["full"]["objects"] if "never_seen_share" in o)
            print(f"  {scene}: never seen in training: {shares}")
    summary = over_seeds(per_seed)
    summary["inpainter"] = args.inpainter
    write_json(summary, Path(args.out) / "results.json")
    text = markdown(summary, args.inpainter)
    with atomic_path(Path(args.out) / "results.md") as tmp:
        tmp.write_text(text)
    print(text)
    print(f"tables: {args.out}/results.md ({(time.perf_counter() - t0) / 60:.1f} min)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
