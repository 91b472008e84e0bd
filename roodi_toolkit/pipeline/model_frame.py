"""A model trained by another tool, checked against the photos of the data it is used with.

:func:`roodi_toolkit.io.model.open_model` brings another tool's scene into the data's frame from what the files say
(an Inria ``cameras.json``, gsplat's normalisation recomputed from the data, nerfstudio's data-parser transform). The
photos settle what the files cannot: which of two gsplat versions' normalisations a checkpoint used, and whether the
scene, rendered from a few training cameras, explains their photos at all (a scene in another frame, or of other
photos, renders something unrelated). The scene comes in memory, as its file holds it (the run layer reads it:
:func:`roodi_toolkit.run.distill.check_model_frame`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from ..errors import ConfigError
from ..gaussians import GaussianCloud
from ..io.dataset import Dataset, split_views
from ..render.renderer import render_cloud
from ..similarity import transform_cloud

CHECK_VIEWS = 2
"""Training views rendered to check the frame (evenly spread)."""
CHECK_WIDTH = 160
"""Width the check renders at (pixels): enough to see a scene, cheap on a CPU."""
MATCH_RATIO = 0.5
"""The scene's squared error on its training photos must be below this share of an empty rendering's (3 dB better
than the background alone, as the prune's photo check asks). Measured (``benchmarks/RESULTS.md``, "Captures and models
as people bring them"): a weak model of the real statue (300 steps at 1/8) scores 0.14 in its own frame and 0.28-0.38
turned or scaled about its centre (0.15 moved by 0.3, a tenth of its size); the tests' object scene 6e-6 in its frame
and 0.69 scaled by 0.37 (a nerfstudio export without its transform). So this refuses a scene of other photos or far off, not a subtly turned one: the
cameras (``cameras.json``) and the share of Gaussians in view (:data:`roodi_toolkit.io.model.SEEN_MIN`) judge frames;
the photos choose between two candidate frames by the lower ratio, which needs no threshold."""


def _errors(cloud: Any, dataset: Dataset, views: list[int], renderer: Any) -> tuple[float, float]:
    """Return the squared error of the cloud's renderings and of empty renderings against the photos (means over
    the views), on the background that suits the photos best.

    The backgrounds tried are the dataset's, black and white: a capture on a white table read with the default black
    background, or a model trained on random backgrounds, is no other frame; what counts is whether some background
    lets the scene explain the photos much better than that background alone does.
    """
    backgrounds = [torch.tensor(b, dtype=torch.float32) for b in (dataset.background, (0.0, 0.0, 0.0),
                                                                  (1.0, 1.0, 1.0))]
    err = torch.zeros(len(backgrounds), dtype=torch.float64)
    empty = torch.zeros(len(backgrounds), dtype=torch.float64)
    for v in views:
        cam = dataset.cameras[v]
        w = min(CHECK_WIDTH, cam.width)
        h = max(1, round(cam.height * w / cam.width))
        photo = torch.nn.functional.interpolate(dataset.images[v].permute(2, 0, 1)[None], size=(h, w),
                                                mode="area")[0].permute(1, 2, 0)
        weight = torch.ones(h, w)
        if dataset.valid is not None:
            weight = torch.nn.functional.interpolate(dataset.valid[v][None, None], size=(h, w), mode="area")[0, 0]
        out = render_cloud(cloud, cam.with_size(w, h), renderer=renderer, background=(0.0, 0.0, 0.0))
        rgb, alpha = out.rgb.clamp(0, 1), out.alpha.reshape(h, w, 1).clamp(0, 1)
        for i, bg in enumerate(backgrounds):
            err[i] += float((((rgb + (1 - alpha) * bg - photo) ** 2).sum(-1) * weight).mean())
            empty[i] += float((((bg - photo) ** 2).sum(-1) * weight).mean())
    best = int(torch.argmin(err / empty.clamp_min(1e-12)))
    return float(err[best]) / len(views), float(empty[best]) / len(views)


def settle_model_frame(model: Any, raw: GaussianCloud, dataset: Dataset, renderer: Any = None) -> dict[str, Any]:
    """Check a model from another tool against its photos and pick its frame where the files leave two; return what
    was measured (for the report). A model this toolkit trained is not checked.

    Args:
        model: the model (:class:`roodi_toolkit.io.model.ModelFolder`): its kind, record, candidate frames and notes
            (its frame and notes are updated here); its ``ply_path`` names it in messages.
        raw: its scene as the file holds it, before any move into the data's frame.
        dataset: the photos it is used with.
        renderer: draws the check views (default: the built-in CPU renderer).

    Raises:
        ConfigError: rendered from the training cameras, the scene's error on the photos is not below
            :data:`MATCH_RATIO` of an empty picture's error: it lies in another frame than the data, or shows other
            photos.
    """
    if model.kind == "roodi":
        return {}
    train, _ = split_views(dataset, int(model.config.get("holdout_every", 8) or 0))
    views = train or list(range(len(dataset)))
    views = [views[int(i)] for i in np.linspace(0, len(views) - 1, min(CHECK_VIEWS, len(views))).round()]
    candidates = model.frames or [model.to_data]
    results = [_errors(raw if frame is None else transform_cloud(raw, frame), dataset, views, renderer)
               for frame in candidates]
    best = int(np.argmin([e / max(e0, 1e-12) for e, e0 in results]))
    err, empty = results[best]
    if len(candidates) > 1:
        model.to_data = candidates[best]
        model.frames = []
        model.notes.append(f"of gsplat's two normalisations the photos chose the {['first', 'second'][best]} "
                           f"(squared error {err:.4g} against {max(e for e, _ in results):.4g})")
    if not err < MATCH_RATIO * empty:
        raise ConfigError(f"{model.ply_path}: rendered from {len(views)} training cameras of the data it explains "
                          f"their photos less than {-10 * np.log10(MATCH_RATIO):.0f} dB better than an empty picture "
                          f"(squared error {err:.4g}, empty {empty:.4g}): the model lies in another frame than the "
                          "data, or shows other photos")
    model.notes.append(f"its renders explain the photos (squared error {err:.4g}, an empty picture's {empty:.4g})")
    return {"model_check_error": err, "model_check_empty": empty}

