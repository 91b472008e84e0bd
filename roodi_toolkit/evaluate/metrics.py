"""Extraction quality as the paper measures it (Sec. 4.1): PSNR, SSIM and LPIPS inside 1.2x the tight bounding box
of the true object, and IoU of the rendered alpha against the true alpha.

The extracted object is rendered from the target's test cameras on a white background, as the ground truth views of
the object alone are. LPIPS needs weights on this machine (:mod:`roodi_toolkit.lpips`); without them it is reported
as unavailable (``None``), never replaced by another number.

Where the scene has never-seen masks (``make-scene --occluded`` or ``--never-seen``: the pixels of each test view whose
surface no training view sees, :mod:`roodi_toolkit.synth.visibility`), the same metrics are also computed inside that
region R of each view (:func:`region_scores`), where a method can only have guessed:

- PSNR: 10 log10(1 / MSE) with the MSE over the pixels of R (all three channels); inf when they are identical.
- SSIM: the SSIM map of the whole view (kornia, 11-pixel Gaussian window, channels averaged) averaged over R.
- IoU: rendered alpha > 0.5 against true alpha > 0.5, counting only the pixels of R:
  |pred & true & R| / |(pred | true) & R| (R lies on the true object, so this is close to the share of R covered).
- LPIPS: of the 1.2x box around R, between the truth with the render pasted into it inside R only, and the truth
  (so only what the method drew inside R differs).

Views whose R is empty have no region scores; an object's region scores are means over its views that have one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional, Sequence

import kornia
import numpy as np
import torch
from torch import Tensor

from ..cameras import Camera
from ..gaussians import GaussianCloud
from ..imaging import mask_iou, psnr, ssim
from ..progress import ProgressFactory, null_progress
from ..render.renderer import Renderer, render_cloud, resolve_renderer

BOX_SCALE = 1.2
"""Metrics are computed inside this multiple of the true object's tight 2D bounding box (paper)."""
ALPHA_THRESHOLD = 0.5
"""A pixel belongs to a mask when its alpha exceeds this."""
LPIPS_MIN_SIDE = 64
"""Crops smaller than this are resized (bilinear) to it on their short side before LPIPS, which needs >= 32 px."""


def box_around(alpha: np.ndarray, scale: float = BOX_SCALE) -> tuple[int, int, int, int] | None:
    """Return ``(y0, y1, x0, x1)``: ``scale`` x the tight box of ``alpha > 0.5`` about its centre, clipped; or None.

    Example:
        >>> a = np.zeros((100, 100)); a[40:60, 30:50] = 1
        >>> box_around(a)
        (38, 62, 28, 52)
    """
    ys, xs = np.nonzero(np.asarray(alpha) > ALPHA_THRESHOLD)
    if ys.size == 0:
        return None
    h, w = alpha.shape
    cy, cx = (ys.min() + ys.max() + 1) / 2.0, (xs.min() + xs.max() + 1) / 2.0
    hh, hw = scale * (ys.max() + 1 - ys.min()) / 2.0, scale * (xs.max() + 1 - xs.min()) / 2.0
    y0, y1 = max(0, int(math.floor(cy - hh))), min(h, int(math.ceil(cy + hh)))
    x0, x1 = max(0, int(math.floor(cx - hw))), min(w, int(math.ceil(cx + hw)))
    return y0, y1, x0, x1


def zoom_box(mask: np.ndarray, scale: float = 3.0) -> tuple[int, int, int, int]:
    """Return ``(y0, y1, x0, x1)``: a square ``scale`` x the mask's box about its centre (at least 8 pixels), shifted
    inside the image; the whole image when the mask is empty. For pictures that zoom in on an object.

    Example:
        >>> m = np.zeros((64, 64), bool); m[10:14, 20:22] = True
        >>> zoom_box(m)
        (6, 18, 15, 27)
    """
    h, w = mask.shape
    ys, xs = np.nonzero(mask)
    if ys.size == 0:
        return 0, h, 0, w
    side = min(h, w, max(8, int(np.ceil(scale * max(ys.max() + 1 - ys.min(), xs.max() + 1 - xs.min())))))
    cy, cx = int(ys.min() + ys.max() + 1) // 2, int(xs.min() + xs.max() + 1) // 2
    y0, x0 = min(max(0, cy - side // 2), h - side), min(max(0, cx - side // 2), w - side)
    return y0, y0 + side, x0, x0 + side


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Return the intersection over union of two alpha maps thresholded at 0.5 (1.0 when both are empty)."""
    return mask_iou(np.asarray(a) > ALPHA_THRESHOLD, np.asarray(b) > ALPHA_THRESHOLD)


def lpips_crop(model: Any, a: np.ndarray, b: np.ndarray) -> float:
    """Return LPIPS of two ``[h, w, 3]`` crops, resized up to :data:`LPIPS_MIN_SIDE` on the short side if smaller."""
    x = torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32).permute(2, 0, 1)[None]
    y = torch.as_tensor(np.ascontiguousarray(b), dtype=torch.float32).permute(2, 0, 1)[None]
    short = min(x.shape[-2:])
    if short < LPIPS_MIN_SIDE:
        size = [max(LPIPS_MIN_SIDE, round(s * LPIPS_MIN_SIDE / short)) for s in x.shape[-2:]]
        x = torch.nn.functional.interpolate(x, size=size, mode="bilinear", align_corners=False)
        y = torch.nn.functional.interpolate(y, size=size, mode="bilinear", align_corners=False)
    with torch.no_grad():
        return float(model(x, y)[0])


REGION_METRICS = ("ns_psnr", "ns_ssim", "ns_lpips", "ns_iou")
"""The never-seen region's metrics (keys in :class:`ViewScores`, :class:`Evaluation` and the benchmark's rows)."""


@dataclass
class ViewScores:
    """The paper's metrics for one test view (crop-based ones are None when the true object is not in view), and
    those inside the view's never-seen region (None when the view has none, or the scene no masks)."""

    name: str
    psnr: Optional[float]
    ssim: Optional[float]
    lpips: Optional[float]
    iou: float
    ns_psnr: Optional[float] = None
    ns_ssim: Optional[float] = None
    ns_lpips: Optional[float] = None
    ns_iou: Optional[float] = None
    ns_pixels: int = 0


@dataclass
class Evaluation:
    """Metrics of one extracted object, per view and averaged.

    Attributes:
        object_id: the target's instance id.
        object_name: its name in scene.json.
        views: per-view scores.
        psnr, ssim, lpips, iou: means over the views (lpips None when unavailable).
        lpips_status: ``"ok"`` or why LPIPS is unavailable.
        never_seen: whether the scene has never-seen masks (then ``ns_*`` are the region's means, None where no view
            has a never-seen pixel).
    """

    object_id: int
    object_name: str
    views: list[ViewScores] = field(default_factory=list)
    psnr: float = float("nan")
    ssim: float = float("nan")
    lpips: Optional[float] = None
    iou: float = float("nan")
    lpips_status: str = "ok"
    never_seen: bool = False
    ns_psnr: Optional[float] = None
    ns_ssim: Optional[float] = None
    ns_lpips: Optional[float] = None
    ns_iou: Optional[float] = None

    @classmethod
    def from_views(cls, object_id: int, object_name: str, views: list[ViewScores],
                   lpips_status: str = "ok", never_seen: bool = False) -> "Evaluation":
        """Return the evaluation averaging ``views`` (crop metrics over the views that have them; LPIPS only when
        ``lpips_status`` is ``"ok"``; region metrics over the views with a never-seen region)."""
        nan = float("nan")
        mean_psnr, mean_ssim = _mean([v.psnr for v in views]), _mean([v.ssim for v in views])
        ok = lpips_status == "ok"
        return cls(object_id, object_name, views, psnr=nan if mean_psnr is None else mean_psnr,
                   ssim=nan if mean_ssim is None else mean_ssim,
                   lpips=_mean([v.lpips for v in views]) if ok else None,
                   iou=float(np.mean([v.iou for v in views])), lpips_status=lpips_status, never_seen=never_seen,
                   ns_psnr=_mean([v.ns_psnr for v in views]), ns_ssim=_mean([v.ns_ssim for v in views]),
                   ns_lpips=_mean([v.ns_lpips for v in views]) if ok else None,
                   ns_iou=_mean([v.ns_iou for v in views]))

    def to_dict(self, per_view: bool = True) -> dict[str, Any]:
        out = {"object_id": self.object_id, "object_name": self.object_name, "psnr": self.psnr, "ssim": self.ssim,
               "lpips": self.lpips, "iou": self.iou, "lpips_status": self.lpips_status,
               "views": len(self.views)}
        if self.never_seen:  # only for scenes with masks: other scenes' records stay as they were
            out.update({k: getattr(self, k) for k in REGION_METRICS})
            out["ns_pixels"] = int(sum(v.ns_pixels for v in self.views))
            out["ns_views"] = int(sum(v.ns_pixels > 0 for v in self.views))
        if per_view:
            keep = (lambda k: True) if self.never_seen else (lambda k: not k.startswith("ns_"))
            out["per_view"] = [{k: x for k, x in v.__dict__.items() if keep(k)} for v in self.views]
        return out


def region_scores(render: np.ndarray, alpha: np.ndarray, truth: np.ndarray, truth_alpha: np.ndarray,
                  region: np.ndarray, lpips_model: Any = None) -> dict[str, Any]:
    """Return PSNR, SSIM, IoU (and LPIPS with a model) of one view inside ``region`` (see the module's definitions).

    Args:
        render: ``[H, W, 3]`` the extracted object on white, in [0, 1].
        alpha: ``[H, W]`` its alpha.
        truth: ``[H, W, 3]`` the true object alone on white.
        truth_alpha: ``[H, W]`` its alpha.
        region: ``[H, W]`` bool, the never-seen pixels.
        lpips_model: an LPIPS module, or None.

    Returns:
        ``{"ns_psnr", "ns_ssim", "ns_lpips", "ns_iou", "ns_pixels"}``; all None (and 0 pixels) for an empty region.

    Example:
        >>> t = np.ones((16, 16, 3)); r = t.copy(); m = np.zeros((16, 16), bool); m[4:8, 4:8] = True
        >>> r[m] = 0.9  # a difference of 0.1 in the region: MSE 0.01, 20 dB
        >>> round(region_scores(r, np.ones((16, 16)), t, np.ones((16, 16)), m)["ns_psnr"], 6)
        20.0
    """
    region = np.asarray(region, dtype=bool)
    n = int(region.sum())
    if n == 0:
        return {"ns_psnr": None, "ns_ssim": None, "ns_lpips": None, "ns_iou": None, "ns_pixels": 0}
    a = np.clip(np.asarray(render, dtype=np.float64), 0, 1)
    b = np.asarray(truth, dtype=np.float64)
    mse = float(((a[region] - b[region]) ** 2).mean())
    region_psnr = float("inf") if mse == 0 else 10.0 * math.log10(1.0 / mse)
    x = torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32).permute(2, 0, 1)[None]
    y = torch.as_tensor(np.ascontiguousarray(b), dtype=torch.float32).permute(2, 0, 1)[None]
    win = min(11, min(region.shape))
    win = win if win % 2 == 1 else win - 1
    ssim_map = kornia.metrics.ssim(x, y, max(win, 1))[0].mean(dim=0).numpy()  # [H, W]
    pred, true = np.asarray(alpha) > ALPHA_THRESHOLD, np.asarray(truth_alpha) > ALPHA_THRESHOLD
    union = int(((pred | true) & region).sum())
    region_iou = 1.0 if union == 0 else float((pred & true & region).sum() / union)
    region_lpips = None
    if lpips_model is not None:
        y0, y1, x0, x1 = box_around(region.astype(np.float32))
        pasted = np.where(region[..., None], a, b)
        region_lpips = lpips_crop(lpips_model, pasted[y0:y1, x0:x1].astype(np.float32),
                                  b[y0:y1, x0:x1].astype(np.float32))
    return {"ns_psnr": region_psnr, "ns_ssim": float(ssim_map[region].mean()), "ns_lpips": region_lpips,
            "ns_iou": region_iou, "ns_pixels": n}



def score_views(renders: np.ndarray, alphas: np.ndarray, truth: np.ndarray, truth_alpha: np.ndarray,
                names: Sequence[str], lpips_model: Any = None,
                never_seen: np.ndarray | None = None) -> list[ViewScores]:
    """Return per-view scores of renders against the true object-alone views.

    Args:
        renders: ``[N, H, W, 3]`` the extracted object on white, in [0, 1].
        alphas: ``[N, H, W]`` its accumulated alpha.
        truth: ``[N, H, W, 3]`` the true object alone on white.
        truth_alpha: ``[N, H, W]`` the true object's alpha.
        names: the views' names.
        lpips_model: an LPIPS module, or None when unavailable.
        never_seen: ``[N, H, W]`` bool never-seen masks (:func:`load_never_seen`), or None.
    """
    scores = []
    for i, name in enumerate(names):
        box = box_around(truth_alpha[i])
        view_iou = iou(alphas[i], truth_alpha[i])
        region = {} if never_seen is None else region_scores(renders[i], alphas[i], truth[i], truth_alpha[i],
                                                             never_seen[i], lpips_model)
        if box is None:
            scores.append(ViewScores(name, None, None, None, view_iou, **region))
            continue
        y0, y1, x0, x1 = box
        a, b = np.clip(renders[i, y0:y1, x0:x1], 0, 1), truth[i, y0:y1, x0:x1]
        scores.append(ViewScores(name, psnr(a, b), float(ssim(a, b)),
                                 None if lpips_model is None else lpips_crop(lpips_model, a, b), view_iou, **region))
    return scores


def _mean(values: list[Optional[float]]) -> Optional[float]:
    """Mean over the views that have a value (an identical crop's PSNR is inf and stays so)."""
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None



def render_object_views(cloud: GaussianCloud, cameras: Sequence[Camera], *, renderer: Renderer | None = None,
                        progress: ProgressFactory = null_progress, desc: str = "evaluate"
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Return the object's colours on white ``[V, H, W, 3]`` (clamped to [0, 1]) and its alpha ``[V, H, W]`` in
    ``cameras``: what it is scored on against the true views."""
    renderer = resolve_renderer(renderer)
    renders, alphas = [], []
    with progress(total=len(cameras), desc=desc) as bar:
        for cam in cameras:
            out = render_cloud(cloud, cam, renderer=renderer, background=(1.0, 1.0, 1.0))
            renders.append(out.rgb.clamp(0, 1).numpy())
            alphas.append(out.alpha[..., 0].numpy())
            bar.update(1)
    return np.stack(renders), np.stack(alphas)


def alpha_iou(cloud: GaussianCloud, cameras: Sequence[Camera], alphas: Sequence[np.ndarray] | Tensor, *,
              level: float = 0.5, renderer: Renderer | None = None) -> list[float]:
    """Return per view the IoU of ``alpha > level`` of the rendered ``cloud`` and of the given alpha maps."""
    renderer = resolve_renderer(renderer)
    out = []
    for cam, a in zip(cameras, alphas):
        rendered = render_cloud(cloud, cam, renderer=renderer).alpha[..., 0].numpy()
        out.append(mask_iou(rendered > level, np.asarray(a) > level))
    return out
