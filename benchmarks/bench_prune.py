"""Speed and memory of ``roodi-toolkit prune`` against Open3D's Euclidean statistical outlier removal.

Builds a planted-floater cloud (torus, 1% far + 1% near floaters, SH degree 3 as 3DGS trains, stored in random
order as training leaves it), then alternates, ``--repeats`` times each, two subprocesses that both read the PLY,
filter and write the kept Gaussians with every column:

- ours:   ``roodi-toolkit prune in.ply out.ply -q --overwrite`` (W2, K=16, default robust rule)
- Open3D: read_ply -> PointCloud(means).remove_statistical_outlier(nb_neighbors=17, std_ratio=2) -> write_ply

and prints the median wall time of each, their ratio, and each one's peak resident memory (ru_maxrss of the child).

    .venv/bin/python benchmarks/bench_prune.py                      # 1,000,000 Gaussians, 3 repeats
    .venv/bin/python benchmarks/bench_prune.py --size 10000000 --repeats 1 --ours-only   # the 10M memory check
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

OPEN3D_SCRIPT = """
import sys
import numpy as np
import open3d as o3d
from roodi_toolkit.io.ply import read_ply, write_ply
cloud = read_ply(sys.argv[1])
pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.means.astype(np.float64)))
_, kept = pcd.remove_statistical_outlier(nb_neighbors=17, std_ratio=2.0)
write_ply(cloud.select(np.asarray(kept, dtype=np.int64)), sys.argv[2])
"""

WRAPPER = """
import resource, subprocess, sys, time
t = time.perf_counter()
rc = subprocess.run(sys.argv[1:]).returncode
dt = time.perf_counter() - t
print(f"{dt} {resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss} {rc}")
"""


def build(path: Path, size: int, seed: int = 0) -> None:
    from roodi_toolkit.io.ply import write_ply
    from roodi_toolkit.synth.floaters import FloaterMix, planted_floater_cloud

    n_object = int(round(size / 1.02))
    planted = planted_floater_cloud(FloaterMix("torus", n_object=n_object, far_fraction=0.01, near_fraction=0.01),
                                    seed)
    cloud = planted.cloud
    rng = np.random.default_rng(seed)
    rest = (rng.standard_normal((len(cloud), 15, 3), dtype=np.float32) * 0.05)
    write_ply(cloud.with_fields(sh_rest=rest), path)


def timed(cmd: list[str], env: dict | None = None) -> tuple[float, float]:
    """Return (seconds, peak RSS in GiB) of one subprocess."""
    out = subprocess.run([sys.executable, "-c", WRAPPER, *cmd], capture_output=True, text=True, check=True, env=env)
    seconds, rss_kib, rc = out.stdout.strip().splitlines()[-1].split()
    if int(rc) != 0:
        raise SystemExit(f"command failed ({rc}): {' '.join(cmd)}\n{out.stderr}")
    return float(seconds), int(rss_kib) / 2**20


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--ours-only", action="store_true", help="skip Open3D (the 10M memory check)")
    parser.add_argument("--workdir", default=None, help="folder for the PLY files (default: a temporary folder)")
    parser.add_argument("--reference", default=None,
                        help="also time the prune command of this source tree (e.g. `git archive COMMIT` unpacked)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(dir=args.workdir) as tmp:
        tmp = Path(tmp)
        src = tmp / "in.ply"
        t = time.perf_counter()
        build(src, args.size)
        print(f"built {src.stat().st_size / 2**20:.0f} MiB PLY with about {args.size:,} Gaussians in "
              f"{time.perf_counter() - t:.0f} s; cores available: {len(os.sched_getaffinity(0))}", flush=True)
        exe = str(Path(sys.executable).with_name("roodi-toolkit"))
        ours_cmd = [exe, "prune", str(src), str(tmp / "ours.ply"), "-q", "--overwrite",
                    "--report", str(tmp / "report.json")]
        o3d_cmd = [sys.executable, "-c", OPEN3D_SCRIPT, str(src), str(tmp / "o3d.ply")]
        ref_cmd = [sys.executable, "-m", "roodi_toolkit.cli.main", "prune", str(src), str(tmp / "ref.ply"), "-q",
                   "--overwrite"]
        ref_env = None if args.reference is None else dict(os.environ, PYTHONPATH=str(Path(args.reference).resolve()))
        ours, theirs, reference = [], [], []
        for r in range(args.repeats):
            ours.append(timed(ours_cmd))
            print(f"  run {r + 1}: ours {ours[-1][0]:.2f} s, {ours[-1][1]:.2f} GiB", flush=True)
            if ref_env is not None:
                reference.append(timed(ref_cmd, ref_env))
                print(f"  run {r + 1}: reference {reference[-1][0]:.2f} s, {reference[-1][1]:.2f} GiB", flush=True)
            if not args.ours_only:
                theirs.append(timed(o3d_cmd))
                print(f"  run {r + 1}: Open3D {theirs[-1][0]:.2f} s, {theirs[-1][1]:.2f} GiB", flush=True)
        report = (tmp / "report.json").read_text()
        import json

        timings = json.loads(report)["timings_s"]
        med_ours = statistics.median(t for t, _ in ours)
        print(f"\nroodi-toolkit prune (w2, K=16): median {med_ours:.2f} s, peak RSS {max(m for _, m in ours):.2f} GiB")
        print("  last run's steps (s): " + ", ".join(f"{k} {v:.2f}" for k, v in timings.items()))
        if theirs:
            med_o3d = statistics.median(t for t, _ in theirs)
            print(f"Open3D remove_statistical_outlier(nb_neighbors=17): median {med_o3d:.2f} s, peak RSS "
                  f"{max(m for _, m in theirs):.2f} GiB")
            print(f"ratio ours / Open3D (medians): {med_ours / med_o3d:.2f}x")
            if reference:
                med_ref = statistics.median(t for t, _ in reference)
                print(f"reference {args.reference}: median {med_ref:.2f} s, ratio to Open3D {med_ref / med_o3d:.2f}x; "
                      f"ours / reference {med_ours / med_ref:.2f}x")
        print(f"load average {os.getloadavg()[0]:.1f} (1 min) at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
