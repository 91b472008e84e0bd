"""Weight-free fill (issue 22): a controlled check of the inpainters on a part of the object that no training view saw.

For each target of a generated scene, the object's Gaussians are sampled on its meshes (tests/mesh_gaussians.py,
no training). The training views are the generator's renders from the cameras on one side of the target only
(their direction from the target within 90 degrees of a horizontal direction), so its far side is never seen; the
object model keeps the Gaussians that at least one of those views sees (the generator's ids and depth), as a
reconstruction would, and the rest is the never-seen part. The scene model is that object plus the Gaussians of the
objects nearby. Then ``refine_object`` (occlusion reasoning, the inpainter on the 2x2 grid, fine-tuning) runs once
per inpainter, and once with the original views only (``inpaint_every`` beyond the iterations: no inpainted view).

Scored in 8 test views around the target (elevation 15-45 degrees) against the intact object's renders on white:
"never-seen" is the pixels whose visible surface in the intact object is a never-seen Gaussian; there PSNR and the
share the model covers (alpha >= 0.5); whole-view silhouette IoU (alpha >= 0.5) and PSNR over the 8 views.

``--texture`` instead times the 2D inpainters on a 2x2 grid of 256 px striped discs with holes and scores the holes.

Usage: .venv/bin/python benchmarks/bench_fill.py [--preset picnic --seed 0 --targets basket_3,plate_1 ...]
       [--inpainters opencv,exemplar,symmetry] [--json out.json]
       .venv/bin/python benchmarks/bench_fill.py --texture
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from roodi_toolkit.gaussians import GaussianCloud  # noqa: E402
from roodi_toolkit.imaging import psnr  # noqa: E402
from roodi_toolkit.params import GaussianParams  # noqa: E402
from roodi_toolkit.io.lpips_weights import lpips_for_loss  # noqa: E402
from roodi_toolkit.pipeline.finetune import FinetuneConfig, refine_object  # noqa: E402
from roodi_toolkit.pipeline.occlusion import OcclusionConfig, object_cameras  # noqa: E402
from roodi_toolkit.render.renderer import TorchRenderer  # noqa: E402
from roodi_toolkit.synth.scene import build_scene, training_cameras  # noqa: E402
from roodi_toolkit.synth.tracer import render_views  # noqa: E402
from benchmarks.bench_inpaint import seen_in_views  # noqa: E402
from tests.mesh_gaussians import mesh_cloud, nearby  # noqa: E402


def _render(cloud: GaussianCloud, cams, background=(1.0, 1.0, 1.0)) -> tuple[torch.Tensor, torch.Tensor]:
    p = GaussianParams.from_cloud(cloud)
    r = TorchRenderer()
    bg = torch.tensor(background, dtype=torch.float32)
    with torch.no_grad():
        outs = [r.render(p, c, background=bg) for c in cams]
    return torch.stack([o.rgb.clamp(0, 1) for o in outs]), torch.stack([o.alpha[..., 0] for o in outs])


def one_sided_setup(scene, target, *, views: int, size: int, per_area: float, seed: int):
    """Return the training images, masks and cameras seeing one side of ``target``, the intact object, the
    never-seen flags of its Gaussians, and the scene model."""
    cams = training_cameras(scene, views, size, size, seed=seed)
    rng = np.random.default_rng(seed)
    az = rng.uniform(0, 2 * math.pi)
    d = np.array([math.cos(az), math.sin(az), 0.0])
    keep = [c for c in cams if float((c.center - target.center) @ d) > 0]
    renders = render_views(scene, keep, supersample=2)
    intact = mesh_cloud([target], per_area=per_area, seed=0)
    spacing = 1 / per_area ** 0.5
    seen = seen_in_views(intact.means.astype(np.float64), keep, renders, target.id, tol=3 * spacing)
    radius = float(np.linalg.norm(target.vertices - target.center, axis=1).max())
    reach = 3 * radius / math.sin(math.radians(50.0) / 2)
    others = nearby(scene, target, reach)
    obj = intact.select(seen)
    scene_cloud = GaussianCloud.concatenate([obj] + ([mesh_cloud(others, per_area=per_area, seed=1)] if others else []))
    images = torch.stack([torch.as_tensor(r.rgb, dtype=torch.float32) for r in renders])
    masks = torch.stack([torch.as_tensor(r.ids == target.id) for r in renders])
    return images, masks, keep, intact, ~seen, obj, scene_cloud


def scores(cloud: GaussianCloud, test_cams, truth_rgb, truth_alpha, never) -> dict[str, float]:
    rgb, alpha = _render(cloud, test_cams)
    on, truth_on = alpha >= 0.5, truth_alpha >= 0.5
    union = (on | truth_on).sum()
    return {"never_seen_psnr": psnr(rgb[never], truth_rgb[never]) if bool(never.any()) else float("nan"),
            "never_seen_covered": float(on[never].float().mean()) if bool(never.any()) else float("nan"),
            "iou": float((on & truth_on).sum() / union) if union else float("nan"),
            "psnr": psnr(rgb, truth_rgb)}


def run_target(scene, target, inpainters, *, views=24, size=64, view_size=64, iterations=100, per_area=15000.0,
               seed=0) -> dict:
    t0 = time.perf_counter()
    images, masks, cams, intact, unseen, obj, scene_cloud = one_sided_setup(scene, target, views=views, size=size,
                                                                            per_area=per_area, seed=seed)
    centre = intact.means.mean(0)
    radius = float(np.quantile(np.linalg.norm(intact.means - centre, axis=1), 0.98))
    test_cams = object_cameras(centre, radius, OcclusionConfig(num_views=8, size=view_size, seed=seed + 100,
                                                               elevation_deg=(15.0, 45.0)))
    truth_rgb, truth_alpha = _render(intact, test_cams)
    # the intact object with never-seen Gaussians white and the others black: which surface each pixel shows
    flag = GaussianCloud.from_activated(intact.means, scales=intact.scales, opacities=intact.opacities,
                                        rgb=np.repeat(unseen[:, None].astype(np.float64), 3, axis=1))
    flag_rgb, _ = _render(flag, test_cams, background=(0.0, 0.0, 0.0))
    never = (truth_alpha >= 0.5) & (flag_rgb[..., 0] > 0.5)
    out = {"target": target.name, "gaussians": len(intact), "never_seen_gaussians": int(unseen.sum()),
           "train_views": len(cams), "never_seen_share_of_test_pixels": float(never.sum() / (truth_alpha >= 0.5).sum()),
           "runs": {"before": scores(obj, test_cams, truth_rgb, truth_alpha, never)}}
    occ = OcclusionConfig(size=view_size)
    runs = [("originals only", "opencv", FinetuneConfig(iterations=iterations, inpaint_every=iterations + 1))]
    runs += [(name, name, FinetuneConfig(iterations=iterations)) for name in inpainters]
    for label, inp, ft in runs:
        t = time.perf_counter()
        res = refine_object(obj, scene_cloud, images, cams, masks, inpainter=inp, occlusion=occ, finetune=ft,
                            up=(0, 0, 1), lpips=lpips_for_loss(ft.perceptual, ft.lpips_weights))
        fill_s = time.perf_counter() - t - res.finetune.seconds
        out["runs"][label] = {**scores(res.cloud, test_cams, truth_rgb, truth_alpha, never),
                              "proposed": res.proposed, "seconds": time.perf_counter() - t,
                              "occlusion_and_fill_s": fill_s}
        print(f"  {target.name} {label}: " + ", ".join(f"{k} {v:.3f}" for k, v in out["runs"][label].items()),
              flush=True)
    out["seconds"] = time.perf_counter() - t0
    return out


def texture_check(size: int = 256) -> dict:
    """Return the fill time and the mean absolute error inside the holes of a 2x2 grid of ``size`` px views of a
    striped disc on white, each with a square hole inside it beside its centre (the mask: holes and background, as occlusion
    reasoning makes it), for the 2D inpainters."""
    from roodi_toolkit.pipeline.inpaint import get_inpainter, inpaint_views

    yy, xx = np.mgrid[0:size, 0:size]
    c, r = size / 2, 0.35 * size
    disc = (xx - c) ** 2 + (yy - c) ** 2 < r ** 2
    views, masks, holes = [], [], []
    for k in range(4):
        img = np.ones((size, size, 3), np.float32)
        stripes = ((xx + yy + 7 * k) // max(2, size // 32)) % 2 == 1
        img[disc & stripes] = (0.8, 0.2, 0.1)
        img[disc & ~stripes] = (0.1, 0.3, 0.8)
        hole = disc & (np.abs(xx - c - 0.12 * size) < 0.1 * size) & (np.abs(yy - c) < 0.1 * size)
        views.append(img), masks.append(hole | ~disc), holes.append(hole)
    truth, mask, hole = (torch.from_numpy(np.array(a)) for a in (views, masks, holes))
    corrupted = torch.where(mask[..., None], torch.ones(()), truth)
    out = {}
    for name in ("opencv", "exemplar"):
        t = time.perf_counter()
        filled, _ = inpaint_views(get_inpainter(name), corrupted, mask)
        out[name] = {"seconds": time.perf_counter() - t, "hole_mae": float((filled - truth).abs()[hole].mean())}
    out["unfilled"] = {"hole_mae": float((corrupted - truth).abs()[hole].mean())}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="picnic")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--targets", default="", help="comma-separated target names (default: all of the scene's)")
    ap.add_argument("--inpainters", default="opencv,exemplar,symmetry")
    ap.add_argument("--views", type=int, default=24, help="training cameras before keeping one side")
    ap.add_argument("--size", type=int, default=64, help="training view size")
    ap.add_argument("--view-size", type=int, default=64, help="object-centred and test view size")
    ap.add_argument("--iterations", type=int, default=100)
    ap.add_argument("--per-area", type=float, default=15000.0, help="Gaussians per square metre of surface")
    ap.add_argument("--json", default=None)
    ap.add_argument("--texture", action="store_true", help="only the 2D texture check (texture_check) and exit")
    a = ap.parse_args()
    if a.texture:
        print(json.dumps(texture_check(), indent=1))
        return
    scene = build_scene(a.preset, a.seed)
    wanted = [t for t in a.targets.split(",") if t]
    targets = [o for o in scene.targets if not wanted or o.name in wanted]
    results = [run_target(scene, t, [n for n in a.inpainters.split(",") if n], views=a.views, size=a.size,
                          view_size=a.view_size, iterations=a.iterations, per_area=a.per_area, seed=a.seed)
               for t in targets]
    labels = list(results[0]["runs"])
    print("\nmean over targets:")
    for label in labels:
        keys = ["never_seen_psnr", "never_seen_covered", "iou", "psnr"]
        means = {k: float(np.nanmean([r["runs"][label][k] for r in results])) for k in keys}
        print(f"  {label}: " + ", ".join(f"{k} {v:.3f}" for k, v in means.items()))
    if a.json:
        Path(a.json).write_text(json.dumps({"args": vars(a), "results": results}, indent=1))


if __name__ == "__main__":
    main()
