"""The tiled CPU rasterizer: agreement with the dense reference, gradients, and analytically known images."""

from __future__ import annotations

import math

import pytest
import torch

from roodi_toolkit.cameras import intrinsics_from_fov, look_at
from roodi_toolkit.errors import CloudError, ConfigError
from roodi_toolkit.render.rasterizer import (ALPHA_MAX, _bin_tiles, _footprints, _RasterizeTiles, project_gaussians,
                                      rasterize, rasterize_dense_reference)
from roodi_toolkit.sh import SH_C0, SH_C1

F64 = torch.float64


def random_scene(n=150, seed=0, sh_k=9, n_features=4, dtype=F64, width=41, height=29):
    """A seeded scene with every awkward case: Gaussians behind the camera, straddling the near plane, off screen
    (some reaching in through the widened Jacobian clamp), large, thin, nearly transparent and nearly opaque."""
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.randn(*s, generator=g, dtype=dtype)  # noqa: E731
    u = lambda *s: torch.rand(*s, generator=g, dtype=dtype)  # noqa: E731
    means = r(n, 3) * torch.tensor([1.5, 1.5, 1.0], dtype=dtype)
    means[: n // 10, 1] -= 5.0  # behind or beside the camera at y = -3
    log_scales = torch.log(u(n, 3) * 0.15 + 0.01)
    log_scales[n // 10: n // 5, 0] += 2.0  # long thin ones
    log_scales[n // 5: n // 5 + 3] += 1.5  # large ones
    opacity_logits = r(n) * 3.0
    colors = r(n, sh_k, 3) * 0.4 if sh_k else u(n, 3)
    features = r(n, n_features) if n_features else None
    w2c = torch.tensor(look_at([0.3, -3.0, 0.6], [0, 0, 0]), dtype=dtype)
    K = torch.tensor(intrinsics_from_fov(math.radians(65), width, height), dtype=dtype)
    K[0, 2] += 1.3  # an off-centre principal point exercises the asymmetric Jacobian clamp
    return dict(means=means, quats_wxyz=r(n, 4), log_scales=log_scales, opacity_logits=opacity_logits,
                colors=colors, world_to_camera=w2c, K=K, width=width, height=height, features=features,
                background=torch.tensor([0.2, 0.5, 0.7], dtype=dtype), near=0.3)


def call(fn, scene, **kw):
    s = dict(scene)
    args = [s.pop(k) for k in ("means", "quats_wxyz", "log_scales", "opacity_logits", "colors", "world_to_camera",
                               "K", "width", "height")]
    return fn(*args, **s, **kw)


def weighted_loss(out, seed=7):
    g = torch.Generator().manual_seed(seed)
    parts = [out.rgb, out.alpha, out.depth] + ([out.features] if out.features is not None else [])
    return sum((p * torch.randn(p.shape, generator=g, dtype=p.dtype)).sum() for p in parts)


LEAVES = ("means", "quats_wxyz", "log_scales", "opacity_logits", "colors", "features")


def grads(fn, scene, **kw):
    scene = {k: (v.clone().requires_grad_() if k in LEAVES and v is not None else v) for k, v in scene.items()}
    out = call(fn, scene, **kw)
    weighted_loss(out).backward()
    return out, {k: scene[k].grad for k in LEAVES if scene[k] is not None}


# ------------------------------------------------------------------------------------------------ dense reference
@pytest.mark.parametrize("sh_k, tile_size, chunk", [(16, 4, 32), (9, 16, 5), (4, 3, 1), (1, 8, 64), (0, 4, 7)])
def test_matches_dense_reference_values_and_gradients(sh_k, tile_size, chunk):
    scene = random_scene(sh_k=sh_k)
    fast, g_fast = grads(rasterize, scene, tile_size=tile_size, chunk=chunk)
    dense, g_dense = grads(rasterize_dense_reference, scene)
    assert 0.05 < fast.alpha.mean() < 0.95  # a scene with both coverage and gaps
    for name in ("rgb", "alpha", "depth", "features"):
        torch.testing.assert_close(getattr(fast, name), getattr(dense, name), atol=1e-5, rtol=0)
    for name, g in g_dense.items():
        scale = max(1.0, g.abs().max().item())
        torch.testing.assert_close(g_fast[name], g, atol=1e-5 * scale, rtol=0, msg=f"gradient of {name}")
    torch.testing.assert_close(fast.means2d_grad(), dense.means2d_grad(), atol=1e-5, rtol=0)


def test_dense_reference_windows_tile_the_image():
    scene = random_scene(n=60)
    full = call(rasterize_dense_reference, scene)
    bands = [call(rasterize_dense_reference, scene, rows=(a, b)) for a, b in ((0, 10), (10, 29))]
    torch.testing.assert_close(torch.cat([b.rgb for b in bands]), full.rgb)
    window = call(rasterize_dense_reference, scene, rows=(3, 9), cols=(5, 20))
    torch.testing.assert_close(window.rgb, full.rgb[3:9, 5:20])


def test_memory_bound_and_tile_size_do_not_change_the_result():
    scene = random_scene(n=120, seed=4)
    ref, g_ref = grads(rasterize, scene)
    for kw in (dict(max_elements=64), dict(tile_size=1, chunk=3), dict(tile_size=32)):
        out, g = grads(rasterize, scene, **kw)
        torch.testing.assert_close(out.rgb, ref.rgb, atol=1e-12, rtol=0)
        for name in g_ref:
            torch.testing.assert_close(g[name], g_ref[name], atol=1e-10, rtol=1e-10)


def test_float32_close_to_float64_at_realistic_resolution():
    scene = random_scene(n=400, seed=2, width=160, height=120)
    scene32 = {k: (v.float() if isinstance(v, torch.Tensor) else v) for k, v in scene.items()}
    a = call(rasterize, scene)
    b = call(rasterize, scene32)
    assert b.rgb.dtype == torch.float32
    torch.testing.assert_close(b.rgb.double(), a.rgb, atol=2e-4, rtol=0)
    torch.testing.assert_close(b.alpha.double(), a.alpha, atol=2e-4, rtol=0)


# ------------------------------------------------------------------------------------------------ gradients
def test_gradcheck_full_pipeline():
    g = torch.Generator().manual_seed(11)
    n = 5
    means = torch.tensor([[0.0, 0.0, 0.0], [0.3, 0.2, 0.1], [-0.3, -0.2, 0.3], [0.1, -0.3, -0.2], [-0.2, 0.3, 0.0]],
                         dtype=F64)
    quats = torch.randn(n, 4, generator=g, dtype=F64)
    log_scales = torch.log(torch.rand(n, 3, generator=g, dtype=F64) * 0.1 + 0.08)
    opacity_logits = torch.randn(n, generator=g, dtype=F64) * 0.5
    sh = torch.randn(n, 4, 3, generator=g, dtype=F64) * 0.3
    features = torch.randn(n, 2, generator=g, dtype=F64)
    w2c = torch.tensor(look_at([0.2, -2.5, 0.4], [0, 0, 0]), dtype=F64)
    K = torch.tensor(intrinsics_from_fov(math.radians(50), 14, 11), dtype=F64)
    bg = torch.tensor([0.1, 0.2, 0.3], dtype=F64)

    def fn(m, q, s, o, c, f):
        out = rasterize(m, q, s, o, c, w2c, K, 14, 11, features=f, background=bg, tile_size=4, chunk=2)
        return torch.cat([out.rgb.reshape(-1), out.alpha.reshape(-1), out.depth.reshape(-1),
                          out.features.reshape(-1)])

    inputs = [t.requires_grad_() for t in (means, quats, log_scales, opacity_logits, sh, features)]
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=True)


def test_gradcheck_compositing_core_with_clamping_and_termination():
    """The hand-written backward alone, on a stack of opaque splats so that alpha clamps and pixels terminate."""
    g = torch.Generator().manual_seed(5)
    n, width, height = 12, 10, 9
    means2d = torch.rand(n, 2, generator=g, dtype=F64) * torch.tensor([width, height], dtype=F64)
    cov = torch.rand(n, 3, generator=g, dtype=F64)
    c00, c11, c01 = 2.0 + 6 * cov[:, 0], 2.0 + 6 * cov[:, 1], cov[:, 2] - 0.5
    det = c00 * c11 - c01 * c01
    conics = torch.stack([c11 / det, -c01 / det, c00 / det], -1)
    opac = 0.6 + 0.399 * torch.rand(n, generator=g, dtype=F64)
    colors = torch.rand(n, 4, generator=g, dtype=F64)
    bg = torch.tensor([0.3, 0.1, 0.9, 0.0], dtype=F64)
    depths = torch.rand(n, generator=g, dtype=F64)
    cov2d = torch.stack([c00, c01, c01, c11], -1).reshape(n, 2, 2)
    bounds, ok, _ = _footprints(means2d, cov2d, opac, torch.ones(n, dtype=torch.bool), width, height)
    tiles = _bin_tiles(bounds, ok, depths, width, height, 4)

    def fn(m, c, o, col, b):
        return _RasterizeTiles.apply(m, c, o, col, b, tiles, width, height, 3, 1 << 20)

    out, alpha = fn(means2d, conics, opac, colors, bg)
    assert (alpha > 1 - 1e-3).any()  # some pixels are (nearly) opaque: termination and clamping are exercised
    inputs = [t.clone().requires_grad_() for t in (means2d, conics, opac, colors, bg)]
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-7, atol=1e-5, rtol=1e-4)


def test_means2d_gradient_for_densification():
    scene = random_scene(n=80, seed=9)
    scene = {k: (v.clone().requires_grad_() if k == "means" else v) for k, v in scene.items()}
    out = call(rasterize, scene)
    assert out.means2d_grad() is None
    weighted_loss(out).backward()
    grad2d = out.means2d_grad()
    assert grad2d.shape == (80, 2)
    assert (grad2d[~out.visible] == 0).all()
    assert (grad2d[out.visible].norm(dim=1) > 0).float().mean() > 0.5
    assert torch.isfinite(scene["means"].grad).all()


def test_fully_transparent_and_degenerate_gaussians_give_finite_gradients():
    scene = random_scene(n=40, seed=3, dtype=torch.float32)
    scene["opacity_logits"][:5] = -1e4  # sigmoid underflows to exactly 0
    scene["log_scales"][5:8] = -30.0  # zero-size: the 2D covariance is the 0.3 filter alone
    scene["quats_wxyz"][8] = 0.0  # zero quaternion: the identity, as in 3DGS files
    out, g = grads(rasterize, scene)
    for name, grad in g.items():
        assert torch.isfinite(grad).all(), name
    assert (g["opacity_logits"][:5] == 0).all()


# ------------------------------------------------------------------------------------------------ analytic images
def axis_camera(f=40.0, size=33):
    """Camera at the origin looking along +z; a mean on the axis projects onto the centre of pixel (16, 16)."""
    K = torch.tensor([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1]], dtype=F64)
    return torch.eye(4, dtype=F64), K, size


def splats(zs, scales, opacities, colors):
    n = len(zs)
    means = torch.zeros(n, 3, dtype=F64)
    means[:, 2] = torch.tensor(zs, dtype=F64)
    quats = torch.tensor([[1.0, 0, 0, 0]] * n, dtype=F64)
    log_scales = torch.log(torch.tensor(scales, dtype=F64))[:, None].repeat(1, 3)
    logits = torch.logit(torch.tensor(opacities, dtype=F64))
    return means, quats, log_scales, logits, torch.tensor(colors, dtype=F64)


@pytest.mark.parametrize("front_opacity", [0.9, 0.999])
def test_opaque_gaussian_in_front_of_another_and_partial_occlusion(front_opacity):
    w2c, K, size = axis_camera()
    f = K[0, 0].item()
    # the back (green) Gaussian is listed first: the renderer must sort by depth
    means, quats, log_scales, logits, colors = splats([4.0, 2.0], [0.5, 0.05], [0.8, front_opacity],
                                                      [[0, 1, 0], [1, 0, 0]])
    bg = torch.tensor([0.0, 0.0, 1.0], dtype=F64)
    out = rasterize(means, quats, log_scales, logits, colors, w2c, K, size, size, background=bg)
    k = torch.arange(0, 10, dtype=F64)  # pixel columns 16 + k of row 16, k pixels right of both means
    var_f = (f * 0.05 / 2.0) ** 2 + 0.3  # on the optical axis the EWA covariance is isotropic
    var_b = (f * 0.5 / 4.0) ** 2 + 0.3
    a_f = torch.clamp_max(front_opacity * torch.exp(-0.5 * k**2 / var_f), ALPHA_MAX)
    a_f = torch.where(a_f >= 1 / 255, a_f, torch.zeros_like(a_f))
    a_b = 0.8 * torch.exp(-0.5 * k**2 / var_b)
    t = (1 - a_f) * (1 - a_b)
    expected_rgb = torch.stack([a_f, (1 - a_f) * a_b, t], -1)
    row = slice(16, 26)
    torch.testing.assert_close(out.rgb[16, row], expected_rgb, atol=1e-12, rtol=0)
    torch.testing.assert_close(out.alpha[16, row, 0], 1 - t, atol=1e-12, rtol=0)
    torch.testing.assert_close(out.depth[16, row, 0], (2.0 * a_f + 4.0 * (1 - a_f) * a_b) / (1 - t), atol=1e-12,
                               rtol=0)
    if front_opacity > ALPHA_MAX:
        assert out.rgb[16, 16, 0].item() == pytest.approx(0.99, abs=1e-12)  # the 3DGS clamp


@pytest.mark.parametrize("chunk", [1, 32])
def test_compositing_stops_before_transmittance_falls_below_1e_minus_4(chunk):
    w2c, K, size = axis_camera()
    # four splats of alpha 0.95 at the centre pixel: T goes 1, .05, .0025, 1.25e-4; the 4th would leave 6.25e-6
    means, quats, log_scales, logits, colors = splats([1, 2, 3, 4, 5], [0.001] * 5, [0.95] * 4 + [0.01],
                                                      [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1], [0, 0, 0]])
    features = torch.tensor([[0.0], [0.0], [0.0], [1.0], [1.0]], dtype=F64)
    out = rasterize(means, quats, log_scales, logits, colors, w2c, K, size, size, features=features, chunk=chunk)
    torch.testing.assert_close(out.rgb[16, 16], torch.tensor([0.95, 0.0475, 0.002375], dtype=F64), atol=1e-12,
                               rtol=0)
    torch.testing.assert_close(out.alpha[16, 16, 0], torch.tensor(1 - 1.25e-4, dtype=F64), atol=1e-12, rtol=0)
    # neither the 4th splat nor the faint 5th (which alone would pass the transmittance test) contributes
    assert out.features[16, 16, 0].item() == 0.0


def test_near_and_far_planes_cull_and_behind_camera_is_harmless():
    w2c, K, size = axis_camera()
    means, quats, log_scales, logits, colors = splats([0.5, -2.0, 50.0], [0.05, 0.5, 1.0], [0.9, 0.9, 0.9],
                                                      [[1, 0, 0], [0, 1, 0], [0, 0, 1]])
    means = means.requires_grad_()
    bg = torch.tensor([0.25, 0.5, 0.75], dtype=F64)
    out = rasterize(means, quats, log_scales, logits, colors, w2c, K, size, size, near=1.0, far=20.0, background=bg)
    assert out.visible.tolist() == [False, False, False]
    assert out.radii.abs().sum() == 0
    assert (out.alpha == 0).all() and (out.depth == 0).all()
    torch.testing.assert_close(out.rgb, bg.expand(size, size, 3))
    out.rgb.sum().backward()
    assert torch.isfinite(means.grad).all() and (means.grad == 0).all()
    near = rasterize(means, quats, log_scales, logits, colors, w2c, K, size, size, near=0.1, far=100.0)
    assert near.visible.tolist() == [True, False, True]
    assert near.rgb[16, 16, 0].item() == pytest.approx(0.9, abs=1e-12)


def test_sh_view_dependence():
    # colour = 0.5 + C0 * dc - C1 * y * c1, with y the view direction (camera -> mean) component
    sh = torch.zeros(1, 4, 3, dtype=F64)
    sh[0, 1] = torch.tensor([0.5, 0.0, -0.5])
    means = torch.zeros(1, 3, dtype=F64)
    args = (means, torch.tensor([[1.0, 0, 0, 0]], dtype=F64), torch.log(torch.full((1, 3), 0.1, dtype=F64)),
            torch.logit(torch.tensor([0.9], dtype=F64)), sh)
    K = torch.tensor(intrinsics_from_fov(0.8, 33, 33), dtype=F64)
    seen = {}
    for name, eye in {"from -y": [0, -3, 0], "from +y": [0, 3, 0], "from +z": [0, 0, 3]}.items():
        w2c = torch.tensor(look_at(eye, [0, 0, 0]), dtype=F64)
        seen[name] = rasterize(*args, w2c, K, 33, 33).rgb[16, 16]
    c1 = torch.tensor([0.5, 0.0, -0.5], dtype=F64)
    torch.testing.assert_close(seen["from -y"], 0.9 * (0.5 - SH_C1 * c1))
    torch.testing.assert_close(seen["from +y"], 0.9 * (0.5 + SH_C1 * c1))
    torch.testing.assert_close(seen["from +z"], torch.full((3,), 0.45, dtype=F64))
    # degree truncation: sh_degree=0 ignores the view-dependent term
    w2c = torch.tensor(look_at([0, -3, 0], [0, 0, 0]), dtype=F64)
    torch.testing.assert_close(rasterize(*args, w2c, K, 33, 33, sh_degree=0).rgb[16, 16],
                               torch.full((3,), 0.45, dtype=F64))
    assert SH_C0 > 0


def test_projection_jacobian_clamp_matches_gsplat_limits():
    # a Gaussian far outside the frustum on +x: J uses x/z clamped to (W - cx)/fx + 0.3 * W / (2 fx)
    K = torch.tensor([[50.0, 0, 20.0], [0, 50.0, 15.0], [0, 0, 1]], dtype=F64)
    means = torch.tensor([[10.0, 0.0, 2.0]], dtype=F64)
    p = project_gaussians(means, torch.tensor([[1.0, 0, 0, 0]], dtype=F64), torch.log(torch.full((1, 3), 0.2,
                          dtype=F64)), torch.eye(4, dtype=F64), K, 40, 30)
    lim = (40 - 20.0) / 50.0 + 0.3 * 0.5 * 40 / 50.0
    J = torch.tensor([[50.0 / 2, 0, -50.0 * lim / 2], [0, 50.0 / 2, 0]], dtype=F64)
    expected = 0.04 * J @ J.T + 0.3 * torch.eye(2, dtype=F64)
    torch.testing.assert_close(p.cov2d[0], expected)
    torch.testing.assert_close(p.means2d[0], torch.tensor([50.0 * 5 + 20, 15.0], dtype=F64))


# ------------------------------------------------------------------------------------------------ errors
def test_input_errors_name_the_shape():
    scene = random_scene(n=10)
    with pytest.raises(CloudError, match=r"quats_wxyz must have shape \[10, 4\], got \[9, 4\]"):
        call(rasterize, {**scene, "quats_wxyz": scene["quats_wxyz"][:9]})
    with pytest.raises(CloudError, match="1, 4, 9 or 16"):
        call(rasterize, {**scene, "colors": torch.zeros(10, 5, 3, dtype=F64)})
    with pytest.raises(ConfigError, match="near"):
        call(rasterize, {**scene, "near": 2.0}, far=1.0)
    with pytest.raises(ConfigError, match="background"):
        call(rasterize, {**scene, "background": torch.zeros(4)})
    with pytest.raises(ConfigError, match=r"K must be \[3, 3\]"):
        call(rasterize, {**scene, "K": torch.eye(4)})


def test_empty_cloud_renders_background():
    z = torch.zeros(0, 3, dtype=F64)
    out = rasterize(z, torch.zeros(0, 4, dtype=F64), z, torch.zeros(0, dtype=F64), z, torch.eye(4, dtype=F64),
                    torch.tensor(intrinsics_from_fov(1.0, 8, 6), dtype=F64), 8, 6,
                    background=torch.tensor([1.0, 0.0, 0.0], dtype=F64))
    assert out.rgb.shape == (6, 8, 3) and (out.rgb[..., 0] == 1).all() and (out.alpha == 0).all()
