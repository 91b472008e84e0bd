"""Splat formats: read speed of compressed PLY against plain PLY, and agreement with splat-transform.

Usage:
    .venv/bin/python benchmarks/bench_formats.py speed [--count 1000000] [--repeats 3]
    .venv/bin/python benchmarks/bench_formats.py oracle [--splat-transform PATH] [MORE_SPLAT_FILES ...]

``speed`` builds a cloud of ``--count`` Gaussians from the real files in ../shared/data (the biker and the donut,
copied with a small jitter until the count is reached), writes it as plain PLY and as compressed PLY, and prints the
best-of-N read times of :func:`read_cloud` side by side with their ratio (goal: compressed <= 2x plain).

``oracle`` needs splat-transform 2.7.1 (``npm install @playcanvas/splat-transform@2.7.1``): for every real file and
for the SOG / meta.json files splat-transform makes from them, it compares our read with splat-transform's own decode
to PLY, row for row; then for compressed PLY and SPZ it compares the error of our writer (read back by
splat-transform) with the error of splat-transform's own write-and-read of the same cloud. Files given after
``oracle`` (any format, splats from elsewhere) join the decode check. Prints JSON lines.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def data_dir() -> Path:
    if os.environ.get("ROODI_DATA"):
        return Path(os.environ["ROODI_DATA"])
    for cand in (ROOT.parent / "shared" / "data", ROOT.parent.parent / "shared" / "data"):
        if cand.is_dir():
            return cand
    sys.exit("real data not found: set ROODI_DATA to the shared data folder")


def speed(count: int, repeats: int) -> None:
    from roodi_toolkit import GaussianCloud, read_cloud, write_cloud

    data = data_dir()
    parts = [read_cloud(data / "biker" / "biker.compressed.ply"), read_cloud(data / "donut" / "point_cloud.ply")]
    rng = np.random.default_rng(0)
    clouds, total, k = [], 0, 0
    while total < count:
        c = parts[k % 2]
        take = min(len(c), count - total)
        c = c.select(np.arange(take))
        jitter = rng.normal(scale=1e-3, size=c.means.shape).astype(np.float32) + np.float32(k // 2)
        clouds.append(c.with_fields(means=c.means + jitter))
        total += take
        k += 1
    cloud = GaussianCloud.concatenate(clouds)
    with tempfile.TemporaryDirectory() as tmp:
        plain = write_cloud(cloud, Path(tmp) / "scene.ply")
        comp = write_cloud(cloud, Path(tmp) / "scene.compressed.ply")
        times = {}
        for name, path in (("ply", plain), ("compressed-ply", comp)):
            best = float("inf")
            for _ in range(repeats):
                t = time.perf_counter()
                read_cloud(path)
                best = min(best, time.perf_counter() - t)
            times[name] = (best, path.stat().st_size)
    print(json.dumps({"gaussians": len(cloud), "ply_read_s": round(times["ply"][0], 3),
                      "ply_bytes": times["ply"][1], "compressed_read_s": round(times["compressed-ply"][0], 3),
                      "compressed_bytes": times["compressed-ply"][1],
                      "ratio_compressed_over_ply": round(times["compressed-ply"][0] / times["ply"][0], 2)}))


def _st(tool: str, src: Path, dst: Path) -> Path:
    subprocess.run([tool, "-q", "-w", "-g", "cpu", str(src), str(dst)], check=True, capture_output=True)
    return dst


def _round(d: dict) -> dict:
    return {k: (int(v) if k == "count" else float(f"{v:.3g}")) for k, v in d.items()}


def oracle(tool: str, extra: list[str]) -> None:
    from roodi_toolkit import read_cloud, write_cloud
    from roodi_toolkit.io.compare import cloud_differences
    from roodi_toolkit.io.compressed_ply import morton_order
    from roodi_toolkit.io.ply import read_ply
    from roodi_toolkit.io.splat import read_cloud_report

    data = data_dir()
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        inputs = [data / "donut" / "point_cloud.ply", data / "biker" / "biker.compressed.ply",
                  data / "biker" / "biker.spz"]
        (t / "meta").mkdir()
        inputs += [_st(tool, inputs[0], t / "donut.sog"), _st(tool, inputs[2], t / "biker.sog"),
                   _st(tool, inputs[0], t / "meta" / "meta.json")]
        # splat-transform cannot write .splat / .ksplat: encode the real biker with the spec encoders of the tests
        sys.path.insert(0, str(ROOT))
        from tests.io.test_formats import encode_ksplat, encode_splat

        biker = read_cloud(inputs[1])
        (t / "biker.splat").write_bytes(encode_splat(biker))
        (t / "biker.ksplat").write_bytes(encode_ksplat(biker, 1))
        inputs += [t / "biker.splat", t / "biker.ksplat"]
        writer_inputs = inputs[:2]
        inputs += [Path(f) for f in extra]
        # decode agreement: our read (raw, +-inf kept) against splat-transform's decode to PLY, row for row
        for src in inputs:
            ours, report = read_cloud_report(src, raw=True)
            theirs = read_ply(_st(tool, src, t / "decoded.ply"))
            print(json.dumps({"check": "decode", "file": src.name, "format": report.format, "count": len(ours),
                              "count_splat_transform": len(theirs), **_round(cloud_differences(theirs, ours))}))
        # writers: our write read back by splat-transform against splat-transform's own write-and-read
        for src in writer_inputs:
            cloud = read_cloud(src)
            for suffix in (".compressed.ply", ".spz"):
                ours = write_cloud(cloud, t / f"ours{suffix}")
                theirs = _st(tool, src, t / f"theirs{suffix}")
                row = {"check": "write", "file": src.name, "format": suffix}
                # both compressed-PLY writers put the Gaussians in the same Morton order: compare row for row
                ref = cloud.select(morton_order(cloud.means)) if suffix == ".compressed.ply" else cloud
                a, b = ours.read_bytes(), theirs.read_bytes()
                if suffix == ".compressed.ply":
                    a, b = a[a.index(b"end_header"):], b[b.index(b"end_header"):]
                    row["same_bytes_after_header"] = a == b
                for who, path in (("ours", ours), ("splat_transform", theirs)):
                    back = read_ply(_st(tool, path, t / f"{who}_back.ply"))
                    d = cloud_differences(ref, back)
                    row[who] = _round({k: d[k] for k in ("position_rel", "log_scale", "rotation", "sh_dc",
                                                          "alpha")})
                    row[f"{who}_bytes"] = path.stat().st_size
                print(json.dumps(row))


def main() -> int:
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="what", required=True)
    sp = sub.add_parser("speed")
    sp.add_argument("--count", type=int, default=1_000_000)
    sp.add_argument("--repeats", type=int, default=3)
    op = sub.add_parser("oracle")
    oracle_bin = Path(__file__).resolve().parents[1] / ".oracle" / "node_modules" / ".bin" / "splat-transform"
    op.add_argument("--splat-transform", default=os.environ.get("ROODI_SPLAT_TRANSFORM")
                    or shutil.which("splat-transform") or str(oracle_bin))
    op.add_argument("files", nargs="*", help="more splat files (any format) for the decode check")
    args = ap.parse_args()
    if args.what == "speed":
        speed(args.count, args.repeats)
    else:
        if not Path(args.splat_transform).exists():
            sys.exit(f"splat-transform not found at {args.splat_transform}")
        oracle(args.splat_transform, args.files)
    return 0


if __name__ == "__main__":
    sys.exit(main())
