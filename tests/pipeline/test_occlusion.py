"""Occlusion reasoning: cameras, the depth test, the opening, the background in the mask, and the masks of a
generated scene against the hidden parts its mesh renderer knows."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from roodi_toolkit.cameras import Camera, intrinsics_from_fov, look_at
from roodi_toolkit.errors import CloudError, ConfigError
from roodi_toolkit.gaussians import GaussianCloud
from roodi_toolkit.pipeline.occlusion import (OcclusionConfig, mask_scores, morphological_opening, object_cameras,
                                     object_extent, occlusion_masks, up_from_cameras)
from roodi_toolkit.run.refine import write_occlusion_images

from ..mesh_gaussians import hidden_truth, mesh_cloud, nearby


def blob(centre, n=600, radius=0.5, seed=0, color=(0.8, 0.2, 0.2), flat_axis=None):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    if flat_axis is None:
        pts = d / np.linalg.norm(d, axis=1, keepdims=True) * radius  # a sphere's surface
    else:
        pts = rng.uniform(-radius, radius, size=(n, 3))
        pts[:, flat_axis] = 0  # a square card
    return GaussianCloud.from_activated(pts + np.asarray(centre), scales=np.full((n, 3), 0.06),
                                        opacities=np.full(n, 0.9), rgb=np.tile(color, (n, 1)))


def test_cameras_surround_the_object_from_above_and_frame_it():
    cfg = OcclusionConfig(size=40, seed=3)
    cams = object_cameras([1.0, 2.0, 0.5], 0.4, cfg, up=(0, 0, 1))
    assert len(cams) == 4 and all(c.width == c.height == 40 for c in cams)
    centre = np.array([1.0, 2.0, 0.5])
    az = []
    for c in cams:
        uv, z = c.project(centre[None])
        np.testing.assert_allclose(uv[0], [20, 20], atol=1e-6)  # looks at the centre
        v = c.center - centre
        assert v[2] > 0 and math.degrees(math.asin(v[2] / np.linalg.norm(v))) <= 60 + 1e-6  # upper hemisphere
        # the bounding sphere fits the view: its angular radius is at most half the field of view
        assert math.asin(0.4 / np.linalg.norm(v)) <= math.radians(cfg.fov_deg) / 2 + 1e-9
        az.append(math.atan2(v[1], v[0]))
    gaps = np.diff(np.sort(np.mod(az, 2 * math.pi)))
    assert gaps.min() > math.radians(20)  # one per sector: spread around the object
    again = object_cameras([1.0, 2.0, 0.5], 0.4, cfg)
    assert all(np.array_equal(a.world_to_camera, b.world_to_camera) for a, b in zip(cams, again))  # seeded
    other = object_cameras([1.0, 2.0, 0.5], 0.4, OcclusionConfig(size=40, seed=4))
    assert not np.allclose(cams[0].world_to_camera, other[0].world_to_camera)


def test_cameras_follow_another_up_axis():
    cams = object_cameras([0, 0, 0], 1.0, OcclusionConfig(size=16), up=(0, 1, 0))
    assert all(c.center[1] > 0 for c in cams)
    assert np.allclose(up_from_cameras(cams) @ np.array([0, 1, 0]) > 0.5, True)


def test_a_card_between_camera_and_object_is_in_the_mask():
    """A known occluder: a card halfway between the camera and the object's left half."""
    obj = blob([0, 0, 0], radius=0.5)
    cam = Camera(look_at([0, -3, 0], [0, 0, 0]), intrinsics_from_fov(math.radians(40), 64, 64), 64, 64)
    card = blob([-0.3, -1.5, 0], n=800, radius=0.25, flat_axis=1, color=(0.1, 0.8, 0.1))
    scene = GaussianCloud.concatenate([obj, card])
    cfg = OcclusionConfig(size=64, opening_size=5, opening_reference=0)
    res = occlusion_masks(obj, scene, [cam], cfg)
    # where the card covers the object (both rendered alone), the mask must be set
    card_alpha = occlusion_masks(card, card, [cam], cfg).object_alpha[0]
    covered = (card_alpha > 0.9) & (res.object_alpha[0] > 0.9)
    assert covered.sum() > 100
    assert res.occluded[0][covered].float().mean() > 0.95
    # and not where the object is in plain view
    free = (card_alpha < 0.01) & (res.object_alpha[0] > 0.9)
    assert res.occluded[0][free].float().mean() < 0.02
    # the background is part of the inpainting mask, the visible object is not
    assert res.mask[0][res.object_alpha[0] < 0.5].all()
    assert not res.mask[0][free].any()


def test_behind_is_not_occluding():
    obj = blob([0, 0, 0], radius=0.5)
    wall = blob([0, 2.0, 0], n=1500, radius=1.5, flat_axis=1, color=(0.2, 0.2, 0.9))
    cam = Camera(look_at([0, -3, 0], [0, 0, 0]), intrinsics_from_fov(math.radians(40), 48, 48), 48, 48)
    res = occlusion_masks(obj, GaussianCloud.concatenate([obj, wall]), [cam], OcclusionConfig(size=48))
    assert not res.occluded_raw.any()


def test_opening_removes_specks_and_keeps_blocks():
    m = torch.zeros(2, 40, 40, dtype=torch.bool)
    m[0, 5:25, 5:25] = True
    m[0, 30, 30] = True
    m[1, 0:3, :] = True  # a thin strip: narrower than the element, removed
    out = morphological_opening(m, 17)
    assert out[0, 5:25, 5:25].all() and out[0].sum() == 400
    assert not out[1].any()
    assert torch.equal(morphological_opening(m, 1), m)


def test_opening_scales_with_the_view_size():
    assert OcclusionConfig(size=512).effective_opening == 17
    assert OcclusionConfig(size=1024).effective_opening == 35
    assert OcclusionConfig(size=96).effective_opening == 3
    assert OcclusionConfig(size=96, opening_reference=0).effective_opening == 17


@pytest.mark.parametrize("kwargs,message", [
    ({"num_views": 0}, "num_views must be a whole number >= 1, got 0"),
    ({"size": 7}, "size must be a whole number in [8, 4096], got 7"),
    ({"size": 4097}, "size must be a whole number in [8, 4096]"),
    ({"fov_deg": 0.5}, "fov_deg must be a finite number in [1, 150]"),
    ({"margin": 0.0}, "margin must be a finite number > 0"),
    ({"elevation_deg": (10.0, float("inf"))}, "elevation_deg must be 2 finite numbers"),
    ({"elevation_deg": (50.0, 10.0)}, "elevation_deg must be lo,hi with -90 <= lo <= hi <= 90"),
    ({"depth_tolerance": -0.01}, "depth_tolerance must be a finite number >= 0"),
    ({"alpha_threshold": 1.0}, "alpha_threshold must be a finite number in (0, 1)"),
    ({"opening_size": 0}, "opening_size must be a whole number >= 1"),
    ({"opening_size": 16}, "opening_size must be odd, got 16"),
    ({"opening_reference": -512}, "opening_reference must be a whole number >= 0"),
    ({"seed": -1}, "seed must be a whole number >= 0, got -1"),  # numpy's generator takes no negative seed
])
def test_occlusion_settings_outside_their_declared_range_are_refused_by_name(kwargs, message):
    with pytest.raises(ConfigError) as err:
        OcclusionConfig(**kwargs)
    assert str(err.value).startswith(message), str(err.value)


def test_occlusion_settings_are_declared_and_the_view_size_is_an_option():
    from dataclasses import fields

    from roodi_toolkit.settings import declared

    settings = {d.name: d for d in declared(OcclusionConfig)}
    assert list(settings) == [f.name for f in fields(OcclusionConfig)]
    assert [name for name, d in settings.items() if d.meta.cli] == ["size"]
    assert settings["size"].option == "--view-size"
    assert OcclusionConfig(size=8, opening_size=1, opening_reference=0, elevation_deg=(-90, 90)).size == 8
    assert "size: Side in pixels of the four object-centred views" in OcclusionConfig.__doc__


def test_bad_settings_and_empty_object():
    with pytest.raises(ConfigError):
        OcclusionConfig(opening_size=16)
    with pytest.raises(ConfigError):
        OcclusionConfig(elevation_deg=(50, 10))
    empty = blob([0, 0, 0]).select(np.zeros(600, bool))
    with pytest.raises(CloudError):
        object_extent(empty)


def test_masks_are_written_as_images(tmp_path):
    obj = blob([0, 0, 0])
    res = occlusion_masks(obj, obj, None, OcclusionConfig(size=24))
    paths = write_occlusion_images(res, tmp_path)
    names = {p.name for p in paths}
    assert {"view_0_mask.png", "view_3_occluded.png", "view_2_object.png", "view_1_scene.png"} <= names
    from roodi_toolkit.io.files import read_image

    mask = read_image(tmp_path / "view_0_mask.png")
    assert mask.shape == (24, 24) and set(np.unique(mask)) <= {0, 255}


def test_generated_scene_masks_match_the_hidden_truth():
    """picnic seed 0, basket_3: about 6% of its object-centred views are hidden by its neighbours."""
    from roodi_toolkit.synth.scene import build_scene

    scene = build_scene("picnic", 0)
    target = next(o for o in scene.targets if o.name == "basket_3")
    obj = mesh_cloud([target])
    centre, radius = object_extent(obj)
    cfg = OcclusionConfig(size=48)
    reach = radius / math.sin(math.radians(cfg.fov_deg) / 2) * cfg.margin + radius
    full = GaussianCloud.concatenate([obj, mesh_cloud(nearby(scene, target, reach), seed=1)])
    res = occlusion_masks(obj, full, None, cfg)
    truth = hidden_truth(scene, target, res.cameras)
    assert truth.mean() > 0.02  # the check means something: part of the target is hidden
    s = mask_scores(res.occluded.numpy(), truth)
    assert s["recall"] > 0.9 and s["precision"] > 0.5, s
    # the full inpainting mask (occluded + background) covers every hidden pixel of the target
    assert mask_scores(res.mask.numpy(), truth)["recall"] > 0.97
