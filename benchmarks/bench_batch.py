"""Throughput of ``roodi-toolkit batch prune`` against a shell loop of ``roodi-toolkit prune`` over the same files.

Makes COUNT generated clouds of SIZE Gaussians with planted floaters (roodi_toolkit.synth.floaters), then times, in
one run on the same files:

- a shell loop: ``for f in in/*.ply; do roodi-toolkit prune $f out/$f; done`` (one process per file, as a user
  would script it);
- ``roodi-toolkit batch prune in/ out/ --jobs J``;
- ``roodi-toolkit batch prune in/ out/ --jobs J --ray local`` when Ray is installed;

checks that every batch output is byte-identical to the loop's, and prints items per second and the ratios, plus
the per-item times the batch recorded (for the N-machine estimate in docs/batch.md).

    .venv/bin/python benchmarks/bench_batch.py --count 200 --size 100000 --jobs 2
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).with_name("roodi-toolkit")


def _make(folder: Path, count: int, size: int) -> None:
    from roodi_toolkit import write_ply
    from roodi_toolkit.synth.floaters import FloaterMix, planted_floater_cloud

    folder.mkdir(parents=True, exist_ok=True)
    for i in range(count):
        path = folder / f"cloud_{i:04d}.ply"
        if not path.exists():
            write_ply(planted_floater_cloud(FloaterMix(n_object=size), seed=i).cloud, path)


def _timed(cmd: list[str] | str, shell: bool = False) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, shell=shell, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--count", type=int, default=200)
    ap.add_argument("--size", type=int, default=100_000, help="Gaussians on the surface of each cloud")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--work", default=None, help="folder for the clouds (kept between runs) [a temporary one]")
    ap.add_argument("--no-ray", action="store_true")
    args = ap.parse_args()
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="bench-batch-"))
    src = work / f"in_{args.count}x{args.size}"
    t0 = time.perf_counter()
    _make(src, args.count, args.size)
    print(f"{args.count} clouds of {args.size:,} Gaussians (+ floaters) in {src} ({time.perf_counter() - t0:.0f} s)")
    files = sorted(src.glob("*.ply"))
    runs: dict[str, float] = {}
    loop_out = work / "loop"
    shutil.rmtree(loop_out, ignore_errors=True)
    loop_out.mkdir()
    script = f'for f in "{src}"/*.ply; do "{BIN}" prune "$f" "{loop_out}/$(basename "$f")" -q || exit 1; done'
    runs["shell loop of prune"] = _timed(script, shell=True)
    variants = {f"batch --jobs {args.jobs}": []}
    try:
        import ray  # noqa: F401

        if not args.no_ray:
            variants[f"batch --jobs {args.jobs} --ray local"] = ["--ray", "local"]
    except ImportError:
        print("Ray is not installed: --ray local not measured")
    per_item = {}
    for name, extra in variants.items():
        out = work / name.replace(" ", "_").replace("-", "")
        shutil.rmtree(out, ignore_errors=True)
        runs[name] = _timed([str(BIN), "batch", "prune", str(src), str(out), "--jobs", str(args.jobs), "-q", *extra])
        lines = [json.loads(t) for t in (out / "results.jsonl").read_text().splitlines()]
        assert all(line["status"] == "ok" for line in lines), "a batch item failed"
        per_item[name] = statistics.median(line["seconds"] for line in lines)
        same = sum((out / f.name).read_bytes() == (loop_out / f.name).read_bytes() for f in files)
        print(f"{name}: {same} of {len(files)} outputs byte-identical to the loop's")
    base = runs["shell loop of prune"]
    print(f"\n| run | seconds | items/s | throughput vs the loop |\n| --- | --- | --- | --- |")
    for name, sec in runs.items():
        print(f"| {name} | {sec:.1f} | {len(files) / sec:.2f} | {base / sec:.2f}x |")
    for name, med in per_item.items():
        print(f"median seconds per item inside '{name}': {med:.2f}")
    ray_name = next((n for n in runs if "ray" in n), None)
    if ray_name:
        jobs_name = f"batch --jobs {args.jobs}"
        print(f"--ray local against --jobs {args.jobs}: {runs[ray_name] / runs[jobs_name]:.2f}x the time")
    return 0


if __name__ == "__main__":
    sys.exit(main())
