"""Occlusion masks, inpainting and fine-tuning on a generated scene, scored against the generator's own truth.

The scene's meshes give both the truth and the models: the scene model is Gaussians sampled on every object's
surface (tests/mesh_gaussians.py); the object model is those on the target, where Gaussians never seen in any training
view (hidden behind other objects, by the mesh renderer's depth) are given a wrong grey colour, as a reconstruction
leaves what it never saw. Training views are the generator's renders. Then:

- occlusion masks from the 4 object-centred views vs the hidden truth (target seen alone, not in the full scene);
- PSNR of the object before and after refinement, on the training views inside the target's mask ("unoccluded")
  and on the 4 object-centred views against the target rendered alone on white, over the hidden-truth pixels
  ("occluded") and over the whole view.

Usage: .venv/bin/python benchmarks/bench_inpaint.py [--preset picnic --seed 0 --target basket_3 --size 64 ...]
       [--finetune KEY=VALUE,...]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from roodi_toolkit.io.lpips_weights import lpips_for_loss  # noqa: E402
from roodi_toolkit.pipeline.finetune import FinetuneConfig, refine_object  # noqa: E402
from roodi_toolkit.run.refine import write_refine_debug  # noqa: E402
from roodi_toolkit.gaussians import GaussianCloud  # noqa: E402
from roodi_toolkit.imaging import psnr  # noqa: E402
from roodi_toolkit.pipeline.occlusion import OcclusionConfig, mask_scores  # noqa: E402
from roodi_toolkit.synth.scene import build_scene, training_cameras  # noqa: E402
from roodi_toolkit.synth.tracer import render_views  # noqa: E402
from roodi_toolkit.params import GaussianParams  # noqa: E402
from roodi_toolkit.render.renderer import TorchRenderer  # noqa: E402
from tests.mesh_gaussians import hidden_truth, mesh_cloud, nearby  # noqa: E402


def masked_psnr(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor) -> float:
    if not bool(mask.any()):
        return float("nan")
    return psnr(a.clamp(0, 1)[mask], b[mask])


def finetune_overrides(text: str) -> dict:
    """Return the :class:`FinetuneConfig` fields of ``KEY=VALUE[,KEY=VALUE...]``, typed as the fields' defaults."""
    defaults = {f.name: f.default for f in dataclasses.fields(FinetuneConfig)}
    overrides = {}
    for item in filter(None, text.split(",")):
        key, eq, value = item.partition("=")
        if not eq or key not in defaults:
            raise argparse.ArgumentTypeError(f"{item!r} is not KEY=VALUE with a FinetuneConfig field "
                                             f"({', '.join(defaults)})")
        kind = type(defaults[key])
        if kind is bool:
            overrides[key] = value.lower() in ("1", "true", "yes", "on")
        elif kind in (int, float):
            overrides[key] = kind(value)
        else:
            overrides[key] = value
    return overrides


def seen_in_views(points: np.ndarray, cams, renders, target_id: int, tol: float) -> np.ndarray:
    seen = np.zeros(len(points), bool)
    for cam, r in zip(cams, renders):
        uv, z = cam.project(points)
        j, i = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        ok = (z > 0) & (j >= 0) & (j < cam.width) & (i >= 0) & (i < cam.height)
        idx = np.where(ok)[0]
        hit = (r.ids[i[idx], j[idx]] == target_id) & (np.abs(r.depth[i[idx], j[idx]] - z[idx]) < tol)
        seen[idx[hit]] = True
    return seen


def object_view_truth(scene, target, cameras) -> tuple[np.ndarray, torch.Tensor, np.ndarray]:
    """Return the hidden truth ``[V, H, W]`` bool (the target seen alone, not in the full scene), the target alone
    on white ``[V, H, W, 3]`` and its z-depth ``[V, H, W]`` (0: not hit) in ``cameras``, all from the generator's mesh
    renderer."""
    truth = hidden_truth(scene, target, cameras)
    views = render_views(scene, cameras, object_ids=[target.id], with_ground=False, background=(1.0, 1.0, 1.0),
                         supersample=2)
    return (truth, torch.stack([torch.as_tensor(r.rgb, dtype=torch.float32) for r in views]),
            np.stack([r.depth for r in views]))


def psnr_figures(cloud: GaussianCloud, train_cams, images: torch.Tensor, masks: torch.Tensor, object_cams,
                 gt: torch.Tensor, truth: np.ndarray) -> dict[str, float]:
    """Return the object's PSNR on white: in the training views inside its mask ``[N, H, W]`` ("unoccluded"), and in
    the object-centred views against ``gt`` over the hidden-truth pixels ("occluded") and over the whole view."""
    white = torch.ones(3)
    p = GaussianParams.from_cloud(cloud)
    renderer = TorchRenderer()
    with torch.no_grad():
        tr = torch.stack([renderer.render(p, c, background=white).rgb for c in train_cams])
        ov = torch.stack([renderer.render(p, c, background=white).rgb for c in object_cams])
    return {
        "unoccluded_train_psnr": masked_psnr(tr, images, masks),
        "occluded_hidden_psnr": masked_psnr(ov, gt, torch.as_tensor(truth)),
        "object_views_psnr": masked_psnr(ov, gt, torch.ones(gt.shape[:3], dtype=torch.bool)),
    }


def run(preset="picnic", seed=0, target_name="basket_3", size=64, train_size=64, train_views=12, iterations=100,
        inpainter="opencv", debug_dir=None, finetune: dict | None = None) -> dict:
    t0 = time.perf_counter()
    scene = build_scene(preset, seed)
    target = next(o for o in scene.targets if o.name == target_name)
    cams = training_cameras(scene, train_views, train_size, train_size)
    renders = render_views(scene, cams, supersample=2)
    obj = mesh_cloud([target], seed=0)
    spacing = 1 / 60000 ** 0.5
    seen = seen_in_views(obj.means.astype(np.float64), cams, renders, target.id, tol=3 * spacing)
    rgb = obj.rgb.copy()
    rgb[~seen] = 0.5  # never seen: a wrong colour, as a reconstruction leaves it
    obj = GaussianCloud.from_activated(obj.means, scales=obj.scales, opacities=obj.opacities, rgb=rgb)
    occ_cfg = OcclusionConfig(size=size)
    radius = float(np.linalg.norm(target.vertices - target.center, axis=1).max())
    reach = 3 * radius / math.sin(math.radians(occ_cfg.fov_deg) / 2)
    scene_cloud = GaussianCloud.concatenate([obj, mesh_cloud(nearby(scene, target, reach), seed=1)])
    images = torch.stack([torch.as_tensor(r.rgb, dtype=torch.float32) for r in renders])
    masks = torch.stack([torch.as_tensor(r.ids == target.id) for r in renders])
    ft = FinetuneConfig(iterations=iterations, **(finetune or {}))
    res = refine_object(obj, scene_cloud, images, cams, masks, inpainter=inpainter, occlusion=occ_cfg, finetune=ft,
                        up=(0, 0, 1), lpips=lpips_for_loss(ft.perceptual, ft.lpips_weights))
    if debug_dir is not None:
        write_refine_debug(res, debug_dir)
    truth, gt, _ = object_view_truth(scene, target, res.occlusion.cameras)
    scores = mask_scores(res.occlusion.occluded.numpy(), truth)
    raw = mask_scores(res.occlusion.occluded_raw.numpy(), truth)
    full_recall = mask_scores(res.occlusion.mask.numpy(), truth)["recall"]
    figures = {label: psnr_figures(cloud, cams, images, masks, res.occlusion.cameras, gt, truth)
               for label, cloud in (("before", obj), ("after", res.cloud))}
    return {"preset": preset, "seed": seed, "target": target_name, "view_size": size, "train_size": train_size,
            "train_views": train_views, "iterations": iterations, "finetune": finetune or {}, "inpainter": res.inpainter,
            "perceptual": res.finetune.perceptual, "object_gaussians": len(obj), "never_seen": int((~seen).sum()),
            "hidden_fraction": float(truth.mean()), "occlusion_opened": scores, "occlusion_raw": raw,
            "inpaint_mask_recall_of_hidden": full_recall, "psnr": figures,
            "finetune_seconds": res.finetune.seconds, "seconds": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="picnic")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--target", default="basket_3")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--train-size", type=int, default=64)
    ap.add_argument("--train-views", type=int, default=12)
    ap.add_argument("--iterations", type=int, default=100)
    ap.add_argument("--inpainter", default="opencv")
    ap.add_argument("--debug-dir", default=None)
    ap.add_argument("--finetune", type=finetune_overrides, default={}, metavar="KEY=VALUE,...",
                    help="FinetuneConfig fields to change, e.g. sh0_lr=0.025")
    a = ap.parse_args()
    out = run(a.preset, a.seed, a.target, a.size, a.train_size, a.train_views, a.iterations, a.inpainter,
              a.debug_dir, a.finetune)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
