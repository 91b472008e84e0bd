"""Exemplar-based inpainting (Criminisi, Perez and Toyama 2004): fill a hole with patches copied from the known part
of the same image, front first, in the order of confidence x data term, so that the object's own texture and edges
continue across the hole instead of being smeared.

Why our own code: no maintained library does this here. OpenCV's exemplar inpainter (``cv2.xphoto.inpaint`` with
``INPAINT_FSR_BEST``/``FSR_FAST``) ships only in opencv-contrib, which cannot sit beside the project's
``opencv-python-headless`` wheel; the PyPI ``exemplar-based-inpainting`` package is a per-pixel Python loop (minutes
for a 512x512 grid); scikit-image's ``inpaint_biharmonic`` is smooth, not exemplar-based. The classic algorithm fills
one patch per iteration; here every iteration fills, at once, every front pixel that is a local maximum of the
priority within a patch-sized window and lies in the upper half of the front's priorities (a batched Criminisi
order), and the best source patch of all of them is found with three matrix products (masked sum of squared
differences), so a 2x2 grid of 256 px views fills in seconds on a CPU.

Sources are patches whose pixels are all outside the region to fill and whose centre is on the object (a pixel the
caller did not mask), taken from anywhere in the image: on the 2x2 grid of object-centred views, a view's hole is
filled from the same object as the other three views see it.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import torch
import torch.nn.functional as F
from scipy.ndimage import binary_fill_holes
from torch import Tensor

from ..errors import ConfigError
from .inpaint import Inpainter, OpenCVInpainter, outline_region


def _patch_offsets(half: int, width: int) -> np.ndarray:
    """Return the flat offsets ``[P * P]`` of a ``P = 2 * half + 1`` patch in an image ``width`` pixels wide."""
    dy, dx = np.mgrid[-half:half + 1, -half:half + 1]
    return (dy * width + dx).ravel()


def _window_max(x: Tensor, size: int) -> Tensor:
    """Return the maximum of ``x`` [H, W] over a ``size`` x ``size`` window around each pixel. [H, W]"""
    return F.max_pool2d(x[None, None], size, stride=1, padding=size // 2)[0, 0]


def exemplar_fill(image: np.ndarray, region: np.ndarray, known: Optional[np.ndarray] = None, *, patch: int = 7,
                  max_sources: int = 8000, seed: int = 0) -> Optional[np.ndarray]:
    """Return ``image`` with ``region`` filled by exemplar-based inpainting, or None if no source patch exists.

    Args:
        image: float RGB. [H, W, 3]
        region: bool, the pixels to fill. [H, W]
        known: bool, pixels that may be copied (default: all outside ``region``); a source patch lies wholly in
            ``known`` (or, with fewer than 16 such patches, wholly outside ``region`` with its centre in ``known``).
            [H, W]
        patch: odd patch side in pixels.
        max_sources: at most this many source patches (a seeded random subset beyond it).
        seed: seeds that subset.

    Example:
        >>> img = np.zeros((32, 32, 3), np.float32)
        >>> img[:, ::4] = 1.0  # vertical stripes
        >>> hole = np.zeros((32, 32), bool)
        >>> hole[12:20, 12:20] = True
        >>> out = exemplar_fill(np.where(hole[..., None], 0.5, img), hole, patch=5)
        >>> float(np.abs(out - img)[hole].mean()) < 0.05
        True
    """
    if patch < 3 or patch % 2 == 0:
        raise ConfigError(f"exemplar inpainter: patch must be odd and >= 3, got {patch}")
    region = np.asarray(region, bool)
    known = ~region if known is None else np.asarray(known, bool) & ~region
    h = patch // 2
    H, W = region.shape
    Wp = W + 2 * h
    # pad by half a patch: padded pixels count as unknown and are never copied nor compared
    img = np.pad(np.asarray(image, np.float32), ((h, h), (h, h), (0, 0)), mode="edge")
    todo = np.pad(region, h, constant_values=False)
    valid = np.pad(~region, h, constant_values=False)
    knownp = np.pad(known, h, constant_values=False)
    offsets = _patch_offsets(h, Wp)

    # sources: patches wholly on the object (known) if there are enough, else wholly outside the region with the
    # centre known; only known pixels of a source are ever copied, so the background never enters the hole
    def inside(m: np.ndarray) -> np.ndarray:
        return -_window_max(-torch.from_numpy(m.astype(np.float32)), patch).numpy() > 0.5

    src = np.flatnonzero(inside(knownp).ravel())
    if len(src) < 16:
        src = np.flatnonzero((inside(valid) & knownp).ravel())
    if len(src) == 0:
        return None
    copyable = knownp.ravel().copy()
    if len(src) > max_sources:
        src = np.sort(np.random.default_rng(seed).choice(src, max_sources, replace=False))
    flat = img.reshape(-1, 3)
    Q = torch.from_numpy(flat[src[:, None] + offsets].reshape(len(src), -1))  # [C, P * P * 3]
    Q2 = Q * Q

    conf = valid.astype(np.float32)
    filled_ok = valid.copy()
    box = torch.ones(1, 1, patch, patch) / patch ** 2
    sobel_x = torch.tensor([[-1.0, 0, 1], [-2, 0, 2], [-1, 0, 1]]) / 8
    kernels = torch.stack([sobel_x, sobel_x.T])[:, None]
    for _ in range(4 * (H + W)):  # each round fills at least one pixel; the bound only guards against a bug
        if not todo.any():
            break
        ok_t = torch.from_numpy(filled_ok.astype(np.float32))
        front = todo & (_window_max(ok_t, 3).numpy() > 0.5)
        # confidence: the mean confidence over the patch (Criminisi's C(p))
        c = F.conv2d(torch.from_numpy(conf)[None, None], box, padding=h)[0, 0].numpy()
        # data term: |isophote . normal| with the isophote of the strongest known gradient in the patch
        grey = torch.from_numpy(img.mean(axis=2))[None, None]
        g = F.conv2d(grey, kernels, padding=1)[0]  # [2, H, W]
        usable = -_window_max(-ok_t, 3) > 0.5  # the Sobel window is wholly filled
        mag = torch.where(usable, g.norm(dim=0), torch.zeros(()))
        _, idx = F.max_pool2d(mag[None, None], patch, stride=1, padding=h, return_indices=True)
        idx = idx[0, 0].reshape(-1)
        gx, gy = g[0].reshape(-1)[idx].reshape(mag.shape), g[1].reshape(-1)[idx].reshape(mag.shape)
        n = F.conv2d(ok_t[None, None], kernels, padding=1)[0]
        nn = n.norm(dim=0).clamp_min(1e-6)
        data = ((-gy * n[0] + gx * n[1]) / nn).abs().numpy()
        prio = np.where(front, c * (data + 1e-3), -1.0).astype(np.float32)
        local = prio >= _window_max(torch.from_numpy(prio), patch).numpy()
        fp = prio[front]
        pick = front & local & (prio >= np.median(fp))
        if not pick.any():
            pick = front & (prio >= fp.max())
        tgt = np.flatnonzero(pick.ravel())
        tidx = tgt[:, None] + offsets  # [B, P * P]
        T = torch.from_numpy(flat[tidx].reshape(len(tgt), -1))
        M = torch.from_numpy(np.repeat(filled_ok.ravel()[tidx], 3, axis=1).astype(np.float32))
        ssd = (M * T * T).sum(1, keepdim=True) - 2 * (M * T) @ Q.T + M @ Q2.T  # [B, C]
        best = src[ssd.argmin(dim=1).numpy()]
        sidx = best[:, None] + offsets
        write = todo.ravel()[tidx] & copyable[sidx]
        flat[tidx[write]] = flat[sidx[write]]
        cflat = conf.reshape(-1)
        cflat[tidx[write]] = np.repeat(c.ravel()[tgt][:, None], tidx.shape[1], axis=1)[write]
        done = tidx[write]
        todo.reshape(-1)[done] = False
        filled_ok.reshape(-1)[done] = True
        copyable[done] = True
    return img[h:h + H, h:h + W]


class ExemplarInpainter(Inpainter):
    """Exemplar-based inpainting (Criminisi et al. 2004, batched; see the module docstring), no weights, offline.

    What it can do: continue the texture and edges of the object's visible part (stripes, print, grain, a rim) into
    holes and occluded patches, copying from all four views of the grid. What it cannot do: invent what no visible
    patch shows, or know the 3D shape (a hidden handle stays missing); like ``opencv`` it fills only masked pixels
    inside the outline of the unmasked region (``extent="outline"``, :func:`~roodi_toolkit.pipeline.inpaint.outline_region`)
    and holes the unmasked region encloses, leaving the background far outside as rendered. An image without a single source patch is filled by the
    ``opencv`` inpainter instead.

    Args:
        patch: odd patch side in pixels; 0 picks it from the image size (7 from 96 px up, 5 from 40, else 3).
        extent: ``"outline"`` (default) or ``"all"``, as for ``opencv``.
        outline_radius: closing radius of the outline as a fraction of the shorter image side.
        max_sources: at most this many source patches per image (a seeded subset beyond; bounds time and memory).
        seed: seeds that subset.

    Example:
        >>> img = torch.zeros(1, 32, 32, 3)
        >>> img[0, ::4] = 1.0  # horizontal stripes
        >>> mask = torch.zeros(1, 32, 32, dtype=torch.bool)
        >>> mask[0, 10:22, 10:22] = True
        >>> out = ExemplarInpainter(extent="all").inpaint(img, mask)
        >>> float((out - img).abs()[mask].mean()) < 0.05
        True
    """

    name = "exemplar"

    def __init__(self, *, patch: int = 0, extent: str = "outline", outline_radius: float = 0.1,
                 max_sources: int = 8000, seed: int = 0) -> None:
        if patch and (patch < 3 or patch % 2 == 0):
            raise ConfigError(f"exemplar inpainter: patch must be 0 (auto) or odd and >= 3, got {patch}")
        if extent not in ("outline", "all"):
            raise ConfigError(f"exemplar inpainter: extent must be 'outline' or 'all', got {extent!r}")
        if not 0 < outline_radius < 1 or max_sources < 1:
            raise ConfigError(f"exemplar inpainter: need 0 < outline_radius < 1 and max_sources >= 1, got "
                              f"{outline_radius}, {max_sources}")
        self.patch = int(patch)
        self.extent = extent
        self.outline_radius = float(outline_radius)
        self.max_sources = int(max_sources)
        self.seed = int(seed)

    def patch_for(self, height: int, width: int) -> int:
        """Return the patch side used for an image of this size."""
        if self.patch:
            return self.patch
        side = min(height, width)
        return 7 if side >= 96 else 5 if side >= 40 else 3

    def fill_image(self, image: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Return one image ``[H, W, 3]`` with the part of ``mask`` [H, W] this inpainter fills filled."""
        if self.extent == "all":
            region = mask
        else:
            # holes wholly enclosed by the object are filled whatever their size (the outline's closing bridges
            # only narrow ones)
            region = outline_region(mask, self.outline_radius) | (binary_fill_holes(~mask) & mask)
        if not region.any():
            return image
        out = exemplar_fill(image, region, ~mask, patch=self.patch_for(*mask.shape), max_sources=self.max_sources,
                            seed=self.seed)
        if out is None:  # no patch of the image is wholly known: nothing to copy from
            out = OpenCVInpainter(extent="all").fill(torch.from_numpy(image)[None],
                                                     torch.from_numpy(region)[None], "")[0].numpy()
        return out

    def fill(self, images: Tensor, masks: Tensor, prompt: str) -> Tensor:
        out = images.clone()
        for b in range(images.shape[0]):
            out[b] = torch.from_numpy(self.fill_image(images[b].numpy().astype(np.float32), masks[b].numpy()))
        return out
