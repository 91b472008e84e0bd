"""The renderer interface, run against every renderer registered under ``roodi_toolkit.renderers``.

Renderers that cannot run here (gsplat without CUDA) are skipped with their own reason; the built-in ``torch``
renderer always runs, so the suite never passes empty.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
from roodi_toolkit.errors import CloudError, PluginError
from roodi_toolkit.gaussians import GaussianCloud
from roodi_toolkit.plugins import discover
from roodi_toolkit.params import GaussianParams
from roodi_toolkit.render.renderer import Renderer, get_renderer, render_cloud, renderer_names

NAMES = [spec.name for spec in discover("renderers")]


def test_builtin_renderers_are_registered_and_numba_is_the_default():
    from roodi_toolkit.render.renderer import NumbaRenderer, resolve_renderer

    for name in ("numba", "torch"):
        assert name in renderer_names()
        assert [s.origin for s in discover("renderers") if s.name == name] == ["roodi-toolkit"]
    assert isinstance(resolve_renderer(None), NumbaRenderer) and get_renderer().name == "numba"


@pytest.fixture(params=NAMES)
def renderer(request) -> Renderer:
    cls = discover("renderers")[NAMES.index(request.param)].load()
    assert isinstance(cls, type) and issubclass(cls, Renderer), f"{request.param} is not a Renderer subclass"
    ok, why = cls.available()
    if not ok:
        assert why, "an unavailable renderer must say why"
        pytest.skip(f"{request.param}: {why}")
    return get_renderer(request.param)


def scene(n=400, seed=0, features=0):
    rng = np.random.default_rng(seed)
    cloud = GaussianCloud.from_activated(rng.normal(size=(n, 3)) * 0.4, scales=np.exp(rng.normal(-3, 0.3, (n, 3))),
                                         opacities=rng.uniform(0.3, 0.98, n), rgb=rng.uniform(0, 1, (n, 3)),
                                         quats_wxyz=rng.normal(size=(n, 4)), sh_degree=1)
    g = GaussianParams.from_cloud(cloud)
    if features:
        g.features = torch.as_tensor(rng.normal(size=(n, features)), dtype=torch.float32)
    cam = Camera(look_at([0.2, -2.5, 0.8], [0, 0, 0]), intrinsics_from_fov(math.radians(55), 48, 36), 48, 36,
                 near=0.05)
    return cloud, g, cam


def test_shapes_and_ranges(renderer):
    _, g, cam = scene(features=16)
    out = renderer.render(g, cam, background=(0.2, 0.4, 0.6))
    n = len(g)
    assert out.rgb.shape == (36, 48, 3) and out.alpha.shape == (36, 48, 1) and out.depth.shape == (36, 48, 1)
    assert out.features.shape == (36, 48, 16)
    assert out.means2d.shape == (n, 2) and out.radii.shape == (n, 2) and out.depths.shape == (n,)
    assert out.visible.shape == (n,) and out.visible.dtype == torch.bool
    assert (out.alpha >= 0).all() and (out.alpha <= 1).all()
    assert 0.1 < out.alpha.mean() < 0.99
    assert torch.isfinite(out.rgb).all() and torch.isfinite(out.depth).all()


def test_background_fills_empty_pixels(renderer):
    _, g, cam = scene()
    a = renderer.render(g, cam, background=(0.0, 0.0, 0.0))
    b = renderer.render(g, cam, background=(1.0, 0.5, 0.25))
    expected = a.rgb + (1 - a.alpha) * torch.tensor([1.0, 0.5, 0.25])
    torch.testing.assert_close(b.rgb, expected, atol=1e-5, rtol=0)
    torch.testing.assert_close(b.depth, a.depth)  # no background on depth
    empty = a.alpha[..., 0] < 1e-6
    assert empty.any() and (b.rgb[empty] == torch.tensor([1.0, 0.5, 0.25])).all()


def test_depth_is_sane(renderer):
    cloud, g, cam = scene()
    out = renderer.render(g, cam)
    _, z = cam.project(cloud.means)
    hit = out.alpha[..., 0] > 0.5
    assert hit.any()
    d = out.depth[..., 0][hit]
    # expected depth is a weighted mean of the Gaussians' z, so it lies within their range
    assert (d >= z.min() - 1e-4).all() and (d <= z.max() + 1e-4).all()
    torch.testing.assert_close(out.depths, torch.as_tensor(z, dtype=torch.float32), atol=1e-4, rtol=1e-5)
    nearer = Camera(look_at([0.1, -1.25, 0.4], [0, 0, 0]), cam.K, cam.width, cam.height, near=0.05)
    assert renderer.render(g, nearer).depth[..., 0][18, 24] < out.depth[..., 0][18, 24]


def test_gradients_reach_every_input(renderer):
    _, g, cam = scene(features=3)
    g.requires_grad_()
    out = renderer.render(g, cam, background=(0.3, 0.3, 0.3))
    (out.rgb.sum() + out.depth.sum() + out.features.sum() + out.alpha.sum()).backward()
    for name, t in g.items():
        assert t.grad is not None and torch.isfinite(t.grad).all() and t.grad.abs().sum() > 0, name
    g2d = out.means2d_grad()
    assert g2d.shape == (len(g), 2) and (g2d[out.visible].abs().sum(-1) > 0).any()


def test_render_cloud_helper_and_errors():
    cloud, _, cam = scene()
    out = render_cloud(cloud, cam, renderer="torch", background=(0, 0, 0))
    assert out.rgb.shape == (36, 48, 3) and not out.rgb.requires_grad
    with pytest.raises(CloudError, match="no extra column"):
        render_cloud(cloud, cam, features=["segment"])
    with pytest.raises(PluginError, match="no renderer plugin named"):
        get_renderer("no-such-renderer")
    with pytest.raises(PluginError, match="does not take these options"):
        get_renderer("torch", bogus=1)


def test_a_plugin_that_is_not_a_renderer_is_refused(monkeypatch):
    monkeypatch.setenv("ROODI_PLUGINS", "renderers:fake=roodi_toolkit.errors:RoodiError")
    with pytest.raises(PluginError, match="not a roodi_toolkit.render.renderer.Renderer subclass"):
        get_renderer("fake")
