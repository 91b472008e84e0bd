"""Time of ``roodi-toolkit inspect IN.ply --view-png out.png`` (the PyVista view; ``--screenshot`` was this view until
issue 38 made it the floater picture, timed by ``bench_upright.py picture``) on a large cloud, split into pruning and
rendering.

Builds a planted-floater cloud (torus, 1% far + 1% near floaters, as ``bench_prune.py``) of ``--size`` Gaussians,
writes it as a PLY (or reuses ``--ply``), then

1. times the whole command in a subprocess (``--repeats`` times; median wall time), and
2. times its steps in process with the same library calls the command makes: read, prune (``prune``'s default,
   the local tests; no photos), build the plotter (splats above 20,000 Gaussians), render and write the PNG.

    .venv/bin/python benchmarks/bench_inspect.py                        # 1,000,000 Gaussians, 1024x768
    .venv/bin/python benchmarks/bench_inspect.py --size 20000 --glyphs ellipsoids
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")


def build(path: Path, size: int, seed: int = 0) -> None:
    from roodi_toolkit.io.ply import write_ply
    from roodi_toolkit.synth.floaters import FloaterMix, planted_floater_cloud

    n_object = int(round(size / 1.02))
    planted = planted_floater_cloud(FloaterMix("torus", n_object=n_object, far_fraction=0.01, near_fraction=0.01),
                                    seed)
    write_ply(planted.cloud, path)


def steps(ply: Path, out: Path, glyphs: str, window: tuple[int, int]) -> dict[str, float]:
    """Return seconds per step of what ``inspect --screenshot`` does, in process."""
    import pyvista as pv

    from roodi_toolkit.viz import inspect as insp
    from roodi_toolkit.io.files import write_image
    from roodi_toolkit.prune.scene import prune_cloud
    from roodi_toolkit.io.splat import read_cloud

    pv.OFF_SCREEN = True
    t = {}
    cpu0 = time.process_time()
    t0 = time.perf_counter()
    cloud = read_cloud(ply)
    t["read"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    _, keep, report = prune_cloud(cloud)
    t["prune"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    plotter = insp.plot_cloud(cloud, keep, glyphs=glyphs, window_size=window, off_screen=True)
    t["build plotter"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    img = insp.screenshot_image(plotter)
    t["render"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    write_image(img, out)
    t["write png"] = time.perf_counter() - t0
    plotter.close()
    t["cpu (process)"] = time.process_time() - cpu0
    t["removed"] = float((~keep).sum())
    return t


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=int, default=1_000_000)
    parser.add_argument("--ply", type=Path, default=None, help="reuse (or create) this input PLY")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--glyphs", default="auto", choices=["auto", "ellipsoids", "splats"])
    parser.add_argument("--window-size", default="1024x768")
    args = parser.parse_args()
    w, h = (int(v) for v in args.window_size.split("x"))

    with tempfile.TemporaryDirectory() as tmp:
        ply = args.ply or Path(tmp) / f"cloud_{args.size}.ply"
        if not ply.exists():
            t0 = time.perf_counter()
            build(ply, args.size)
            print(f"built {ply} ({args.size:,} Gaussians) in {time.perf_counter() - t0:.1f} s")
        out = Path(tmp) / "view.png"
        cli = Path(sys.executable).with_name("roodi-toolkit")
        command = [str(cli), "inspect", str(ply), "--view-png", str(out), "--window-size", args.window_size,
                   "--glyphs", args.glyphs, "-q", "--overwrite"]
        print("command:", " ".join(command[:1] + ["inspect", "IN.ply"] + command[3:]))
        print(f"load average before: {' '.join(f'{v:.1f}' for v in os.getloadavg())} on {os.cpu_count()} cores")
        walls, cpus = [], []
        for _ in range(args.repeats):
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
            walls.append(time.perf_counter() - t0)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpus.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
        print(f"whole command: median {statistics.median(walls):.1f} s wall over {len(walls)} runs "
              f"({', '.join(f'{v:.1f}' for v in walls)}); CPU time (user + sys) median "
              f"{statistics.median(cpus):.1f} s")
        t = steps(ply, out, args.glyphs, (w, h))
        cpu = t.pop("cpu (process)")
        print(f"steps in process ({int(t.pop('removed')):,} removed):")
        for name, seconds in t.items():
            print(f"  {name:14s} {seconds:6.2f} s")
        print(f"  prune part     {t['read'] + t['prune']:6.2f} s (read + prune)")
        print(f"  render part    {t['build plotter'] + t['render'] + t['write png']:6.2f} s "
              "(build plotter + render + write)")
        print(f"  CPU time of these steps (user + sys, this process): {cpu:.1f} s")


if __name__ == "__main__":
    main()
