"""The click segmenter alone, clicked at many places of a scale scene's object: each click's masks against the truth.

For each named view: the object's visible pixel nearest its centre, the one farthest from it and a random one (seed
0) are clicked at the working size (512x512 pixels at most); each click's masks are scored (IoU) against the object's
true alpha (> 0.5) in every ``STEP``-th view. With ``--no-support`` the support plane of the clicked region
(:func:`roodi_toolkit.pipeline.click_regions.support_plane`) is switched off: the click as it was before it. With
``--negative PX`` each click comes with a negative click on the surface nearest the object's centre at least PX
pixels from it (what a user adds to keep the ground out). With ``--inside PX`` the three are picked among the object's
pixels at least PX pixels inside its silhouette: the farthest is then a click on the object, not on its last pixel
beside the ground (which at the working size can show the ground).

    .venv/bin/python benchmarks/bench_click_many.py /tmp/scale/donut500 10 r_0,r_25,r_40,r_70 [--negative 12]

The scene is a folder of ``benchmarks/scale_scene.py`` (``data/``, ``model/``, ``truth.npz``).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import ndimage


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("step", type=int, help="score in every STEP-th view")
    ap.add_argument("views", help="the clicked views, comma-separated")
    ap.add_argument("--no-support", action="store_true", help="the click without its support plane (as before)")
    ap.add_argument("--inside", type=int, default=0, metavar="PX",
                    help="pick the clicks among the object's pixels at least PX pixels (full size) inside its "
                         "silhouette (0: any of its pixels, its edge included)")
    ap.add_argument("--negative", type=int, default=None, metavar="PX",
                    help="with each click, a negative click on the surface nearest the object's centre that lies at "
                         "least PX pixels (full size) from the object's pixels: the ground under a resting object")
    args = ap.parse_args(argv)

    from roodi_toolkit.imaging import mask_iou
    from roodi_toolkit.io.dataset import load_dataset
    from roodi_toolkit.io.ply import read_ply
    from roodi_toolkit.pipeline import click as click_module
    from roodi_toolkit.pipeline.click import ClickSegmenter
    from roodi_toolkit.pipeline.resolution import working_dataset
    from roodi_toolkit.pipeline.segment import Click, SegmentationError, SegmentPrompt
    from roodi_toolkit.render import fast
    from roodi_toolkit.render.renderer import render_cloud

    if args.no_support:
        click_module.off_support = lambda cam0, depth0, region, *a, **k: (region, np.zeros_like(region))
    truth = np.load(f"{args.scene}/truth.npz")["object"]
    model = read_ply(f"{args.scene}/model/point_cloud/iteration_0/point_cloud.ply")
    ds = load_dataset(f"{args.scene}/data", 1)
    views = args.views.split(",")
    work, f = working_dataset(ds, 512 * 512)
    keep = sorted(set(range(0, len(work), args.step)) | {work.names.index(v) for v in views})
    work = work.subset(keep)
    truth_masks = [render_cloud(model.select(truth), c).alpha[..., 0].numpy() > 0.5 for c in work.cameras]
    rng = np.random.default_rng(0)
    f32 = lambda a: np.ascontiguousarray(a, np.float32)  # noqa: E731
    for view in views:
        cam = ds.cameras[ds.names.index(view)]
        top, alpha, _ = fast.surface_ids(f32(model.means), f32(model.quats_wxyz), f32(model.log_scales),
                                         f32(model.opacity_logits),
                                         fast.make_view(cam.world_to_camera, cam.K, cam.width, cam.height))
        on = (top >= 0) & truth[np.maximum(top, 0)] & (alpha > 0.9)
        if args.inside > 0:
            on &= ndimage.distance_transform_edt(on) > args.inside
        ys, xs = np.nonzero(on)
        if not len(ys):
            print(f"{view}: the object shows no opaque pixel")
            continue
        d = (xs - xs.mean()) ** 2 + (ys - ys.mean()) ** 2
        picks = {"centre": int(np.argmin(d)), "far": int(np.argmax(d)), "random": int(rng.integers(len(xs)))}
        negative = ()
        if args.negative is not None:
            away = ndimage.distance_transform_edt(~((top >= 0) & truth[np.maximum(top, 0)])) >= args.negative
            ny, nx = np.nonzero(away & (top >= 0) & (alpha > 0.9))
            j = int(np.argmin((nx - xs.mean()) ** 2 + (ny - ys.mean()) ** 2))
            negative = (Click(view, (nx[j] + 0.5) / f, (ny[j] + 0.5) / f, positive=False),)
            print(f"{view}: negative click at ({nx[j]},{ny[j]})")
        for name, k in picks.items():
            t0 = time.time()
            prompt = SegmentPrompt((Click(view, (xs[k] + 0.5) / f, (ys[k] + 0.5) / f),) + negative)
            try:
                masks = ClickSegmenter().segment(work, prompt, scene=model)
            except SegmentationError as e:
                print(f"{view} {name} ({xs[k]},{ys[k]}): failed, IoU 0 ({e})", flush=True)
                continue
            ious = [mask_iou(masks.masks[v].numpy() > 0, truth_masks[v]) for v in range(len(work))]
            print(f"{view} {name} ({xs[k]},{ys[k]}): IoU mean {np.mean(ious):.3f} min {np.min(ious):.3f} "
                  f"free {masks.info.get('free_standing')} sel {masks.info['selected_gaussians']} "
                  f"{time.time() - t0:.0f}s", flush=True)


if __name__ == "__main__":
    main()
