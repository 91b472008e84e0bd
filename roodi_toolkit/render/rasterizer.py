"""Differentiable Gaussian splat rasterization on the CPU: a fast tiled renderer and a slow dense reference beside it.

Both follow the reference 3DGS rasterizer ("classic" mode, as gsplat's ``rasterization`` with
``rasterize_mode="classic"``):

- EWA projection: ``cov2d = J W Sigma W^T J^T + eps2d * I`` with the perspective Jacobian ``J`` evaluated at the
  camera-space mean whose ``x/z`` and ``y/z`` are clamped to the view frustum widened by 30% (3DGS' ``1.3 * tan(fov)``,
  gsplat's ``lim_x_pos/lim_x_neg`` for off-centre principal points); ``eps2d = 0.3``.
- Pixel centres at ``(j + 0.5, i + 0.5)``; ``alpha = min(0.99, opacity * exp(-0.5 d^T cov2d^-1 d))``; contributions
  with ``alpha < 1/255`` are skipped.
- Front-to-back compositing sorted by camera-space depth; a pixel stops at the first Gaussian that would bring its
  transmittance below ``1e-4`` (that Gaussian is not blended), as in 3DGS.
- Gaussians with ``z <= near`` or ``z >= far`` are culled.
- RGB gets ``background * T_final``; depth and feature channels are composited with the same weights and no background.
  Depth is gsplat's ``"ED"``: ``sum(w_i z_i) / max(sum(w_i), 1e-10)``.

The fast path bins Gaussians to square tiles by their exact footprint (the ellipse outside which
``opacity * G < 1/255``, i.e. Mahalanobis radius ``sqrt(2 ln(255 opacity))`` <= 3.33 sigma, the opacity-aware extent
of current gsplat), so it skips only contributions the alpha test would skip anyway and agrees with the dense
reference to rounding. Per tile, the depth-sorted list is composited in chunks of Gaussians for all tiles at once; the
quadratic form of every (pixel, Gaussian) pair in a chunk is one batched matrix product in tile-local coordinates.
The backward pass is hand-written (:class:`_RasterizeTiles`), recomputes each chunk front to back, and so needs memory
for one chunk, not for the whole (pixel, Gaussian) list.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import torch
from torch import Tensor

from ..errors import ConfigError
from ..sh import eval_sh_colors
from .projection import EPS2D, camera_tensors, check_inputs, project_gaussians, project_gaussians_reference

ALPHA_MIN = 1.0 / 255.0
"""Contributions below this alpha are skipped (3DGS)."""
ALPHA_MAX = 0.99
"""Alpha is clamped to this (3DGS; gsplat uses 0.999)."""
TRANSMITTANCE_MIN = 1e-4
"""A pixel stops before the Gaussian that would bring its transmittance below this (3DGS)."""
_LOG_ZERO = -1e4  # exp() of this is 0 in float32 and float64: the log-opacity of padding entries


@dataclass
class RasterOutput:
    """What one rasterization returns. Image tensors are channels-last, like gsplat's.

    Attributes:
        rgb: composited colour including the background. [H, W, 3]
        alpha: accumulated opacity, ``1 - T_final``. [H, W, 1]
        depth: expected depth (gsplat ``"ED"``), 0 where nothing was hit. [H, W, 1]
        features: composited extra channels (no background), or None if none were given. [H, W, F]
        means2d: projected means in pixels; when the inputs require grad, :meth:`means2d_grad` returns their gradient
            after backward (the screen-space gradient that densification strategies accumulate). [N, 2]
        radii: half-extents in pixels of each Gaussian's footprint, 0 where culled (the dense reference, which has
            no footprints, leaves them 0). [N, 2]
        depths: camera-space z of each mean. [N]
        visible: Gaussians that touch at least one pixel (not culled, on screen). [N]
    """

    rgb: Tensor
    alpha: Tensor
    depth: Tensor
    features: Optional[Tensor]
    means2d: Tensor
    radii: Tensor
    depths: Tensor
    visible: Tensor
    grad_source: Optional[Tensor] = field(default=None, repr=False)

    def means2d_grad(self) -> Optional[Tensor]:
        """Return the gradient ``[N, 2]`` of the loss w.r.t. the projected means after ``backward()``, or None.

        Backends whose screen-space means live in a batched tensor (gsplat's ``[C, N, 2]``) set ``grad_source``;
        otherwise this is ``means2d.grad``.
        """
        source = self.means2d if self.grad_source is None else self.grad_source
        grad = source.grad
        return None if grad is None else grad.reshape(-1, 2)


def _colors_and_background(means, colors, features, depths, w2c, background, sh_degree, dtype):
    """Stack [rgb | depth | features] per Gaussian and the matching background (zero for depth and features)."""
    if colors.ndim == 3:
        center = -w2c[:3, :3].T @ w2c[:3, 3]
        rgb = eval_sh_colors(colors, means - center, sh_degree)
    else:
        rgb = colors
    parts = [rgb, depths[:, None]]
    if features is not None:
        parts.append(features.to(dtype))
    stacked = torch.cat(parts, dim=-1)
    bg = torch.zeros(stacked.shape[1], dtype=dtype, device=means.device)
    if background is not None:
        bg_rgb = torch.as_tensor(background, dtype=dtype, device=means.device).reshape(-1)
        if bg_rgb.shape != (3,):
            raise ConfigError(f"background must have 3 values, got {list(bg_rgb.shape)}")
        bg = torch.cat([bg_rgb, bg[3:]])
    return stacked, bg


def _split_output(render, alpha, n_feat, means2d, radii, depths, visible) -> RasterOutput:
    acc_depth = render[..., 3:4]
    depth = acc_depth / alpha.clamp_min(1e-10)
    return RasterOutput(rgb=render[..., :3], alpha=alpha, depth=depth,
                        features=render[..., 4:] if n_feat else None, means2d=means2d, radii=radii, depths=depths,
                        visible=visible)


# ------------------------------------------------------------------------------------------------ dense reference
def rasterize_dense_reference(
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
    rows: Optional[tuple[int, int]] = None,
    cols: Optional[tuple[int, int]] = None,
) -> RasterOutput:
    """Return the rendering computed the slow way: every Gaussian at every pixel, plain autograd, from the equations.

    Memory and time grow as N x H x W; meant for tests and as the benchmark baseline. Arguments as
    :func:`rasterize`, plus ``rows=(start, stop)`` and ``cols=(start, stop)`` to render only that window of the image
    (the outputs are then ``[rows, cols, ...]``), which lets a caller bound memory by rendering in pieces.
    """
    check_inputs(means, quats_wxyz, log_scales, opacity_logits, colors, features, width, height, near, far)
    dtype = means.dtype
    w2c, Kt = camera_tensors(world_to_camera, K, dtype, means.device)
    means2d, conic, depths, in_range = project_gaussians_reference(means, quats_wxyz, log_scales, w2c, Kt, width, height,
                                                          near, far, eps2d)
    if means2d.requires_grad:
        means2d.retain_grad()
    opac = torch.sigmoid(opacity_logits)
    stacked, bg = _colors_and_background(means, colors, features, depths, w2c, background, sh_degree, dtype)
    r0, r1 = (0, height) if rows is None else rows
    c0, c1 = (0, width) if cols is None else cols
    order = torch.sort(torch.where(in_range, depths, torch.full_like(depths, math.inf)).detach(), stable=True)[1]
    order = order[in_range[order]]
    ys, xs = torch.meshgrid(torch.arange(r0, r1, dtype=dtype) + 0.5, torch.arange(c0, c1, dtype=dtype) + 0.5,
                            indexing="ij")
    pix = torch.stack([xs.reshape(-1), ys.reshape(-1)], -1)  # [P, 2]
    d = pix[:, None, :] - means2d[order][None, :, :]  # [P, M, 2]
    maha = torch.einsum("pmi,mij,pmj->pm", d, conic[order], d)
    alpha = torch.clamp_max(opac[order][None, :] * torch.exp(-0.5 * maha), ALPHA_MAX)
    alpha = torch.where(alpha >= ALPHA_MIN, alpha, torch.zeros_like(alpha))
    t_incl = torch.cumprod(1.0 - alpha, dim=1)
    keep = t_incl >= TRANSMITTANCE_MIN  # a prefix of each pixel's list: transmittance only decreases
    t_excl = torch.cat([torch.ones_like(t_incl[:, :1]), t_incl[:, :-1]], dim=1)
    weights = alpha * t_excl * keep
    t_final = torch.prod(torch.where(keep, 1.0 - alpha, torch.ones_like(alpha)), dim=1)
    render = weights @ stacked[order] + t_final[:, None] * bg
    render = render.reshape(r1 - r0, c1 - c0, -1)
    alpha_img = (1.0 - t_final).reshape(r1 - r0, c1 - c0, 1)
    radii = torch.zeros(means.shape[0], 2, dtype=torch.int32)
    visible = in_range & (opac >= ALPHA_MIN)
    return _split_output(render, alpha_img, 0 if features is None else features.shape[1], means2d, radii, depths,
                         visible)


# ------------------------------------------------------------------------------------------------ tiled renderer
@dataclass
class _Tiles:
    """Gaussian-to-tile intersections, sorted by tile then depth (no gradients)."""

    tile_size: int
    tiles_x: int
    tiles_y: int
    pair_ids: Tensor  # [M] Gaussian index of each intersection, grouped by tile, depth order within a tile
    offsets: Tensor  # [T] start of each tile's run in pair_ids
    counts: Tensor  # [T] length of each tile's run


@torch.no_grad()
def _footprints(means2d: Tensor, cov2d: Tensor, opacities: Tensor, usable: Tensor, width: int, height: int):
    """Return pixel-index bounds ``[N, 4]`` (x0, x1, y0, y1, inclusive) of each footprint and whether it is non-empty.

    The footprint is the ellipse where ``opacity * G >= 1/255``: Mahalanobis radius^2 ``2 ln(255 opacity)``; its
    bounding box has half-widths ``sqrt(r2 * cov_xx)`` and ``sqrt(r2 * cov_yy)``. A relative margin of 1e-6 keeps
    pixels exactly on the boundary (the alpha test decides them).
    """
    r2 = 2.0 * torch.log(torch.clamp_min(opacities * 255.0, 1.0)) * (1.0 + 1e-6)
    hx = torch.sqrt(r2 * cov2d[:, 0, 0])
    hy = torch.sqrt(r2 * cov2d[:, 1, 1])
    mx, my = means2d[:, 0], means2d[:, 1]
    x0 = torch.ceil(mx - hx - 0.5)
    x1 = torch.floor(mx + hx - 0.5)
    y0 = torch.ceil(my - hy - 0.5)
    y1 = torch.floor(my + hy - 0.5)
    ok = usable & (opacities >= ALPHA_MIN) & (x0 <= x1) & (y0 <= y1) & (x1 >= 0) & (y1 >= 0)
    ok &= (x0 <= width - 1) & (y0 <= height - 1)
    ok &= torch.isfinite(mx) & torch.isfinite(my) & torch.isfinite(hx) & torch.isfinite(hy)
    bounds = torch.stack([x0.clamp(0, width - 1), x1.clamp(0, width - 1), y0.clamp(0, height - 1),
                          y1.clamp(0, height - 1)], -1)
    bounds = torch.where(ok[:, None], bounds, torch.zeros_like(bounds)).long()
    return bounds, ok, torch.stack([torch.ceil(hx), torch.ceil(hy)], -1)


@torch.no_grad()
def _bin_tiles(bounds: Tensor, ok: Tensor, depths: Tensor, width: int, height: int, tile_size: int) -> _Tiles:
    tiles_x = -(-width // tile_size)
    tiles_y = -(-height // tile_size)
    ids = torch.nonzero(ok).squeeze(1)
    ids = ids[torch.sort(depths[ids], stable=True)[1]]
    b = bounds[ids] // tile_size  # tile bounds, inclusive
    nx = b[:, 1] - b[:, 0] + 1
    ny = b[:, 3] - b[:, 2] + 1
    per = nx * ny
    total = int(per.sum())
    pair_ids = torch.repeat_interleave(ids, per, output_size=total)
    start = torch.repeat_interleave(torch.cumsum(per, 0) - per, per, output_size=total)
    k = torch.arange(total) - start
    nx_r = torch.repeat_interleave(nx, per, output_size=total)
    tx = torch.repeat_interleave(b[:, 0], per, output_size=total) + k % nx_r
    ty = torch.repeat_interleave(b[:, 2], per, output_size=total) + k // nx_r
    tile = ty * tiles_x + tx
    tile, order = torch.sort(tile, stable=True)  # stable: keeps depth order within a tile
    pair_ids = pair_ids[order]
    counts = torch.bincount(tile, minlength=tiles_x * tiles_y)
    offsets = torch.cumsum(counts, 0) - counts
    return _Tiles(tile_size, tiles_x, tiles_y, pair_ids, offsets, counts)


def _tile_basis(tile_size: int, dtype) -> Tensor:
    """``[P, 6]`` monomials (u^2, v^2, uv, u, v, 1) of the pixel centres in coordinates centred on the tile."""
    c = torch.arange(tile_size, dtype=dtype) + 0.5 - 0.5 * tile_size
    v, u = torch.meshgrid(c, c, indexing="ij")
    u, v = u.reshape(-1), v.reshape(-1)
    return torch.stack([u * u, v * v, u * v, u, v, torch.ones_like(u)], -1)


def _quadratic_coeffs(m: Tensor, n: Tensor, a: Tensor, b: Tensor, c: Tensor, log_o: Tensor) -> Tensor:
    """Coefficients ``[..., 6]`` of ``log(opacity) - sigma`` in the monomials of :func:`_tile_basis`.

    ``sigma = 0.5 a (u-m)^2 + 0.5 c (v-n)^2 + b (u-m)(v-n)`` with (m, n) the mean relative to the tile centre.
    """
    return torch.stack([-0.5 * a, -0.5 * c, -b, a * m + b * n, c * n + b * m,
                        log_o - (0.5 * a * m * m + 0.5 * c * n * n + b * m * n)], -1)


class _Compositor:
    """Walks each tile's depth-sorted list in chunks, for many tiles at once (shared by forward and backward)."""

    def __init__(self, tiles: _Tiles, params: Tensor, chunk: int, max_elements: int):
        self.tiles = tiles
        self.params = params  # [N, 6]: mx, my, a, b, c, log opacity
        self.chunk = chunk
        ts = tiles.tile_size
        self.P = ts * ts
        self.basis = _tile_basis(ts, params.dtype)  # [P, 6]
        t = torch.arange(tiles.tiles_x * tiles.tiles_y)
        self.centers = torch.stack([(t % tiles.tiles_x) * ts + 0.5 * ts, (t // tiles.tiles_x) * ts + 0.5 * ts],
                                   -1).to(params.dtype)  # [T, 2]
        self.tiles_per_group = max(1, max_elements // (self.P * chunk))

    def groups(self):
        """Yield index tensors of tiles processed together (only tiles with at least one Gaussian)."""
        busy = torch.nonzero(self.tiles.counts > 0).squeeze(1)
        for i in range(0, len(busy), self.tiles_per_group):
            yield busy[i:i + self.tiles_per_group]

    def weights(self, group: Tensor, t_carry: Tensor):
        """Yield ``(active, ids, w)`` per chunk of ``group``'s tiles, front to back: the tiles still compositing
        (indices into ``group``), their chunk's Gaussian ids ``[Ta, B]`` and compositing weights ``[Ta, P, B]``.

        ``t_carry`` ``[len(group), P]`` is the transmittance entering the group and is updated in place, so it holds
        the final transmittance when the generator is exhausted.
        """
        chunk = self.chunk
        done = torch.zeros_like(t_carry, dtype=torch.bool)
        active = torch.arange(len(group))
        for r in range(-(-int(self.tiles.counts[group].max()) // chunk)):
            active = active[(self.tiles.counts[group[active]] > r * chunk) & ~done[active].all(-1)]
            if len(active) == 0:
                return
            ids, _, _, _, alpha = self.chunk_alpha(group[active], r)
            w, _, _, t_new, done_new = self.transmittance(alpha, t_carry[active], done[active])
            yield active, ids, w
            t_carry[active] = t_new
            done[active] = done_new

    def chunk_alpha(self, tiles: Tensor, r: int):
        """Return (ids [Ta, B], params [Ta, B, 6], local means [Ta, B, 2], alpha_raw [Ta, P, B], alpha [Ta, P, B])."""
        B = self.chunk
        start = self.tiles.offsets[tiles] + r * B
        pos = start[:, None] + torch.arange(B)
        inb = pos < (self.tiles.offsets[tiles] + self.tiles.counts[tiles])[:, None]
        ids = self.tiles.pair_ids[torch.where(inb, pos, torch.zeros_like(pos))]
        p = self.params[ids]  # [Ta, B, 6]
        local = p[..., :2] - self.centers[tiles][:, None, :]
        log_o = torch.where(inb, p[..., 5], torch.full_like(p[..., 5], _LOG_ZERO))
        coeffs = _quadratic_coeffs(local[..., 0], local[..., 1], p[..., 2], p[..., 3], p[..., 4], log_o)
        alpha_raw = torch.exp(torch.matmul(self.basis, coeffs.transpose(1, 2)))  # [Ta, P, B]
        alpha = alpha_raw.clamp_max(ALPHA_MAX)
        alpha = alpha * (alpha >= ALPHA_MIN)
        return ids, p, local, alpha_raw, alpha

    @staticmethod
    def transmittance(alpha: Tensor, t_carry: Tensor, done: Tensor):
        """Return (weights, T before each Gaussian, kept mask, new carry, new done) for one chunk."""
        one_minus = 1.0 - alpha
        t_incl = torch.cumprod(one_minus, dim=-1) * t_carry[..., None]
        keep = (t_incl >= TRANSMITTANCE_MIN) & ~done[..., None]
        t_excl = t_incl / one_minus
        weights = alpha * t_excl * keep
        t_new = torch.where(keep, t_incl, t_carry[..., None]).amin(-1)
        done_new = done | (t_incl[..., -1] < TRANSMITTANCE_MIN)
        return weights, t_excl, keep, t_new, done_new


def _to_image(tiled: Tensor, tiles: _Tiles, width: int, height: int) -> Tensor:
    """``[T, P, C]`` tile-major -> ``[H, W, C]``."""
    ts, C = tiles.tile_size, tiled.shape[-1]
    img = tiled.reshape(tiles.tiles_y, tiles.tiles_x, ts, ts, C).permute(0, 2, 1, 3, 4)
    return img.reshape(tiles.tiles_y * ts, tiles.tiles_x * ts, C)[:height, :width]


def _to_tiles(img: Tensor, tiles: _Tiles) -> Tensor:
    """``[H, W, C]`` -> ``[T, P, C]`` tile-major, zero-padded."""
    ts, C = tiles.tile_size, img.shape[-1]
    H, W = img.shape[:2]
    pad = img.new_zeros(tiles.tiles_y * ts, tiles.tiles_x * ts, C)
    pad[:H, :W] = img
    return pad.reshape(tiles.tiles_y, ts, tiles.tiles_x, ts, C).permute(0, 2, 1, 3, 4).reshape(-1, ts * ts, C)


class _RasterizeTiles(torch.autograd.Function):
    """Tiled front-to-back compositing with a hand-written, chunk-recomputing backward."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, background, tiles, width, height, chunk, max_elements):
        T = tiles.tiles_x * tiles.tiles_y
        params = torch.cat([means2d, conics, torch.log(opacities)[:, None]], dim=-1).detach()
        comp = _Compositor(tiles, params, chunk, max_elements)
        C = colors.shape[1]
        acc = colors.new_zeros(T, comp.P, C)
        t_final = colors.new_ones(T, comp.P)
        for group in comp.groups():
            t_carry = t_final[group]
            acc_g = acc[group]
            for active, ids, w in comp.weights(group, t_carry):
                acc_g[active] += torch.bmm(w, colors[ids])
            acc[group] = acc_g
            t_final[group] = t_carry
        render = acc + t_final[..., None] * background
        ctx.save_for_backward(params, colors, background, acc, t_final)
        ctx.tiles, ctx.chunk, ctx.max_elements, ctx.size = tiles, chunk, max_elements, (width, height)
        return _to_image(render, tiles, width, height), _to_image(1.0 - t_final[..., None], tiles, width, height)

    @staticmethod
    def backward(ctx, g_render, g_alpha):
        params, colors, background, acc, t_final = ctx.saved_tensors
        tiles, chunk = ctx.tiles, ctx.chunk
        comp = _Compositor(tiles, params, chunk, ctx.max_elements)
        gC = _to_tiles(g_render, tiles)  # [T, P, C]
        gA = _to_tiles(g_alpha, tiles)[..., 0]  # [T, P]
        s_all = (acc * gC).sum(-1)  # sum over the pixel's Gaussians of w_k (c_k . g)
        gT = (gC * background).sum(-1) - gA  # dL/dT_final
        tail = gT * t_final  # dL/dT_final * T_final
        N = params.shape[0]
        g_params = params.new_zeros(N, 6)  # grads w.r.t. mx, my, a, b, c, log opacity
        g_colors = torch.zeros_like(colors)
        g_background = (gC * t_final[..., None]).sum((0, 1))
        for group in comp.groups():
            t_carry = torch.ones(len(group), comp.P, dtype=params.dtype)
            done = torch.zeros_like(t_carry, dtype=torch.bool)
            prefix = torch.zeros_like(t_carry)
            n_rounds = -(-int(tiles.counts[group].max()) // chunk)
            active = torch.arange(len(group))
            for r in range(n_rounds):
                active = active[(tiles.counts[group[active]] > r * chunk) & ~done[active].all(-1)]
                if len(active) == 0:
                    break
                tg = group[active]
                ids, p, local, alpha_raw, alpha = comp.chunk_alpha(tg, r)
                w, t_excl, keep, t_new, done_new = comp.transmittance(alpha, t_carry[active], done[active])
                cols = colors[ids]  # [Ta, B, C]
                g_px = gC[tg]  # [Ta, P, C]
                g_colors.index_add_(0, ids.reshape(-1), torch.bmm(w.transpose(1, 2), g_px).reshape(-1, cols.shape[-1]))
                cg = torch.bmm(g_px, cols.transpose(1, 2))  # [Ta, P, B]: c_k . g at each pixel
                pref = torch.cumsum(w * cg, dim=-1) + prefix[active][..., None]
                after = s_all[tg][..., None] - pref + tail[tg][..., None]
                g_a = t_excl * cg - after / (1.0 - alpha)
                # alpha = exp(s) where it is neither clamped nor skipped nor past termination: ds = dalpha * alpha
                live = keep & (alpha_raw < ALPHA_MAX)
                g_s = torch.where(live, g_a * alpha, torch.zeros_like(g_a))
                g_coeffs = torch.matmul(comp.basis.T, g_s)  # [Ta, 6, B]
                g0, g1, g2, g3, g4, g5 = g_coeffs.unbind(1)
                m, n = local[..., 0], local[..., 1]
                a, b, c = p[..., 2], p[..., 3], p[..., 4]
                g_pair = torch.stack([
                    a * g3 + b * g4 - (a * m + b * n) * g5,
                    b * g3 + c * g4 - (c * n + b * m) * g5,
                    -0.5 * g0 + m * g3 - 0.5 * m * m * g5,
                    -g2 + n * g3 + m * g4 - m * n * g5,
                    -0.5 * g1 + n * g4 - 0.5 * n * n * g5,
                    g5,
                ], -1)
                g_params.index_add_(0, ids.reshape(-1), g_pair.reshape(-1, 6))
                prefix[active] = pref[..., -1]
                t_carry[active] = t_new
                done[active] = done_new
        g_means2d = g_params[:, :2]
        g_conics = g_params[:, 2:5]
        g_opac = g_params[:, 5] / params[:, 5].exp().clamp_min(1e-30)  # opacity 0: never composited, gradient 0
        return g_means2d, g_conics, g_opac, g_colors, g_background, None, None, None, None, None


def rasterize(
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
    tile_size: int = 4,
    chunk: int = 32,
    max_elements: int = 1 << 22,
) -> RasterOutput:
    """Return the differentiable rendering of Gaussians in one camera (tiled, CPU).

    Args:
        means: world-space centres. [N, 3]
        quats_wxyz: rotations, w first, not necessarily normalised. [N, 4]
        log_scales: log standard deviations. [N, 3]
        opacity_logits: pre-sigmoid opacities. [N]
        colors: RGB, or SH coefficients (DC first, coefficient-major) evaluated towards the camera. [N, 3] or [N, K, 3]
        world_to_camera: OpenCV-axes view matrix (tensor or array). [4, 4]
        K: intrinsics (tensor or array). [3, 3]
        width: image width in pixels.
        height: image height in pixels.
        near: Gaussians with camera-space ``z <= near`` are culled.
        far: Gaussians with ``z >= far`` are culled.
        features: extra per-Gaussian channels composited with the same weights (no background). [N, F]
        background: RGB added with the final transmittance; default black. [3]
        sh_degree: evaluate SH only up to this degree (default: all coefficients given).
        eps2d: added to the 2D covariance diagonal.
        tile_size: tile edge in pixels; 4 measured fastest on 2 CPU cores (benchmarks/RESULTS.md); 16 as on GPUs works.
        chunk: Gaussians per tile composited per step.
        max_elements: bound on (pixel, Gaussian) pairs held at once, forward and backward.

    Example:
        >>> out = rasterize(torch.tensor([[0.0, 0.0, 2.0]]), torch.tensor([[1.0, 0, 0, 0]]),
        ...     torch.log(torch.full((1, 3), 0.05)), torch.tensor([10.0]), torch.tensor([[1.0, 0.5, 0.0]]),
        ...     torch.eye(4), torch.tensor([[64.0, 0, 16.5], [0, 64, 16.5], [0, 0, 1]]), 33, 33)
        >>> out.rgb.shape  # the mean projects onto the centre of pixel (16, 16), where alpha is clamped at 0.99
        torch.Size([33, 33, 3])
        >>> [round(v, 4) for v in out.rgb[16, 16].tolist()], round(out.depth[16, 16].item(), 4)
        ([0.99, 0.495, 0.0], 2.0)
    """
    check_inputs(means, quats_wxyz, log_scales, opacity_logits, colors, features, width, height, near, far)
    if tile_size < 1 or chunk < 1:
        raise ConfigError(f"tile_size and chunk must be positive, got {tile_size} and {chunk}")
    dtype = means.dtype
    w2c, Kt = camera_tensors(world_to_camera, K, dtype, means.device)
    proj = project_gaussians(means, quats_wxyz, log_scales, w2c, Kt, width, height, near=near, far=far, eps2d=eps2d)
    means2d = proj.means2d
    if means2d.requires_grad:
        means2d.retain_grad()
    opac = torch.sigmoid(opacity_logits)
    stacked, bg = _colors_and_background(means, colors, features, proj.depths, w2c, background, sh_degree, dtype)
    bounds, visible, half = _footprints(means2d.detach(), proj.cov2d.detach(), opac.detach(), proj.in_range,
                                        width, height)
    tiles = _bin_tiles(bounds, visible, proj.depths.detach(), width, height, tile_size)
    render, alpha = _RasterizeTiles.apply(means2d, proj.conics, opac, stacked, bg, tiles, width, height, chunk,
                                          max_elements)
    radii = torch.where(visible[:, None], half, torch.zeros_like(half)).to(torch.int32)
    return _split_output(render, alpha, 0 if features is None else features.shape[1], means2d, radii, proj.depths,
                         visible)


@torch.no_grad()
def compositing_pairs(
    means: Tensor,  # [N, 3]
    quats_wxyz: Tensor,  # [N, 4]
    log_scales: Tensor,  # [N, 3]
    opacity_logits: Tensor,  # [N]
    world_to_camera: Tensor,  # [4, 4]
    K: Tensor,  # [3, 3]
    width: int,
    height: int,
    *,
    near: float = 0.01,
    far: float = 1e10,
    eps2d: float = EPS2D,
    tile_size: int = 4,
    chunk: int = 32,
    max_elements: int = 1 << 22,
) -> tuple[Tensor, Tensor, Tensor]:
    """Return ``(pixels, gaussians, weights)``: every non-zero alpha-compositing weight ``alpha_i T_i`` of the view,
    with its row-major pixel index and Gaussian index, exactly as :func:`rasterize` composites them (same tiles, depth
    order and cut-offs), so that summing ``weights * features[gaussians]`` per pixel gives its feature image.

    Only the Gaussians binned to a tile are evaluated there, so the cost follows the rendering's, not pixels x
    Gaussians.
    """
    dtype = means.dtype
    w2c, Kt = camera_tensors(world_to_camera, K, dtype, means.device)
    proj = project_gaussians(means, quats_wxyz, log_scales, w2c, Kt, width, height, near=near, far=far, eps2d=eps2d)
    opac = torch.sigmoid(opacity_logits)
    bounds, visible, _ = _footprints(proj.means2d, proj.cov2d, opac, proj.in_range, width, height)
    tiles = _bin_tiles(bounds, visible, proj.depths, width, height, tile_size)
    params = torch.cat([proj.means2d, proj.conics, torch.log(opac)[:, None]], dim=-1)
    comp = _Compositor(tiles, params, chunk, max_elements)
    t = torch.arange(tiles.tiles_x * tiles.tiles_y)
    ly, lx = torch.meshgrid(torch.arange(tile_size), torch.arange(tile_size), indexing="ij")
    px = (t % tiles.tiles_x)[:, None] * tile_size + lx.reshape(-1)[None]  # [T, P]
    py = (t // tiles.tiles_x)[:, None] * tile_size + ly.reshape(-1)[None]
    inside = (px < width) & (py < height)
    pixel = py * width + px
    rows, cols, vals = [], [], []
    for group in comp.groups():
        for active, ids, w in comp.weights(group, torch.ones(len(group), comp.P, dtype=dtype)):
            a, p, b = torch.nonzero(w, as_tuple=True)
            tg = group[active][a]
            ok = inside[tg, p]
            rows.append(pixel[tg, p][ok])
            cols.append(ids[a, b][ok])
            vals.append(w[a, p, b][ok])
    if not rows:
        empty = torch.zeros(0, dtype=torch.long)
        return empty, empty, torch.zeros(0, dtype=dtype)
    return torch.cat(rows), torch.cat(cols), torch.cat(vals)
