"""The refinement's debug pictures: what :func:`roodi_toolkit.pipeline.finetune.refine_object` hands back, written
into an object's ``debug/`` folder with its ``refine.json``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..gaussians import GaussianCloud
from ..io.files import write_image, write_json
from ..pipeline.finetune import RefineResult, same_columns, to_row
from ..pipeline.occlusion import OcclusionResult, fill_picture, hidden_part_picture
from ..render.renderer import Renderer, resolve_renderer


def write_occlusion_images(result: OcclusionResult, folder: str | Path) -> list[Path]:
    """Write the four renders, depths and masks of ``result`` as PNGs into ``folder``; return the paths.

    Per view ``k``: ``view_k_object.png``, ``view_k_scene.png``, ``view_k_occluded.png`` (after the opening),
    ``view_k_occluded_raw.png``, ``view_k_mask.png`` (white = to inpaint) and ``view_k_depths.png`` (object | scene,
    near = bright, on one scale).
    """
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for k in range(len(result.cameras)):
        od, sd = result.object_depth[k], result.scene_depth[k]
        valid = torch.cat([od[od > 0], sd[sd > 0]])
        lo, hi = (float(valid.min()), float(valid.max())) if len(valid) else (0.0, 1.0)

        def shade(d: Tensor) -> np.ndarray:
            return torch.where(d > 0, 1 - (d - lo) / max(hi - lo, 1e-9) * 0.8, torch.zeros_like(d)).numpy()

        items = {"object": result.object_rgb[k].numpy(), "scene": result.scene_rgb[k].numpy(),
                 "occluded": result.occluded[k].numpy(), "occluded_raw": result.occluded_raw[k].numpy(),
                 "mask": result.mask[k].numpy(), "depths": np.concatenate([shade(od), shade(sd)], axis=1)}
        for name, img in items.items():
            paths.append(write_image(img, out / f"view_{k}_{name}.png"))
    return paths


def write_refine_debug(result: RefineResult, folder: str | Path, renderer: Renderer | None = None) -> Path:
    """Write the refinement's pictures and ``refine.json`` into ``folder``; return the folder.

    The pictures: occlusion masks (:func:`write_occlusion_images`), inpainting grids, each view inpainted and before
    and after fine-tuning, what the fill added and, with a 3D completion, the part no training view saw (drawn by
    ``renderer``, default the built-in CPU renderer).
    """
    out = Path(folder)
    occ, after, inpainted, filled = result.occlusion, result.after_views, result.inpainted, result.filled
    write_occlusion_images(occ, out)
    for name, img in result.grids.items():
        write_image(img.numpy(), out / f"grid_{name}.png")
    for k in range(len(occ.cameras)):
        write_image(inpainted[k].numpy(), out / f"view_{k}_inpainted.png")
        write_image(torch.cat([occ.object_rgb[k], after[k]], dim=1).numpy(),
                    out / f"view_{k}_object_before_after.png")
    write_image(torch.cat([to_row(occ.object_rgb), to_row(after)], dim=0).numpy(), out / "object_before_after.png")
    write_image(fill_picture(occ.object_rgb, inpainted, filled, occ.occluded), out / "fill_views.png")
    write_image(fill_picture(occ.object_rgb, after, filled, occ.occluded), out / "fill_before_after.png")
    if result.completion is not None:
        whole = GaussianCloud.concatenate([result.object_cloud, same_columns(result.completion, result.object_cloud)])
        write_image(hidden_part_picture(whole, result.completion, occ, after, resolve_renderer(renderer),
                                        result.background), out / "hidden_part.png")
    write_json(result.record, out / "refine.json")
    return out
