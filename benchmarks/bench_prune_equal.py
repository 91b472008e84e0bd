"""The default prune's decisions against a reference implementation of the same tests (another checkout's
``roodi_toolkit/prune/scene.py``, loaded beside this package): the keep masks must be identical.

Used to show that speed work changed nothing: the reference is main's scene.py from before it (SciPy cKDTree in
float64, input order, one-pass pieces). Clouds: the real files given, the same files with 300 specks + 300 blobs
planted (``bench_real_prune.py safety``'s seed 0), and every planted-floater mix of ``bench_floaters.py`` (3 seeds).

    git -C ../main show main:roodi_toolkit/prune/scene.py > /tmp/scene_ref.py
    .venv/bin/python benchmarks/bench_prune_equal.py /tmp/scene_ref.py ../shared/data/donut/point_cloud.ply /tmp/biker.ply
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def load_reference(path: str):
    """Import a scene.py as ``roodi_toolkit.prune.scene_reference`` (its relative imports resolve here)."""
    import roodi_toolkit.prune

    name = "roodi_toolkit.prune.scene_reference"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("reference", help="the reference scene.py")
    parser.add_argument("files", nargs="*", help="real splat PLYs")
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args(argv)
    from bench_real_prune import load_real

    from roodi_toolkit.prune.scene import prune_cloud
    from roodi_toolkit.synth.floaters import STANDARD_MIXES, plant_floaters, planted_floater_cloud

    reference = load_reference(args.reference)
    clouds = []
    for path in args.files:
        cloud = load_real(path)
        clouds += [(path, cloud), (f"{path} + planted (seed 0)", plant_floaters(cloud, 0)[0])]
    clouds += [(f"{mix} seed {seed}", planted_floater_cloud(mix, seed).cloud)
               for mix in STANDARD_MIXES for seed in range(args.seeds)]
    differ = 0
    for name, cloud in clouds:
        ours = prune_cloud(cloud)
        ref = reference.prune_cloud(cloud)
        same = np.array_equal(ours.keep_mask, ref.keep_mask) and ours.report.stages == ref.report.stages
        differ += not same
        if not same or args.files and name in args.files:
            print(f"{name}: {len(cloud):,} Gaussians, removed {int((~ours.keep_mask).sum()):,} "
                  f"({'identical' if same else 'DIFFERENT: ' + str(int((ours.keep_mask != ref.keep_mask).sum()))})",
                  flush=True)
    print(f"{len(clouds)} clouds, {len(clouds) - differ} with identical keep masks and stage counts, {differ} different")
    return int(differ > 0)


if __name__ == "__main__":
    raise SystemExit(main())
