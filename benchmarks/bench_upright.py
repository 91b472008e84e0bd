"""Which way is up, measured on real splats whose up is known: what each rule of ``roodi_toolkit.render.upright``
says, and how long the floater picture takes.

Usage::

    python benchmarks/bench_upright.py up FILE:UP [FILE:UP ...]        # UP as x,y,z, e.g. biker.spz:0,-1,0
    python benchmarks/bench_upright.py picture FILE [FILE ...]         # floater picture time (default prune)

``up`` prints, per file, the up ``resolve_up`` gives (and from where) and what the ground plane alone finds, with its
angle to the known up; ``picture`` prints the prune's and the picture's seconds.
"""

from __future__ import annotations

import sys
import time

import numpy as np


def angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


def up_table(specs: list[str]) -> None:
    from roodi_toolkit.io.splat import read_cloud
    from roodi_toolkit.render.upright import ground_plane_up, resolve_up

    print("| file | Gaussians | resolve_up (default) | ground plane alone | angle to the known up | s |")
    print("| --- | --- | --- | --- | --- | --- |")
    for spec in specs:
        path, _, up_text = spec.rpartition(":")
        known = np.array([float(v) for v in up_text.split(",")])
        cloud = read_cloud(path)
        up = resolve_up(None, path, cloud.means)
        t = time.perf_counter()
        found = ground_plane_up(cloud.means)
        seconds = time.perf_counter() - t
        ground = "none" if found is None else (f"{', '.join(f'{v:.3f}' for v in found[0] + 0.0)} "
                                               f"(share {found[1]['share']:.2f}, free {found[1]['free']:.2f})")
        off = "-" if found is None else f"{angle(found[0], known):.2f} deg"
        print(f"| {path} | {len(cloud):,} | {up.kind}: {', '.join(f'{v:.3g}' for v in up.vector + 0.0)} "
              f"({angle(up.vector, known):.1f} deg off) | {ground} | {off} | {seconds:.2f} |")


def picture_times(paths: list[str]) -> None:
    import torch

    from roodi_toolkit.io.splat import read_cloud
    from roodi_toolkit.prune.scene import prune_cloud
    from roodi_toolkit.render.upright import resolve_up
    from roodi_toolkit.viz.floaters import floater_picture

    torch.set_num_threads(1)
    print("| file | Gaussians | prune s | picture s (two renders of 560x420 included) |")
    print("| --- | --- | --- | --- |")
    for path in paths:
        cloud = read_cloud(path)
        t = time.perf_counter()
        _, keep, report = prune_cloud(cloud)
        prune_s = time.perf_counter() - t
        up = resolve_up(None, path, cloud.means)
        t = time.perf_counter()
        floater_picture(cloud, keep, report, up, title=path, dry_run=True)
        print(f"| {path} | {len(cloud):,} | {prune_s:.1f} | {time.perf_counter() - t:.1f} |")


if __name__ == "__main__":
    if len(sys.argv) < 3 or sys.argv[1] not in ("up", "picture"):
        sys.exit(__doc__)
    (up_table if sys.argv[1] == "up" else picture_times)(sys.argv[2:])
