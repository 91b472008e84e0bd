"""The renderer plugin interface: :class:`~roodi_toolkit.params.GaussianParams` + a camera -> images.

A renderer is a class registered under the entry-point group ``roodi_toolkit.renderers``; the built-in ones register
exactly as a third-party one does (this package's ``setup.cfg``), e.g. the ``gsplat`` CUDA renderer in
``plugins/roodi-gsplat``::

    [options.entry_points]
    roodi_toolkit.renderers =
        numba = roodi_toolkit.render.renderer:NumbaRenderer
        torch = roodi_toolkit.render.renderer:TorchRenderer

``numba`` (:class:`NumbaRenderer`, compiled kernels, all cores) is the default; ``torch`` (:class:`TorchRenderer`,
plain torch tensor code with autograd-free hand-written backward) is kept beside it as the reference it is tested
against.

A renderer class subclasses :class:`Renderer`: ``available()`` says whether it can run here (and why not), and
``render(params, camera, ...)`` returns a :class:`RenderOutput` (channels-last images, differentiable w.r.t. every
tensor in ``params``; ``params.features`` are rendered when set).

Optional capabilities: a renderer that can list the alpha-compositing weights of a view as a sparse matrix implements
``compositing_weights(params, camera)`` (:class:`CompositingWeights`; both built-in ones do), which distillation
caches when the weights fit its memory bound; one that can composite features alone implements
``render_features(params, features, camera)`` (:class:`FeatureRenderer`; the ``numba`` one does), which
distillation and the click segmenter use through :func:`render_features`, and the full ``render`` otherwise.

Every pipeline stage that renders takes ``renderer: Renderer | None = None``; :func:`resolve_renderer` turns that
(or a registered name) into an instance, None meaning the default :class:`NumbaRenderer`.
"""

from __future__ import annotations

import warnings
from abc import ABC, abstractmethod
from typing import Any, Optional, Protocol, Sequence, runtime_checkable

import numpy as np
import scipy.sparse as sp
import torch
from torch import Tensor

from ..cameras import Camera
from ..errors import PluginError
from ..gaussians import GaussianCloud
from ..params import GaussianParams
from ..plugins import discover, instantiate
from . import fast as _fast
from . import rasterizer as _rasterizer
from .rasterizer import RasterOutput

RenderOutput = RasterOutput
"""What every renderer returns: rgb [H, W, 3], alpha [H, W, 1], depth [H, W, 1] (expected depth), features
[H, W, F] or None, means2d [N, 2] (see ``means2d_grad()``), radii [N, 2], depths [N], visible [N]."""


class Renderer(ABC):
    """Base class of renderer plugins. Subclasses take their options as keyword arguments of ``__init__``."""

    name: str = ""

    @classmethod
    def available(cls) -> tuple[bool, str]:
        """Return (True, "") if this renderer can run on this machine, else (False, why not and what to do)."""
        return True, ""

    @abstractmethod
    def render(self, params: GaussianParams, camera: Camera, *, background: Optional[Sequence[float]] = None,
               sh_degree: Optional[int] = None) -> RenderOutput:
        """Return the rendering of ``params`` seen by ``camera``.

        Args:
            params: the Gaussians (any tensor may require grad); ``params.features`` ``[N, F]`` are composited with
                the same weights into ``RenderOutput.features`` when set.
            camera: the view; ``near``/``far`` cull Gaussians by camera-space depth.
            background: RGB behind the Gaussians (default black); not applied to depth or features.
            sh_degree: evaluate SH only up to this degree (default: all coefficients given).
        """


@runtime_checkable
class CompositingWeights(Protocol):
    """The optional capability of a renderer to list a view's alpha-compositing weights (see the module doc)."""

    def compositing_weights(self, params: GaussianParams, camera: Camera, *,
                            max_elements: Optional[int] = None) -> Tensor:
        """Return the sparse CSR ``[H*W, N]`` matrix of ``alpha_i T_i`` per pixel (row-major) and Gaussian."""


class NumbaRenderer(Renderer):
    """The default differentiable CPU renderer: compiled kernels on all the threads torch may use
    (:func:`roodi_toolkit.render.fast.rasterize_fast`), the same images and gradients as :class:`TorchRenderer`.

    Example:
        >>> from roodi_toolkit.cameras import look_at, intrinsics_from_fov
        >>> cloud = GaussianCloud.from_activated(np.zeros((1, 3)), scales=np.full((1, 3), 0.2),
        ...                                      opacities=np.array([0.99]), rgb=np.array([[1.0, 0.0, 0.0]]))
        >>> cam = Camera(look_at([0, -3, 0], [0, 0, 0]), intrinsics_from_fov(0.8, 33, 33), 33, 33)
        >>> out = NumbaRenderer().render(GaussianParams.from_cloud(cloud), cam, background=(0, 0, 1))
        >>> [round(v, 3) for v in out.rgb[16, 16].tolist()], round(out.depth[16, 16].item(), 3)
        ([0.99, 0.0, 0.01], 3.0)
    """

    name = "numba"

    def __init__(self, *, tile_size: Optional[int] = None) -> None:
        self.tile_size = tile_size  # None: each call's own (``fast.TILE_SIZE``, features alone ``FEATURE_TILE_SIZE``)

    def _tile(self, default: int) -> int:
        return default if self.tile_size is None else self.tile_size

    def render(self, params: GaussianParams, camera: Camera, *, background: Optional[Sequence[float]] = None,
               sh_degree: Optional[int] = None) -> RenderOutput:
        dtype = params.dtype
        bg = None if background is None else torch.as_tensor(background, dtype=dtype)
        return _fast.rasterize_fast(
            params.means, params.quats_wxyz, params.log_scales, params.opacity_logits, params.colors,
            camera.world_to_camera, camera.K, camera.width, camera.height, near=camera.near, far=camera.far,
            features=params.features, background=bg, sh_degree=sh_degree,
            tile_size=self._tile(_fast.TILE_SIZE))

    def render_features(self, params: GaussianParams, features: Tensor, camera: Camera) -> tuple[Tensor, Tensor]:
        """Return the composited ``features`` ``[N, F]`` ``[H, W, F]`` and the alpha ``[H, W, 1]`` of ``params`` in
        ``camera`` (differentiable), without colours or depth: the optional :class:`FeatureRenderer` capability."""
        return _fast.rasterize_features(
            params.means, params.quats_wxyz, params.log_scales, params.opacity_logits, features,
            camera.world_to_camera, camera.K, camera.width, camera.height, near=camera.near, far=camera.far,
            tile_size=self._tile(_fast.FEATURE_TILE_SIZE))

    def compositing_weights(self, params: GaussianParams, camera: Camera, *,
                            max_elements: Optional[int] = None) -> Tensor:
        """Return the sparse CSR ``[H*W, N]`` matrix of the alpha-compositing weights of ``params`` in ``camera``
        (``W @ features`` is the rendered feature image, to float rounding). It holds one entry per blended
        (pixel, Gaussian): at 1000 px and hundreds of Gaussians per pixel that is gigabytes, so prefer rendering
        features and their gradients (what distillation and the click segmenter do). ``max_elements`` is accepted
        for the interface and not needed: the kernels hold no more than the result."""
        view = _fast.make_view(camera.world_to_camera, camera.K, camera.width, camera.height, near=camera.near,
                               far=camera.far, tile=self._tile(_fast.TILE_SIZE))
        arrays = [t.detach().contiguous().numpy() for t in (params.means, params.quats_wxyz, params.log_scales,
                                                              params.opacity_logits)]
        proj = _fast.project(*arrays, np.zeros((len(params), 3), arrays[0].dtype), 0, view)
        pixels, ids, weights = _fast.compositing_pairs(_fast.bin_gaussians(proj, view), proj, view)
        coo = torch.sparse_coo_tensor(torch.stack([torch.from_numpy(pixels), torch.from_numpy(ids.astype(np.int64))]),
                                      torch.from_numpy(weights), (camera.height * camera.width, len(params)),
                                      check_invariants=False)
        return to_csr(coo)


@runtime_checkable
class FeatureRenderer(Protocol):
    """The optional capability of a renderer to composite per-Gaussian features alone (no colours, no depth)."""

    def render_features(self, params: GaussianParams, features: Tensor, camera: Camera) -> tuple[Tensor, Tensor]:
        """Return the composited features ``[H, W, F]`` and the alpha ``[H, W, 1]`` (differentiable)."""


def render_features(renderer: Renderer, params: GaussianParams, features: Tensor,
                    camera: Camera) -> tuple[Tensor, Tensor]:
    """Return the composited ``features`` ``[N, F]`` ``[H, W, F]`` and the alpha ``[H, W, 1]`` of ``params`` in
    ``camera`` with ``renderer``: through its :class:`FeatureRenderer` capability when it has one, else from a full
    rendering with the features attached."""
    if isinstance(renderer, FeatureRenderer):
        return renderer.render_features(params, features, camera)
    out = renderer.render(params.with_features(features), camera)
    return out.features, out.alpha


class TorchRenderer(Renderer):
    """The reference differentiable CPU renderer in torch tensor code (:func:`roodi_toolkit.render.rasterizer.
    rasterize`), kept beside the default :class:`NumbaRenderer` that the tests compare with it.

    Example:
        >>> from roodi_toolkit.cameras import look_at, intrinsics_from_fov
        >>> cloud = GaussianCloud.from_activated(np.zeros((1, 3)), scales=np.full((1, 3), 0.2),
        ...                                      opacities=np.array([0.99]), rgb=np.array([[1.0, 0.0, 0.0]]))
        >>> cam = Camera(look_at([0, -3, 0], [0, 0, 0]), intrinsics_from_fov(0.8, 33, 33), 33, 33)
        >>> out = TorchRenderer().render(GaussianParams.from_cloud(cloud), cam, background=(0, 0, 1))
        >>> [round(v, 3) for v in out.rgb[16, 16].tolist()], round(out.depth[16, 16].item(), 3)
        ([0.99, 0.0, 0.01], 3.0)
        >>> isinstance(TorchRenderer(), CompositingWeights)
        True
    """

    name = "torch"

    def __init__(self, *, tile_size: int = 4, chunk: int = 32, max_elements: int = 1 << 22) -> None:
        self.tile_size = tile_size
        self.chunk = chunk
        self.max_elements = max_elements

    def render(self, params: GaussianParams, camera: Camera, *, background: Optional[Sequence[float]] = None,
               sh_degree: Optional[int] = None) -> RenderOutput:
        dtype = params.dtype
        bg = None if background is None else torch.as_tensor(background, dtype=dtype)
        return _rasterizer.rasterize(
            params.means, params.quats_wxyz, params.log_scales, params.opacity_logits, params.colors,
            torch.as_tensor(camera.world_to_camera, dtype=dtype), torch.as_tensor(camera.K, dtype=dtype),
            camera.width, camera.height, near=camera.near, far=camera.far, features=params.features, background=bg,
            sh_degree=sh_degree, tile_size=self.tile_size, chunk=self.chunk, max_elements=self.max_elements)

    def compositing_weights(self, params: GaussianParams, camera: Camera, *,
                            max_elements: Optional[int] = None) -> Tensor:
        """Return the sparse CSR ``[H*W, N]`` matrix of the alpha-compositing weights of ``params`` in ``camera``.

        Row ``p`` holds ``alpha_i T_i`` of every Gaussian that contributes to pixel ``p`` (row-major), computed by
        the rasterizer's own tiles (:func:`roodi_toolkit.render.rasterizer.compositing_pairs`), so ``W @ features``
        is the feature image :meth:`render` returns, to float rounding. ``max_elements`` (default this renderer's)
        bounds the (pixel, Gaussian) pairs held at once.
        """
        dtype = params.dtype
        rows, cols, vals = _rasterizer.compositing_pairs(
            params.means.detach(), params.quats_wxyz.detach(), params.log_scales.detach(),
            params.opacity_logits.detach(), torch.as_tensor(camera.world_to_camera, dtype=dtype),
            torch.as_tensor(camera.K, dtype=dtype), camera.width, camera.height, near=camera.near, far=camera.far,
            tile_size=self.tile_size, chunk=self.chunk,
            max_elements=self.max_elements if max_elements is None else max_elements)
        coo = torch.sparse_coo_tensor(torch.stack([rows, cols]), vals, (camera.height * camera.width, len(params)),
                                      check_invariants=False)
        return to_csr(coo)


def to_csr(coo: Tensor) -> Tensor:
    """Return a sparse COO matrix in CSR form (64-bit indices, columns sorted in each row, repeated entries summed:
    what ``coo.coalesce().to_sparse_csr()`` gives). scipy sorts the entries: 0.10 s for a 400 px view's 4M pairs,
    where torch's coalesce takes 0.43 s."""
    idx = coo._indices().numpy()
    m = sp.csr_matrix((coo._values().detach().numpy(), (idx[0], idx[1])), shape=tuple(coo.shape))
    m.sort_indices()
    return csr_tensor(m)


def csr_tensor(m: Any, index_dtype: Any = np.int64) -> Tensor:
    """Return a scipy CSR matrix ``m`` as a torch sparse CSR tensor sharing its values, with ``index_dtype`` indices
    (torch warns that CSR is beta; the products used here are stable)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return torch.sparse_csr_tensor(torch.from_numpy(m.indptr.astype(index_dtype)),
                                       torch.from_numpy(m.indices.astype(index_dtype)), torch.from_numpy(m.data),
                                       tuple(m.shape))


def renderer_names() -> list[str]:
    """Return the names of the registered renderers (loaded or not)."""
    return [spec.name for spec in discover("renderers")]


def get_renderer(name: str = "numba", **options: Any) -> Renderer:
    """Return an instance of the renderer registered as ``name``, built with ``options``.

    Raises:
        PluginError: unknown name, failed import, not a :class:`Renderer`, or not available on this machine (the
            message says why, e.g. no CUDA).
    """
    return instantiate("renderers", name, Renderer, **options)


def resolve_renderer(renderer: Renderer | str | None = None) -> Renderer:
    """Return ``renderer`` itself, the renderer registered under that name, or the default :class:`NumbaRenderer`
    for None: the one place every stage turns its ``renderer`` argument into an instance.

    Example:
        >>> type(resolve_renderer()).__name__, resolve_renderer("torch").name
        ('NumbaRenderer', 'torch')
    """
    if renderer is None:
        return NumbaRenderer()
    if isinstance(renderer, str):
        return get_renderer(renderer)
    if not isinstance(renderer, Renderer):
        raise PluginError(f"a renderer must be a roodi_toolkit Renderer or a registered name, got "
                          f"{type(renderer).__name__}")
    return renderer


def has_compositing_weights(renderer: Renderer) -> bool:
    """Return whether ``renderer`` has the optional :class:`CompositingWeights` capability."""
    return isinstance(renderer, CompositingWeights)


def render_cloud(cloud: GaussianCloud, camera: Camera, *, renderer: Renderer | str | None = None,
                 background: Optional[Sequence[float]] = None, sh_degree: Optional[int] = None,
                 features: Optional[Sequence[str]] = None) -> RenderOutput:
    """Return the rendering of a :class:`GaussianCloud` in ``camera`` (no gradients).

    Args:
        cloud: the Gaussians.
        camera: the view.
        renderer: a renderer instance, a registered name, or None for the built-in one.
        background: RGB behind the Gaussians (default black).
        sh_degree: evaluate SH only up to this degree.
        features: names of extra columns of the cloud to render as feature channels.
    """
    renderer = resolve_renderer(renderer)
    params = GaussianParams.from_cloud(cloud, features=features)
    with torch.no_grad():
        return renderer.render(params, camera, background=background, sh_degree=sh_degree)
