"""The renderer plugin interface: Gaussians as tensors + a :class:`~roodi_toolkit.cameras.Camera` -> images.

A renderer is a class registered under the entry-point group ``roodi_toolkit.renderers``; the built-in ``torch``
renderer (:class:`TorchRenderer`, this package's ``setup.cfg``) registers exactly as a third-party one does, e.g. the
``gsplat`` CUDA renderer in ``plugins/roodi-gsplat``::

    [options.entry_points]
    roodi_toolkit.renderers =
        torch = roodi_toolkit.render.renderer:TorchRenderer

A renderer class subclasses :class:`Renderer`: ``available()`` says whether it can run here (and why not), and
``render(gaussians, camera, ...)`` returns a :class:`RenderOutput` (channels-last images, differentiable w.r.t. every
tensor in ``gaussians``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, fields
from typing import Any, Optional, Sequence

import numpy as np
import torch
from torch import Tensor

from ..cameras import Camera
from ..errors import CloudError, PluginError
from ..gaussians import GaussianCloud
from ..plugins import discover, instantiate
from .rasterizer import RasterOutput, rasterize

RenderOutput = RasterOutput
"""What every renderer returns: rgb [H, W, 3], alpha [H, W, 1], depth [H, W, 1] (expected depth), features
[H, W, F] or None, means2d [N, 2] (see ``means2d_grad()``), radii [N, 2], depths [N], visible [N]."""


@dataclass
class GaussianTensors:
    """Gaussians as (possibly trainable) tensors in their raw value spaces, the renderers' input.

    Attributes:
        means: centres. [N, 3]
        quats_wxyz: rotations, w first, not necessarily normalised. [N, 4]
        log_scales: log standard deviations. [N, 3]
        opacity_logits: pre-sigmoid opacities. [N]
        colors: SH coefficients, DC first, coefficient-major ([N, K, 3]), or plain RGB ([N, 3]).
        features: extra channels composited with the same weights, e.g. object features, or None. [N, F]

    Example:
        >>> cloud = GaussianCloud.from_activated(np.zeros((2, 3)), scales=np.full((2, 3), 0.1),
        ...                                      opacities=np.array([0.5, 0.9]), rgb=np.full((2, 3), 0.5))
        >>> g = GaussianTensors.from_cloud(cloud)
        >>> len(g), tuple(g.colors.shape)
        (2, (2, 1, 3))
    """

    means: Tensor
    quats_wxyz: Tensor
    log_scales: Tensor
    opacity_logits: Tensor
    colors: Tensor
    features: Optional[Tensor] = None

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @classmethod
    def from_cloud(cls, cloud: GaussianCloud, *, dtype: torch.dtype = torch.float32, device: str = "cpu",
                   features: Optional[Sequence[str]] = None) -> "GaussianTensors":
        """Return the cloud's arrays as tensors; ``features`` names extra columns to stack as feature channels."""
        t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=dtype, device=device)  # noqa: E731
        feats = None
        if features:
            missing = [name for name in features if name not in cloud.extras]
            if missing:
                raise CloudError(f"the cloud has no extra column(s) {missing}; it has {list(cloud.extras) or 'none'}")
            feats = t(np.stack([cloud.extras[name].astype(np.float64) for name in features], axis=1))
        return cls(t(cloud.means), t(cloud.quats_wxyz), t(cloud.log_scales), t(cloud.opacity_logits), t(cloud.sh),
                   feats)

    def tensors(self) -> dict[str, Optional[Tensor]]:
        """Return the fields by name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


class Renderer(ABC):
    """Base class of renderer plugins. Subclasses take their options as keyword arguments of ``__init__``."""

    name: str = ""

    @classmethod
    def available(cls) -> tuple[bool, str]:
        """Return (True, "") if this renderer can run on this machine, else (False, why not and what to do)."""
        return True, ""

    @abstractmethod
    def render(self, gaussians: GaussianTensors, camera: Camera, *, background: Optional[Sequence[float]] = None,
               sh_degree: Optional[int] = None) -> RenderOutput:
        """Return the rendering of ``gaussians`` seen by ``camera``.

        Args:
            gaussians: the Gaussians (any tensor may require grad).
            camera: the view; ``near``/``far`` cull Gaussians by camera-space depth.
            background: RGB behind the Gaussians (default black); not applied to depth or features.
            sh_degree: evaluate SH only up to this degree (default: all coefficients given).
        """


class TorchRenderer(Renderer):
    """The built-in differentiable CPU renderer (:func:`roodi_toolkit.render.rasterizer.rasterize`).

    Example:
        >>> from roodi_toolkit.cameras import look_at, intrinsics_from_fov
        >>> cloud = GaussianCloud.from_activated(np.zeros((1, 3)), scales=np.full((1, 3), 0.2),
        ...                                      opacities=np.array([0.99]), rgb=np.array([[1.0, 0.0, 0.0]]))
        >>> cam = Camera(look_at([0, -3, 0], [0, 0, 0]), intrinsics_from_fov(0.8, 33, 33), 33, 33)
        >>> out = TorchRenderer().render(GaussianTensors.from_cloud(cloud), cam, background=(0, 0, 1))
        >>> [round(v, 3) for v in out.rgb[16, 16].tolist()], round(out.depth[16, 16].item(), 3)
        ([0.99, 0.0, 0.01], 3.0)
    """

    name = "torch"

    def __init__(self, *, tile_size: int = 4, chunk: int = 32, max_elements: int = 1 << 22) -> None:
        self.tile_size = tile_size
        self.chunk = chunk
        self.max_elements = max_elements

    def render(self, gaussians: GaussianTensors, camera: Camera, *, background: Optional[Sequence[float]] = None,
               sh_degree: Optional[int] = None) -> RenderOutput:
        dtype = gaussians.means.dtype
        bg = None if background is None else torch.as_tensor(background, dtype=dtype)
        return rasterize(gaussians.means, gaussians.quats_wxyz, gaussians.log_scales, gaussians.opacity_logits,
                         gaussians.colors, torch.as_tensor(camera.world_to_camera, dtype=dtype),
                         torch.as_tensor(camera.K, dtype=dtype), camera.width, camera.height, near=camera.near,
                         far=camera.far, features=gaussians.features, background=bg, sh_degree=sh_degree,
                         tile_size=self.tile_size, chunk=self.chunk, max_elements=self.max_elements)


def renderer_names() -> list[str]:
    """Return the names of the registered renderers (loaded or not)."""
    return [spec.name for spec in discover("renderers")]


def get_renderer(name: str = "torch", **options: Any) -> Renderer:
    """Return an instance of the renderer registered as ``name``, built with ``options``.

    Raises:
        PluginError: unknown name, failed import, not a :class:`Renderer`, or not available on this machine (the
            message says why, e.g. no CUDA).
    """
    return instantiate("renderers", name, Renderer, **options)


def render_cloud(cloud: GaussianCloud, camera: Camera, *, renderer: Renderer | str = "torch",
                 background: Optional[Sequence[float]] = None, sh_degree: Optional[int] = None,
                 features: Optional[Sequence[str]] = None) -> RenderOutput:
    """Return the rendering of a :class:`GaussianCloud` in ``camera`` (no gradients).

    Args:
        cloud: the Gaussians.
        camera: the view.
        renderer: a renderer instance or a registered name.
        background: RGB behind the Gaussians (default black).
        sh_degree: evaluate SH only up to this degree.
        features: names of extra columns of the cloud to render as feature channels.
    """
    if isinstance(renderer, str):
        renderer = get_renderer(renderer)
    gaussians = GaussianTensors.from_cloud(cloud, features=features)
    with torch.no_grad():
        return renderer.render(gaussians, camera, background=background, sh_degree=sh_degree)
