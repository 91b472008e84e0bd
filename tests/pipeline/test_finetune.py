"""Fine-tuning the object on originals and inpainted views: losses, targets, schedule, the whole refinement's debug
images, and (slow) the generated-scene check that unoccluded views stay and occluded ones improve."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch

from roodi_toolkit.errors import ConfigError
from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
from roodi_toolkit.pipeline.finetune import (FinetuneConfig, ViewTargets, finetune_object, object_view_targets,
                                    refine_object, seed_hole_gaussians)
from roodi_toolkit.lpips import LPIPS
from roodi_toolkit.pipeline.perceptual import LaplacianLoss, LPIPSLoss, perceptual_loss
from roodi_toolkit.run.refine import write_refine_debug
from roodi_toolkit.gaussians import GaussianCloud
from roodi_toolkit.pipeline.occlusion import OcclusionConfig, OcclusionResult

from .test_inpaint import tiny_refine_inputs
from ..paths import REPO


def test_laplacian_loss_is_zero_on_equal_images_and_differentiable():
    g = torch.Generator().manual_seed(0)
    a = torch.rand(32, 32, 3, generator=g)
    b = torch.rand(32, 32, 3, generator=g, requires_grad=True)
    loss = LaplacianLoss()
    assert float(loss(a, a)) == 0.0
    value = loss(b, a)
    value.backward()
    assert value > 0 and b.grad.abs().sum() > 0
    # a constant shift lives only in the low-pass residual: one level of three at 32 px
    base = 0.5 * a
    assert float(loss(base + 0.1, base)) == pytest.approx(0.1 / 3, rel=1e-3)


def test_perceptual_choice_takes_the_network_it_is_given():
    """The stage reads no weights: LPIPS runs with the network handed in, the Laplacian loss without one, and
    ``"lpips"`` without one is an error (the run layer reads the weights: io.lpips_weights.lpips_for_loss)."""
    assert perceptual_loss("auto").name == "laplacian"
    assert perceptual_loss("laplacian").name == "laplacian"
    with pytest.raises(ConfigError, match="'lpips' needs the LPIPS network"):
        perceptual_loss("lpips")
    torch.manual_seed(0)
    reference = LPIPS()
    for p in reference.parameters():
        p.data.uniform_(0, 0.1)
    assert perceptual_loss("laplacian", reference).name == "laplacian"
    for kind in ("auto", "lpips"):
        loss = perceptual_loss(kind, reference)
        assert isinstance(loss, LPIPSLoss) and loss.name == "lpips" and loss.model is reference
    a, b = torch.rand(40, 40, 3), torch.rand(40, 40, 3)
    expected = reference(a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None])
    assert float(loss(a, b)) == pytest.approx(float(expected), rel=1e-6)
    assert float(loss(a, a)) == pytest.approx(0.0, abs=1e-7)


def test_finetune_uses_the_lpips_network_it_is_given():
    """finetune_object hands its ``lpips`` to the perceptual loss (and the result says which ran)."""
    obj, scene, images, cams, masks = tiny_refine_inputs()
    originals = object_view_targets(images, cams, masks)
    inpainted = ViewTargets(cams[:1], images[:1], torch.ones(images.shape[1:3])[None])
    config = FinetuneConfig(iterations=2, inpaint_every=1)
    assert finetune_object(obj, originals, inpainted, config).perceptual == "laplacian"
    calls = []

    class Counted(torch.nn.Module):
        def forward(self, x, y):
            calls.append(x.shape)
            return (x - y).abs().mean((1, 2, 3))

    assert finetune_object(obj, originals, inpainted, config, lpips=Counted()).perceptual == "lpips"
    assert len(calls) == 2 and calls[0][:2] == (1, 3)


def test_targets_keep_the_object_and_ignore_where_it_may_hide():
    from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at

    cam = Camera(look_at([0, -4, 0], [0, 0, 0]), intrinsics_from_fov(0.6, 32, 32), 32, 32)
    images = torch.full((1, 32, 32, 3), 0.3)
    masks = torch.zeros(1, 32, 32, dtype=torch.bool)
    masks[0, 12:20, 12:20] = True
    depths = torch.full((1, 32, 32), 10.0)  # far behind the object: background for sure
    depths[0, 12:20, 2:12] = 3.5  # something in front of the object's left side
    t = object_view_targets(images, [cam], masks, depths=depths, centre=np.zeros(3), radius=0.5,
                            background=(1.0, 1.0, 1.0))
    assert torch.equal(t.images[0][masks[0]], images[0][masks[0]])
    assert (t.images[0][~masks[0]] == 1.0).all()
    assert (t.weights[0][14:18, 10:12] == 0).all()  # may hide the object: not supervised
    assert (t.weights[0][12:20, 2:4] == 1).all()  # outside the object's outline
    assert (t.weights[0][masks[0]] == 1).all() and t.weights[0][0, 0] == 1


def test_targets_render_the_depth_only_round_the_objects_outline():
    """Asked to render the depth itself, the targets' test asks for the rectangle round the sphere's outline only,
    and finds the pixels that may hide the object exactly as from the whole view's depth."""
    from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
    from roodi_toolkit.params import GaussianParams
    from roodi_toolkit.render.renderer import resolve_renderer

    rng = np.random.default_rng(2)
    n = 400
    scene = GaussianCloud.from_activated(rng.uniform(-1.5, 1.5, (n, 3)) * [1, 0.2, 1] - [0, 1.2, 0],
                                         scales=np.full((n, 3), 0.08), opacities=np.full(n, 0.9),
                                         rgb=rng.random((n, 3)))  # a wall between the camera and the object
    params = GaussianParams.from_cloud(scene)
    renderer = resolve_renderer(None)
    cam = Camera(look_at([0.3, -4, 0.2], [0, 0, 0]), intrinsics_from_fov(0.8, 96, 80), 96, 80)
    masks = torch.zeros(1, 80, 96, dtype=torch.bool)
    masks[0, 35:45, 40:55] = True
    images = torch.full((1, 80, 96, 3), 0.3)
    asked = []

    def render_depth(camera):
        asked.append((camera.width, camera.height))
        return renderer.render(params, camera).depth[..., 0]

    whole = renderer.render(params, cam).depth[..., 0][None]
    kwargs = dict(centre=np.zeros(3), radius=0.6, background=(1.0, 1.0, 1.0))
    cropped = object_view_targets(images, [cam], masks, render_depth=render_depth, **kwargs)
    full = object_view_targets(images, [cam], masks, depths=whole, **kwargs)
    assert len(asked) == 1 and asked[0][0] * asked[0][1] < 96 * 80 / 3
    assert torch.equal(cropped.weights[0], full.weights[0])
    assert (full.weights[0] == 0).sum() > 20  # the wall in front hides part of the outline


def test_finetune_fits_targets_follows_the_schedule_and_leaves_the_input_alone():
    obj, _, images, cams, masks = tiny_refine_inputs()
    before = obj.copy()
    tinted = images.clone()
    tinted[masks] = torch.tensor([0.2, 0.2, 0.8])  # the object should turn blue
    originals = object_view_targets(tinted, cams, masks)
    inpainted = ViewTargets(cams[:2], originals.images[:2], torch.ones(2, 24, 24))
    res = finetune_object(obj, originals, inpainted, FinetuneConfig(iterations=30))
    assert np.array_equal(obj.sh_dc, before.sh_dc) and np.array_equal(obj.means, before.means)
    assert res.perceptual in ("laplacian", "lpips") and len(res.history) == 30
    with_inpaint = [h["step"] for h in res.history if "l1_inpainted" in h]
    assert with_inpaint == [float(s) for s in range(2, 31, 2)]  # every other iteration
    l1 = [h["l1_original"] for h in res.history]
    assert np.mean(l1[-5:]) < 0.97 * np.mean(l1[:5])  # 3DGS learning rates: 30 steps move colours a little
    with pytest.raises(ConfigError):
        FinetuneConfig(perceptual="ssim")


@pytest.mark.parametrize("kwargs,message", [
    ({"iterations": -1}, "iterations must be a whole number >= 0, got -1"),
    ({"inpaint_every": 0}, "inpaint_every must be a whole number >= 1"),
    ({"iterations": 2.5}, "iterations must be a whole number"),
    ({"perceptual_weight": -0.1}, "perceptual_weight must be a finite number >= 0"),
    ({"means_lr": -1e-4}, "means_lr must be a finite number >= 0"),
    ({"shN_lr": float("nan")}, "shN_lr must be a finite number >= 0"),
    ({"perceptual": "ssim"}, "perceptual must be one of auto, lpips, laplacian"),
    ({"background": (1.0, 1.0)}, "background must be 3 finite numbers"),
    ({"seed_opacity": 1.0}, "seed_opacity must be a finite number in (0, 1)"),
    ({"seed_min_difference": 1.0}, "seed_min_difference must be a finite number in [0, 1)"),
    ({"seed_holes": "yes"}, "seed_holes must be true or false"),
    ({"lpips_weights": 3}, "lpips_weights must be text or None"),
])
def test_finetune_settings_outside_their_declared_range_are_refused_by_name(kwargs, message):
    with pytest.raises(ConfigError) as err:
        FinetuneConfig(**kwargs)
    assert str(err.value).startswith(message), str(err.value)


def test_finetune_settings_are_declared_with_their_defaults_and_listed_in_the_docstring():
    from dataclasses import fields

    from roodi_toolkit.settings import declared

    assert [d.name for d in declared(FinetuneConfig)] == [f.name for f in fields(FinetuneConfig)]
    config = FinetuneConfig(iterations=0, inpaint_every=1, seed_opacity=0.01, seed_min_difference=0.0,
                            lpips_weights="w.pth", seed=-3)
    assert (config.iterations, config.seed) == (0, -3)
    assert (FinetuneConfig().iterations, FinetuneConfig().shN_lr, FinetuneConfig().background) == \
        (100, 2.5e-3 / 20, (1.0, 1.0, 1.0))
    doc = FinetuneConfig.__doc__
    assert "iterations: Fine-tuning steps. (default 100; a whole number >= 0; --iterations)" in doc
    assert doc.count("Attributes:") == 1 and "seed_min_difference: A pixel counts as filled" in doc


def test_refine_writes_the_debug_images(tmp_path):
    obj, scene, images, cams, masks = tiny_refine_inputs()
    res = refine_object(obj, scene, images, cams, masks, occlusion=OcclusionConfig(size=24),
                        finetune=FinetuneConfig(iterations=2))
    write_refine_debug(res, tmp_path)
    names = {p.name for p in tmp_path.iterdir()}
    for k in range(4):
        assert {f"view_{k}_object.png", f"view_{k}_scene.png", f"view_{k}_mask.png", f"view_{k}_inpainted.png",
                f"view_{k}_object_before_after.png"} <= names
    assert {"grid_before.png", "grid_mask.png", "grid_after.png", "object_before_after.png", "refine.json"} <= names
    assert res.inpainter == "opencv" and res.inpainted.shape == (4, 24, 24, 3)
    with pytest.raises(ConfigError, match="2x2"):
        refine_object(obj, scene, images, cams, masks, occlusion=OcclusionConfig(size=24, num_views=3))


def test_hole_seeds_go_where_an_occluder_hides_a_filled_hole():
    """One 16x16 view of an object at depth 5 whose right half is missing: seeds only where the inpainter filled it
    and something in the scene is in front, at the visible surface's depth, with the filled colour."""
    cam = Camera(look_at([0, 0, -5], [0, 0, 0], up=[0, 1, 0]), intrinsics_from_fov(0.6, 16, 16), 16, 16)
    alpha = torch.zeros(1, 16, 16)
    alpha[0, 4:12, 4:8] = 1.0
    depth = alpha * 5.0
    scene_depth = torch.zeros(1, 16, 16)
    scene_depth[0, :, 8:] = 3.0  # an occluder in front of the right half ...
    scene_depth[0, 12:, :] = 0.0  # ... but nothing in front of the bottom rows
    inpainted = torch.ones(1, 16, 16, 3)
    inpainted[0, 4:14, 8:12] = torch.tensor([0.9, 0.1, 0.1])  # the fill: red right of the object
    mask = alpha < 0.5
    occ = OcclusionResult([cam], torch.ones(1, 16, 16, 3), alpha, depth, torch.ones(1, 16, 16, 3), scene_depth,
                          torch.zeros_like(mask), torch.zeros_like(mask), mask, np.zeros(3), 1.0)
    obj = GaussianCloud.from_activated(np.zeros((2, 3)), scales=np.full((2, 3), 0.1), opacities=np.full(2, 0.9),
                                       rgb=np.full((2, 3), 0.5), sh_degree=1, extras={"f_0": np.ones(2, np.float32)})
    seeds = seed_hole_gaussians(obj, occ, inpainted, stride=2, opacity=0.4)
    uv, z = cam.project(seeds.means)
    assert len(seeds) == 2 * 4  # rows 4, 6, 8, 10 (not 12: nothing in front) x columns 8, 10
    assert np.allclose(z, 5.0, atol=1e-4) and (uv[:, 0] > 8).all() and (uv[:, 1] < 12).all()
    assert np.allclose(seeds.rgb, [0.9, 0.1, 0.1], atol=1e-5) and np.allclose(seeds.opacities, 0.4)
    assert seeds.sh_degree == 1 and list(seeds.extras) == ["f_0"] and (seeds.extras["f_0"] == 0).all()
    GaussianCloud.concatenate([obj, seeds])  # same columns: the refinement can join them
    # nothing filled: no seeds
    assert len(seed_hole_gaussians(obj, occ, torch.ones(1, 16, 16, 3))) == 0


def test_refine_with_hole_seeding_adds_gaussians_and_records_them(tmp_path):
    obj, scene, images, cams, masks = tiny_refine_inputs()
    res = refine_object(obj, scene, images, cams, masks, occlusion=OcclusionConfig(size=24),
                        finetune=FinetuneConfig(iterations=2, seed_holes=True, seed_stride=1))
    write_refine_debug(res, tmp_path)
    record = __import__("json").loads((tmp_path / "refine.json").read_text())
    assert record["seeded_gaussians"] > 0 and len(res.cloud) == len(obj) + record["seeded_gaussians"]
    with pytest.raises(ConfigError, match="seed_stride"):
        FinetuneConfig(seed_stride=0)


@pytest.fixture(scope="module")
def picnic_refinement():
    """benchmarks/bench_inpaint.py's default run (picnic 0, basket_3): about 20 s on a quiet 2-core machine."""
    sys.path.insert(0, str(REPO))
    from benchmarks.bench_inpaint import run

    return run()


@pytest.mark.slow
def test_generated_scene_masks_and_unoccluded_views_stay(picnic_refinement):
    out = picnic_refinement
    before, after = out["psnr"]["before"], out["psnr"]["after"]
    assert out["occlusion_opened"]["recall"] > 0.9 and out["occlusion_opened"]["precision"] > 0.5
    assert after["unoccluded_train_psnr"] >= before["unoccluded_train_psnr"] - 0.5


@pytest.mark.slow
@pytest.mark.xfail(strict=False, reason="issue 9 open: with the classical opencv inpainter the hidden pixels gain "
                   "only ~0.001-0.01 dB (the fills cannot know the hidden colours); see benchmarks/RESULTS.md")
def test_generated_scene_occluded_views_improve(picnic_refinement):
    before, after = picnic_refinement["psnr"]["before"], picnic_refinement["psnr"]["after"]
    assert after["occluded_hidden_psnr"] >= before["occluded_hidden_psnr"] + 0.1
