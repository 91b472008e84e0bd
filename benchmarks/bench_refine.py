"""Occlusion reasoning, inpainting and fine-tuning of trained object models, scored against the generator's truth.

For every target of a ``roodi-toolkit benchmark`` output (``OUT/<preset>/full``: the trained and distilled scene in
``scene/``, and per target ``object_<ID>/selected.ply``, the object after selection and pruning, and ``object.ply``,
after occlusion-reasoned inpainting and fine-tuning), this compares ``selected.ply`` ("before") with ``object.ply``
("after"); nothing is trained or fine-tuned again:

- occlusion masks: recomputed from ``selected.ply`` and the scene model with the run's occlusion settings (same seed
  and up axis, so the same 4 object-centred cameras; checked against the run's ``debug/refine.json``), scored against
  the hidden truth: the pixels where the target is seen when rendered alone but not in the full scene (the
  generator's mesh ray casting from the same cameras);
- PSNR in those 4 views against the true target alone on white, over the hidden-truth pixels ("occluded") and over
  the whole view;
- whether the hidden parts were ever seen: the hidden-truth pixels' surface points (the target alone, the generator's
  depth) counted in the training views that see them (the generator's ids and depth), and the object model's alpha
  there before refinement;
- PSNR in the training views inside the target's mask ("unoccluded");
- the paper's metrics (:func:`roodi_toolkit.run.evaluate.evaluate_object`: PSNR in 1.2x the true box, alpha IoU) on the
  target's object-alone test views: the "w/o inpainting" vs "full" comparison per object.

With ``--control``, ``selected.ply`` is also fine-tuned again with the run's settings but on the original views only
(the same steps in the same order, without the inpainted views' terms), which tells what the inpainted views add
beyond more fitting to the training views. (Re-running the whole refinement reproduces ``object.ply`` exactly.)
With ``--variant NAME:KEY=VALUE[,KEY=VALUE...]`` (repeatable) the whole refinement runs again from ``selected.ply``
with those :class:`~roodi_toolkit.pipeline.finetune.FinetuneConfig` fields changed, e.g. ``--variant lr10:sh0_lr=0.025``;
``--seed-holes`` is ``--variant seeded:seed_holes=true``.

Usage: .venv/bin/python benchmarks/bench_refine.py [OUT_DIR SCENES_ROOT] [--preset P ...] [--control] [--seed-holes]
       [--variant NAME:KEY=VALUE,...] [--json PATH]
(default: the 64x64 benchmark run, /work/bench/out and /work/bench/scenes). Read only: writes nothing but the JSON.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

torch.set_num_threads(1)  # two threads on a busy 2-core machine are ~10x slower
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.bench_inpaint import (finetune_overrides, object_view_truth, psnr_figures,  # noqa: E402
                                      seen_in_views)
from roodi_toolkit.evaluate.benchmark import MACHINE_SIZE, PRESETS, extract_config  # noqa: E402
from roodi_toolkit.io.dataset import load_dataset  # noqa: E402
from roodi_toolkit.io.model import find_model  # noqa: E402
from roodi_toolkit.io.files import read_json, write_json  # noqa: E402
from roodi_toolkit.io.lpips_weights import lpips_for_loss  # noqa: E402
from roodi_toolkit.pipeline.finetune import (FinetuneConfig, ViewTargets, finetune_object, object_view_targets,  # noqa: E402
                                    refine_object)
from roodi_toolkit.run.evaluate import evaluate_object  # noqa: E402
from roodi_toolkit.pipeline.occlusion import OcclusionConfig, mask_scores, occlusion_masks, up_from_cameras  # noqa: E402
from roodi_toolkit.io.ply import read_ply  # noqa: E402
from roodi_toolkit.synth.scene import scene_from_record  # noqa: E402
from roodi_toolkit.synth.tracer import render_views  # noqa: E402
from roodi_toolkit.params import GaussianParams  # noqa: E402
from roodi_toolkit.render.renderer import TorchRenderer  # noqa: E402

FIGURES = ("occluded_hidden_psnr", "object_views_psnr", "unoccluded_train_psnr", "test_psnr", "test_iou")
LABELS = {"occluded_hidden_psnr": "occluded PSNR (hidden-truth px)", "object_views_psnr": "object views PSNR",
          "unoccluded_train_psnr": "unoccluded PSNR (train, in mask)", "test_psnr": "test PSNR (paper)",
          "test_iou": "test IoU (paper)"}


def run_configs(record: dict | None) -> tuple[OcclusionConfig, FinetuneConfig]:
    """Return the occlusion and fine-tuning settings the run used: from its ``debug/refine.json`` record, else the
    benchmark's defaults."""
    if record is None:
        base = extract_config(MACHINE_SIZE)
        return base.occlusion, base.finetune
    occ, fine = dict(record["occlusion"]), dict(record["finetune"])
    occ["elevation_deg"] = tuple(occ["elevation_deg"])
    fine["background"] = tuple(fine["background"])
    return OcclusionConfig(**occ), FinetuneConfig(**fine)


def parse_variant(text: str) -> tuple[str, dict]:
    """Return the name and the FinetuneConfig overrides of ``NAME:KEY=VALUE[,KEY=VALUE...]``."""
    name, sep, body = text.partition(":")
    if not sep or not name or name in ("before", "after", "originals_only"):
        raise argparse.ArgumentTypeError(f"--variant wants NAME:KEY=VALUE[,...] with a new name, got {text!r}")
    try:
        return name, finetune_overrides(body)
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"--variant {name}: {exc}") from None


def finetune_originals_only(cloud, cams, images: torch.Tensor, masks: torch.Tensor, depths: torch.Tensor, occ,
                            config: FinetuneConfig):
    """Return ``cloud`` fine-tuned as :func:`roodi_toolkit.pipeline.finetune.refine_object` does, without the inpainted views.

    Args:
        cloud: the object before refinement.
        cams: the training views.
        images: their images. [N, H, W, 3]
        masks: the object's masks in them. [N, H, W]
        depths: the scene model's depth in them. [N, H, W]
        occ: the occlusion result (the object's centre and radius).
        config: the run's fine-tuning settings.
    """
    originals = object_view_targets(images, cams, masks, depths=depths, centre=occ.centre, radius=occ.radius,
                                    background=config.background)
    no_views = ViewTargets([], torch.zeros(0, 1, 1, 3), torch.zeros(0, 1, 1))
    return finetune_object(cloud, originals, no_views, config,
                           lpips=lpips_for_loss(config.perceptual, config.lpips_weights)).cloud


def hidden_seen(target, occ, truth: np.ndarray, alone_depth: np.ndarray, cams, train_renders) -> dict:
    """Return how the hidden-truth pixels' surface points (``alone_depth``: the target alone's depth ``[V, H, W]`` in
    ``occ.cameras``) were seen in the training views (the generator's renders ``train_renders`` from ``cams``) and the
    object model's alpha at those pixels (``occ``: its occlusion result)."""
    if not truth.any():
        return {"seen_1": float("nan"), "seen_3": float("nan"), "median_views": float("nan"),
                "object_alpha": float("nan")}
    points = np.concatenate([cam.backproject(np.argwhere(truth[k]), alone_depth[k][truth[k]])
                             for k, cam in enumerate(occ.cameras) if truth[k].any()])
    # depth slack: a fifth of the target's radius (the far side of the target must not count as seen)
    tol = 0.2 * float(np.linalg.norm(target.vertices - target.center, axis=1).max())
    counts = sum(seen_in_views(points, [c], [r], target.id, tol=tol).astype(np.int64)
                 for c, r in zip(cams, train_renders))
    return {"seen_1": float(np.mean(counts >= 1)), "seen_3": float(np.mean(counts >= 3)),
            "median_views": float(np.median(counts)), "object_alpha": float(occ.object_alpha.numpy()[truth].mean())}


def measure_target(data_dir: Path, out_dir: Path, scene, dataset, scene_cloud, object_id: int,
                   scene_depths: torch.Tensor | None = None, variants: dict[str, dict] | None = None,
                   train_renders=None) -> dict:
    """Return the figures of one target: occlusion-mask scores, PSNRs and paper metrics before and after refinement
    (and after fine-tuning on the original views only, given the scene's depth ``[N, H, W]`` in the training views;
    and after the whole refinement again with each of ``variants``' FinetuneConfig overrides)."""
    t0 = time.perf_counter()
    odir = out_dir / f"object_{object_id}"
    target = next(o for o in scene.objects if o.id == object_id)
    before, after = read_ply(odir / "selected.ply"), read_ply(odir / "object.ply")
    record = odir / "debug" / "refine.json"
    rec = read_json(record, "refine record") if record.is_file() else None
    config, fine = run_configs(rec)
    views = dataset.train_indices
    cams = [dataset.cameras[v] for v in views]
    # the run's refine_object had up=None: the up axis estimated from the training cameras
    occ = occlusion_masks(before, scene_cloud, None, config, up=up_from_cameras(cams), background=(1.0, 1.0, 1.0))
    reproduced = None
    if rec is not None:  # the same cameras as the run: the same centre and occluded fractions
        reproduced = {"centre_error": float(np.abs(np.asarray(rec["object_centre"]) - occ.centre).max()),
                      "occluded_fraction_error": float(np.abs(np.asarray(rec["occluded_fraction"])
                                                              - occ.occluded.float().mean((1, 2)).numpy()).max())}
    truth, gt, alone_depth = object_view_truth(scene, target, occ.cameras)
    images = dataset.images[views]
    masks = dataset.masks[views] == object_id
    clouds = {"before": before, "after": after}
    if scene_depths is not None:
        clouds["originals_only"] = finetune_originals_only(before, cams, images, masks, scene_depths, occ, fine)
    for label, overrides in (variants or {}).items():
        variant = replace(fine, **overrides)
        clouds[label] = refine_object(before, scene_cloud, images, cams, masks, occlusion=config, finetune=variant,
                                      lpips=lpips_for_loss(variant.perceptual, variant.lpips_weights)).cloud
    psnr = {}
    for label, cloud in clouds.items():
        figures = psnr_figures(cloud, cams, images, masks, occ.cameras, gt, truth)
        ev, _ = evaluate_object(cloud, data_dir, object_id)
        psnr[label] = {**figures, "test_psnr": ev.psnr, "test_ssim": ev.ssim, "test_iou": ev.iou}
    return {"object_id": object_id, "object_name": target.name, "gaussians": len(before),
            "gaussians_after": len(after), "view_size": config.size, "opening": config.effective_opening,
            "hidden_fraction": float(truth.mean()), "hidden_pixels": int(truth.sum()),
            "occlusion_opened": mask_scores(occ.occluded.numpy(), truth),
            "occlusion_raw": mask_scores(occ.occluded_raw.numpy(), truth),
            "inpaint_mask_recall_of_hidden": mask_scores(occ.mask.numpy(), truth)["recall"],
            "hidden_seen": hidden_seen(target, occ, truth, alone_depth, cams, train_renders),
            "reproduced": reproduced, "psnr": psnr, "seconds": time.perf_counter() - t0}


def measure_preset(out_root: Path, scenes_root: Path, preset: str, control: bool = False,
                   variants: dict[str, dict] | None = None) -> list[dict]:
    """Return the figures of every target of one preset (with the originals-only control if ``control``, and the
    refinement again with each of ``variants``' overrides)."""
    data = scenes_root / preset
    record = read_json(data / "scene.json", "scene record")
    scene = scene_from_record(record)
    dataset = load_dataset(data)
    full = out_root / preset / "full"
    scene_cloud = read_ply(find_model(full / "scene").ply_path)
    depths = None
    if control:  # as refine_object: where the scene may hide the object in the training views
        params = GaussianParams.from_cloud(scene_cloud)
        with torch.no_grad():
            depths = torch.stack([TorchRenderer().render(params, dataset.cameras[v]).depth[..., 0]
                                  for v in dataset.train_indices])
    train_renders = render_views(scene, [dataset.cameras[v] for v in dataset.train_indices], supersample=1)
    rows = []
    for t in record["targets"]:
        row = measure_target(data, full, scene, dataset, scene_cloud, int(t["id"]), depths, variants, train_renders)
        rows.append({"preset": preset, **row})
        print_row(rows[-1])
    return rows


def _nanmean(values) -> float:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(vals)) if vals else float("nan")


def pooled_scores(rows: list[dict], key: str) -> dict[str, float]:
    """Return precision, recall and IoU over all pixels of all rows (objects with more hidden pixels weigh more)."""
    tp = sum(r[key]["recall"] * r[key]["true"] for r in rows if r[key]["true"])
    pred, true = sum(r[key]["predicted"] for r in rows), sum(r[key]["true"] for r in rows)
    nan = float("nan")
    return {"precision": tp / pred if pred else nan, "recall": tp / true if true else nan,
            "iou": tp / (pred + true - tp) if pred + true - tp else nan, "predicted": pred, "true": true}


def summarize(rows: list[dict]) -> dict:
    """Return the mean before / after / change of every figure (NaN rows left out, counted in ``n``)."""
    out = {}
    for f in FIGURES:
        kept = [r["psnr"] for r in rows if all(math.isfinite(v[f]) for v in r["psnr"].values())]
        out[f] = {"n": len(kept), "improved": sum(p["after"][f] > p["before"][f] for p in kept)}
        for label in kept[0] if kept else ():
            out[f][label] = _nanmean([p[label][f] for p in kept])
            if label != "before":
                out[f][f"change_{label}"] = _nanmean([p[label][f] - p["before"][f] for p in kept])
    out["occlusion_opened"] = pooled_scores(rows, "occlusion_opened")
    out["occlusion_raw"] = pooled_scores(rows, "occlusion_raw")
    hidden = sum(r["hidden_pixels"] for r in rows)
    out["inpaint_mask_recall_of_hidden"] = (sum(r["inpaint_mask_recall_of_hidden"] * r["hidden_pixels"] for r in rows
                                                if r["hidden_pixels"]) / hidden if hidden else float("nan"))
    out["hidden_fraction"] = _nanmean([r["hidden_fraction"] for r in rows])
    for key in ("seen_1", "seen_3", "object_alpha"):  # over hidden pixels, all objects pooled
        out[f"hidden_{key}"] = (sum(r["hidden_seen"][key] * r["hidden_pixels"] for r in rows if r["hidden_pixels"])
                                / hidden if hidden else float("nan"))
    return out


def _change(m: dict) -> str:
    """Return ``before -> after (+change)`` and the originals-only control where measured."""
    out = f"{m['before']:8.3f} -> {m['after']:8.3f} ({m['change_after']:+.3f})"
    for label in m:
        if label.startswith("change_") and label != "change_after":
            label = label[len("change_"):]
            out += f" | {label.replace('_', ' ')} {m[label]:8.3f} ({m[f'change_{label}']:+.3f})"
    return out


def print_row(r: dict) -> None:
    p, o = r["psnr"], r["occlusion_opened"]

    def pair(f: str, digits: int = 2) -> str:
        text = f"{p['before'][f]:.{digits}f} -> {p['after'][f]:.{digits}f}"
        return text + "".join(f" [{label[:6]} {p[label][f]:.{digits}f}]" for label in p
                              if label not in ("before", "after"))

    h = r["hidden_seen"]
    print(f"{r['preset']:<10} {r['object_name']:<10} {r['gaussians']:>4} G, hidden {100 * r['hidden_fraction']:5.2f}% "
          f"(seen in >=3 train views {h['seen_3']:.2f}, object alpha {h['object_alpha']:.2f}) "
          f"P {o['precision']:.2f} R {o['recall']:.2f} | occluded {pair('occluded_hidden_psnr')} | "
          f"view {pair('object_views_psnr')} | unoccluded {pair('unoccluded_train_psnr')} | "
          f"test {pair('test_psnr')} IoU {pair('test_iou', 3)} | {r['seconds']:.0f} s", flush=True)


def print_summary(name: str, s: dict) -> None:
    print(f"\n{name}: hidden {100 * s['hidden_fraction']:.2f}% of view pixels; occlusion mask (pooled) opened "
          f"P {s['occlusion_opened']['precision']:.3f} R {s['occlusion_opened']['recall']:.3f} "
          f"IoU {s['occlusion_opened']['iou']:.3f}, raw P {s['occlusion_raw']['precision']:.3f} "
          f"R {s['occlusion_raw']['recall']:.3f} IoU {s['occlusion_raw']['iou']:.3f}; inpainting mask recall "
          f"{s['inpaint_mask_recall_of_hidden']:.3f}; hidden pixels seen in >=1 / >=3 training views "
          f"{s['hidden_seen_1']:.2f} / {s['hidden_seen_3']:.2f}, object alpha there {s['hidden_object_alpha']:.2f}")
    for f in FIGURES:
        if s[f]["n"]:
            print(f"  {LABELS[f]:<34} {_change(s[f])}; improved {s[f]['improved']}/{s[f]['n']}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dir", nargs="?", default="/work/bench/out", help="a roodi-toolkit benchmark output")
    ap.add_argument("scenes_root", nargs="?", default="/work/bench/scenes", help="its generated scenes")
    ap.add_argument("--preset", action="append", choices=PRESETS, help="only these presets (default all)")
    ap.add_argument("--control", action="store_true", help="also fine-tune on the original views only")
    ap.add_argument("--seed-holes", action="store_true",
                    help="also run the whole refinement again with hole seeding (FinetuneConfig.seed_holes)")
    ap.add_argument("--variant", action="append", type=parse_variant, default=[], metavar="NAME:KEY=VALUE,...",
                    help="also run the whole refinement again with these FinetuneConfig fields (repeatable)")
    ap.add_argument("--json", default=None, help="write every figure here")
    a = ap.parse_args()
    t0 = time.perf_counter()
    presets = a.preset or [p for p in PRESETS if (Path(a.out_dir) / p / "full").is_dir()]
    variants = dict(a.variant)
    if a.seed_holes:
        variants["seeded"] = {"seed_holes": True}
    rows = []
    for preset in presets:
        rows += measure_preset(Path(a.out_dir), Path(a.scenes_root), preset, a.control, variants)
    per_preset = {p: summarize([r for r in rows if r["preset"] == p]) for p in presets}
    overall = summarize(rows)
    # the paper's protocol: the mean per scene, then over scenes (the pooled mask scores are over all objects)
    keys = [k for k in overall["object_views_psnr"] if k not in ("n", "improved")]
    scene_mean = {f: {k: _nanmean([per_preset[p][f].get(k, float("nan")) for p in presets]) for k in keys}
                  for f in FIGURES}
    for p in presets:
        print_summary(p, per_preset[p])
    print_summary(f"all {len(rows)} objects", overall)
    print("\nmean of per-scene means:")
    for f in FIGURES:
        print(f"  {LABELS[f]:<34} {_change(scene_mean[f])}")
    seconds = time.perf_counter() - t0
    print(f"\n{len(rows)} objects in {seconds:.0f} s")
    if a.json:
        write_json({"out_dir": a.out_dir, "scenes_root": a.scenes_root, "control": a.control,
                    "variants": variants, "objects": rows,
                    "per_preset": per_preset, "all_objects": overall, "scene_mean": scene_mean, "seconds": seconds},
                   a.json)


if __name__ == "__main__":
    main()
