"""Fold inpainted views back into the object's Gaussians (paper, Sec. 3.3 "Training with inpainted images").

:func:`finetune_object` optimises the object model for 100 iterations: every iteration an L1 loss against an original
training view restricted to the object (its mask; other pixels are the background colour), and every other iteration,
in addition, ``l1_inpaint_weight * L1 + perceptual_weight * perceptual`` against one of the inpainted views. No D-SSIM:
the paper found it harmful because inpaintings are not always right.

:func:`refine_object` is the whole step: occlusion reasoning, inpainting of the four views as one 2x2 grid, fine-tuning,
returning what the debug images are made of (renders, masks, grids before and after inpainting, the object before
and after; :func:`roodi_toolkit.run.refine.write_refine_debug` writes them and ``refine.json``). Nothing here opens a
file.

The perceptual loss is :mod:`roodi_toolkit.pipeline.perceptual`'s (LPIPS with the network the caller hands in as
``lpips``, else a Laplacian-pyramid L1; its classes are re-exported here); :attr:`FinetuneResult.perceptual` says which
one ran.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Optional, Sequence

import numpy as np
import torch
from scipy import ndimage
from torch import Tensor

from ..cameras import Camera
from ..errors import ConfigError, DatasetError
from ..gaussians import GaussianCloud
from ..params import GaussianParams
from ..progress import ProgressFactory, null_progress
from ..render.renderer import Renderer, resolve_renderer
from ..settings import check_settings, documented, setting
from .inpaint import FillContext, Inpainter, get_inpainter, inpaint_views
from .occlusion import (OcclusionConfig, OcclusionResult, object_extent, occlusion_masks, seen_through,
                        up_from_cameras)
from .perceptual import LaplacianLoss, LPIPSLoss, perceptual_loss  # noqa: F401 (re-exported)
from .support import other_gaussians, pixel_size, support_height


@documented
@dataclass(frozen=True)
class FinetuneConfig:
    """Hyperparameters of fine-tuning. Sources: paper (iterations, schedule, no D-SSIM), 3DGS (learning rates), ours."""

    # paper: 100 steps
    iterations: int = setting(100, "Fine-tuning steps.", low=0)
    # paper: every other step
    inpaint_every: int = setting(2, "Use an inpainted view every this many steps.", low=1, cli=False)
    # not published; 1.0, like the original views' L1
    l1_inpaint_weight: float = setting(1.0, "Weight of the L1 loss to the inpainted views.", low=0, cli=False)
    # not published; 0.2 puts the perceptual term at the order of the L1 term at the start on our benchmark scenes
    perceptual_weight: float = setting(0.2, "Weight of the perceptual loss to the inpainted views.", low=0, cli=False)
    perceptual: str = setting("auto", "Perceptual loss: lpips (required), laplacian (a Laplacian-pyramid L1), or "
                              "auto (LPIPS if its weights are here, else laplacian).",
                              choices=("auto", "lpips", "laplacian"), cli=False)
    lpips_weights: str | None = setting(None, "A local LPIPS weights file (None: $ROODI_LPIPS_WEIGHTS or the "
                                        "upstream local caches).", cli=False)
    # 3DGS: 1.6e-4 per unit of scene extent; here per unit of the object's radius
    means_lr: float = setting(1.6e-4, "Position learning rate per unit of the object's radius.", low=0, cli=False)
    # 3DGS's learning rates
    scales_lr: float = setting(5e-3, "Learning rate of the log scales.", low=0, cli=False)
    quats_lr: float = setting(1e-3, "Learning rate of the rotations.", low=0, cli=False)
    opacities_lr: float = setting(5e-2, "Learning rate of the opacity logits.", low=0, cli=False)
    sh0_lr: float = setting(2.5e-3, "Learning rate of the base colours.", low=0, cli=False)
    shN_lr: float = setting(2.5e-3 / 20, "Learning rate of the higher SH coefficients.", low=0, cli=False)
    background: tuple[float, float, float] = setting((1.0, 1.0, 1.0), "RGB behind the object in renders and "
                                                     "targets.", cli=False)
    seed: int = setting(0, "Seed of the order of the views.", cli=False)
    # ours, not in the paper: without seeds the 100 steps can only recolour and nudge existing Gaussians, which leaves
    # holes behind occluders empty (seed_hole_gaussians)
    seed_holes: bool = setting(False, "Before fine-tuning, add Gaussians where an inpainted view shows the object but "
                               "the object model renders (almost) nothing.", cli=False)
    seed_stride: int = setting(2, "One seeded Gaussian per this many pixels along each axis of a view.", low=1,
                               cli=False)
    seed_opacity: float = setting(0.5, "Opacity of the seeded Gaussians.", low=0, high=1, low_open=True,
                                  high_open=True, cli=False)
    seed_min_difference: float = setting(0.1, "A pixel counts as filled where its inpainted colour differs from the "
                                         "background by more than this (largest over the channels).", low=0, high=1,
                                         high_open=True, cli=False)
    # 2D inpainters propose none, so this changes nothing for them
    adopt_proposed: bool = setting(True, "Add the Gaussians a 3D-aware inpainter proposes (symmetry's mirrored "
                                   "copies that land where the object has none; FillContext) before fine-tuning.",
                                   cli=False)

    def __post_init__(self) -> None:
        check_settings(self)


# ------------------------------------------------------------------------------------------------------ fine-tuning


class PerView:
    """A sequence of per-view tensors made on demand, for the views of a capture that need not all be held at once:
    ``seq[i]`` is ``make(i)``, ``seq[a:b]`` their stack, ``len(seq)`` the number of views.

    Example:
        >>> seq = PerView(3, lambda i: torch.full((2,), float(i)))
        >>> seq[2].tolist(), seq[:2].shape, len(seq)
        ([2.0, 2.0], torch.Size([2, 2]), 3)
    """

    def __init__(self, count: int, make: Callable[[int], Tensor]) -> None:
        self._count, self._make = int(count), make

    def __len__(self) -> int:
        return self._count

    def __getitem__(self, index: int | slice) -> Tensor:
        if isinstance(index, slice):
            return torch.stack([self._make(i) for i in range(self._count)[index]])
        if not -self._count <= index < self._count:
            raise IndexError(f"view {index} of {self._count}")
        return self._make(index % self._count)


@dataclass
class ViewTargets:
    """Images the object is fitted to, with per-pixel weights.

    Attributes:
        cameras: V views.
        images: targets in [0, 1]: a tensor, or a :class:`PerView` that makes each view's when it is asked for.
            [V, H, W, 3]
        weights: 1 where a pixel is supervised, 0 where it is not (e.g. the object may be hidden there), likewise.
            [V, H, W]
    """

    cameras: list[Camera] = field(repr=False)
    images: Tensor | PerView = field(repr=False)
    weights: Tensor | PerView = field(repr=False)


def sphere_outline(camera: Camera, centre: Sequence[float], radius: float) -> tuple[Optional[np.ndarray], float]:
    """Return the pixels ``[H, W]`` (bool, by their centres) inside the image outline of a sphere, and the depth of
    its centre; ``None`` for the pixels when the centre is not in front of the camera."""
    uv, z = camera.project(np.asarray(centre, dtype=np.float64)[None])
    z = float(z[0])
    if z <= 0:
        return None, z
    r_px = camera.K[0, 0] * radius / max(math.sqrt(max(z * z - radius * radius, 1e-12)), 1e-9)
    ys, xs = np.mgrid[0:camera.height, 0:camera.width]
    return (xs + 0.5 - uv[0, 0]) ** 2 + (ys + 0.5 - uv[0, 1]) ** 2 <= r_px ** 2, z


def object_view_targets(images: Tensor | PerView, cameras: Sequence[Camera], object_masks: Tensor, *,
                        depths: Optional[Tensor | PerView] = None, centre: Optional[np.ndarray] = None,
                        radius: float = 0.0, background: Sequence[float] = (1.0, 1.0, 1.0),
                        render_depth: Optional[Callable[[Camera], Tensor]] = None) -> ViewTargets:
    """Return training views restricted to the object: its pixels kept, all others set to the background colour.

    A pixel outside the object's mask whose surface lies nearer than the far side of the object's bounding sphere
    (and inside the sphere's outline) may be hiding the object: with the scene's depth there it gets weight 0
    instead of a background target, so that the originals do not undo inpainted hidden parts.

    The targets are made view by view when fine-tuning asks for them: what is held for every view is its mask and
    which pixels may hide the object (2 bytes a pixel), not its target colours and weights (16), and the photos are
    read where they are (``images`` may be a :class:`PerView` over the dataset's own tensor).

    Args:
        images: the views. [N, H, W, 3]
        cameras: their cameras.
        object_masks: True on the object. [N, H, W]
        depths: scene depth along the optical axis, 0 = nothing. [N, H, W]
        centre: the object's bounding-sphere centre. [3]
        radius: its radius.
        background: the colour off the object.
        render_depth: without ``depths``, renders the scene's depth ``[h, w]`` in a camera: it is asked for the
            rectangle round the sphere's outline only (:meth:`Camera.cropped`), the only pixels the test reads
            (with the depth at SH degree 0, 1.17x the whole view's with colours on a 650k-Gaussian scene, where the
            outline covers 45% of a view: the per-Gaussian work does not shrink with the rectangle).
    """
    bg = torch.as_tensor(background, dtype=torch.float32)
    masks = torch.as_tensor(object_masks).bool()
    hidden = torch.zeros(masks.shape, dtype=torch.bool)
    if (depths is not None or render_depth is not None) and centre is not None and radius > 0:
        for i, cam in enumerate(cameras):
            inside, z = sphere_outline(cam, centre, radius)
            if inside is None or not inside.any():
                continue
            rows, cols = np.flatnonzero(inside.any(axis=1)), np.flatnonzero(inside.any(axis=0))
            y0, y1, x0, x1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
            if depths is not None:
                d = depths[i][y0:y1, x0:x1]
            else:
                d = render_depth(cam.cropped(x0, y0, x1 - x0, y1 - y0))
            hidden[i, y0:y1, x0:x1] = torch.from_numpy(inside[y0:y1, x0:x1]) & (d > 0) & (d < z + radius) & \
                ~masks[i, y0:y1, x0:x1]
    targets = PerView(len(masks), lambda i: torch.where(masks[i][..., None], images[i].float(), bg))
    weights = PerView(len(masks), lambda i: (~hidden[i]).float())
    return ViewTargets(list(cameras), targets, weights)


@dataclass
class FinetuneResult:
    """The fine-tuned object and how it went.

    Attributes:
        cloud: the fine-tuned object model.
        perceptual: the perceptual loss that was used (``"lpips"`` or ``"laplacian"``).
        history: per-step losses.
        seconds: wall time.
    """

    cloud: GaussianCloud
    perceptual: str
    history: list[dict[str, float]]
    seconds: float


def _l1(render: Tensor, target: Tensor, weight: Optional[Tensor] = None) -> Tensor:
    diff = (render - target).abs()
    if weight is None:
        return diff.mean()
    return (diff * weight[..., None]).sum() / (weight.sum() * 3).clamp_min(1.0)


def finetune_object(cloud: GaussianCloud, originals: ViewTargets, inpainted: ViewTargets,
                    config: FinetuneConfig = FinetuneConfig(), *,
                    progress: ProgressFactory = null_progress, renderer: Renderer | None = None,
                    lpips: torch.nn.Module | None = None) -> FinetuneResult:
    """Return the object model fine-tuned to the original views and the inpainted views (no densification).

    Args:
        cloud: the object's Gaussians.
        originals: training views restricted to the object (:func:`object_view_targets`), used every step.
        inpainted: the inpainted object-centred views, used every ``config.inpaint_every`` steps.
        config: hyperparameters.
        progress: progress factory.
        renderer: draws every view (default: the built-in CPU renderer).
        lpips: the LPIPS network of the perceptual loss (``config.perceptual`` ``"auto"`` or ``"lpips"``; read by
            :func:`roodi_toolkit.io.lpips_weights.lpips_for_loss`); None: the Laplacian loss, unless ``"lpips"``.
    """
    if len(originals.cameras) == 0:
        raise DatasetError("fine-tuning needs at least one original view of the object")
    t0 = time.perf_counter()
    perceptual = perceptual_loss(config.perceptual, lpips)
    renderer = resolve_renderer(renderer)
    params = GaussianParams.from_cloud(cloud, requires_grad=True)  # copies: the caller's cloud is left as it was
    _, radius = object_extent(cloud)
    optimizers = list(params.adam(config, radius).values())
    bg = torch.as_tensor(config.background, dtype=torch.float32)
    gen = torch.Generator().manual_seed(config.seed)
    order_o = torch.randperm(len(originals.cameras), generator=gen).tolist()
    history = []
    with progress(total=config.iterations, desc="fine-tune") as bar:
        for step in range(config.iterations):
            i = order_o[step % len(order_o)]
            out = renderer.render(params, originals.cameras[i], background=bg)
            l1_orig = _l1(out.rgb, originals.images[i], originals.weights[i])
            loss = l1_orig
            record = {"step": float(step + 1), "l1_original": float(l1_orig.detach())}
            if len(inpainted.cameras) and step % config.inpaint_every == config.inpaint_every - 1:
                j = (step // config.inpaint_every) % len(inpainted.cameras)
                out_j = renderer.render(params, inpainted.cameras[j], background=bg)
                l1_inp = _l1(out_j.rgb, inpainted.images[j], inpainted.weights[j])
                perc = perceptual(out_j.rgb.clamp(0, 1), inpainted.images[j])
                loss = loss + config.l1_inpaint_weight * l1_inp + config.perceptual_weight * perc
                record.update(l1_inpainted=float(l1_inp.detach()), perceptual=float(perc.detach()))
            loss.backward()
            for opt in optimizers:
                opt.step()
                opt.zero_grad(set_to_none=True)
            record["loss"] = float(loss.detach())
            history.append(record)
            bar.update(1)
    return FinetuneResult(params.to_cloud(), perceptual.name, history, time.perf_counter() - t0)


def seed_hole_gaussians(object_cloud: GaussianCloud, occlusion: OcclusionResult, inpainted: Tensor, *,
                        stride: int = 2, opacity: float = 0.5, min_difference: float = 0.1,
                        alpha_threshold: float = 0.5, depth_tolerance: float = 0.05,
                        background: Sequence[float] = (1.0, 1.0, 1.0)) -> GaussianCloud:
    """Return new Gaussians (same columns as ``object_cloud``) where the inpainted views show the object, the object
    model renders less than ``alpha_threshold`` alpha, and the scene has a surface in front: the object's holes
    behind occluders, which the inpainter filled.

    A seeded pixel (every ``stride``-th along each axis) is inside the inpainting mask, inside the outline of the
    object's bounding sphere, has object alpha below ``alpha_threshold`` and an inpainted colour away from the
    background. Its depth is the object's rendered depth at the nearest pixel that shows the object (the hidden part
    continues the visible surface beside it), kept within the bounding sphere's depth range; the scene's depth there
    must be nearer by ``depth_tolerance`` times the object's radius (the occlusion test), so that translucent but
    visible parts of the object, which the training views constrain, get no seeds. The Gaussian is round,
    as wide as ``stride`` pixels at that depth, with the inpainted colour (degree-0 SH; higher bands zero) and
    ``opacity``. Fine-tuning then moves and recolours the seeds with the other Gaussians; seeds that a training view
    sees on the background are pulled transparent there.

    Args:
        object_cloud: the object (for its SH degree and extra columns).
        occlusion: the occlusion reasoning of the views (cameras, object alpha and depth, mask, bounding sphere).
        inpainted: the inpainted views. [V, H, W, 3]
        stride: pixel stride of the seeds.
        opacity: their opacity.
        min_difference: a pixel is filled when its inpainted colour differs from ``background`` by more than this.
        alpha_threshold: object alpha below which a pixel is a hole.
        depth_tolerance: how much nearer (times the object's radius) the scene must be than the seed.
        background: the views' background colour.
    """
    bg = np.asarray(background, dtype=np.float32)
    means, colours, sizes = [], [], []
    for k, cam in enumerate(occlusion.cameras):
        alpha = occlusion.object_alpha[k].numpy()
        depth = occlusion.object_depth[k].numpy()
        image = inpainted[k].numpy()
        shown = alpha >= alpha_threshold
        if not shown.any():
            continue
        inside, zc = sphere_outline(cam, occlusion.centre, occlusion.radius)
        if inside is None or zc <= occlusion.radius:
            continue
        grid = np.zeros_like(shown)
        grid[::stride, ::stride] = True
        filled = np.abs(image - bg).max(axis=2) > min_difference
        seeds = grid & inside & filled & ~shown & occlusion.mask[k].numpy()
        if not seeds.any():
            continue
        # depth of the nearest pixel that shows the object
        _, (iy, ix) = ndimage.distance_transform_edt(~shown, return_indices=True)
        z_all = np.clip(depth[iy, ix], zc - occlusion.radius, zc + occlusion.radius)
        scene_z = occlusion.scene_depth[k].numpy()
        seeds &= (scene_z > 0) & (scene_z < z_all - depth_tolerance * occlusion.radius)
        if not seeds.any():
            continue
        rc = np.argwhere(seeds)
        z = z_all[seeds]
        means.append(cam.backproject(rc, z))
        colours.append(image[seeds])
        sizes.append(stride * z / cam.K[0, 0] / 2.0)
    n = int(sum(len(m) for m in means))
    extras = {name: np.zeros(n, dtype=col.dtype) for name, col in object_cloud.extras.items()}
    if n == 0:
        return object_cloud.select(np.zeros(0, dtype=np.int64))
    size = np.concatenate(sizes)
    seeded = GaussianCloud.from_activated(np.concatenate(means), scales=np.repeat(size[:, None], 3, axis=1),
                                         opacities=np.full(n, opacity), rgb=np.clip(np.concatenate(colours), 0, 1),
                                         sh_degree=object_cloud.sh_degree, extras=extras)
    if object_cloud.normals is not None:
        seeded.normals = np.zeros((n, 3), dtype=np.float32)
    return seeded


# ------------------------------------------------------------------------------------------- the whole refinement


@dataclass
class RefineResult:
    """Everything :func:`refine_object` produced.

    Attributes:
        cloud: the refined object model.
        occlusion: the occlusion reasoning (views, renders, masks).
        inpainted: the inpainted views. [V, H, W, 3]
        finetune: the fine-tuning run.
        inpainter: the inpainter's name.
        filled: the masked pixels the inpainter changed (what the fill added). [V, H, W] bool
        proposed: Gaussians a 3D-aware inpainter proposed and the refinement added before fine-tuning.
        after_views: the refined object rendered in the occlusion views. [V, H, W, 3]
        record: the refinement's settings, what it added and the shares of each view it filled (``refine.json``).
        grids: the inpainting's 2x2 grids by name (``before``, ``mask``, ``after``). [2H, 2W, 3]
        object_cloud: the object as it came in (after selection and pruning).
        completion: the Gaussians a 3D completion added before the views were framed, or None.
        background: RGB behind the object's renders.
    """

    cloud: GaussianCloud
    occlusion: OcclusionResult
    inpainted: Tensor
    finetune: FinetuneResult
    inpainter: str
    filled: Optional[Tensor] = None
    proposed: int = 0
    after_views: Optional[Tensor] = field(default=None, repr=False)
    record: dict[str, Any] = field(default_factory=dict, repr=False)
    grids: dict[str, Tensor] = field(default_factory=dict, repr=False)
    object_cloud: Optional[GaussianCloud] = field(default=None, repr=False)
    completion: Optional[GaussianCloud] = field(default=None, repr=False)
    background: Sequence[float] = (1.0, 1.0, 1.0)


def _resolve_inpainter(inpainter: Any, inpainter_options: Optional[dict], occlusion: OcclusionConfig) -> Any:
    """Return the :class:`~roodi_toolkit.pipeline.inpaint.Inpainter` (made from its registered name with the
    options).

    Raises:
        ConfigError: occlusion views other than the grid's 4, or something that is no inpainter.
    """
    if occlusion.num_views != 4:
        raise ConfigError(f"the inpainting grid is 2x2: occlusion.num_views must be 4, got {occlusion.num_views}")
    if isinstance(inpainter, str):
        inpainter = get_inpainter(inpainter, **(inpainter_options or {}))
    if not isinstance(inpainter, Inpainter):
        raise ConfigError(f"inpainter must be an Inpainter or a registered name, got {type(inpainter).__name__}")
    return inpainter


def _fill_context(object_cloud: GaussianCloud, scene_cloud: GaussianCloud, scene_params: GaussianParams,
                  cameras: list[Camera], object_masks: Tensor, up: np.ndarray, background: Sequence[float],
                  occlusion: OcclusionConfig, wants: bool, renderer: Renderer) -> Any:
    """Return what a 3D-aware inpainter reads (:class:`~roodi_toolkit.pipeline.inpaint.FillContext`): which points
    the training views see through (empty space), the pixel size and, when it ``wants`` them, the support the
    object stands on and the other Gaussians; the occlusion fields are filled in later."""
    masks_np = torch.as_tensor(object_masks).bool().numpy()
    _, seen_radius = object_extent(object_cloud)

    def empty(points: np.ndarray) -> np.ndarray:
        return seen_through(points, cameras, masks_np, scene_params, occlusion.depth_tolerance * seen_radius,
                            renderer=renderer)

    return FillContext(object_cloud, [], renderer, background, None, up=tuple(float(u) for u in up),
                       seen_empty=empty, support=support_height(object_cloud, scene_cloud, up) if wants else None,
                       pixel=pixel_size(cameras, object_extent(object_cloud)[0]),
                       obstacles=other_gaussians(scene_cloud, object_cloud) if wants else None)


def _grown_object(object_cloud: GaussianCloud, proposed: Optional[GaussianCloud], occ: OcclusionResult,
                  inpainted: Tensor, finetune: FinetuneConfig,
                  occlusion: OcclusionConfig) -> tuple[GaussianCloud, int, int]:
    """Return the object to fine-tune, with the Gaussians a 3D-aware inpainter ``proposed`` (when adopted) and those
    seeded in the inpainted holes (when asked), and how many of each were added."""
    added = 0
    if finetune.adopt_proposed and proposed is not None and len(proposed):
        added = len(proposed)
        object_cloud = GaussianCloud.concatenate([object_cloud, same_columns(proposed, object_cloud)])
    seeded = 0
    if finetune.seed_holes:
        seeds = seed_hole_gaussians(object_cloud, occ, inpainted, stride=finetune.seed_stride,
                                    opacity=finetune.seed_opacity, min_difference=finetune.seed_min_difference,
                                    alpha_threshold=occlusion.alpha_threshold,
                                    depth_tolerance=occlusion.depth_tolerance, background=finetune.background)
        seeded = len(seeds)
        if seeded:
            object_cloud = GaussianCloud.concatenate([object_cloud, seeds])
    return object_cloud, added, seeded


def _refine_record(inpainter: Any, result: FinetuneResult, occlusion: OcclusionConfig, finetune: FinetuneConfig,
                   occ: OcclusionResult, seeded: int, proposed: int, filled: Tensor, support: Any,
                   completion: Optional[GaussianCloud]) -> dict[str, Any]:
    """Return the refinement's ``refine.json``: its settings, what it added and the shares of each view it filled."""
    return {"inpainter": getattr(inpainter, "name", "") or type(inpainter).__name__,
            "perceptual_loss": result.perceptual, "occlusion": asdict(occlusion),
            "finetune": asdict(finetune), "object_centre": occ.centre.tolist(), "object_radius": occ.radius,
            "seeded_gaussians": seeded, "proposed_gaussians": proposed,
            "filled_fraction": [float(m.float().mean()) for m in filled],
            "mirror": _mirror_record(inpainter), "support": support,
            "extruded_gaussians": int(getattr(inpainter, "last_extruded", 0)),
            "completion_gaussians": 0 if completion is None else len(completion),
            "occluded_fraction": [float(m.float().mean()) for m in occ.occluded],
            "mask_fraction": [float(m.float().mean()) for m in occ.mask],
            "seconds_finetune": result.seconds, "history": result.history}


def refine_object(object_cloud: GaussianCloud, scene_cloud: GaussianCloud, images: Tensor, cameras: Sequence[Camera],
                  object_masks: Tensor, *, inpainter: Any = "opencv", inpainter_options: Optional[dict] = None,
                  occlusion: OcclusionConfig = OcclusionConfig(), finetune: FinetuneConfig = FinetuneConfig(),
                  up: Optional[Sequence[float]] = None, prompt: Optional[str] = None,
                  progress: ProgressFactory = null_progress, renderer: Renderer | None = None,
                  lpips: torch.nn.Module | None = None) -> RefineResult:
    """Return the object model after occlusion reasoning, inpainting (one 2x2 grid) and fine-tuning.

    Args:
        object_cloud: the object's Gaussians (after selection and pruning).
        scene_cloud: the whole scene's Gaussians.
        images: the training views (a tensor, or a :class:`PerView` over them: each is read when its target is
            made). [N, H, W, 3]
        cameras: their cameras.
        object_masks: the object's 2D masks in the training views. [N, H, W]
        inpainter: an :class:`~roodi_toolkit.pipeline.inpaint.Inpainter` or a registered name (default ``opencv``).
        inpainter_options: options for a named inpainter.
        occlusion: occlusion-reasoning settings (``num_views`` must be 4 for the 2x2 grid).
        finetune: fine-tuning settings.
        up: the scene's up axis (default: estimated from ``cameras``).
        prompt: inpainting prompt (the paper uses none).
        progress: progress factory.
        renderer: draws every view of occlusion reasoning and fine-tuning (default: the built-in CPU renderer).
        lpips: the LPIPS network of fine-tuning's perceptual loss (:func:`finetune_object`).
    """
    inpainter = _resolve_inpainter(inpainter, inpainter_options, occlusion)
    cameras = list(cameras)
    up = up_from_cameras(cameras) if up is None else np.asarray(up, dtype=np.float64)
    bg = finetune.background
    renderer = resolve_renderer(renderer)
    # scene depth in the training views tells where something may hide the object, and where a view looks through
    # empty space (what a 3D completion must not fill)
    scene_params = GaussianParams.from_cloud(scene_cloud)

    def depth(camera: Camera) -> Tensor:  # rendered once per view, where the targets are made; never all held
        with torch.no_grad():  # no colours needed: SH degree 0
            return renderer.render(scene_params, camera, sh_degree=0).depth[..., 0]

    # only a 3D-aware inpainter reads the context: the support is looked for only for one
    wants = getattr(inpainter, "uses_context", False) and len(object_cloud) >= 4
    context = _fill_context(object_cloud, scene_cloud, scene_params, cameras, object_masks, up, bg, occlusion, wants,
                            renderer)
    # a 3D completion first, so that the views frame the whole object, the part no training view saw included
    completion = inpainter.complete(context) if wants else None
    frame = None if completion is None else GaussianCloud.concatenate([object_cloud, completion])
    occ = occlusion_masks(object_cloud, scene_cloud, None, occlusion, up=up, background=bg, renderer=renderer,
                          frame=frame)
    context.cameras, context.occlusion, context.completion = occ.cameras, occ, completion
    inpainted, grids = inpaint_views(inpainter, occ.object_rgb, occ.mask, prompt, context=context)
    filled = occ.mask & ((inpainted - occ.object_rgb).abs().amax(dim=-1) > FILL_CHANGE)
    grown, proposed, seeded = _grown_object(object_cloud, context.proposed, occ, inpainted, finetune, occlusion)
    originals = object_view_targets(images, cameras, object_masks, centre=occ.centre, radius=occ.radius,
                                    background=bg, render_depth=depth)
    inpainted_targets = ViewTargets(occ.cameras, inpainted, torch.ones(inpainted.shape[:3]))
    result = finetune_object(grown, originals, inpainted_targets, finetune, progress=progress,
                             renderer=renderer, lpips=lpips)
    after_params = GaussianParams.from_cloud(result.cloud)
    with torch.no_grad():
        after = torch.stack([renderer.render(after_params, c, background=bg).rgb.clamp(0, 1) for c in occ.cameras])
    record = _refine_record(inpainter, result, occlusion, finetune, occ, seeded, proposed, filled, context.support,
                            completion)
    return RefineResult(result.cloud, occ, inpainted, result, getattr(inpainter, "name", "") or type(inpainter).__name__,
                        filled, proposed, after, record, grids, object_cloud, completion, bg)


#: a masked pixel counts as filled when the inpainter changed it by more than this (max over channels)
FILL_CHANGE = 0.02


def same_columns(cloud: GaussianCloud, like: GaussianCloud) -> GaussianCloud:
    """Return ``cloud`` with ``like``'s SH degree, extras (zeros where missing) and normals, ready to concatenate."""
    k = like.sh_rest.shape[1]
    rest = np.zeros((len(cloud), k, 3), np.float32)
    n = min(k, cloud.sh_rest.shape[1])
    rest[:, :n] = cloud.sh_rest[:, :n]
    extras = {name: (cloud.extras[name] if name in cloud.extras else np.zeros(len(cloud), col.dtype))
              for name, col in like.extras.items()}
    normals = None
    if like.normals is not None:
        normals = cloud.normals if cloud.normals is not None else np.zeros((len(cloud), 3), like.normals.dtype)
    out = cloud.copy()
    out.sh_rest, out.extras, out.normals = rest, extras, normals
    return out


def _mirror_record(inpainter: Any) -> Optional[dict]:
    mirror = getattr(inpainter, "last_mirror", None)
    if mirror is None:
        return None
    return {"normal": [float(x) for x in mirror.normal], "offset": mirror.offset, "agreement": mirror.agreement}


def to_row(views: Tensor) -> Tensor:
    """Return views ``[V, H, W, C]`` side by side as one ``[H, V * W, C]`` image."""
    return torch.cat(list(views), dim=1)
