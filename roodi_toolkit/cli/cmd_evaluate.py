"""``roodi-toolkit evaluate``: the paper's metrics of an extracted object against the target's true views."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import click
import numpy as np

from roodi_toolkit.run.evaluate import evaluate_object, find_target
from roodi_toolkit.io import files
from roodi_toolkit.io.dataset import load_dataset
from roodi_toolkit.io.lpips_weights import ENV_WEIGHTS, read_lpips
from roodi_toolkit.io.model import open_model
from roodi_toolkit.io.other_models import GSPLAT_CKPT
from roodi_toolkit.io.splat import input_paths, read_cloud

from .common import overwrite_option, progress_factory, quiet_option
from .renderer_option import renderer_option

EXAMPLE = """Example:

\b
  roodi-toolkit evaluate out/object.ply scenes/bedroom --object 2
  roodi-toolkit evaluate out/object.ply scenes/bedroom --object 2 --json scores.json --renders eval_renders/
"""


@click.command(epilog=EXAMPLE)
@click.argument("object_ply", metavar="OBJECT.ply", type=click.Path(path_type=str))
@click.argument("data_dir", type=click.Path(path_type=str))
@click.option("--object", "object_id", type=int, required=True, help="The target's instance id (see scene.json).")
@click.option("--json", "json_path", type=click.Path(path_type=str), default=None,
              help="Write the scores (per view too) as JSON.")
@click.option("--renders", "renders_dir", type=click.Path(path_type=str), default=None,
              help="Write each render beside its ground truth into this folder.")
@click.option("--lpips-weights", type=click.Path(path_type=str), default=None,
              help="Local LPIPS weights (default: $ROODI_LPIPS_WEIGHTS or the upstream local caches).")
@renderer_option
@click.option("--max-views", type=click.IntRange(1), default=None, help="Score only the first N test views.")
@click.option("--dataparser-transforms", type=click.Path(dir_okay=False, path_type=str), default=None,
              help="OBJECT is a nerfstudio export: its training run's dataparser_transforms.json (moves it into "
                   "DATA_DIR's frame).")
@click.option("--filter-nan", is_flag=True,
              help="Drop Gaussians with NaN/Inf values instead of refusing the file (as render does).")
@overwrite_option
@quiet_option
def evaluate(object_ply: str, data_dir: str, object_id: int, json_path: str | None, renders_dir: str | None,
             lpips_weights: str | None, renderer: Any, max_views: int | None, dataparser_transforms: str | None,
             filter_nan: bool, overwrite: bool, quiet: bool) -> None:
    """Score OBJECT.ply against the true views of target --object in DATA_DIR (a make-scene folder).

    OBJECT.ply is any splat file, or a model another tool trained (an Inria or gsplat output folder, a gsplat
    checkpoint; a nerfstudio export with --dataparser-transforms), read in DATA_DIR's frame.

    PSNR, SSIM and LPIPS inside 1.2x the true object's tight bounding box, and IoU of the rendered alpha, on a
    white background, averaged over the target's test views. LPIPS is reported as unavailable without local weights.
    When DATA_DIR has never-seen masks (make-scene --occluded / --never-seen) the same metrics are also given inside
    each view's never-seen region (PSNR over its pixels, the SSIM map averaged over it, IoU of alpha > 0.5 counting
    its pixels only, LPIPS of its box with the render pasted into the truth inside it).
    """
    # --json over scene.json or --renders into DATA_DIR is refused
    inputs = [*input_paths(object_ply), data_dir, lpips_weights, dataparser_transforms]
    files.check_outputs([("--json", json_path)], overwrite=overwrite, inputs=inputs)
    if renders_dir is not None:
        if json_path is not None and files.same_file(json_path, renders_dir):
            raise click.BadParameter(f"{renders_dir} is also the --json file", param_hint="--renders")
        out_dir = files.prepare_output_dir(renders_dir, overwrite=overwrite, inputs=inputs)
    if lpips_weights or os.environ.get(ENV_WEIGHTS):  # weights named by the user must load: fail now, naming them
        read_lpips(lpips_weights)
    if Path(object_ply).is_dir() or dataparser_transforms or GSPLAT_CKPT.fullmatch(Path(object_ply).name):
        cloud = open_model(object_ply, data_dir, dataparser_transforms=dataparser_transforms).read_cloud()
    else:
        cloud = read_cloud(object_ply)
    if filter_nan:
        cloud = cloud.select(~cloud.nonfinite_rows())
    cloud.require_finite(object_ply)  # NaN rows render as nothing: scores of them would mislead
    ev, renders = evaluate_object(cloud, data_dir, object_id, renderer=renderer, lpips_weights=lpips_weights,
                                  max_views=max_views, progress=progress_factory(quiet))
    if json_path is not None:
        files.write_json({"object_ply": object_ply, "data_dir": data_dir, **ev.to_dict()}, json_path)
    if renders_dir is not None:
        truth = load_dataset(find_target(data_dir, object_id)[0], background=(1.0, 1.0, 1.0))
        for i, view in enumerate(ev.views):
            files.write_image(np.concatenate([renders[i], truth.images[i].numpy()], axis=1),
                              out_dir / f"{view.name}_render_vs_truth.png")
    lp = f"{ev.lpips:.4f}" if ev.lpips is not None else f"unavailable ({ev.lpips_status.removeprefix('unavailable: ')})"
    click.echo(f"{ev.object_name} (id {ev.object_id}), {len(ev.views)} views: PSNR {ev.psnr:.2f} dB, "
               f"SSIM {ev.ssim:.4f}, LPIPS {lp}, IoU {ev.iou:.4f}")
    if ev.never_seen:
        with_region = sum(v.ns_pixels > 0 for v in ev.views)
        if ev.ns_iou is None:
            click.echo(f"never-seen region: none in these {len(ev.views)} views")
        else:
            ns_lp = f"{ev.ns_lpips:.4f}" if ev.ns_lpips is not None else "unavailable"
            click.echo(f"never-seen region ({with_region} views, {sum(v.ns_pixels for v in ev.views)} pixels): "
                       f"PSNR {ev.ns_psnr:.2f} dB, SSIM {ev.ns_ssim:.4f}, LPIPS {ns_lp}, IoU {ev.ns_iou:.4f}")
