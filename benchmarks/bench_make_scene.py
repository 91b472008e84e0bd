"""Time `make-scene` for each preset at the default settings (200x200, 50 training views, 50 test views per target).

Run from the repository root:

    .venv/bin/python benchmarks/bench_make_scene.py [--size 200] [--seed 0]

Prints a markdown table: preset, objects, targets, rendered views, seconds, seconds per view.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from roodi_toolkit.synth.objects import PRESETS
from roodi_toolkit.synth.scene import SceneSettings, make_scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--train-views", type=int, default=50)
    ap.add_argument("--test-views", type=int, default=50)
    args = ap.parse_args()
    settings = SceneSettings(width=args.size, height=args.size, train_views=args.train_views,
                             test_views=args.test_views)
    print(f"| preset | objects | targets | views rendered | seconds | s / view |")
    print(f"| --- | --- | --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        make_scene(Path(tmp) / "warmup", "bedroom", 99, settings=SceneSettings(width=16, height=16, train_views=1,
                                                                                test_views=1))  # imports
        for preset in PRESETS:
            t0 = time.perf_counter()
            rec = make_scene(Path(tmp) / preset, preset, args.seed, settings=settings)
            dt = time.perf_counter() - t0
            views = settings.train_views + settings.test_views * len(rec["targets"])
            print(f"| {preset} | {len(rec['objects'])} | {len(rec['targets'])} | {views} | {dt:.1f} | "
                  f"{dt / views:.3f} |", flush=True)


if __name__ == "__main__":
    main()
