"""Distillation's cache of compositing weights: each view's fixed sparse map from Gaussian features to pixels.

The geometry is frozen while features are distilled, so rendering a view's features is one sparse linear map
``W [H*W, N]`` (the alpha-compositing weights ``alpha_i T_i``), the same at every step. :class:`WeightCache` lists it
once per view and renders by a sparse product forwards and by its transpose backwards, for as many views as fit the
bytes it is given (the rest render every step). A map and its transpose are kept in CSR with 32-bit indices: 16 bytes
a (pixel, Gaussian) pair, half of what 64-bit indices hold, for the same product time (measured: 6M pairs times
16 features, 0.07-0.09 s either way), and scipy builds the transpose 20 times faster than torch's COO route. The
products are a compiled loop of this module's (:func:`csr_product`), not PyTorch's: its [N, 16] backward product
faulted in fresh pages for its temporaries on every step (the extraction's system time fell from about 30 s to 12).
"""

from __future__ import annotations

from typing import Mapping

import numba as nb
import numpy as np
import scipy.sparse as sp
import torch
from torch import Tensor

from ..cameras import Camera
from ..errors import ConfigError
from ..params import GaussianParams
from ..progress import ProgressFactory, null_progress
from ..render.cores import set_workers
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


@nb.njit(parallel=True, cache=True, nogil=True)
def _csr_product(indptr, indices, data, dense, out):  # pragma: no cover - compiled
    """Write ``M @ dense`` into ``out`` [rows, F] for the CSR matrix ``M`` (``indptr``, ``indices``, ``data``): each
    row's entries added in order, every row written (zeros where it has none)."""
    F = dense.shape[1]
    for i in nb.prange(out.shape[0]):
        for f in range(F):
            out[i, f] = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            w = data[k]
            j = indices[k]
            for f in range(F):
                out[i, f] += w * dense[j, f]


def csr_product(m: Tensor, dense: Tensor) -> Tensor:
    """Return ``m @ dense`` for a CSR tensor ``m`` [R, K] and a dense ``dense`` [K, F], into a fresh numpy array.

    Written for the cache: PyTorch's CSR product made its [N, 16] result (the backward's, at 650k Gaussians) through
    temporaries of its own, 20k page faults and 35 ms of system time a call on two threads (38 ms in all); numpy
    allocates large arrays on huge pages."""
    d = dense.detach().contiguous().numpy()
    out = np.empty((m.shape[0], d.shape[1]), d.dtype)
    set_workers()
    _csr_product(m.crow_indices().numpy(), m.col_indices().numpy(), m.values().numpy(), d, out)
    return torch.from_numpy(out)


class _SparseRender(torch.autograd.Function):
    """``W @ f`` for a fixed sparse ``W`` with its transpose kept for the backward (CSR products both ways)."""

    @staticmethod
    def forward(ctx, features: Tensor, weights: Tensor, weights_t: Tensor) -> Tensor:  # type: ignore[override]
        ctx.weights_t = weights_t
        return csr_product(weights, features)

    @staticmethod
    def backward(ctx, grad: Tensor):  # type: ignore[override]
        return csr_product(ctx.weights_t, grad), None, None


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
