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
