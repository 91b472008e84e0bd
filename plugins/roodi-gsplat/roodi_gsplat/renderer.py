"""The :class:`GsplatRenderer`: roodi-toolkit's renderer interface on top of ``gsplat.rasterization``.

gsplat is imported lazily, inside :meth:`GsplatRenderer.available` and :meth:`GsplatRenderer.render`, so that this
plugin loads (and ``roodi-toolkit plugins`` lists it) on machines without gsplat or CUDA.
"""

from __future__ import annotations

from typing import Any, Optional, Sequence

import torch

from roodi_toolkit.cameras import Camera
from roodi_toolkit.errors import PluginError
from roodi_toolkit.params import GaussianParams
from roodi_toolkit.render.renderer import Renderer, RenderOutput

INSTALL_HINT = "install it with `pip install gsplat` (or `pip install roodi-gsplat[cuda]`) on a machine with CUDA"


def _import_gsplat() -> Any:
    try:
        import gsplat
    except ImportError as exc:
        raise PluginError(f"the gsplat renderer needs the gsplat package ({exc}); {INSTALL_HINT}") from None
    return gsplat


class GsplatRenderer(Renderer):
    """Render with gsplat's CUDA rasterizer in 3DGS "classic" mode (the conventions of the built-in renderer).

    It has no ``compositing_weights``: distillation renders the features densely through :meth:`render`, and the
    click segmenter takes its weights from the built-in renderer.
    """

    name = "gsplat"

    def __init__(self, *, device: str = "cuda", packed: bool = False, tile_size: int = 16) -> None:
        self.device = torch.device(device)
        self.packed = packed
        self.tile_size = tile_size

    @classmethod
    def status(cls) -> tuple[str, str]:
        """Return ``("installed", "")``, ``("needs CUDA", ...)`` (torch sees no CUDA GPU: gsplat builds and
        rasterizes only there) or ``("needs a package", ...)`` (a CUDA GPU without the gsplat package)."""
        import importlib.util

        cuda = torch.cuda.is_available()
        if importlib.util.find_spec("gsplat") is None:
            if cuda:
                return "needs a package", f"the gsplat package is not installed; {INSTALL_HINT}"
            return "needs CUDA", f"torch sees no CUDA GPU here, and the gsplat package is not installed; {INSTALL_HINT}"
        ok, why = cls.available()
        return ("installed", "") if ok else ("needs CUDA", why)

    @classmethod
    def available(cls) -> tuple[bool, str]:
        try:
            _import_gsplat()
        except PluginError as exc:
            return False, str(exc)
        if not torch.cuda.is_available():
            return False, "gsplat rasterizes only on CUDA GPUs and torch sees none; use the default renderer (numba) on CPUs"
        return True, ""

    def render(self, params: GaussianParams, camera: Camera, *, background: Optional[Sequence[float]] = None,
               sh_degree: Optional[int] = None) -> RenderOutput:
        gsplat = _import_gsplat()
        src_device = params.device
        dev = self.device
        g = {k: v.to(dev) for k, v in params.items()}  # .to keeps the autograd graph back to the caller's tensors
        g.setdefault("features", None)
        dtype = g["means"].dtype
        viewmats = torch.as_tensor(camera.world_to_camera, dtype=dtype, device=dev)[None]
        Ks = torch.as_tensor(camera.K, dtype=dtype, device=dev)[None]
        colors = torch.cat([g["sh_dc"][:, None, :], g["sh_rest"]], dim=1)  # [N, K, 3]
        degree = params.sh_degree if sh_degree is None else sh_degree
        # [1, 3]: in "RGB+ED" mode gsplat appends the depth channel's background (zero) itself
        bg = None if background is None else torch.as_tensor(background, dtype=dtype, device=dev).reshape(1, 3)
        common = dict(means=g["means"], quats=g["quats_wxyz"], scales=torch.exp(g["log_scales"]),
                      opacities=torch.sigmoid(g["opacity_logits"]), viewmats=viewmats, Ks=Ks, width=camera.width,
                      height=camera.height, near_plane=camera.near, far_plane=camera.far, eps2d=0.3,
                      packed=self.packed, tile_size=self.tile_size, rasterize_mode="classic")
        render, alpha, meta = gsplat.rasterization(colors=colors, sh_degree=degree, backgrounds=bg,
                                                   render_mode="RGB+ED", **common)
        features = None
        if g["features"] is not None:
            features, _, _ = gsplat.rasterization(colors=g["features"], sh_degree=None, render_mode="RGB", **common)
            features = features[0].to(src_device)
        means2d = meta["means2d"]
        if means2d.requires_grad:
            means2d.retain_grad()  # densification reads its gradient after backward
        radii = meta["radii"][0]
        if radii.ndim == 1:  # gsplat < 1.5 returns one radius per Gaussian
            radii = radii[:, None].expand(-1, 2)
        depths = meta["depths"][0]
        out = RenderOutput(rgb=render[0, ..., :3].to(src_device), alpha=alpha[0].to(src_device),
                           depth=render[0, ..., 3:4].to(src_device), features=features,
                           means2d=means2d.detach()[0].to(src_device), radii=radii.to(src_device).int(),
                           depths=depths.to(src_device), visible=(radii > 0).any(-1).to(src_device),
                           grad_source=means2d)
        return out
