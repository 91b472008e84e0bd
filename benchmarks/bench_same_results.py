"""Print what a tiny occluded benchmark run makes, to compare two versions of the code (issue 35: the run layer moved
no result).

Runs ``run_benchmark`` on a generated occluded picnic at 32 px with 40 training steps (full, no_inpaint,
feature_similarity, gaussian_grouping and the no_two_stage model it selects from) into ``OUT/bench``, then again into
``OUT/bench2`` (reusing the scores), and prints the SHA-256 of every object PLY and the scores without timings, one
line each. Run it with each version's sources first on ``PYTHONPATH`` and ``diff`` the two outputs::

    git archive BASE | tar -x -C /tmp/base
    PYTHONPATH=/tmp/base python benchmarks/bench_same_results.py /tmp/b_old > /tmp/old.txt
    PYTHONPATH=$PWD python benchmarks/bench_same_results.py /tmp/b_new > /tmp/new.txt
    diff /tmp/old.txt /tmp/new.txt
"""

import hashlib
import json
import sys
from pathlib import Path

from roodi_toolkit.evaluate.benchmark import BenchmarkSize
from roodi_toolkit.pipeline.distill import DistillConfig
from roodi_toolkit.pipeline.extract import ExtractConfig
from roodi_toolkit.pipeline.finetune import FinetuneConfig
from roodi_toolkit.pipeline.occlusion import OcclusionConfig
from roodi_toolkit.pipeline.strategy import MCMCStrategy
from roodi_toolkit.pipeline.train import TrainConfig
from roodi_toolkit.synth.scene import make_benchmark_scene

try:
    from roodi_toolkit.run.benchmark import run_benchmark
except ImportError:  # before the run layer (883c36a and earlier)
    from roodi_toolkit.evaluate.benchmark import run_benchmark

TINY = ExtractConfig(
    train=TrainConfig(iterations=40, init="depth", init_num_points=800, eval_every=0,
                      strategy=MCMCStrategy(cap_max=1000, refine_start_iter=10, refine_every=10)),
    distill=DistillConfig(iterations=40), occlusion=OcclusionConfig(size=32, opening_reference=0, opening_size=5),
    finetune=FinetuneConfig(iterations=2))
SIZE = BenchmarkSize(size=32, train_views=10, test_views=2, iterations=40, init_points=800, cap_max=1000,
                     supersample=1)
METHODS = ["full", "no_inpaint", "feature_similarity", "gaussian_grouping"]


def _without_timings(x):
    if isinstance(x, dict):
        return {k: _without_timings(v) for k, v in x.items()
                if "second" not in k and k not in ("_picture", "ply", "root")}
    if isinstance(x, list):
        return [_without_timings(v) for v in x]
    return x


def main() -> None:
    out = Path(sys.argv[1])
    for run in ("bench", "bench2"):
        results = run_benchmark(out / "scenes", out / run, presets=["picnic"], size=SIZE, config=TINY,
                                methods=METHODS, occluded=True, make_scene=make_benchmark_scene)
        for ply in sorted((out / run).rglob("*.ply")):
            print(run, ply.relative_to(out / run), hashlib.sha256(ply.read_bytes()).hexdigest()[:16])
        print(run, "scores", json.dumps(_without_timings(results["scenes"]), sort_keys=True))
        print(run, "mean", json.dumps(_without_timings(results["mean"]), sort_keys=True))


if __name__ == "__main__":
    main()
