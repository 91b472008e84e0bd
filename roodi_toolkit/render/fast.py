"""The default CPU renderer: compiled kernels behind one torch autograd function.

Every per-Gaussian and per-pixel step (projection, SH colours, footprints, tile binning, compositing) and its
gradient runs in the compiled kernels of :mod:`roodi_toolkit.render.projection_kernels` and
:mod:`roodi_toolkit.render.kernels`; torch only holds the tensors. The images are those of
:func:`~roodi_toolkit.render.rasterizer.rasterize` (the torch tiled path, kept beside it as the reference) and of the
dense reference, to float rounding, and so are the gradients (``tests/render/test_fast.py``).

Why numba: it installs as a wheel with LLVM inside (no compiler on the user's machine), compiles plain loops over
numpy arrays to native code on all cores (``prange``) and caches what it compiled. ``docs/rendering.md`` has the
figures of what was tried.

Cost of one view: O(N) per-Gaussian work (projection, SH, footprints; ``parallel``), a sort of the drawn Gaussians by
depth (O(N), a compiled radix sort of the depths' bits), a counting sort into 32x32 tiles (16x16 for features alone;
O(pairs), each worker a
stretch of the depth order), and compositing in 4x4 pixel blocks (``parallel`` over tiles): each block evaluates on
its 16 pixels at once the Gaussians of its tile's run whose box touches it, up to where its pixels stop
(``docs/rendering.md``, "The 4x4 blocks: what they gave and what they cost"). Memory: a few arrays of N and of (tile,
Gaussian) pairs, plus the image; a differentiable forward keeps a 64-bit word a pair (the blocks each pair blended
in: what the backward walks), and the backward adds a [pairs, 6 + channels] gradient array, reduced per Gaussian in
pair order, so the gradients do not depend on the number of threads either.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import torch
from torch import Tensor

from ..errors import ConfigError
from ..progress import take_first_compile
from . import kernels, lanes, projection_kernels, tiles
from .cores import set_workers, uncompiled
from .projection import EPS2D, camera_tensors, check_inputs
from .rasterizer import RasterOutput, _split_output

TILE_SIZE = 32
"""Tile edge in pixels of a rendering. The compositing works on 4x4 blocks, each walking the entries of its tile's
run that touch it, so the image is the same for any tile size; smaller tiles hold more (tile, Gaussian) pairs
(binning, the runs' copies, the backward's per-pair gradients: 4-pixel tiles have 3.4x the pairs of 16-pixel ones at
500k Gaussians, 800x800), larger ones longer runs for each worker to hold. 32 pixels (gsplat and 3DGS use 16): a
real 653k-Gaussian splat's forward and backward 1.06-1.10x at 800 and 1000 px, its forward 1.03-1.05x (0.99x and
1.02x at 400 px); the benchmark scene 1.04-1.24x (``benchmarks/bench_tiles.py``, ``docs/rendering.md``)."""

FEATURE_TILE_SIZE = 16
"""Tile edge in pixels of a rendering of features alone (:func:`rasterize_features`: distillation, the click
segmenter), where 32-pixel tiles measured 0.95-0.98x of 16-pixel ones at 400 px, distillation's working size, on
the same splat (0.95-1.08x at 800-1000 px: 16 channels, whose sums in the walks outweigh the pairs' work)."""


def _tell_if_compiling() -> None:
    """Call the notice the command line registered (:func:`~roodi_toolkit.progress.tell_first_compile`), once, where
    this render compiles the kernels."""
    notice = take_first_compile()
    if notice is not None and uncompiled(projection_kernels.project_forward, tiles.depth_order, tiles.bin_tiles,
                                         lanes.fill_records, kernels.composite_forward):
        notice("compiling the renderer's kernels for this machine: about half a minute to a minute on first use, "
               "once (numba keeps them)")


@dataclass
class View:
    """One camera as the kernels take it (float64)."""

    view: np.ndarray  # [4, 4] world-to-camera
    center: np.ndarray  # [3] camera centre
    intr: np.ndarray  # [4] fx, fy, cx, cy
    width: int
    height: int
    near: float
    far: float
    eps2d: float
    tile: int


def make_view(world_to_camera, K, width: int, height: int, *, near: float = 0.01, far: float = 1e10,
              eps2d: float = EPS2D, tile: int = TILE_SIZE) -> View:
    """Return the camera as the kernels take it."""
    w2c, Kt = camera_tensors(world_to_camera, K, torch.float64, "cpu")
    view = w2c.numpy().copy()
    center = -view[:3, :3].T @ view[:3, 3]
    k = Kt.numpy()
    return View(view, center, np.array([k[0, 0], k[1, 1], k[0, 2], k[1, 2]]), int(width), int(height), float(near),
                float(far), float(eps2d), int(tile))


@dataclass
class Projected:
    """Gaussians projected into one view (numpy, the inputs' dtype)."""

    means2d: np.ndarray  # [N, 2]
    conics: np.ndarray  # [N, 3]
    depths: np.ndarray  # [N]
    channels: np.ndarray  # [N, 4 + F] what the compositing blends: rgb, depth, then the features (``channels_of``)
    opacities: np.ndarray  # [N]
    bounds: np.ndarray  # [N, 4] int32 inclusive pixel box of each footprint
    half: np.ndarray  # [N, 2] int32
    ntiles: np.ndarray  # [N] int64, 0 where not drawn
    scales: np.ndarray  # [N, 3] exp(log-scales), what the backward reuses
    clamped: np.ndarray  # [N] uint8, bit c: SH colour channel c was clamped at 0 (no gradient)


@dataclass
class Bins:
    """The drawn Gaussians binned to the view's tiles in depth order (what forward and backward walk)."""

    lists: np.ndarray  # [M] int32 Gaussian ids, grouped by tile, depth order within a tile
    starts: np.ndarray  # [T] int64
    counts: np.ndarray  # [T] int64
    busy: np.ndarray  # [B] int64 tiles with at least one Gaussian


def _numpy(t: Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy()


def _sh_bases(colors: Tensor, sh_degree: Optional[int]) -> int:
    """Return how many SH bases to evaluate (0: ``colors`` are RGB)."""
    if colors.ndim == 2:
        return 0
    k = colors.shape[1]
    full = {1: 0, 4: 1, 9: 2, 16: 3}[k]
    degree = full if sh_degree is None else int(sh_degree)
    if not 0 <= degree <= full:
        raise ConfigError(f"SH degree {degree} needs more than the {k} coefficients given")
    return (degree + 1) ** 2


def project(means: np.ndarray, quats: np.ndarray, log_scales: np.ndarray, opacity_logits: np.ndarray,
            colors: np.ndarray, n_bases: int, view: View, n_features: int = 0) -> Projected:
    """Return the Gaussians projected into ``view`` with their colours and footprints (compiled, no autograd);
    ``channels`` has ``n_features`` columns after rgb and depth for :func:`channels_of` to fill."""
    _tell_if_compiling()
    n, dtype = means.shape[0], means.dtype
    # the kernel reads rows as vectors: C order (no copy where they are already)
    means, quats = np.ascontiguousarray(means), np.ascontiguousarray(quats)
    sh = np.ascontiguousarray(colors) if n_bases > 0 else np.ascontiguousarray(colors, dtype).reshape(n, 1, 3)
    scales, opacities, r2 = projection_kernels.activations(log_scales, opacity_logits)
    out = Projected(np.empty((n, 2), dtype), np.empty((n, 3), dtype), np.empty(n, dtype),
                    np.empty((n, 4 + n_features), dtype), opacities,
                    np.zeros((n, 4), np.int32), np.zeros((n, 2), np.int32), np.zeros(n, np.int64), scales,
                    np.zeros(n, np.uint8))
    set_workers()
    projection_kernels.project_forward(means, quats, scales, opacities, r2, sh, n_bases, view.view, view.center,
                                       view.intr, view.width, view.height, view.near, view.far, view.eps2d, view.tile,
                                       out.means2d, out.conics, out.depths, out.channels, out.bounds, out.half,
                                       out.ntiles, out.clamped)
    return out


def bin_gaussians(proj: Projected, view: View) -> Bins:
    """Return the drawn Gaussians binned to tiles, in depth order (stable: ties keep index order)."""
    order = tiles.depth_order(proj.ntiles, proj.depths, set_workers())
    lists, starts, counts = tiles.bin_tiles(order, proj.bounds, view.width, view.height, view.tile, set_workers())
    return Bins(lists, starts, counts, np.flatnonzero(counts > 0))


def marks_shape(pairs: int, tile: int) -> tuple[int, int]:
    """The shape of the forward's marks (:func:`composite`): a row of 64-bit words for each of the ``pairs`` (tile,
    Gaussian) pairs, one bit per 4x4 block of a ``tile``-pixel tile."""
    blocks = ((tile + 3) // 4) ** 2
    return pairs, (blocks + 63) // 64


def record_buffer(n: int, dtype) -> np.ndarray:
    """Return an uninitialised [n, 16] array of ``dtype`` whose rows start on 64-byte cache lines (numpy aligns less):
    room for :func:`records`."""
    buf = np.empty(n * 16 + 16, dtype)
    skip = (-buf.ctypes.data % 64) // buf.itemsize
    return buf[skip:skip + n * 16].reshape(n, 16)


def records(proj: Projected, channels: Optional[np.ndarray]) -> np.ndarray:
    """Return each Gaussian's 64-byte record [N, 16] that the compositing kernels gather (geometry, box, and the
    ``channels`` where they are at most four; none for None), on cache lines. Made in numpy, once per render (the
    backward reuses the forward's): numpy asks Linux for huge pages for large arrays, where the kernels' own
    allocation faulted its pages 4 KB at a time in every call (with the reduction's sums, a quarter of a
    650k-Gaussian features step at 400x400)."""
    n, dtype = len(proj.opacities), proj.opacities.dtype
    nc = 4 if channels is not None and channels.shape[1] <= 4 else 0
    rec = record_buffer(n, dtype)
    colors = channels if channels is not None else np.zeros((1, 1), dtype)
    set_workers()
    lanes.fill_records(proj.bounds, proj.means2d, proj.conics, proj.opacities, colors, nc, rec)
    return rec


def composite(bins: Bins, proj: Projected, channels: np.ndarray, view: View, *, want_top: bool = False,
              want_marks: bool = False, rec: Optional[np.ndarray] = None) -> tuple[
                  np.ndarray, np.ndarray, np.ndarray, Optional[np.ndarray], Optional[np.ndarray]]:
    """Return (channels composited [H, W, C] without background, final transmittance [H, W], walked run lengths
    [H, W] (the backward's starting points), each pixel's largest-weight Gaussian [H, W] (-1: none) or None, the
    blocks each (tile, Gaussian) pair blended in [M, words] uint64 (what the backward walks) or None). ``rec``:
    :func:`records` of ``proj`` and ``channels`` where the caller keeps them (for the backward)."""
    H, W, C = view.height, view.width, channels.shape[1]
    out = np.zeros((H, W, C), channels.dtype)
    t_final = np.ones((H, W), channels.dtype)
    last = np.zeros((H, W), np.int32)
    top = np.full((H, W) if want_top else (0, 0), -1, np.int32)
    marks = np.zeros(marks_shape(len(bins.lists), view.tile) if want_marks else (0, 1), np.uint64)
    n_workers = set_workers()
    rec = records(proj, channels) if rec is None else rec
    kernels.composite_forward(bins.lists, bins.starts, bins.counts, bins.busy, rec, channels,
                              kernels.channel_groups(C), W, H, view.tile, n_workers, out, t_final, last, top, marks)
    return out, t_final, last, (top if want_top else None), (marks if want_marks else None)


def channels_of(proj: Projected, features: Optional[np.ndarray], colours: bool = True) -> np.ndarray:
    """Return the per-Gaussian channels composited: ``[rgb | depth | features]`` [N, 4 + F] (``proj.channels``, the
    features copied into the columns :func:`project` left for them), or the features alone ``[N, F]`` without
    ``colours``."""
    dtype = proj.channels.dtype
    if not colours and features is not None:  # no copy of the features themselves
        return np.ascontiguousarray(features, dtype=dtype)
    n_features = 0 if features is None else features.shape[1]
    if proj.channels.shape[1] != 4 + n_features:
        raise ValueError(f"project() left {proj.channels.shape[1] - 4} feature columns for {n_features} features")
    if n_features:
        proj.channels[:, 4:] = features
    return proj.channels


def _differentiable(*tensors: Tensor) -> bool:
    """Whether a render of ``tensors`` will be differentiated: then its forward keeps what the backward needs (the
    compositing's marks; ``needs_input_grad`` is set under ``torch.no_grad()`` too)."""
    return torch.is_grad_enabled() and any(t.requires_grad for t in tensors)


class _Render(torch.autograd.Function):
    """Projection, colours and compositing of one view, with the compiled backward. ``colors`` of shape [N, 0]
    composite the features alone (no colours, no depth, no background)."""

    @staticmethod
    def forward(ctx, means, quats, log_scales, opacity_logits, colors, features, background, probe, view,
                n_bases, differentiable):  # type: ignore[override]
        colours = colors.shape[-1] > 0
        arrays = [_numpy(t) for t in (means, quats, log_scales, opacity_logits, colors)]
        feats = _numpy(features) if features.shape[1] else None
        proj = project(*arrays[:4], arrays[4] if colours else np.zeros((len(arrays[0]), 3), arrays[0].dtype),
                       n_bases, view, features.shape[1] if colours else 0)
        channels = channels_of(proj, feats, colours)
        bins = bin_gaussians(proj, view)
        rec = records(proj, channels)
        out, t_final, last, _, marks = composite(bins, proj, channels, view, want_marks=differentiable, rec=rec)
        ctx.save_for_backward(background)
        ctx.state = (arrays, proj, channels, rec if differentiable else None, bins, t_final, last, marks, view, n_bases,
                     features.shape[1], colours)
        t_t = torch.from_numpy(t_final)
        render = torch.from_numpy(out)
        if colours:  # in place: the array is this call's own
            render[..., :3].addcmul_(t_t[..., None], background)
        drawn = proj.ntiles > 0
        means2d, depths = torch.from_numpy(proj.means2d), torch.from_numpy(proj.depths)
        radii = torch.from_numpy(proj.half)  # 0 where not drawn (``project`` writes only the drawn ones')
        ctx.mark_non_differentiable(means2d, depths)
        return render, (1.0 - t_t)[..., None], means2d, depths, torch.from_numpy(drawn), radii

    @staticmethod
    def backward(ctx, g_render, g_alpha, *_unused):  # type: ignore[override]
        (background,) = ctx.saved_tensors
        arrays, proj, channels, rec, bins, t_final, last, marks, view, n_bases, n_feat, colours = ctx.state
        means, quats, _, _, colors = arrays  # the scales and opacities are the forward's (``proj``)
        n, C = channels.shape
        dtype = channels.dtype
        geometry = any(ctx.needs_input_grad[i] for i in (0, 1, 2, 3, 7))
        n_workers = set_workers()
        m = len(bins.lists)
        pair_geom = np.empty((m if geometry else 0, 6), dtype)  # both written by the kernel, tile by tile
        pair_chan = np.empty((m, C), dtype)
        bg = np.concatenate([_numpy(background).astype(np.float64), np.zeros(C - 3)]) if colours else np.zeros(C)
        g_render = g_render.contiguous()
        kernels.composite_backward(bins.lists, bins.starts, bins.counts, bins.busy, rec, channels,
                                   kernels.channel_groups(C), view.width, view.height, view.tile,
                                   n_workers, t_final, last, marks, _numpy(g_render),
                                   np.ascontiguousarray(_numpy(g_alpha)[..., 0]), bg, pair_geom, pair_chan, geometry)
        g_chan = np.empty((n, C), dtype)  # in numpy: huge pages (see ``records``)
        kernels.reduce_pairs(bins.lists, pair_chan, g_chan, n_workers)
        if colours:
            g_background = (g_render[..., :3] * torch.from_numpy(t_final)[..., None]).sum((0, 1))
            g_features = torch.from_numpy(np.ascontiguousarray(g_chan[:, 4:])) if n_feat else None
        else:  # the features alone: no colour, depth or background channels
            g_background = torch.zeros_like(background)
            g_features = torch.from_numpy(g_chan)
            if not geometry:
                return None, None, None, None, None, g_features, g_background, None, None, None, None
            g_chan = np.concatenate([np.zeros((n, 4), dtype), g_chan], axis=1)
        need_colors = ctx.needs_input_grad[4] and colours
        if not (geometry or need_colors):
            return None, None, None, None, None, g_features, g_background, None, None, None, None
        g = np.empty((n, 6), dtype) if geometry else np.zeros((n, 6), dtype)
        if geometry:
            kernels.reduce_pairs(bins.lists, pair_geom, g, n_workers)
        fresh = np.empty if geometry else np.zeros  # the kernel writes every row with geometry (zeros where not drawn)
        g_means = fresh((n, 3), dtype)
        g_quats = fresh((n, 4), dtype)
        g_log_scales = fresh((n, 3), dtype)
        g_logits = fresh(n, dtype)
        g_sh = np.empty(colors.shape, dtype) if n_bases > 0 else np.zeros((n, 1, 3), dtype)
        g_rgb = g_chan[:, :3]
        # the gradients' columns are passed as views (strided): copies of them were a tenth of the glue
        projection_kernels.project_backward(means, quats, proj.scales, proj.opacities,
                                            colors if n_bases > 0 else np.zeros((n, 1, 3), dtype), n_bases,
                                            view.view, view.center, view.intr, view.width, view.height, view.near,
                                            view.far, view.eps2d, proj.ntiles, proj.clamped, g[:, :2], g[:, 2:5],
                                            g[:, 5], g_rgb, g_chan[:, 3], g_means, g_quats, g_log_scales, g_logits,
                                            g_sh, geometry)
        t = torch.from_numpy
        g_colors = (t(g_sh) if n_bases > 0 else t(np.ascontiguousarray(g_rgb))) if need_colors else None
        if not geometry:
            return None, None, None, None, g_colors, g_features, g_background, None, None, None, None
        return (t(g_means), t(g_quats), t(g_log_scales), t(g_logits), g_colors, g_features, g_background,
                t(g)[:, :2], None, None, None)


def rasterize_fast(
    means: Tensor,  # [N, 3]
    quats_wxyz: Tensor,  # [N, 4]
    log_scales: Tensor,  # [N, 3]
    opacity_logits: Tensor,  # [N]
    colors: Tensor,  # [N, 3] or [N, K, 3]
    world_to_camera: Tensor,  # [4, 4]
    K: Tensor,  # [3, 3]
    width: int,
    height: int,
    *,
    near: float = 0.01,
    far: float = 1e10,
    features: Optional[Tensor] = None,  # [N, F]
    background: Optional[Tensor] = None,  # [3]
    sh_degree: Optional[int] = None,
    eps2d: float = EPS2D,
    tile_size: int = TILE_SIZE,
) -> RasterOutput:
    """Return the differentiable rendering of Gaussians in one camera with the compiled CPU kernels.

    Arguments and outputs as :func:`roodi_toolkit.render.rasterizer.rasterize` (the torch reference), which this
    matches to float rounding; ``means2d_grad()`` of the output gives the screen-space gradient.

    Example:
        >>> out = rasterize_fast(torch.tensor([[0.0, 0.0, 2.0]]), torch.tensor([[1.0, 0, 0, 0]]),
        ...     torch.log(torch.full((1, 3), 0.05)), torch.tensor([10.0]), torch.tensor([[1.0, 0.5, 0.0]]),
        ...     torch.eye(4), torch.tensor([[64.0, 0, 16.5], [0, 64, 16.5], [0, 0, 1]]), 33, 33)
        >>> [round(v, 4) for v in out.rgb[16, 16].tolist()], round(out.depth[16, 16].item(), 4)
        ([0.99, 0.495, 0.0], 2.0)
    """
    check_inputs(means, quats_wxyz, log_scales, opacity_logits, colors, features, width, height, near, far)
    if not 1 <= tile_size <= 64:
        raise ConfigError(f"tile_size must be 1 to 64 pixels, got {tile_size}")
    dtype = means.dtype
    n = means.shape[0]
    view = make_view(world_to_camera, K, width, height, near=near, far=far, eps2d=eps2d, tile=tile_size)
    n_bases = _sh_bases(colors, sh_degree)
    bg = torch.zeros(3, dtype=dtype) if background is None else torch.as_tensor(background, dtype=dtype).reshape(-1)
    if bg.shape != (3,):
        raise ConfigError(f"background must have 3 values, got {list(bg.shape)}")
    feats = features.to(dtype) if features is not None else torch.zeros(n, 0, dtype=dtype)
    geometry = any(t.requires_grad for t in (means, quats_wxyz, log_scales, opacity_logits)) and \
        torch.is_grad_enabled()
    probe = torch.zeros(n, 2, dtype=dtype, requires_grad=True) if geometry else torch.zeros(0, 2, dtype=dtype)
    colors = colors.to(dtype)
    differentiable = _differentiable(means, quats_wxyz, log_scales, opacity_logits, colors, feats, bg)
    render, alpha, means2d, depths, visible, radii = _Render.apply(
        means, quats_wxyz, log_scales, opacity_logits, colors, feats, bg, probe, view, n_bases, differentiable)
    out = _split_output(render, alpha, 0 if features is None else features.shape[1], means2d, radii, depths,
                        visible)
    out.grad_source = probe if geometry else None
    return out


def compositing_pairs(bins: Bins, proj: Projected, view: View) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return ``(pixels, gaussians, weights)`` [M]: every blended ``alpha T`` of the view with its row-major pixel
    index, exactly as :func:`composite` blends them (two compiled passes: count, then fill)."""
    n_workers = set_workers()
    offsets = np.zeros(len(bins.busy) + 1, np.int64)
    empty_i, empty_f = np.zeros(0, np.int64), np.zeros(0, proj.opacities.dtype)
    args = (bins.lists, bins.starts, bins.counts, bins.busy, records(proj, None), view.width, view.height, view.tile,
            n_workers, offsets)
    kernels.composite_pairs(*args, empty_i, np.zeros(0, np.int32), empty_f)
    np.cumsum(offsets, out=offsets)
    total = int(offsets[-1])
    pixels, ids, weights = np.empty(total, np.int64), np.empty(total, np.int32), np.empty(total, proj.opacities.dtype)
    if total:
        kernels.composite_pairs(*args, pixels, ids, weights)
    return pixels, ids, weights


def surface_ids(means: np.ndarray, quats: np.ndarray, log_scales: np.ndarray, opacity_logits: np.ndarray,
                view: View) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return each pixel's largest-weight Gaussian ``[H, W]`` (-1 where none), the alpha ``[H, W]`` and every
    Gaussian's camera-space depth ``[N]``: what a depth that does not blend across object edges is made of (the
    click segmenter's flood fill). No colours are evaluated."""
    proj = project(means, quats, log_scales, opacity_logits, np.zeros((len(means), 3), means.dtype), 0, view)
    _, t_final, _, top, _ = composite(bin_gaussians(proj, view), proj, np.zeros((len(means), 1), means.dtype), view,
                                      want_top=True)
    return top, 1.0 - t_final, proj.depths


def rasterize_features(
    means: Tensor,  # [N, 3]
    quats_wxyz: Tensor,  # [N, 4]
    log_scales: Tensor,  # [N, 3]
    opacity_logits: Tensor,  # [N]
    features: Tensor,  # [N, F]
    world_to_camera: Tensor,  # [4, 4]
    K: Tensor,  # [3, 3]
    width: int,
    height: int,
    *,
    near: float = 0.01,
    far: float = 1e10,
    eps2d: float = EPS2D,
    tile_size: int = FEATURE_TILE_SIZE,
) -> tuple[Tensor, Tensor]:
    """Return the composited features ``[H, W, F]`` and alpha ``[H, W, 1]`` of one view, differentiable: what
    :func:`rasterize_fast` returns as ``features`` and ``alpha``, without evaluating colours or depth (object
    features are distilled and clicks propagated with thousands of these)."""
    n = means.shape[0]
    check_inputs(means, quats_wxyz, log_scales, opacity_logits, torch.zeros(n, 3, dtype=means.dtype), features, width,
                 height, near, far)
    if not 1 <= tile_size <= 64:
        raise ConfigError(f"tile_size must be 1 to 64 pixels, got {tile_size}")
    dtype = means.dtype
    view = make_view(world_to_camera, K, width, height, near=near, far=far, eps2d=eps2d, tile=tile_size)
    geometry = any(t.requires_grad for t in (means, quats_wxyz, log_scales, opacity_logits)) and \
        torch.is_grad_enabled()
    probe = torch.zeros(n if geometry else 0, 2, dtype=dtype, requires_grad=geometry)
    features = features.to(dtype)
    render, alpha, *_ = _Render.apply(means, quats_wxyz, log_scales, opacity_logits, torch.zeros(n, 0, dtype=dtype),
                                      features, torch.zeros(3, dtype=dtype), probe, view, 0,
                                      _differentiable(means, quats_wxyz, log_scales, opacity_logits, features))
    return render, alpha
