"""The gsplat plugin: loads everywhere, reports itself unavailable without CUDA, agrees with the torch renderer."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
from roodi_toolkit.errors import PluginError
from roodi_toolkit.gaussians import GaussianCloud
from roodi_toolkit.params import GaussianParams
from roodi_toolkit.render.renderer import TorchRenderer, get_renderer

from roodi_gsplat import GsplatRenderer


def test_unavailable_reason_is_actionable():
    ok, why = GsplatRenderer.available()
    if ok:
        pytest.skip("gsplat and CUDA are present")
    assert "gsplat" in why and ("pip install gsplat" in why or "CUDA" in why)
    with pytest.raises(PluginError, match="cannot run here"):
        get_renderer("gsplat")


needs_cuda = pytest.mark.skipif(not GsplatRenderer.available()[0], reason="needs gsplat and a CUDA GPU")


@needs_cuda
def test_agrees_with_torch_renderer():
    rng = np.random.default_rng(0)
    n = 2000
    cloud = GaussianCloud.from_activated(rng.normal(size=(n, 3)) * 0.5, scales=np.exp(rng.normal(-3.5, 0.3, (n, 3))),
                                         opacities=rng.uniform(0.05, 0.6, n), rgb=rng.uniform(0, 1, (n, 3)),
                                         quats_wxyz=rng.normal(size=(n, 4)))
    cam = Camera(look_at([0, -3, 1], [0, 0, 0]), intrinsics_from_fov(math.radians(50), 96, 80), 96, 80)
    g = GaussianParams.from_cloud(cloud)
    ref = TorchRenderer().render(g, cam, background=(0.1, 0.2, 0.3))
    out = GsplatRenderer().render(g, cam, background=(0.1, 0.2, 0.3))
    # opacities below 0.6 never reach either alpha clamp (0.99 here, 0.999 in gsplat), so the images agree
    torch.testing.assert_close(out.rgb, ref.rgb, atol=2e-3, rtol=0)
    torch.testing.assert_close(out.alpha, ref.alpha, atol=2e-3, rtol=0)


def test_background_has_the_colour_channels_only(monkeypatch):
    """gsplat 1.5's ``rasterization`` appends the depth channel's (zero) background itself in "RGB+ED" mode and
    asserts ``backgrounds`` then matches the rasterized channels: the plugin passes the 3 colour channels. (Handing
    it 4 failed every render with a background on a real H100, issue 33.) A stand-in for gsplat checks the contract
    here, so that it holds on machines without CUDA too."""
    import sys
    import types

    seen = {}

    def rasterization(*, means, colors, backgrounds=None, render_mode="RGB", width, height, **_):
        n = means.shape[0]
        channels = colors.shape[-1] if colors.ndim == 2 else 3
        if backgrounds is not None:
            assert backgrounds.shape == (1, channels), backgrounds.shape  # gsplat's own check, before its depth
            seen["background"] = backgrounds
        extra = 1 if render_mode == "RGB+ED" else 0
        meta = {"means2d": torch.zeros(1, n, 2), "radii": torch.ones(1, n, 2, dtype=torch.int32),
                "depths": torch.ones(1, n)}
        return torch.zeros(1, height, width, channels + extra), torch.zeros(1, height, width, 1), meta

    monkeypatch.setitem(sys.modules, "gsplat", types.SimpleNamespace(rasterization=rasterization))
    rng = np.random.default_rng(0)
    cloud = GaussianCloud.from_activated(rng.normal(size=(10, 3)), scales=np.full((10, 3), 0.1),
                                         opacities=np.full(10, 0.5), rgb=rng.uniform(0, 1, (10, 3)))
    cam = Camera(look_at([0, -3, 1], [0, 0, 0]), intrinsics_from_fov(math.radians(50), 16, 12), 16, 12)
    out = GsplatRenderer(device="cpu").render(GaussianParams.from_cloud(cloud), cam, background=(0.1, 0.2, 0.3))
    assert seen["background"].tolist() == [[pytest.approx(0.1), pytest.approx(0.2), pytest.approx(0.3)]]
    assert out.rgb.shape == (12, 16, 3) and out.depth.shape == (12, 16, 1)
