"""The default ``prune`` on real splats: render safety, planted floaters, lego's fog, and speed against Open3D SOR.

Real files come from other tools (``../shared/data``, see its README) or from ``roodi-toolkit train`` on the posed
datasets there, in any format the toolkit reads; opacity logits of +-inf are mapped to +-20 here (fully opaque /
transparent; the figures below were measured so, on PLY decodes made with ``roodi-toolkit convert``).

    # safety (8 fixed views, same cameras for both clouds) and 300 + 300 planted floaters, per file
    .venv/bin/python benchmarks/bench_real_prune.py safety ../shared/data/donut/point_cloud.ply /tmp/biker.ply
    # planted floaters only (no renders), over several seeds: the worst seed per file is the figure to watch
    .venv/bin/python benchmarks/bench_real_prune.py seeds ../shared/data/donut/point_cloud.ply --seeds 0,1,2,3,4 \
        [--foreign-size 0]
    # lego trained on its white background: alpha IoU on the held-out views (r_0, r_8, ...) against the masks
    .venv/bin/python benchmarks/bench_real_prune.py fog /work/exp/lego_model/point_cloud/iteration_2000/point_cloud.ply \\
        ../shared/data/lego
    # larger real scenes: copies of the biker side by side (x shifted by 1.2x its width)
    .venv/bin/python benchmarks/bench_real_prune.py tile /tmp/biker.ply /tmp/biker_x4.ply --copies 4
    # whole command (read, decide, write) against plyfile + Open3D remove_statistical_outlier(16, 2.0) + write
    # (--reference DIR: also the command of another source tree, alternated with the two)
    .venv/bin/python benchmarks/bench_real_prune.py speed /tmp/biker.ply /tmp/biker_x4.ply --repeats 3
    # the photo check: prune of a trained model's PLY (it finds its photos), against another source tree
    .venv/bin/python benchmarks/bench_real_prune.py photos MODEL/point_cloud/iteration_3000/point_cloud.ply \\
        --reference /tmp/base --repeats 3
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

OPEN3D_SOR = """
import sys
import numpy as np
import open3d as o3d
from plyfile import PlyData, PlyElement
ply = PlyData.read(sys.argv[1])
v = ply["vertex"].data
pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64)))
_, kept = pcd.remove_statistical_outlier(nb_neighbors=16, std_ratio=2.0)
PlyData([PlyElement.describe(v[np.asarray(kept, dtype=np.int64)], "vertex")]).write(sys.argv[2])
"""


def load_real(path: str):
    """Read a splat in any format and map +-inf opacity logits to +-20 (see the module docstring)."""
    from roodi_toolkit.io.splat import read_cloud_report

    cloud, _ = read_cloud_report(path, raw=True)
    logits = np.clip(cloud.opacity_logits, -20, 20)
    return cloud.with_fields(opacity_logits=logits.astype(np.float32))


def renders(cloud, cameras, background=(0.0, 0.0, 0.0)) -> list[tuple[np.ndarray, np.ndarray]]:
    """Return ``[(rgb [H, W, 3], alpha [H, W]), ...]`` of the cloud in each camera."""
    from roodi_toolkit.render.renderer import render_cloud

    out = []
    for cam in cameras:
        r = render_cloud(cloud, cam, background=background)
        out.append((np.clip(r.rgb.numpy(), 0, 1), r.alpha.numpy()[..., 0]))
    return out


def mean_psnr(a, b) -> float:
    from roodi_toolkit.evaluate.metrics import psnr

    return float(np.mean([psnr(x[0], y[0]) for x, y in zip(a, b)]))


def safety(paths: list[str], size: int, seed: int) -> list[dict]:
    """Default prune on each real file alone and with 300 specks + 300 blobs planted; renders against the unpruned."""
    from roodi_toolkit.prune.scene import prune_cloud
    from roodi_toolkit.render.views import framing_orbit
    from roodi_toolkit.synth.floaters import BLOB, SPECK, plant_floaters

    rows = []
    for path in paths:
        cloud = load_real(path)
        cameras = framing_orbit(cloud, 8, width=size, height=size)
        ref = renders(cloud, cameras)
        t = time.perf_counter()
        pruned, keep, report = prune_cloud(cloud)
        seconds = time.perf_counter() - t
        planted, labels = plant_floaters(cloud, seed)
        p_pruned, p_keep, p_report = prune_cloud(planted)
        row = {"file": path, "gaussians": len(cloud), "mode": report.mode, "removed": int((~keep).sum()),
               "removed_pct": round(100 * float((~keep).mean()), 3), "prune_s": round(seconds, 2),
               "psnr_pruned_vs_unpruned": round(mean_psnr(ref, renders(pruned, cameras)), 2),
               "planted_mode": p_report.mode,
               "specks_removed_pct": round(100 * float((~p_keep[labels == SPECK]).mean()), 1),
               "blobs_removed_pct": round(100 * float((~p_keep[labels == BLOB]).mean()), 1),
               "planted_real_removed_pct": round(100 * float((~p_keep[labels == 0]).mean()), 3),
               "psnr_planted_unpruned_vs_clean": round(mean_psnr(ref, renders(planted, cameras)), 2),
               "psnr_planted_pruned_vs_clean": round(mean_psnr(ref, renders(p_pruned, cameras)), 2)}
        print(json.dumps(row), flush=True)
        rows.append(row)
    return rows


def seeds(paths: list[str], seed_list: list[int], **options) -> list[dict]:
    """Default prune (or with ``options`` of ``PruneConfig``) on each real file with 300 specks + 300 blobs
    planted, once per seed; no renders."""
    from roodi_toolkit.prune.scene import prune_cloud
    from roodi_toolkit.synth.floaters import BLOB, SPECK, plant_floaters

    rows = []
    for path in paths:
        cloud = load_real(path)
        runs = []
        for seed in seed_list:
            planted, labels = plant_floaters(cloud, seed)
            _, keep, _ = prune_cloud(planted, **options)
            runs.append({"seed": seed, "specks_removed_pct": round(100 * float((~keep[labels == SPECK]).mean()), 1),
                         "blobs_removed_pct": round(100 * float((~keep[labels == BLOB]).mean()), 1),
                         "real_removed": int((~keep[labels == 0]).sum())})
        row = {"file": path, "gaussians": len(cloud), "runs": runs,
               "worst_specks_pct": min(r["specks_removed_pct"] for r in runs),
               "worst_blobs_pct": min(r["blobs_removed_pct"] for r in runs),
               "most_real_removed": max(r["real_removed"] for r in runs)}
        print(json.dumps(row), flush=True)
        rows.append(row)
    return rows


def fog(model: str, data: str, every: int, downscale: float, photos: str = "auto") -> dict:
    """Alpha IoU (threshold 0.5) of the unpruned and the default-pruned model against lego's masks, held-out views.

    The prune is the command's default, photo check included: the model's training photos when the PLY sits in its
    model folder (``photos`` as ``prune --photos``)."""
    from roodi_toolkit.io.dataset import load_cameras
    from roodi_toolkit.io.files import read_image
    from roodi_toolkit.prune.photos import find_photos
    from roodi_toolkit.prune.scene import prune_cloud

    cloud = load_real(model)
    def number(name: str) -> int:  # r_8 -> 8
        return int("".join(ch for ch in name if ch.isdigit()) or 0)

    held = [cam.scaled(1 / downscale) for cam in load_cameras(data) if number(cam.name) % every == 0]
    checked = find_photos(model, photos)
    pruned, keep, report = prune_cloud(cloud, photos=checked)
    result = {"model": model, "gaussians": len(cloud), "mode": report.mode, "removed": int((~keep).sum()),
              "photos": None if checked is None else checked.source, "stages": report.to_dict()["stages"], "views": len(held), "size": [held[0].width, held[0].height]}
    from roodi_toolkit.evaluate.metrics import psnr

    truth = [_truth_on_white(read_image, data, cam) for cam in held]
    for label, c in (("unpruned", cloud), ("pruned", pruned)):
        ious = []
        for cam, (_, alpha) in zip(held, renders(c, held)):
            mask = _mask(read_image, data, cam)
            a, m = alpha > 0.5, mask > 0.5
            ious.append(float((a & m).sum() / max(1, (a | m).sum())))
        result[f"iou_{label}"] = round(float(np.mean(ious)), 4)
        # render safety against the ground truth, on the white background the model was trained on
        white = renders(c, held, background=(1.0, 1.0, 1.0))
        result[f"psnr_white_vs_truth_{label}"] = round(float(np.mean([psnr(r[0], t) for r, t in zip(white, truth)])), 2)
    print(json.dumps(result), flush=True)
    return result


def _mask(read_image, data: str, cam) -> np.ndarray:
    """The dataset's alpha channel for a camera, resized to the camera's size."""
    import torch

    image = read_image(Path(data) / "train" / f"{cam.name}.png").astype(np.float32)
    image = image / 255.0 if image.max() > 1.5 else image  # 8-bit PNGs read as 0-255
    alpha = image[..., 3] if image.shape[-1] == 4 else np.ones(image.shape[:2])
    t = torch.from_numpy(np.ascontiguousarray(alpha, dtype=np.float32))[None, None]
    return torch.nn.functional.interpolate(t, size=(cam.height, cam.width), mode="area")[0, 0].numpy()


def _truth_on_white(read_image, data: str, cam) -> np.ndarray:
    """The dataset image composited on white, resized (area) to the camera's size: ``[H, W, 3]``."""
    import torch

    image = read_image(Path(data) / "train" / f"{cam.name}.png").astype(np.float32)
    image = image / 255.0 if image.max() > 1.5 else image
    rgb = image[..., :3] * image[..., 3:4] + (1.0 - image[..., 3:4]) if image.shape[-1] == 4 else image[..., :3]
    t = torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1)))[None]
    return torch.nn.functional.interpolate(t, size=(cam.height, cam.width), mode="area")[0].numpy().transpose(1, 2, 0)


def speed(paths: list[str], repeats: int, reference: str | None = None) -> list[dict]:
    """Median wall and CPU time of the whole default prune command and of the Open3D SOR script, alternated per file
    (and of the prune command of another source tree, ``reference``, when given: e.g. an export of an earlier
    commit). CPU time is the child's user + system time (all threads): on a shared machine it moves less than the
    wall time."""
    import os
    import resource

    from roodi_toolkit.io.ply import write_ply

    def run(cmd: list[str], env: dict | None = None) -> tuple[float, float]:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True, env=env)
        wall = time.perf_counter() - t
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for path in paths:
            src = Path(tmp) / "in.ply"
            write_ply(load_real(path), src)  # finite opacities, so both read the same finite file
            prune = [sys.executable, "-m", "roodi_toolkit.cli.main", "prune", str(src), str(Path(tmp) / "ours.ply"),
                     "-q", "--overwrite"]
            commands = {"ours": (prune, None),
                        "open3d_sor": ([sys.executable, "-c", OPEN3D_SOR, str(src), str(Path(tmp) / "o3d.ply")], None)}
            if reference:
                env = dict(os.environ, PYTHONPATH=str(Path(reference).resolve()))
                commands["reference"] = (prune[:-3] + [str(Path(tmp) / "ref.ply"), "-q", "--overwrite"], env)
            times: dict[str, list[tuple[float, float]]] = {k: [] for k in commands}
            for _ in range(repeats):
                for name, (cmd, env) in commands.items():
                    times[name].append(run(cmd, env))
            med = {k: (statistics.median(t[0] for t in v), statistics.median(t[1] for t in v))
                   for k, v in times.items()}
            row = {"file": path, "gaussians": _count(src)}
            for name, (wall, cpu) in med.items():
                row[f"{name}_s"], row[f"{name}_cpu_s"] = round(wall, 2), round(cpu, 2)
            row["ratio"] = round(med["ours"][0] / med["open3d_sor"][0], 2)
            row["cpu_ratio"] = round(med["ours"][1] / med["open3d_sor"][1], 2)
            if reference:
                row["ratio_reference"] = round(med["reference"][0] / med["open3d_sor"][0], 2)
                row["ours_vs_reference"] = round(med["ours"][0] / med["reference"][0], 2)
                if (Path(tmp) / "ref.ply").read_bytes() != (Path(tmp) / "ours.ply").read_bytes():
                    row["outputs"] = "DIFFERENT"
            row["load_average"] = round(os.getloadavg()[0], 1)
            print(json.dumps(row), flush=True)
            rows.append(row)
    return rows


def photos_speed(models: list[str], repeats: int, reference: str | None = None) -> list[dict]:
    """Median wall and CPU time of ``prune MODEL.ply OUT.ply`` with its photo check (the PLY in its model folder,
    whose ``cfg.json`` names the training photos), alternated with the same command of ``reference`` (another source
    tree) when given; the outputs must be the same bytes (the same keep decisions)."""
    import os
    import resource

    def run(cmd: list[str], env: dict | None) -> tuple[float, float, float]:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True, env=env)
        wall = time.perf_counter() - t
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        report = json.loads(Path(cmd[cmd.index("--report") + 1]).read_text())
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        return wall, cpu, report["timings_s"].get("photo_check", 0.0)

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for model in models:
            commands = {}
            for name, tree in (("ours", None), ("reference", reference)):
                if name == "reference" and not tree:
                    continue
                out, rep = Path(tmp) / f"{name}.ply", Path(tmp) / f"{name}.json"
                env = None if tree is None else dict(os.environ, PYTHONPATH=str(Path(tree).resolve()))
                commands[name] = ([sys.executable, "-m", "roodi_toolkit.cli.main", "prune", model, str(out), "-q",
                                   "--overwrite", "--report", str(rep)], env)
            times: dict[str, list[tuple[float, float, float]]] = {k: [] for k in commands}
            for _ in range(repeats):
                for name, (cmd, env) in commands.items():
                    times[name].append(run(cmd, env))
            row = {"model": model}
            for name, values in times.items():
                for i, key in enumerate(("s", "cpu_s", "photo_check_s")):
                    row[f"{name}_{key}"] = round(statistics.median(v[i] for v in values), 2)
            report = json.loads((Path(tmp) / "ours.json").read_text())
            row["removed"] = {stage["stage"]: stage["removed"] for stage in report["stages"] if stage["removed"]}
            row["photo_views"] = report["statistics"].get("photo_views")
            if reference:
                row["ours_vs_reference"] = round(row["ours_s"] / row["reference_s"], 2)
                row["cpu_ours_vs_reference"] = round(row["ours_cpu_s"] / row["reference_cpu_s"], 2)
                row["outputs"] = ("identical" if (Path(tmp) / "ours.ply").read_bytes()
                                  == (Path(tmp) / "reference.ply").read_bytes() else "DIFFERENT")
            row["load_average"] = round(os.getloadavg()[0], 1)
            print(json.dumps(row), flush=True)
            rows.append(row)
    return rows


def tile(path: str, out: str, copies: int) -> None:
    """Write ``copies`` of a real cloud (finite opacities, :func:`load_real`) side by side along x, each shifted by
    1.2x the cloud's width: a larger scene with the same local structure."""
    from roodi_toolkit.gaussians import GaussianCloud
    from roodi_toolkit.io.ply import write_ply

    cloud = load_real(path)
    width = float(np.ptp(cloud.means[:, 0]))
    parts = [cloud.with_fields(means=(cloud.means + np.array([1.2 * width * i, 0, 0], dtype=np.float32))
                               .astype(np.float32)) for i in range(copies)]
    write_ply(GaussianCloud.concatenate(parts), out)
    print(json.dumps({"file": out, "gaussians": len(cloud) * copies}), flush=True)


def _count(path: Path) -> int:
    from roodi_toolkit.io.ply import read_header

    return int(read_header(path).elements[0].count)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    s = sub.add_parser("safety")
    s.add_argument("files", nargs="+")
    s.add_argument("--size", type=int, default=256, help="render size in pixels")
    s.add_argument("--seed", type=int, default=0)
    d = sub.add_parser("seeds")
    d.add_argument("files", nargs="+")
    d.add_argument("--seeds", default="0,1,2,3,4", help="comma-separated planting seeds")
    d.add_argument("--foreign-size", type=float, default=None, help="as prune --foreign-size (0: the test off)")
    f = sub.add_parser("fog")
    f.add_argument("model")
    f.add_argument("data")
    f.add_argument("--every", type=int, default=8)
    f.add_argument("--downscale", type=float, default=4, help="render and compare at 1/this of the image size")
    f.add_argument("--photos", default="auto", help="as prune --photos (auto: the model folder's training photos)")
    p = sub.add_parser("speed")
    p.add_argument("files", nargs="+")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--reference", default=None,
                   help="also time the prune command of this source tree (e.g. `git archive COMMIT` unpacked)")
    q = sub.add_parser("photos")
    q.add_argument("models", nargs="+", help="PLYs inside their model folders (MODEL/point_cloud/iteration_N/...)")
    q.add_argument("--repeats", type=int, default=3)
    q.add_argument("--reference", default=None, help="also time the prune command of this source tree")
    t = sub.add_parser("tile")
    t.add_argument("file")
    t.add_argument("out")
    t.add_argument("--copies", type=int, default=4)
    args = parser.parse_args(argv)
    if args.what == "safety":
        safety(args.files, args.size, args.seed)
    elif args.what == "seeds":
        options = {} if args.foreign_size is None else {"foreign_size": args.foreign_size}
        seeds(args.files, [int(x) for x in args.seeds.split(",")], **options)
    elif args.what == "fog":
        fog(args.model, args.data, args.every, args.downscale, args.photos)
    elif args.what == "photos":
        photos_speed(args.models, args.repeats, args.reference)
    elif args.what == "tile":
        tile(args.file, args.out, args.copies)
    else:
        speed(args.files, args.repeats, args.reference)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
