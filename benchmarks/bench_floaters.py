"""Planted-floater benchmark: how much of each floater kind and of the object each pruning method removes.

Methods: prune's default (``--mode auto``, :func:`roodi_toolkit.prune.scene.prune_cloud`), the statistical default
rule (robust, W2, K=16; what extract runs on a selected object), the paper's single pass (``--rule paper``, W2, alpha 2) and Open3D's
``remove_statistical_outlier(nb_neighbors=K+1, std_ratio=2)`` on the centres. Clouds: every mix of
``roodi_toolkit.synth.floaters.STANDARD_MIXES`` (4 surfaces, 7 mixes of far / near-surface oversized floaters and
densities) for several seeds. Prints one row per mix (worst over seeds) and the worst case over all mixes.

Target for the default (issue 3): at least 95% of each floater kind removed, at most 1% of the object lost, on
every mix.

    .venv/bin/python benchmarks/bench_floaters.py                 # table, 3 seeds
    .venv/bin/python benchmarks/bench_floaters.py --sweep         # also the K / alpha sweep behind the defaults
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import numpy as np

from roodi_toolkit.prune.outliers import NeighborDistances, PruneConfig, outlier_mask
from roodi_toolkit.prune.scene import prune_cloud
from roodi_toolkit.synth.floaters import FAR, NEAR, OBJECT, STANDARD_MIXES, planted_floater_cloud

TARGET_REMOVED = 0.95
TARGET_OBJECT_LOST = 0.01


def scores(labels: np.ndarray, removed: np.ndarray) -> tuple[float, float, float]:
    """Return (far removed, near removed, object lost) fractions; nan for a kind that is absent."""
    def frac(label: int) -> float:
        sel = labels == label
        return float(removed[sel].mean()) if sel.any() else float("nan")

    return frac(FAR), frac(NEAR), frac(OBJECT)


def open3d_removed(means: np.ndarray, k: int, std_ratio: float) -> np.ndarray:
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(means.astype(np.float64)))
    _, kept = pcd.remove_statistical_outlier(nb_neighbors=k + 1, std_ratio=std_ratio)
    removed = np.ones(len(means), dtype=bool)
    removed[np.asarray(kept, dtype=np.int64)] = False
    return removed


def evaluate(mixes, seeds, methods: dict[str, PruneConfig | tuple[str, int, float] | str]) -> dict[str, list]:
    """Return per method a list of (mix name, seed, far, near, object) rows."""
    rows: dict[str, list] = {name: [] for name in methods}
    for mix in mixes:
        for seed in seeds:
            planted = planted_floater_cloud(mix, seed)
            cache: dict[tuple, NeighborDistances] = {}
            for name, method in methods.items():
                if method == "auto":
                    removed = ~prune_cloud(planted.cloud)[1]
                elif isinstance(method, tuple):
                    removed = open3d_removed(planted.cloud.means, method[1], method[2])
                else:
                    key = (method.k, method.distance, method.neighbors)
                    if key not in cache:
                        cache[key] = NeighborDistances(planted.cloud, method)
                    removed = outlier_mask(cache[key], method)
                rows[name].append((mix.name, seed, *scores(planted.labels, removed)))
    return rows


def worst(rows: list) -> tuple[float, float, float]:
    arr = np.array([r[2:] for r in rows], dtype=np.float64)

    def pick(col: np.ndarray, fn) -> float:
        col = col[~np.isnan(col)]
        return float(fn(col)) if col.size else float("nan")

    return pick(arr[:, 0], np.min), pick(arr[:, 1], np.min), pick(arr[:, 2], np.max)


def meets_target(rows: list) -> bool:
    far, near, obj = worst(rows)
    return far >= TARGET_REMOVED and near >= TARGET_REMOVED and obj <= TARGET_OBJECT_LOST


def pct(x: float) -> str:
    return "   -  " if x != x else f"{100 * x:6.2f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--sweep", action="store_true", help="also sweep K and alpha of the robust rule")
    args = parser.parse_args(argv)
    seeds = list(range(args.seeds))
    default = PruneConfig()
    methods = {
        f"statistical default (robust, w2, K={default.k}, alpha={default.effective_alpha:g}; extract's rule)": default,
        "prune's default (--mode auto)": "auto",
        "paper (w2, K=16, alpha=2)": PruneConfig(rule="paper", alpha=2.0),
        "paper (w2, K=16, alpha=1)": PruneConfig(rule="paper", alpha=1.0),
        "Open3D SOR (nb_neighbors=17, std_ratio=2)": ("open3d", 16, 2.0),
        "robust, euclidean (K=16, alpha=3.5)": PruneConfig(distance="euclidean"),
    }
    t0 = time.perf_counter()
    rows = evaluate(STANDARD_MIXES, seeds, methods)
    print(f"planted-floater benchmark: {len(STANDARD_MIXES)} mixes x {len(seeds)} seeds "
          f"({time.perf_counter() - t0:.0f} s); per mix the worst seed: far removed % / near removed % / object "
          "lost %\n")
    names = list(methods)
    print("| mix | " + " | ".join(names) + " |")
    print("| --- |" + " --- |" * len(names))
    for i in range(0, len(rows[names[0]]), len(seeds)):
        mix = rows[names[0]][i][0]
        cells = []
        for name in names:
            far, near, obj = worst(rows[name][i:i + len(seeds)])
            cells.append(f"{pct(far)} / {pct(near)} / {pct(obj)}")
        print(f"| {mix} | " + " | ".join(cells) + " |")
    print("| **worst over all mixes** | " + " | ".join(
        "**" + " / ".join(pct(v) for v in worst(rows[name])) + "**" for name in names) + " |")
    ok = meets_target(rows[names[0]])
    for name in names[:2]:
        print(f"\n{name} {'MEETS' if meets_target(rows[name]) else 'MISSES'} the target (>= 95% of each floater kind "
              "removed, <= 1% of the object lost, every mix and seed)")

    if args.sweep:
        print("\nsweep of the robust rule (worst over all mixes and seeds: far % / near % / object lost %)")
        for k in (8, 16, 32):
            sweep = {f"K={k} alpha={a:g}": replace(default, k=k, alpha=a) for a in (2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 7.0)}
            res = evaluate(STANDARD_MIXES, seeds, sweep)
            for name, r in res.items():
                far, near, obj = worst(r)
                print(f"  {name:18s} {pct(far)} / {pct(near)} / {pct(obj)}  {'target met' if meets_target(r) else ''}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
