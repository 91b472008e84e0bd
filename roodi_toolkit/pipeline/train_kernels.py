"""Compiled kernels of a training step besides the renderer: the D-SSIM loss and the MCMC position noise.

Once the renderer is compiled (:mod:`roodi_toolkit.render.kernels`), the rest of a training step is a few passes of
torch operations over every Gaussian and every pixel, each with its own temporaries: on the lego model at 200x200
(60k Gaussians) kornia's SSIM took 19 ms forward and backward and the position noise 11-13 ms per step, CPU time
on one thread (``benchmarks/bench_train_step.py`` measures them against the plain versions). Here each is one
compiled pass (numba, cached beside this file, as the renderer's kernels):

- :func:`ssim` is kornia's ``metrics.ssim`` (the same Gaussian window, sigma 1.5, reflect padding, C1, C2 and eps),
  averaged over the image, as a torch autograd function whose backward is written out (the moments' adjoints through
  the transposed separable blur). It matches kornia to float rounding, value and gradient
  (``tests/pipeline/test_train_kernels.py``); :func:`roodi_toolkit.imaging.ssim` (kornia) stays the metric every
  report uses.
- :func:`covariance_noise` is ``Sigma_i n_i`` of 3DGS-MCMC's position noise without building the ``[N, 3, 3]``
  covariances: ``R (s^2 * (R^T n))`` per Gaussian.

Per-pixel sums run in float64 whatever the images' dtype.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import torch
from torch import Tensor

from ..imaging import ssim as kornia_ssim
from ..render.cores import set_workers

SSIM_SIGMA = 1.5
"""kornia's (and the SSIM paper's) Gaussian window: sigma 1.5 whatever the window's size."""
SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2
SSIM_EPS = 1e-12
"""kornia's constants for images in [0, 1] (``max_val`` 1): C1 = (0.01 L)^2, C2 = (0.03 L)^2, eps added to the
denominator."""


def gaussian_window(size: int, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """Return the normalised 1D Gaussian window ``[size]`` (float64) as kornia's ``get_gaussian_kernel1d`` samples it
    (centred at ``size // 2``; ``size`` odd)."""
    x = np.arange(size, dtype=np.float64) - size // 2
    w = np.exp(-(x ** 2) / (2.0 * sigma ** 2))
    return w / w.sum()


@nb.njit(cache=True, nogil=True)
def _reflect(i, n):  # pragma: no cover - compiled
    """Return the index ``i`` mirrored into [0, n) without repeating the edge (torch's ``reflect`` padding)."""
    if i < 0:
        return -i
    if i >= n:
        return 2 * n - 2 - i
    return i


@nb.njit(cache=True, nogil=True)
def _blur_rows(src, window, out):  # pragma: no cover - compiled
    """``out [M, H, W]``: each row of ``src`` convolved with ``window`` (reflect padding). The tap loop is outermost,
    so that LLVM vectorises the loop along the row."""
    m, h, w = src.shape
    r = window.shape[0] // 2
    padded = np.empty(w + 2 * r)
    for c in range(m):
        for y in range(h):
            for x in range(w + 2 * r):
                padded[x] = src[c, y, _reflect(x - r, w)]
            row = out[c, y]
            row[:] = 0.0
            for t in range(2 * r + 1):
                wt = window[t]
                for x in range(w):
                    row[x] += wt * padded[x + t]


@nb.njit(cache=True, nogil=True)
def _blur_columns(src, window, out):  # pragma: no cover - compiled
    """``out [M, H, W]``: each column of ``src`` convolved with ``window`` (reflect padding)."""
    m, h, w = src.shape
    r = window.shape[0] // 2
    for c in range(m):
        for y in range(h):
            row = out[c, y]
            row[:] = 0.0
            for t in range(2 * r + 1):
                wt = window[t]
                above = src[c, _reflect(y + t - r, h)]
                for x in range(w):
                    row[x] += wt * above[x]


@nb.njit(cache=True, nogil=True)
def _blur(src, window, out):  # pragma: no cover - compiled
    """``out [M, H, W] = G(src [M, H, W])``: the separable Gaussian blur with reflect padding, rows then columns
    (kornia's ``filter2d_separable`` order)."""
    tmp = np.empty(src.shape)
    _blur_rows(src, window, tmp)
    _blur_columns(tmp, window, out)


@nb.njit(cache=True, nogil=True)
def _blur_transposed(src, window, out):  # pragma: no cover - compiled
    """``out [M, H, W] = G^T(src [M, H, W])``: the adjoint of :func:`_blur`, the column pass's adjoint then the row
    pass's, each folding the padding back onto the pixels it mirrors."""
    m, h, w = src.shape
    r = window.shape[0] // 2
    taps = 2 * r + 1
    tmp = np.empty((m, h, w))
    # columns: tmp[yy] = sum of window[t] * src[y] over the (y, t) with reflect(y + t - r) == yy, that is over the
    # padded rows k that reflect onto yy: k = yy, -yy (top padding), 2h - 2 - yy (bottom padding)
    for c in range(m):
        for yy in range(h):
            row = tmp[c, yy]
            row[:] = 0.0
            for side in range(3):
                if side == 0:
                    k = yy
                elif side == 1:
                    k = -yy
                    if yy == 0 or k < -r:
                        continue
                else:
                    k = 2 * h - 2 - yy
                    if k < h or k > h - 1 + r:
                        continue
                for t in range(taps):
                    y = k + r - t
                    if 0 <= y < h:
                        wt = window[t]
                        below = src[c, y]
                        for x in range(w):
                            row[x] += wt * below[x]
    # rows: scatter into a padded row, then fold the padding back
    padded = np.empty(w + 2 * r)
    for c in range(m):
        for y in range(h):
            padded[:] = 0.0
            row = tmp[c, y]
            for t in range(taps):
                wt = window[t]
                for x in range(w):
                    padded[x + t] += wt * row[x]
            dest = out[c, y]
            for x in range(w):
                dest[x] = padded[x + r]
            for p in range(r):
                dest[r - p] += padded[p]
            for p in range(w + r, w + 2 * r):
                dest[2 * w - 2 - (p - r)] += padded[p]


@nb.njit(cache=True, nogil=True)
def _ssim_forward(x, y, window, c1, c2, eps, moments):  # pragma: no cover - compiled
    """Fill ``moments [5, C, H, W]`` (mu_x, mu_y, E[x^2], E[y^2], E[xy]) of ``x``, ``y`` ``[C, H, W]`` and return
    the sum of their SSIM map. The row pass forms the five products from the padded rows of ``x`` and ``y``."""
    ch, h, w = x.shape
    r = window.shape[0] // 2
    tmp = np.empty((5, ch, h, w))
    pa = np.empty(w + 2 * r)
    pb = np.empty(w + 2 * r)
    for c in range(ch):
        for i in range(h):
            for j in range(w + 2 * r):
                pa[j] = x[c, i, _reflect(j - r, w)]
                pb[j] = y[c, i, _reflect(j - r, w)]
            r0, r1, r2, r3, r4 = tmp[0, c, i], tmp[1, c, i], tmp[2, c, i], tmp[3, c, i], tmp[4, c, i]
            r0[:] = 0.0
            r1[:] = 0.0
            r2[:] = 0.0
            r3[:] = 0.0
            r4[:] = 0.0
            for t in range(2 * r + 1):
                wt = window[t]
                for j in range(w):
                    a = pa[j + t]
                    b = pb[j + t]
                    r0[j] += wt * a
                    r1[j] += wt * b
                    r2[j] += wt * (a * a)
                    r3[j] += wt * (b * b)
                    r4[j] += wt * (a * b)
    _blur_columns(tmp.reshape((5 * ch, h, w)), window, moments.reshape((5 * ch, h, w)))
    total = 0.0
    for c in range(ch):
        for i in range(h):
            for j in range(w):
                mx = moments[0, c, i, j]
                my = moments[1, c, i, j]
                num = (2.0 * mx * my + c1) * (2.0 * (moments[4, c, i, j] - mx * my) + c2)
                den = (mx * mx + my * my + c1) * ((moments[2, c, i, j] - mx * mx) + (moments[3, c, i, j] - my * my)
                                                  + c2)
                total += num / (den + eps)
    return total


@nb.njit(cache=True, nogil=True)
def _ssim_backward(x, y, window, c1, c2, eps, moments, scale, grad):  # pragma: no cover - compiled
    """``grad [C, H, W]``: the gradient of ``scale * sum(SSIM map)`` with respect to ``x``."""
    ch, h, w = x.shape
    adj = np.empty((3, ch, h, w))  # d/d mu_x, d/d E[x^2], d/d E[xy] of the scaled map's sum
    for c in range(ch):
        for i in range(h):
            for j in range(w):
                mx = moments[0, c, i, j]
                my = moments[1, c, i, j]
                a1 = 2.0 * mx * my + c1
                a2 = 2.0 * (moments[4, c, i, j] - mx * my) + c2
                b1 = mx * mx + my * my + c1
                b2 = (moments[2, c, i, j] - mx * mx) + (moments[3, c, i, j] - my * my) + c2
                d = b1 * b2 + eps
                s = a1 * a2 / d
                adj[0, c, i, j] = scale * (2.0 * my * (a2 - a1) - s * 2.0 * mx * (b2 - b1)) / d
                adj[1, c, i, j] = scale * (-s * b1 / d)
                adj[2, c, i, j] = scale * (2.0 * a1 / d)
    back = np.empty((3, ch, h, w))
    _blur_transposed(adj.reshape((3 * ch, h, w)), window, back.reshape((3 * ch, h, w)))
    for c in range(ch):
        for i in range(h):
            for j in range(w):
                grad[c, i, j] = back[0, c, i, j] + 2.0 * np.float64(x[c, i, j]) * back[1, c, i, j] \
                    + np.float64(y[c, i, j]) * back[2, c, i, j]


class _SSIM(torch.autograd.Function):
    """Mean SSIM of two channels-last images; the gradient flows to the first."""

    @staticmethod
    def forward(ctx, a, b, window_size):  # type: ignore[override]
        x = np.ascontiguousarray(a.detach().permute(2, 0, 1).numpy())  # [C, H, W]
        y = np.ascontiguousarray(b.detach().permute(2, 0, 1).numpy())
        window = gaussian_window(window_size)
        moments = np.empty((5, *x.shape))
        total = _ssim_forward(x, y, window, SSIM_C1, SSIM_C2, SSIM_EPS, moments)
        ctx.state = (x, y, window, moments)
        return torch.tensor(total / x.size, dtype=a.dtype)

    @staticmethod
    def backward(ctx, g):  # type: ignore[override]
        x, y, window, moments = ctx.state
        grad = np.empty(x.shape)
        _ssim_backward(x, y, window, SSIM_C1, SSIM_C2, SSIM_EPS, moments, float(g) / x.size, grad)
        return torch.from_numpy(grad.transpose(1, 2, 0)).to(g.dtype), None, None


def ssim(a: Tensor, b: Tensor, window: int = 11) -> Tensor:
    """Return the mean SSIM of two images, differentiable with respect to ``a`` (``kornia.metrics.ssim``'s value).

    The window is shrunk to the images' short side (kept odd), as :func:`roodi_toolkit.imaging.ssim` does; ``b`` is
    the reference (a photo: no gradient flows to it, so it must not require one).

    Args:
        a: the rendering in [0, 1]. [H, W, C]
        b: the reference, the same shape. [H, W, C]
        window: the Gaussian window's side (3DGS: 11).

    Example:
        >>> x = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(0))
        >>> round(float(ssim(x, x)), 6)
        1.0
    """
    if a.shape != b.shape or a.ndim != 3:
        raise ValueError(f"ssim needs two [H, W, C] images of one shape, got {list(a.shape)} and {list(b.shape)}")
    if b.requires_grad:
        raise ValueError("ssim's reference image must not require a gradient")
    if a.device.type != "cpu" or b.device.type != "cpu":
        return kornia_ssim(a, b, window)
    win = min(window, min(a.shape[:2]))
    win = win if win % 2 == 1 else win - 1
    return _SSIM.apply(a, b, max(win, 1))


@nb.njit(parallel=True, cache=True, nogil=True)
def _covariance_times(quats, log_scales, vectors, out):  # pragma: no cover - compiled
    """``out[i] = R_i diag(exp(2 log_scales[i])) R_i^T vectors[i]``, ``R_i`` the rotation of the (normalised)
    quaternion ``quats[i]`` (w, x, y, z)."""
    for i in nb.prange(quats.shape[0]):
        qw = np.float64(quats[i, 0])
        qx = np.float64(quats[i, 1])
        qy = np.float64(quats[i, 2])
        qz = np.float64(quats[i, 3])
        norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        norm = max(norm, 1e-12)  # kornia's normalisation: q / max(|q|, eps)
        qw /= norm
        qx /= norm
        qy /= norm
        qz /= norm
        r00 = 1.0 - 2.0 * (qy * qy + qz * qz)
        r01 = 2.0 * (qx * qy - qw * qz)
        r02 = 2.0 * (qx * qz + qw * qy)
        r10 = 2.0 * (qx * qy + qw * qz)
        r11 = 1.0 - 2.0 * (qx * qx + qz * qz)
        r12 = 2.0 * (qy * qz - qw * qx)
        r20 = 2.0 * (qx * qz - qw * qy)
        r21 = 2.0 * (qy * qz + qw * qx)
        r22 = 1.0 - 2.0 * (qx * qx + qy * qy)
        v0 = np.float64(vectors[i, 0])
        v1 = np.float64(vectors[i, 1])
        v2 = np.float64(vectors[i, 2])
        u0 = (r00 * v0 + r10 * v1 + r20 * v2) * math.exp(2.0 * np.float64(log_scales[i, 0]))
        u1 = (r01 * v0 + r11 * v1 + r21 * v2) * math.exp(2.0 * np.float64(log_scales[i, 1]))
        u2 = (r02 * v0 + r12 * v1 + r22 * v2) * math.exp(2.0 * np.float64(log_scales[i, 2]))
        out[i, 0] = r00 * u0 + r01 * u1 + r02 * u2
        out[i, 1] = r10 * u0 + r11 * u1 + r12 * u2
        out[i, 2] = r20 * u0 + r21 * u1 + r22 * u2


def covariance_noise(quats_wxyz: Tensor, log_scales: Tensor, vectors: Tensor) -> Tensor:
    """Return ``Sigma_i v_i`` ``[N, 3]`` for each Gaussian's covariance ``Sigma_i = R diag(s^2) R^T``.

    Args:
        quats_wxyz: rotations, normalised here. [N, 4]
        log_scales: log of the three scales. [N, 3]
        vectors: one vector per Gaussian. [N, 3]
    """
    out = np.empty(tuple(vectors.shape), dtype=vectors.detach().numpy().dtype)
    set_workers()
    _covariance_times(quats_wxyz.detach().contiguous().numpy(), log_scales.detach().contiguous().numpy(),
                      vectors.detach().contiguous().numpy(), out)
    return torch.from_numpy(out)
