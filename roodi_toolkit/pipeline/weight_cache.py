"""Distillation's cache of compositing weights: each view's fixed sparse map from Gaussian features to pixels.

The geometry is frozen while features are distilled, so rendering a view's features is one sparse linear map
``W [H*W, N]`` (the alpha-compositing weights ``alpha_i T_i``), the same at every step. :class:`WeightCache` lists it
once per view and renders by a sparse product forwards and by its transpose backwards, for as many views as fit the
bytes it is given (the rest render every step). A map and its transpose are kept in CSR with 32-bit indices: 16 bytes
a (pixel, Gaussian) pair, half of what 64-bit indices hold, for the same product time (measured: 6M pairs times
16 features, 0.07-0.09 s either way), and scipy builds the transpose 20 times faster than torch's COO route.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.sparse as sp
import torch
from torch import Tensor

from ..cameras import Camera
from ..errors import ConfigError
from ..params import GaussianParams
from ..progress import ProgressFactory, null_progress
from ..render.renderer import Renderer, csr_tensor, has_compositing_weights, resolve_renderer


def compositing_weights(params: GaussianParams, camera: Camera, *, renderer: Renderer | None = None,
                        max_elements: int = 1 << 22) -> Tensor:
    """Return the sparse CSR ``[H*W, N]`` matrix of alpha-compositing weights of the Gaussians in ``camera``, from a
    renderer with that capability (:class:`~roodi_toolkit.render.renderer.CompositingWeights`; default the built-in
    one): ``W @ features`` is the rendered feature image, to float rounding.

    Raises:
        ConfigError: the renderer cannot list compositing weights.
    """
    renderer = resolve_renderer(renderer)
    if not has_compositing_weights(renderer):
        raise ConfigError(f"the {renderer.name or type(renderer).__name__} renderer cannot list compositing weights; "
                          "render the features instead (DistillConfig(cache_weights=False))")
    return renderer.compositing_weights(params, camera, max_elements=max_elements)


def map_bytes(w: Tensor) -> int:
    """Return the bytes a CSR map ``w`` and its transpose hold as :func:`both_ways` keeps them (16 a pair), or, for a
    map already kept so (32-bit indices), its own bytes."""
    if w.crow_indices().dtype == torch.int32:
        return sum(t.numel() * t.element_size() for t in (w.crow_indices(), w.col_indices(), w.values()))
    return 16 * w.values().numel() + 4 * (w.shape[0] + w.shape[1] + 2)


def both_ways(w: Tensor) -> tuple[Tensor, Tensor]:
    """Return the CSR map ``w`` and its transpose, both with 32-bit indices where they fit (else 64-bit)."""
    m = sp.csr_matrix((w.values().numpy(), w.col_indices().numpy(), w.crow_indices().numpy()), shape=tuple(w.shape))
    index = np.int32 if m.nnz < 2**31 - 1 and max(m.shape) < 2**31 - 1 else np.int64
    return csr_tensor(m, index), csr_tensor(m.T.tocsr(), index)


class _SparseRender(torch.autograd.Function):
    """``W @ f`` for a fixed sparse ``W`` with its transpose kept for the backward (CSR products both ways)."""

    @staticmethod
    def forward(ctx, features: Tensor, weights: Tensor, weights_t: Tensor) -> Tensor:  # type: ignore[override]
        ctx.weights_t = weights_t
        return weights @ features

    @staticmethod
    def backward(ctx, grad: Tensor):  # type: ignore[override]
        return ctx.weights_t @ grad, None, None


class WeightCache:
    """The maps of the views that fit a byte budget (see the module's docstring).

    Attributes:
        maps: view index -> (map ``[H*W, N]``, its transpose), CSR.
        bytes: what the maps hold.
    """

    def __init__(self) -> None:
        self.maps: dict[int, tuple[Tensor, Tensor]] = {}
        self.bytes = 0

    @classmethod
    def build(cls, params: GaussianParams, cameras: Mapping[int, Camera], room: float, *,
              renderer: Renderer | None = None, progress: ProgressFactory = null_progress) -> "WeightCache":
        """List the maps of ``cameras`` (view index -> camera) in order until the next would take the cache past
        ``room`` bytes; nothing is listed with ``room`` 0."""
        cache = cls()
        if room <= 0:
            return cache
        with progress(total=len(cameras), desc="compositing weights") as bar:
            for v, camera in cameras.items():
                w = compositing_weights(params, camera, renderer=renderer)
                if cache.bytes + map_bytes(w) > room:
                    break  # this view and the rest render every step
                cache.maps[v] = both_ways(w)
                cache.bytes += sum(map_bytes(m) for m in cache.maps[v])
                bar.update(1)
        return cache

    def __contains__(self, view: int) -> bool:
        return view in self.maps

    def __len__(self) -> int:
        return len(self.maps)

    def render(self, view: int, features: Tensor) -> Tensor:
        """Return the features ``[N, F]`` composited in ``view``: ``[H*W, F]``, differentiable in ``features``."""
        return _SparseRender.apply(features, *self.maps[view])
